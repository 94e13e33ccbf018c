//! A minimal client of the GDB remote serial protocol, enough to inject upsets into the
//! firmware through QEMU's gdbstub (`-gdb tcp::PORT`): halt, continue, single-step,
//! breakpoints, registers and memory. (The `gdbstub` crate is a server; this is the other
//! end.)
//!
//! QEMU stops the guest when a client connects, answers `p`/`P` (one register) only after
//! the client has read the target description, and lays out the Cortex-M registers as
//! r0–r15 (numbers 0–15), xPSR (25), d0–d15 (26–41, 64 bits each) and FPSCR (42).
//! Packets are acknowledged (`+`) both ways; the socket has Nagle's algorithm off, or each
//! exchange waits for a delayed acknowledgement (about 40 ms).
//!
//! Device registers: QEMU's gdbstub writes guest memory as a debugger's ROM load
//! (`address_space_write_rom`), which writes RAM and ROM and drops a write to a device
//! (the SysTick's, a UART's): [`Gdb::write_memory`] cannot reach them.
//! [`Gdb::write_device_u32`] and [`Gdb::read_device_u32`] make the guest's own CPU do the
//! access, one `str`/`ldr` single-stepped at the halted PC.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// Register number of the program counter.
pub const PC: u32 = 15;
/// Register number of the stack pointer.
pub const SP: u32 = 13;
/// Register number of xPSR.
pub const XPSR: u32 = 25;
/// Register number of d0 (d0–d15 follow).
pub const D0: u32 = 26;
/// Register number of FPSCR.
pub const FPSCR: u32 = 42;

/// Thumb `str r0, [r1]` (STR immediate, encoding T1, offset 0; ARMv7-M A7.7.158).
const STR_R0_AT_R1: u16 = 0x6008;
/// Thumb `ldr r0, [r1]` (LDR immediate, encoding T1, offset 0; ARMv7-M A7.7.42).
const LDR_R0_AT_R1: u16 = 0x6808;
/// Thumb `cpsid i` (CPS, encoding T1; ARMv7-M B5.2.1): PRIMASK set.
const CPSID_I: u16 = 0xb672;
/// xPSR's IT bits (EPSR ICI/IT[7:2] in 15:10, IT[1:0] in 26:25): cleared while the access
/// is stepped, or an IT block the guest was halted in would make it conditional.
const XPSR_IT_MASK: u32 = 0x0600_fc00;

/// Largest memory block read or written in one packet, bytes (QEMU's packet is 4 KiB of
/// hexadecimal).
const MEM_CHUNK: usize = 0x7f0;

/// A connection to a gdbstub.
pub struct Gdb {
    s: TcpStream,
    buf: Vec<u8>,
}

impl Gdb {
    /// Connects to the gdbstub on `127.0.0.1:port` (retrying for up to `wait`) and reads the
    /// target description (QEMU halts the guest on connect: [`Gdb::resume`] lets it run).
    pub fn connect(port: u16, wait: Duration) -> Result<Gdb> {
        let t0 = Instant::now();
        let s = loop {
            match TcpStream::connect(("127.0.0.1", port)) {
                Ok(s) => break s,
                Err(e) if t0.elapsed() < wait => {
                    let _ = e;
                    std::thread::sleep(Duration::from_millis(20));
                }
                Err(e) => return Err(e).with_context(|| format!("cannot connect to QEMU's gdbstub on port {port}")),
            }
        };
        s.set_nodelay(true)?;
        let mut g = Gdb { s, buf: Vec::new() };
        g.command("qSupported:swbreak+;xmlRegisters=arm")?;
        g.command("qXfer:features:read:target.xml:0,ffb")?;
        // The stop QEMU makes on a debugger's attach, reported before anything else is
        // sent: a `c` that overtook it would leave the machine paused.
        g.send("?")?;
        g.wait_stop(wait)?.context("gdbstub: no stop reply to `?`")?;
        Ok(g)
    }

    fn send(&mut self, data: &str) -> Result<()> {
        let sum = data.bytes().fold(0u8, |a, b| a.wrapping_add(b));
        let p = format!("${data}#{sum:02x}");
        if std::env::var_os("SSIS_GDB_TRACE").is_some() {
            eprintln!("gdb -> {data:.80}");
        }
        self.s.write_all(p.as_bytes())?;
        Ok(())
    }

    /// The next packet's payload (acknowledged), waiting at most `timeout` (`None`: no
    /// packet in time).
    fn receive(&mut self, timeout: Duration) -> Result<Option<String>> {
        let t0 = Instant::now();
        // A zero timeout still reads what has arrived (one read of at most 1 ms).
        let mut read_once = false;
        loop {
            if let Some(i) = self.buf.iter().position(|&b| b == b'$') {
                if let Some(j) = self.buf[i..].iter().position(|&b| b == b'#').map(|j| i + j) {
                    if self.buf.len() >= j + 3 {
                        let payload = String::from_utf8_lossy(&self.buf[i + 1..j]).into_owned();
                        self.buf.drain(..j + 3);
                        self.s.write_all(b"+")?;
                        if std::env::var_os("SSIS_GDB_TRACE").is_some() {
                            eprintln!("gdb <- {payload:.80}");
                        }
                        return Ok(Some(payload));
                    }
                }
            }
            let left = timeout.saturating_sub(t0.elapsed());
            if left.is_zero() && read_once {
                return Ok(None);
            }
            read_once = true;
            self.s.set_read_timeout(Some(left.max(Duration::from_millis(1))))?;
            let mut chunk = [0u8; 8192];
            match self.s.read(&mut chunk) {
                Ok(0) => bail!("QEMU's gdbstub closed the connection"),
                Ok(n) => self.buf.extend_from_slice(&chunk[..n]),
                // Interrupted: the runner stopped and continued (SIGSTOP, SIGCONT) in a read
                // with a timeout, which the kernel does not restart.
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Sends a packet and returns the reply, skipping console output (`O…`) and stop
    /// replies (`T…`: QEMU sends one of its own when a client connects, before the reply to
    /// the first packet; no command used here answers with one).
    pub fn command(&mut self, data: &str) -> Result<String> {
        self.send(data)?;
        loop {
            let r = self.receive(Duration::from_secs(10))?.with_context(|| format!("gdbstub: no reply to {data}"))?;
            let console = r.starts_with('O') && r.len() > 1 && r != "OK";
            if !console && !r.starts_with('T') {
                return Ok(r);
            }
        }
    }

    /// A command of QEMU's monitor (`qRcmd`); its printed output.
    pub fn monitor(&mut self, cmd: &str) -> Result<String> {
        self.send(&format!("qRcmd,{}", hex_encode(cmd.as_bytes())))?;
        let mut out = Vec::new();
        loop {
            let r = self
                .receive(Duration::from_secs(10))?
                .with_context(|| format!("gdbstub: no reply to monitor {cmd}"))?;
            match r.strip_prefix('O') {
                Some(h) if r != "OK" => out.extend(hex_decode(h).unwrap_or_default()),
                _ if r.starts_with('T') => {}
                _ => {
                    anyhow::ensure!(r == "OK", "gdbstub: monitor {cmd}: {r}");
                    return Ok(String::from_utf8_lossy(&out).into_owned());
                }
            }
        }
    }

    /// Saves the halted guest's whole state to `path` (QEMU's migration to a file: start
    /// another QEMU with `-incoming exec:cat PATH`), waiting until it is written.
    pub fn save_state(&mut self, path: &std::path::Path) -> Result<()> {
        self.monitor(&format!("migrate \"exec:cat > {}\"", path.display()))?;
        let t0 = Instant::now();
        loop {
            let st = self.monitor("info migrate")?;
            if st.contains("status: completed") {
                return Ok(());
            }
            anyhow::ensure!(
                !st.contains("status: failed") && t0.elapsed() < Duration::from_secs(60),
                "QEMU's migration to {} did not complete: {st}",
                path.display()
            );
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    fn ok(&mut self, data: &str) -> Result<()> {
        let r = self.command(data)?;
        anyhow::ensure!(r == "OK", "gdbstub refused {data}: {r}");
        Ok(())
    }

    /// Halts a running guest and waits for its stop reply.
    pub fn halt(&mut self) -> Result<()> {
        self.s.write_all(&[0x03])?;
        self.wait_stop(Duration::from_secs(10))?.context("gdbstub: the guest did not halt")?;
        Ok(())
    }

    /// Resumes the guest (the stop reply comes later: [`Gdb::wait_stop`]).
    pub fn resume(&mut self) -> Result<()> {
        self.send("c")
    }

    /// Resumes a guest stopped at its breakpoint at `addr`: QEMU stops there again at
    /// once unless the instruction is stepped over first (the breakpoint lifted for
    /// one step, then set again).
    pub fn resume_past(&mut self, addr: u32) -> Result<()> {
        self.clear_breakpoint(addr)?;
        self.step()?;
        self.set_breakpoint(addr)?;
        self.resume()
    }

    /// Waits up to `timeout` for a stop reply (`T…`/`S…`; `W`/`X`: the guest ended).
    pub fn wait_stop(&mut self, timeout: Duration) -> Result<Option<String>> {
        let t0 = Instant::now();
        loop {
            let left = timeout.saturating_sub(t0.elapsed());
            match self.receive(left)? {
                Some(r) if r.starts_with(['T', 'S', 'W', 'X']) => return Ok(Some(r)),
                Some(_) => {}
                None => return Ok(None),
            }
        }
    }

    /// Executes one instruction (interrupts held off, QEMU's default).
    pub fn step(&mut self) -> Result<()> {
        self.send("s")?;
        self.wait_stop(Duration::from_secs(10))?.context("gdbstub: no stop after a single step")?;
        Ok(())
    }

    /// Sets a breakpoint at `addr` (a Thumb instruction).
    pub fn set_breakpoint(&mut self, addr: u32) -> Result<()> {
        self.ok(&format!("Z0,{addr:x},2"))
    }

    /// Removes the breakpoint at `addr`.
    pub fn clear_breakpoint(&mut self, addr: u32) -> Result<()> {
        self.ok(&format!("z0,{addr:x},2"))
    }

    /// Register `n` as its little-endian bytes (4, or 8 for d0–d15).
    pub fn read_register(&mut self, n: u32) -> Result<Vec<u8>> {
        let r = self.command(&format!("p{n:x}"))?;
        hex_decode(&r).with_context(|| format!("gdbstub: register {n}: {r}"))
    }

    /// Writes register `n` (little-endian bytes).
    pub fn write_register(&mut self, n: u32, bytes: &[u8]) -> Result<()> {
        self.ok(&format!("P{n:x}={}", hex_encode(bytes)))
    }

    /// A 32-bit register.
    pub fn register_u32(&mut self, n: u32) -> Result<u32> {
        let b = self.read_register(n)?;
        let a: [u8; 4] = b.get(..4).and_then(|s| s.try_into().ok()).context("gdbstub: short register")?;
        Ok(u32::from_le_bytes(a))
    }

    /// `len` bytes of memory at `addr`.
    pub fn read_memory(&mut self, addr: u32, len: usize) -> Result<Vec<u8>> {
        let mut out = Vec::with_capacity(len);
        while out.len() < len {
            let n = (len - out.len()).min(MEM_CHUNK);
            let a = addr + out.len() as u32;
            let r = self.command(&format!("m{a:x},{n:x}"))?;
            let b = hex_decode(&r).with_context(|| format!("gdbstub: memory at {a:#x}: {r}"))?;
            anyhow::ensure!(b.len() == n, "gdbstub: memory at {a:#x}: {} bytes of {n}", b.len());
            out.extend_from_slice(&b);
        }
        Ok(out)
    }

    /// Writes `bytes` at `addr` (RAM or ROM: a device register's write is dropped, see
    /// [`Gdb::write_device_u32`]).
    pub fn write_memory(&mut self, addr: u32, bytes: &[u8]) -> Result<()> {
        self.ok(&format!("M{addr:x},{:x}:{}", bytes.len(), hex_encode(bytes)))
    }

    /// Writes the 32-bit word `value` to `addr` with the guest's own `str`, so that a
    /// device register (the SysTick's, the NVIC's, a peripheral's) takes it, which
    /// [`Gdb::write_memory`] cannot do ([`Gdb::guest_access`]). The guest must be halted
    /// at an instruction (a breakpoint, a step, `-S`), not asleep in `wfi`.
    pub fn write_device_u32(&mut self, addr: u32, value: u32) -> Result<()> {
        self.guest_access(STR_R0_AT_R1, addr, value).map(|_| ())
    }

    /// The 32-bit word at `addr` read with the guest's own `ldr` (a device register as the
    /// CPU sees it; [`Gdb::write_device_u32`]'s conditions).
    pub fn read_device_u32(&mut self, addr: u32) -> Result<u32> {
        self.guest_access(LDR_R0_AT_R1, addr, 0)
    }

    /// Sets PRIMASK with the guest's own `cpsid i` (interrupts of configurable priority
    /// masked; the NMI and HardFault are not); [`Gdb::write_device_u32`]'s conditions.
    pub fn mask_interrupts(&mut self) -> Result<()> {
        self.guest_access(CPSID_I, 0, 0).map(|_| ())
    }

    /// Runs the Thumb instruction `insn` (an access through r0 at [r1]) once in the halted
    /// guest: saves r0, r1, SP, LR, PC, xPSR and the two bytes at PC; writes `insn` at PC,
    /// r0 = `r0`, r1 = `addr`, xPSR without its IT bits; single-steps (interrupts held off,
    /// QEMU's default); restores the bytes and the registers. Returns r0 after the step
    /// (what an `ldr` read). An access that faults (PC not advanced by 2: the fault's
    /// handler entered) is an error; the registers are restored, the fault's active state
    /// is not.
    fn guest_access(&mut self, insn: u16, addr: u32, r0: u32) -> Result<u32> {
        let saved: Vec<(u32, Vec<u8>)> = [0, 1, SP, 14, PC, XPSR]
            .into_iter()
            .map(|n| self.read_register(n).map(|v| (n, v)))
            .collect::<Result<_>>()?;
        let pc = self.register_u32(PC)?;
        let xpsr = self.register_u32(XPSR)?;
        let code = self.read_memory(pc, 2)?;
        self.write_memory(pc, &insn.to_le_bytes())?;
        let stepped = (|| {
            self.write_register(XPSR, &(xpsr & !XPSR_IT_MASK).to_le_bytes())?;
            self.write_register(0, &r0.to_le_bytes())?;
            self.write_register(1, &addr.to_le_bytes())?;
            self.step()?;
            Ok::<_, anyhow::Error>((self.register_u32(0)?, self.register_u32(PC)?))
        })();
        self.write_memory(pc, &code)?;
        for (n, v) in &saved {
            self.write_register(*n, v)?;
        }
        let (out, pc_after) = stepped?;
        anyhow::ensure!(
            pc_after == pc.wrapping_add(2),
            "the guest's access at {addr:#x} from {pc:#x} faulted (PC then {pc_after:#x})"
        );
        Ok(out)
    }
}

fn hex_encode(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// Bytes from hexadecimal (`None`: an error reply such as `E14`, odd in length, or not
/// hexadecimal).
fn hex_decode(s: &str) -> Option<Vec<u8>> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len()).step_by(2).map(|i| s.get(i..i + 2).and_then(|h| u8::from_str_radix(h, 16).ok())).collect()
}

#[cfg(test)]
mod tests {
    #[test]
    fn hex_round_trip() {
        let b = [0u8, 1, 0xab, 0xff];
        assert_eq!(super::hex_decode(&super::hex_encode(&b)).as_deref(), Some(&b[..]));
        assert_eq!(super::hex_decode("E14"), None);
        assert_eq!(super::hex_decode("zz"), None);
    }
}

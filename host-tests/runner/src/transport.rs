//! How the runner reaches the unit's UARTs: a [`Port`] per UART, whatever carries it.
//!
//! - [`Transport::Sockets`]: QEMU's UARTs as Unix sockets the runner listens on;
//! - [`Transport::Pty`]: QEMU's UARTs as pseudo-terminals (`-serial pty`), opened through
//!   the real serial-port path ([`open_serial`], the `serialport` crate), exactly as the
//!   runner opens the USB–RS-422 adapters wired to the STM32H7 board
//!   (`boards/stm32h7/README.md`: USART1 output, USART2 FOG bus, USART3 star tracker);
//! - [`BoardPorts`]: no QEMU at all: serial ports the user names, to a unit that is
//!   already running (`ssis-qemu --board OUT,FOG,STAR`).
//!
//! Framing on the links (`docs/ICD.md`): [`BAUD`] baud, 8 data bits, no parity, one stop
//! bit, no flow control.

use std::io::{self, Read, Write};
use std::os::unix::net::UnixStream;
use std::time::Duration;

use anyhow::{Context, Result};

/// Line rate of every link, baud (the STM32H7 board's USARTs).
pub const BAUD: u32 = 921_600;

/// How the UARTs are carried.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum Transport {
    /// Unix sockets (QEMU `-chardev socket`).
    #[default]
    Sockets,
    /// Pseudo-terminals (QEMU `-serial pty`) through the serial-port path.
    Pty,
}

/// One UART as the runner sees it: bytes both ways, and a second handle for the thread
/// that reads it.
pub trait Port: Read + Write + Send {
    /// Another handle on the same UART.
    fn try_clone_port(&self) -> io::Result<Box<dyn Port>>;
}

impl Port for UnixStream {
    fn try_clone_port(&self) -> io::Result<Box<dyn Port>> {
        Ok(Box::new(self.try_clone()?))
    }
}

/// A serial port (a USB–RS-422 adapter, or a pseudo-terminal): reads wait for data
/// instead of timing out.
pub struct SerialLink {
    port: Box<dyn serialport::SerialPort>,
}

impl Read for SerialLink {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        loop {
            match self.port.read(buf) {
                Err(e) if e.kind() == io::ErrorKind::TimedOut || e.kind() == io::ErrorKind::Interrupted => continue,
                r => return r,
            }
        }
    }
}

impl Write for SerialLink {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.port.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.port.flush()
    }
}

impl Port for SerialLink {
    fn try_clone_port(&self) -> io::Result<Box<dyn Port>> {
        let port = self.port.try_clone().map_err(io::Error::other)?;
        Ok(Box::new(SerialLink { port }))
    }
}

/// A unit already running, reached over serial ports the user names: the STM32H7 board
/// through its USB–RS-422 adapters (`boards/stm32h7/README.md`), or QEMU started by hand
/// with `-serial pty` standing in for it. Each link at its baud rate, with the ICD's
/// framing ([`open_serial`]: 8 data bits, no parity, one stop bit, no flow control).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BoardPorts {
    /// (path, baud) of UART0 (output frames out, control frames in), UART1 (FOG bus) and
    /// UART2 (star tracker), in that order.
    pub links: [(String, u32); 3],
}

impl BoardPorts {
    /// From `OUT,FOG,STAR`: three port paths, each optionally `PATH@BAUD` (default
    /// [`BAUD`], the ICD's).
    pub fn parse(arg: &str) -> Result<BoardPorts> {
        let parts: Vec<&str> = arg.split(',').collect();
        let [out, fog, star] = parts[..] else {
            anyhow::bail!("--board: `{arg}`: give three ports, OUT,FOG,STAR (each PATH or PATH@BAUD)");
        };
        let link = |p: &str| -> Result<(String, u32)> {
            match p.rsplit_once('@') {
                Some((path, baud)) => {
                    let b: u32 =
                        baud.parse().with_context(|| format!("--board: `{p}`: baud `{baud}` is not a number"))?;
                    anyhow::ensure!(b > 0 && !path.is_empty(), "--board: `{p}`: a path and a baud above 0");
                    Ok((path.to_string(), b))
                }
                None if !p.is_empty() => Ok((p.to_string(), BAUD)),
                None => anyhow::bail!("--board: `{arg}`: an empty port"),
            }
        };
        Ok(BoardPorts { links: [link(out)?, link(fog)?, link(star)?] })
    }
}

/// Opens a serial port with the ICD's framing at `baud` (raw mode: no echo, no line
/// discipline).
pub fn open_serial(path: &str, baud: u32) -> Result<SerialLink> {
    let port = serialport::new(path, baud)
        .data_bits(serialport::DataBits::Eight)
        .parity(serialport::Parity::None)
        .stop_bits(serialport::StopBits::One)
        .flow_control(serialport::FlowControl::None)
        .timeout(Duration::from_secs(1))
        .open()
        .with_context(|| format!("cannot open serial port {path}"))?;
    Ok(SerialLink { port })
}

/// The pseudo-terminals QEMU names on its standard output for `-serial pty`, in the order
/// of its serial ports: lines `char device redirected to /dev/pts/N (label serialK)`.
/// Reads `out` line by line until `n` are found; the rest stays in `out`.
pub fn read_pty_names(out: &mut impl io::BufRead, n: usize) -> Result<Vec<String>> {
    let mut names = vec![String::new(); n];
    let mut found = 0;
    let mut line = Vec::new();
    while found < n {
        line.clear();
        if out.read_until(b'\n', &mut line)? == 0 {
            anyhow::bail!("QEMU ended its output before naming {n} pseudo-terminals ({found} named)");
        }
        let text = String::from_utf8_lossy(&line);
        if let Some((path, label)) = parse_pty_line(&text) {
            if let Some(k) = label.strip_prefix("serial").and_then(|k| k.parse::<usize>().ok()).filter(|&k| k < n) {
                names[k] = path.to_string();
                found += 1;
            }
        }
    }
    Ok(names)
}

/// `char device redirected to PATH (label LABEL)` → (PATH, LABEL).
pub fn parse_pty_line(line: &str) -> Option<(&str, &str)> {
    let rest = line.trim().strip_prefix("char device redirected to ")?;
    let (path, label) = rest.split_once(" (label ")?;
    Some((path, label.strip_suffix(')')?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn board_ports_parse_paths_and_bauds_and_refuse_the_rest() {
        let b = BoardPorts::parse("/dev/ttyUSB0,/dev/ttyUSB1@460800,/dev/pts/3").expect("parses");
        assert_eq!(
            b.links,
            [("/dev/ttyUSB0".into(), BAUD), ("/dev/ttyUSB1".into(), 460_800), ("/dev/pts/3".into(), BAUD)]
        );
        for bad in [
            "/dev/a,/dev/b",
            "/dev/a,/dev/b,/dev/c,/dev/d",
            "/dev/a,,/dev/c",
            "/dev/a@fast,/dev/b,/dev/c",
            "/dev/a@0,/dev/b,/dev/c",
        ] {
            let e = BoardPorts::parse(bad).expect_err(bad).to_string();
            assert!(e.starts_with("--board:"), "{bad}: {e}");
        }
    }
}

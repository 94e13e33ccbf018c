//! Timeouts that follow the emulated unit's progress, not the wall clock.
//!
//! On a busy host the runner and QEMU may each wait seconds for a core. A timeout in wall
//! time then fails a run in which nothing is wrong. Every wait on QEMU here is instead
//! bounded by the processor time QEMU itself has used since the wait began: a firmware
//! that is stuck keeps QEMU busy (lockstep runs use `-icount …,sleep=off`, where an idle
//! guest's virtual time jumps from timer to timer, so even a firmware asleep in `wfi`
//! costs QEMU processor time), while a QEMU that is merely not scheduled uses none. A
//! wall-time cap ([`WALL_CAP`]) remains as the last resort.

use std::process::Child;
use std::time::{Duration, Instant};

/// The `-icount` setting of every lockstep run: one instruction per ns of virtual time
/// (SysTick differences are instruction counts), and an idle guest's virtual time jumps
/// to its next timer deadline instead of following the host's clock. Virtual time then
/// moves only as the guest executes: a stalled QEMU process cannot make the watchdog
/// fire, and a slow runner costs no virtual time the firmware would notice.
pub const ICOUNT_LOCKSTEP: &str = "shift=0,sleep=off";

/// QEMU processor time a wait allows before it gives up, s (an idle lockstep guest jumps
/// through thousands of timer periods per processor second; a boot takes well under
/// one).
pub const QEMU_CPU_PATIENCE_S: f64 = 20.0;

/// Wall time after which any wait gives up, whatever QEMU's state.
pub const WALL_CAP: Duration = Duration::from_secs(30 * 60);

/// Wall time after which a wait ends if QEMU has used no processor time in it (a running
/// guest always uses some; a paused machine none).
pub const IDLE_CAP: Duration = Duration::from_secs(120);

/// User plus system time of process `pid` so far, s (Linux `/proc/PID/stat`); `None`
/// where it cannot be read.
pub fn process_cpu_s(pid: u32) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) in parentheses: state is the
    // 3rd field of the line, utime the 14th, stime the 15th.
    let rest = stat.rsplit_once(')')?.1;
    let mut f = rest.split_whitespace().skip(11);
    let utime: u64 = f.next()?.parse().ok()?;
    let stime: u64 = f.next()?.parse().ok()?;
    // SAFETY: sysconf only reads a configuration value.
    let hz = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    (hz > 0).then(|| (utime + stime) as f64 / hz as f64)
}

/// A wait on one QEMU process: how much it has been given, and whether it is used up.
pub struct Patience {
    pid: u32,
    cpu0_s: Option<f64>,
    wall0: Instant,
    cpu_s: f64,
}

impl Patience {
    /// A wait starting now that allows `cpu_s` of `child`'s processor time (or, where that
    /// cannot be read, `cpu_s` of wall time).
    pub fn new(child: &Child, cpu_s: f64) -> Patience {
        let pid = child.id();
        Patience { pid, cpu0_s: process_cpu_s(pid), wall0: Instant::now(), cpu_s }
    }

    /// A wait of `s` of wall time (a board: no process to count).
    pub fn wall_clock(s: f64) -> Patience {
        Patience { pid: 0, cpu0_s: None, wall0: Instant::now(), cpu_s: s }
    }

    /// QEMU's processor time since the wait began, s (wall time where not readable).
    pub fn cpu_used_s(&self) -> f64 {
        match (self.cpu0_s, process_cpu_s(self.pid)) {
            (Some(a), Some(b)) => b - a,
            _ => self.wall0.elapsed().as_secs_f64(),
        }
    }

    /// Why the wait is over, if it is: QEMU used its allowance, or the wall cap passed.
    pub fn exhausted(&self) -> Option<String> {
        let used = self.cpu_used_s();
        let wall = self.wall0.elapsed();
        if used >= self.cpu_s {
            Some(format!(
                "QEMU used {used:.1} s of processor time ({:.1} s of wall time) without it",
                wall.as_secs_f64()
            ))
        } else if wall >= IDLE_CAP && self.cpu0_s.is_some() && used < 0.05 {
            Some(format!(
                "QEMU used no processor time in {:.0} s of wall time: its guest is not running",
                wall.as_secs_f64()
            ))
        } else if wall >= WALL_CAP {
            Some(format!("{:.0} s of wall time passed (QEMU used {used:.1} s of processor time)", wall.as_secs_f64()))
        } else {
            None
        }
    }

    /// Wall time since the wait began.
    pub fn wall(&self) -> Duration {
        self.wall0.elapsed()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn own_processor_time_is_read_and_grows_with_work() {
        // A fixed amount of work (about 0.3 s of one core), however long the host takes
        // to give it: the reading must grow by about that much.
        let me = std::process::id();
        let t0 = process_cpu_s(me).expect("/proc/self/stat readable");
        let mut x = 0u64;
        for _ in 0..300_000_000u64 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        std::hint::black_box(x);
        let t1 = process_cpu_s(me).expect("readable");
        assert!(t1 - t0 >= 0.05, "the work counted {:.3} s", t1 - t0);
    }
}

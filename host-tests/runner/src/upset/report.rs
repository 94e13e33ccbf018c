//! The campaign's figures: counts per outcome with 95 % intervals, per target class,
//! recovery times, the events logged, the crashes' causes; as text, JSON and the document
//! (`docs/UPSET-CAMPAIGN-QEMU.md`).

use std::fmt::Write;

use ssis_common::cli::{json, Value};

use super::{Flip, Outcome, UpsetOptions, BOUND_ARCSEC};

/// A share with its 95 % Wilson score interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interval {
    /// Observed share.
    pub share: f64,
    /// Lower bound.
    pub low: f64,
    /// Upper bound.
    pub high: f64,
}

impl Interval {
    /// The Wilson score interval of `k` of `n` at 95 %.
    pub fn wilson(k: usize, n: usize) -> Interval {
        if n == 0 {
            return Interval { share: 0.0, low: 0.0, high: 1.0 };
        }
        let (k, n, z) = (k as f64, n as f64, 1.959_964);
        let p = k / n;
        let d = 1.0 + z * z / n;
        let c = (p + z * z / (2.0 * n)) / d;
        let h = z * (p * (1.0 - p) / n + z * z / (4.0 * n * n)).sqrt() / d;
        // At k = 0 (k = n) the bound is exactly 0 (1): c − h cancels, to rounding.
        let low = if k == 0.0 { 0.0 } else { (c - h).max(0.0) };
        let high = if k == n { 1.0 } else { (c + h).min(1.0) };
        Interval { share: p, low, high }
    }

    fn pct(&self) -> String {
        format!("{:.2} % [{:.2}, {:.2}]", 100.0 * self.share, 100.0 * self.low, 100.0 * self.high)
    }
}

/// The outcome rows, in table order.
const ROWS: [&str; 7] = [
    "masked",
    "tolerated",
    "detected and recovered",
    "detected, not recovered in the window",
    "reset and recovered",
    "silent",
    "crash",
];

/// A campaign's flips and how it ran.
#[derive(Debug, Clone)]
pub struct Campaign {
    /// Scenario name.
    pub name: String,
    /// The options it ran with.
    pub options: UpsetOptions,
    /// Every flip, in order.
    pub flips: Vec<Flip>,
    /// QEMU flights started.
    pub flights: u32,
    /// Wall time, s.
    pub wall_s: f64,
    /// The step's entry (breakpoint) address.
    pub entry: u32,
    /// Instructions in the traced path of a step.
    pub path_len: usize,
    /// Flights that stopped (crash) after every flip in them had been classed masked or
    /// tolerated: a latent effect of one of them.
    pub latent: u32,
    /// Top of the stack.
    pub stack_top: u32,
    /// Statics' range.
    pub statics: (u32, u32),
}

impl Campaign {
    fn count(&self, row: &str, class: Option<&str>) -> usize {
        self.flips.iter().filter(|f| f.outcome.name() == row && class.is_none_or(|c| f.target.class() == c)).count()
    }

    /// Flips per hour of wall time.
    pub fn flips_per_hour(&self) -> f64 {
        self.flips.len() as f64 * 3600.0 / self.wall_s.max(1e-9)
    }

    /// Flips classed silent.
    pub fn silent(&self) -> usize {
        self.count("silent", None)
    }

    /// The summary as text.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let n = self.flips.len();
        let _ = writeln!(
            s,
            "upset campaign  {}  in QEMU: {n} flips in {} flights, wall {:.0} s ({:.0} flips/h)",
            self.name,
            self.flights,
            self.wall_s,
            self.flips_per_hour()
        );
        for row in ROWS {
            let k = self.count(row, None);
            let _ = writeln!(s, "  {row:<40} {k:>6}  {}", Interval::wilson(k, n).pct());
        }
        if let Some(w) = self.flips.iter().filter(|f| f.silent_arcsec > 0.0).map(|f| f.silent_arcsec).reduce(f64::max) {
            let _ = writeln!(s, "  worst silent error {w:.0}″");
        }
        s
    }

    /// The `--json` object's fields.
    pub fn json(&self) -> Value {
        let n = self.flips.len();
        let rows: Vec<Value> = ROWS
            .iter()
            .map(|r| {
                let k = self.count(r, None);
                let i = Interval::wilson(k, n);
                json!({"outcome": r, "flips": k, "share": i.share, "ci95_low": i.low, "ci95_high": i.high})
            })
            .collect();
        let flips: Vec<Value> = self
            .flips
            .iter()
            .map(|f| {
                json!({
                    "step": f.step, "instr": f.instr, "target": f.target.describe(), "class": f.target.class(),
                    "outcome": f.outcome.name(),
                    "crash": match &f.outcome { Outcome::Crash(w) => Some(w.clone()), _ => None },
                    "worst_arcsec": f.worst_arcsec, "silent_arcsec": f.silent_arcsec,
                    "recovery_s": f.recovery_s, "events": f.events,
                })
            })
            .collect();
        json!({
            "scenario": self.name, "flips": n, "flights": self.flights, "wall_s": self.wall_s,
            "flips_per_hour": self.flips_per_hour(), "seed": self.options.seed, "latent_flights": self.latent,
            "outcomes": rows, "per_flip": flips,
        })
    }

    /// The campaign document (Markdown): how it was run, the table of outcomes with 95 %
    /// intervals, per target class, the recovery times, events and crashes, and each
    /// changed flip.
    pub fn document(&self, command: &str) -> String {
        let o = &self.options;
        let n = self.flips.len();
        let mut s = String::new();
        let _ = writeln!(s, "# Upset campaign on the firmware in QEMU\n");
        let _ = writeln!(
            s,
            "Written by `ssis-qemu-upset` (host-tests/runner/src/upset/); the host campaign on the \
             flight core's state is docs/UPSET-CAMPAIGN.md. Issue 30, item 1. Command:\n\n```\n{command}\n```\n"
        );
        let _ = writeln!(
            s,
            "Scenario `{}` on `ssis-fw-test` in QEMU mps2-an500, lockstep, `-icount shift=0,sleep=off`. \
             One bit per flip, through QEMU's gdbstub, at a random instruction inside a random step: the \
             runner breaks at the first instruction of the inlined `FlightCore::step` ({:#x}, from the \
             ELF's DWARF), draws an instruction uniformly over the path of a step (traced once by \
             single-stepping) and runs to it through a breakpoint at its address (the m-th time it is \
             reached, as in the traced path; a step that leaves the path stops at that address or at \
             the step's end), then flips a bit chosen uniformly in the RAM in use (the live stack from SP to {:#x}, the statics \
             {:#x}..{:#x}) or, for {:.0} % of the flips, uniformly over the bits of r0–r15, xPSR, d0–d15 \
             and FPSCR. First flip at {} s (the observer converges at 10.05 s), seed {}.\n",
            self.name,
            self.entry,
            self.stack_top,
            self.statics.0,
            self.statics.1,
            100.0 * o.register_share,
            o.first_s,
            o.seed
        );
        let _ = writeln!(
            s,
            "Classes (the host campaign's): **masked** every output frame identical to the undisturbed \
             run's (the in-process core on the same bytes; the board's step time and overrun counters \
             set aside) for {} s after the flip; **tolerated** outputs changed, every frame's attitude \
             error within max({BOUND_ARCSEC}″, the unit's own 3σ) on each axis; **detected and \
             recovered** beyond that only in frames that do not claim a good attitude (a frame claims \
             one when it says converged, not degraded, no parity alarm) and back, claiming it, before \
             the window ends ({} s after the flip); **silent** a claimed-good frame beyond the bound; \
             **crash** QEMU exited (HardFault, watchdog), the guest stopped at a breakpoint \
             instruction, or no output for {} s of QEMU's processor time. **Reset and recovered** \
             needs the reset path of issue 30 (a watchdog or HardFault reset that resumes from a \
             snapshot); until the firmware has it, a reset ends the run and counts as a crash.\n",
            o.quiet_s,
            o.window_s,
            super::HANG_CPU_S
        );
        let _ = writeln!(
            s,
            "Cost: {n} flips in {} QEMU flights, {:.0} s of wall time ({:.0} flips an hour on this \
             host): a flip whose outputs stay identical costs its quiet time, and the next flip goes \
             into the same flight (so does one whose outputs changed within the bound and were \
             identical again for the quiet time: tolerated); any other flip is followed for the \
             window and ends its flight (the next one starts QEMU from the guest's state saved by the first flight \
             before the first flip time, `-incoming`, instead of booting and converging again). \
             Placing a flip costs tens of milliseconds. 1,000 flips at this rate take {:.1} h. A corruption that stays invisible for the quiet time and shows \
             later is charged to a later flip of the same flight: of the changed flips below, {} had \
             earlier flips before them in their flight; {} flights stopped with no flip being \
             watched (every flip in them already classed masked or tolerated).\n",
            self.flights,
            self.wall_s,
            self.flips_per_hour(),
            1000.0 / self.flips_per_hour().max(1e-9),
            self.flips.iter().filter(|f| f.outcome != Outcome::Masked && f.earlier_in_flight > 0).count(),
            self.latent
        );
        let classes = ["stack", "statics", "core register", "sp/pc", "FPU register"];
        let _ = writeln!(s, "| outcome | flips | share [95 % interval] | {} |", classes.join(" | "));
        let _ = writeln!(s, "|---|---|---|{}", "---|".repeat(classes.len()));
        for row in ROWS {
            let k = self.count(row, None);
            let per: Vec<String> = classes.iter().map(|c| self.count(row, Some(c)).to_string()).collect();
            let _ = writeln!(s, "| {row} | {k} | {} | {} |", Interval::wilson(k, n).pct(), per.join(" | "));
        }
        let totals: Vec<String> =
            classes.iter().map(|c| self.flips.iter().filter(|f| f.target.class() == *c).count().to_string()).collect();
        let _ = writeln!(s, "| all | {n} | | {} |\n", totals.join(" | "));
        s.push_str(&self.details());
        let changed: Vec<&Flip> = self.flips.iter().filter(|f| f.outcome != Outcome::Masked).collect();
        if changed.is_empty() {
            let _ = writeln!(s, "No flip changed an output.");
        } else {
            let _ = writeln!(s, "Every flip that changed an output:\n");
            let _ =
                writeln!(s, "| step (s) | instruction | bit | outcome | worst error ″ | recovery s | events | cause |");
            let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
            for f in changed {
                let cause = match &f.outcome {
                    Outcome::Crash(w) => w.replace('|', "/"),
                    _ => String::new(),
                };
                let _ = writeln!(
                    s,
                    "| {:.3} | {} | {} | {} | {:.1} | {} | {} | {} |",
                    f.step as f64 * 0.005,
                    f.instr,
                    f.target.describe(),
                    f.outcome.name(),
                    f.worst_arcsec,
                    f.recovery_s.map_or(String::new(), |r| format!("{r:.2}")),
                    f.events.join(", "),
                    cause
                );
            }
        }
        s
    }
}

impl Campaign {
    /// When the flips landed, the recovery times, the events logged and the crashes'
    /// causes (Markdown paragraphs).
    fn details(&self) -> String {
        let mut s = String::new();
        let mut t: Vec<f64> = self.flips.iter().map(|f| f.step as f64 * 0.005).collect();
        t.sort_by(f64::total_cmp);
        let q = |v: &[f64], p: f64| v.get(((v.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN);
        let _ = writeln!(
            s,
            "Flip times: first {:.1} s, median {:.1} s, last {:.1} s (every flight restarts at the \
             first flip time, so early times are sampled more often than late ones). Instruction \
             of the flip within the step's traced path of {} instructions: median {}.\n",
            q(&t, 0.0),
            q(&t, 0.5),
            q(&t, 1.0),
            self.path_len,
            {
                let mut k: Vec<u32> = self.flips.iter().map(|f| f.instr).collect();
                k.sort_unstable();
                k.get(k.len() / 2).copied().unwrap_or(0)
            }
        );
        let mut r: Vec<f64> = self.flips.iter().filter_map(|f| f.recovery_s).collect();
        r.sort_by(f64::total_cmp);
        if !r.is_empty() {
            let _ = writeln!(
                s,
                "Recovery (detected and recovered: from the flip to the last frame beyond the bound or \
                 not claiming a good attitude): {} flips, median {:.2} s, worst {:.2} s.\n",
                r.len(),
                q(&r, 0.5),
                q(&r, 1.0)
            );
        }
        let mut events: Vec<(String, usize)> = Vec::new();
        for e in self.flips.iter().flat_map(|f| f.events.iter()) {
            match events.iter_mut().find(|(n, _)| n == e) {
                Some((_, k)) => *k += 1,
                None => events.push((e.clone(), 1)),
            }
        }
        let list: Vec<String> = events.iter().map(|(n, k)| format!("`{n}` {k}")).collect();
        let _ = writeln!(
            s,
            "Events the unit logged after a flip that the undisturbed run did not: {}.\n",
            if list.is_empty() { "none".to_string() } else { list.join(", ") }
        );
        let mut causes: Vec<(&str, usize)> = Vec::new();
        for f in &self.flips {
            if let Outcome::Crash(w) = &f.outcome {
                let c = if w.starts_with("hang") {
                    "no output (hang)"
                } else if w.contains("hard fault") || w.contains("HardFault") {
                    "HardFault"
                } else if w.contains("watchdog") {
                    "watchdog reset"
                } else if w.contains("debugger") {
                    "breakpoint instruction"
                } else {
                    "QEMU ended otherwise"
                };
                match causes.iter_mut().find(|(n, _)| *n == c) {
                    Some((_, k)) => *k += 1,
                    None => causes.push((c, 1)),
                }
            }
        }
        if !causes.is_empty() {
            let list: Vec<String> = causes.iter().map(|(n, k)| format!("{n} {k}")).collect();
            let _ = writeln!(s, "Crashes by cause: {}.\n", list.join(", "));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::Interval;

    #[test]
    fn wilson_interval() {
        // 0 of 1,000: the upper bound is about 3.8/n.
        let i = Interval::wilson(0, 1000);
        assert_eq!(i.low, 0.0);
        assert!((i.high - 0.00383).abs() < 1e-4, "{i:?}");
        let i = Interval::wilson(50, 100);
        assert!((i.low - 0.4038).abs() < 1e-3 && (i.high - 0.5962).abs() < 1e-3, "{i:?}");
    }
}

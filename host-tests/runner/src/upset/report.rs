//! The campaign's figures: counts per outcome with 95 % intervals, per target class,
//! recovery times, the events logged, the crashes' causes; as text, JSON and the document
//! (`docs/UPSET-CAMPAIGN-QEMU.md`).

use std::fmt::Write;

use ssis_common::cli::{json, Value};

use super::{Flip, Mix, Outcome, PathKind, Target, UpsetOptions, BOUND_ARCSEC, DEVICE_REGS, RESET_DOWN_STEPS};

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

    /// The exact (Clopper–Pearson) interval of `k` of `n` at 95 %.
    pub fn clopper_pearson(k: usize, n: usize) -> Interval {
        if n == 0 {
            return Interval { share: 0.0, low: 0.0, high: 1.0 };
        }
        let (low, high) = ssis_faults::upset::clopper_pearson(k as u64, n as u64);
        Interval { share: k as f64 / n as f64, low, high }
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
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
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
    /// Instructions in the traced path of a pass without a star update.
    pub path_len: usize,
    /// Instructions in each traced path.
    pub path_lens: Vec<(PathKind, usize)>,
    /// The populations and their shares of the flips.
    pub mix: Mix,
    /// Flights dropped because the runner failed in them (a breakpoint never reached).
    pub failed_flights: u32,
    /// Flights that stopped (crash) after every flip in them had been classed masked or
    /// tolerated: a latent effect of one of them.
    pub latent: u32,
    /// Top of the stack.
    pub stack_top: u32,
    /// Statics' range.
    pub statics: (u32, u32),
    /// The undisturbed flight's attitude error 3σ per axis after settling, ″.
    pub nominal_3sigma_arcsec: [f64; 3],
    /// Campaigns run side by side (`--jobs`), each in its own QEMU.
    pub jobs: usize,
    /// The step, s.
    pub dt_s: f64,
    /// The launch vehicle's judgement: the bounds (position m, velocity m/s, attitude ″)
    /// and the undisturbed flight's largest errors they come from.
    pub lv: Option<LvBounds>,
    /// The FNV-1a hash of the firmware ELF's bytes: campaigns merged must share it.
    pub elf_hash: u64,
    /// The runs merged into this one ([`Campaign::merge`]); empty: one run.
    pub runs: Vec<Run>,
}

/// One run of a campaign merged with others ([`Campaign::merge`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Run {
    /// Its seed (job j drew with seed + j).
    pub seed: u64,
    /// Its jobs side by side.
    pub jobs: usize,
    /// Its flips.
    pub flips: usize,
    /// Its wall time, s.
    pub wall_s: f64,
}

/// The launch vehicle's bounds ([`super::lv`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LvBounds {
    /// Position m, velocity m/s, attitude ″.
    pub bound: [f64; 3],
    /// The undisturbed flight's largest errors against truth: m, m/s, ″.
    pub undisturbed_max: [f64; 3],
}

impl Campaign {
    /// Adds the flips, flights and paths of `c`, a campaign of the same firmware and
    /// scenario drawn with other seeds (a job of the same run, or another run).
    pub(super) fn absorb(&mut self, c: Campaign) {
        self.flips.extend(c.flips);
        self.flights += c.flights;
        self.failed_flights += c.failed_flights;
        self.latent += c.latent;
        self.path_len = self.path_len.max(c.path_len);
        for (k, l) in c.path_lens {
            if !self.path_lens.iter().any(|(ak, _)| *ak == k) {
                self.path_lens.push((k, l));
            }
        }
    }

    /// This campaign's runs (itself, if it is one run).
    fn own_runs(&self) -> Vec<Run> {
        match self.runs.is_empty() {
            true => {
                vec![Run { seed: self.options.seed, jobs: self.jobs, flips: self.flips.len(), wall_s: self.wall_s }]
            }
            false => self.runs.clone(),
        }
    }

    /// Campaigns saved by separate runs (`ssis-qemu-upset --save`) as one: the same
    /// firmware (ELF hash), scenario, populations and schedule, drawn with seeds whose
    /// jobs do not overlap (a run's job j draws with its seed + j), so the flips are
    /// independent draws of one distribution. Wall time and flights are summed.
    pub fn merge(parts: Vec<Campaign>) -> anyhow::Result<Campaign> {
        let mut it = parts.into_iter();
        let mut all = it.next().ok_or_else(|| anyhow::anyhow!("no campaign to merge"))?;
        let mut runs = all.own_runs();
        for c in it {
            let (a, b) = (&all.options, &c.options);
            anyhow::ensure!(
                c.elf_hash == all.elf_hash,
                "another firmware (ELF hash {:#x}, not {:#x})",
                c.elf_hash,
                all.elf_hash
            );
            anyhow::ensure!(c.name == all.name, "another scenario ({}, not {})", c.name, all.name);
            anyhow::ensure!(format!("{:?}", c.mix) == format!("{:?}", all.mix), "other populations ({:?})", c.mix);
            anyhow::ensure!(
                (a.first_s, a.quiet_s, a.window_s, a.gap_s, a.register_share, a.forced_reset)
                    == (b.first_s, b.quiet_s, b.window_s, b.gap_s, b.register_share, b.forced_reset),
                "another schedule (first, quiet, window, gap, register share or forced reset differ)"
            );
            for r in c.own_runs() {
                let end = |q: &Run| q.seed.saturating_add(q.jobs as u64);
                anyhow::ensure!(
                    !runs.iter().any(|q| r.seed < end(q) && q.seed < end(&r)),
                    "seeds {}..{} overlap another run's: its flips would repeat",
                    r.seed,
                    end(&r)
                );
                runs.push(r);
            }
            all.wall_s += c.wall_s;
            all.jobs = all.jobs.max(c.jobs);
            all.absorb(c);
        }
        all.options.flips = all.flips.len();
        all.runs = runs;
        Ok(all)
    }

    /// The runs, for the document (nothing for one run).
    fn runs_text(&self) -> String {
        if self.runs.len() < 2 {
            return String::new();
        }
        let each: Vec<String> = self
            .runs
            .iter()
            .map(|r| format!("seed {} × {} job(s), {} flips, {:.0} s", r.seed, r.jobs, r.flips, r.wall_s))
            .collect();
        format!(
            " Merged from {} runs of the same ELF (FNV-1a {:#018x}) by `--merge` of their `--save` files: {}; \
             the wall time is their sum.",
            self.runs.len(),
            self.elf_hash,
            each.join("; ")
        )
    }

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

    /// Why a flip's drawn place lies outside what this campaign may flip (the live stack,
    /// the statics, the core and FPU registers, a listed device register's writable
    /// bits), or `None` when it lies within: a check on the drawing, for the tests.
    pub fn out_of_reach(&self, f: &Flip) -> Option<String> {
        let in_ram = |end: u32| end <= self.stack_top || (self.statics.0..=self.statics.1).contains(&end);
        let ok = match f.target {
            Target::Stack { addr, bit } => addr < self.stack_top && bit < 8,
            Target::Static { addr, bit } => (self.statics.0..self.statics.1).contains(&addr) && bit < 8,
            Target::Core { reg, bit } => (reg < 16 || reg == 25) && bit < 32,
            Target::Fpu { reg, bit } => (26..=42).contains(&reg) && bit < 64,
            Target::Double { addr, bit, words } => {
                in_ram(addr + if words { 8 } else { 4 }) && bit < if words { 32 } else { 31 }
            }
            Target::Device { reg, bit } => {
                DEVICE_REGS.get(usize::from(reg)).is_some_and(|d| bit < 32 && d.mask & (1 << bit) != 0)
            }
            Target::SnapshotReset { .. } | Target::Reset => true,
            Target::TickStopped | Target::Stall => false,
        };
        let masked_clean = f.outcome != Outcome::Masked || (f.events.is_empty() && f.recovery_s.is_none());
        match (ok, masked_clean) {
            (true, true) => None,
            (false, _) => Some(format!(
                "drawn outside the campaign's reach (stack top {:#x}, statics {:#x}..{:#x}): {f:?}",
                self.stack_top, self.statics.0, self.statics.1
            )),
            (true, false) => Some(format!("classed masked with events or a recovery: {f:?}")),
        }
    }

    /// The summary as text.
    pub fn report(&self) -> String {
        let mut s = String::new();
        let n = self.flips.len();
        let _ = writeln!(
            s,
            "upset campaign  {}  in QEMU: {n} flips in {} flights ({} dropped by the runner), wall {:.0} s ({:.0} flips/h)",
            self.name,
            self.flights,
            self.failed_flights,
            self.wall_s,
            self.flips_per_hour()
        );
        for row in ROWS {
            let k = self.count(row, None);
            let _ = writeln!(s, "  {row:<40} {k:>6}  {}", Interval::clopper_pearson(k, n).pct());
        }
        if let Some(w) = self.flips.iter().filter(|f| f.silent_arcsec > 0.0).map(|f| f.silent_arcsec).reduce(f64::max) {
            let _ = match self.lv {
                Some(_) => writeln!(s, "  worst silent error {w:.2} × its bound"),
                None => writeln!(s, "  worst silent error {w:.0}″"),
            };
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
                let i = Interval::clopper_pearson(k, n);
                json!({"outcome": r, "flips": k, "share": i.share, "ci95_low": i.low, "ci95_high": i.high})
            })
            .collect();
        let flips: Vec<Value> = self
            .flips
            .iter()
            .map(|f| {
                json!({
                    "population": f.population.name(), "star": f.star,
                    "step": f.step, "instr": f.instr, "at": f.at, "target": f.target.describe(), "class": f.target.class(),
                    "outcome": f.outcome.name(),
                    "crash": match &f.outcome { Outcome::Crash(w) => Some(w.clone()), _ => None },
                    "worst_arcsec": f.worst_arcsec, "silent_arcsec": f.silent_arcsec,
                    "recovery_s": f.recovery_s, "events": f.events,
                    "reset_cause": f.reset_cause, "reset_aligned_s": f.reset_aligned_s,
                    "reset_nominal_s": f.reset_nominal_s,
                })
            })
            .collect();
        json!({
            "scenario": self.name, "flips": n, "flights": self.flights, "wall_s": self.wall_s,
            "flips_per_hour": self.flips_per_hour(), "seed": self.options.seed, "latent_flights": self.latent,
            "nominal_3sigma_arcsec": self.nominal_3sigma_arcsec.to_vec(),
            "outcomes": rows, "per_flip": flips,
        })
    }

    /// The campaign document (Markdown): how it was run, the table of outcomes with 95 %
    /// intervals, per target class, the recovery times, events and crashes, and each
    /// changed flip.
    pub fn document(&self, command: &str) -> String {
        if let Some(lv) = self.lv {
            return self.document_lv(command, lv);
        }
        let o = &self.options;
        let n = self.flips.len();
        let mut s = String::new();
        let _ = writeln!(s, "# Upset campaign on the firmware in QEMU\n");
        let _ = writeln!(
            s,
            "Written by `ssis-qemu-upset` (host-tests/runner/src/upset/); the host campaign on the \
             flight core's state is docs/UPSET-CAMPAIGN.md. Command:\n\n```\n{command}\n```\n"
        );
        let share = if o.register_share < 0.0 {
            "the bits of the RAM in use (the live stack from SP to {top}, the statics {s0}..{s1}) and of \
             r0–r15, xPSR, d0–d15 and FPSCR, uniform over all of them (the registers' share in proportion \
             to their bits, about 1 %)"
                .to_string()
        } else {
            format!(
                "the RAM in use (the live stack from SP to {{top}}, the statics {{s0}}..{{s1}}) or, for {:.0} % \
                 of the flips, the bits of r0–r15, xPSR, d0–d15 and FPSCR",
                100.0 * o.register_share
            )
        }
        .replace("{top}", &format!("{:#x}", self.stack_top))
        .replace("{s0}", &format!("{:#x}", self.statics.0))
        .replace("{s1}", &format!("{:#x}", self.statics.1));
        let _ = writeln!(
            s,
            "Scenario `{}` on `ssis-fw-test` in QEMU mps2-an500, lockstep, `-icount shift=0,sleep=off`, \
             through QEMU's gdbstub. Each flip is drawn from one population (table \"Per population\"): \
             **state** one bit of {share}; **double** two bits of the RAM in use, adjacent in a word or the \
             same bit of two adjacent words; **device** one bit of a device or system register the unit \
             depends on (SysTick CSR and RVR, VTOR, SHPR3, NVIC_ISER0, NVIC_IPR0–1, UART 0–2 CTRL and \
             BAUDDIV, MPU_CTRL, region 0's RBAR and RASR, region 1's RASR, the watchdog's LOAD and CONTROL, \
             written with the guest's own store since the gdbstub drops writes to device memory; PRIMASK \
             and FAULTMASK set with `cpsid`); **snapshot-reset** one bit of the snapshot record in RAM, \
             then a reset (QEMU's `system_reset`, as SYSRESETREQ); these four at a random instruction of \
             a random pass: the runner breaks at the first instruction of the inlined `FlightCore::step` \
             ({:#x}, from the ELF's DWARF) and draws an instruction uniformly over the pass's path (the \
             step, its outputs and the after-step work up to the loop's next `wfi`, traced once by \
             single-stepping, in a step of its own, for a step with a star update and once for one \
             without, kept under the ELF's hash for later campaigns; a pass taken in proportion to its \
             path's length), then runs to it: a breakpoint at the last instruction before it whose \
             address occurs there for the first time, then single steps (a breakpoint hit more than \
             once can let QEMU warp its virtual clock to the next timer deadline: ten hits in the \
             pass's wait loop reset the unit by its watchdog; single steps hold QEMU's timers); \
             **handler** one bit of the state at a random instruction of the \
             UART receive interrupt (`DefaultHandler`, traced from its entry to its return); \
             **snapshot-write** at a random instruction of `FlightCore::snapshot_into` on a step that \
             writes the snapshot (every 80th), a reset there (half) or one bit of the state. First flip \
             at {} s (the observer converges at 10.05 s), seed {}.\n",
            self.name, self.entry, o.first_s, o.seed
        );
        let _ = writeln!(
            s,
            "Classes (the host campaign's): **masked** every output frame identical to the undisturbed \
             run's (the in-process core on the same bytes; the board's step time and overrun counters \
             set aside) and no event the undisturbed run did not log for {} s after the flip; **tolerated** outputs changed, every frame's attitude \
             error within max({BOUND_ARCSEC}″, the unit's own 3σ) on each axis; **detected and \
             recovered** beyond that only in frames that do not claim a good attitude (a frame claims \
             one when it says converged, not degraded, no parity alarm) and back, claiming it, before \
             the window ends ({} s after the flip); **reset and recovered** the unit reset (a \
             HardFault's reset, or the watchdog's: QEMU runs with `-action watchdog=reset`) and came \
             back, every frame claiming a good attitude within the bound and the last frames back \
             within it by the window's end; **silent** a claimed-good frame beyond the bound (the \
             flip's run ends there); **crash** QEMU ended (a lockup: QEMU 7.2 ends the emulation \
             where a Cortex-M7 would stay locked up until its watchdog reset it), the guest stopped \
             at a breakpoint instruction, no output for {} s of QEMU's processor time (a hang: the \
             firmware's loop runs on without a step, or the watchdog did not reset it), or a reset \
             not back within the bound by the window's end.\n",
            o.quiet_s,
            o.window_s,
            super::HANG_CPU_S
        );
        let [a, b, c] = self.nominal_3sigma_arcsec;
        let _ = writeln!(
            s,
            "Following a reset: the runner keeps breakpoints on the firmware's `Reset`, `HardFault` \
             entries, and reads the watchdog's warnings at `Reset` (the firmware's count; with none, \
             the watchdog's raw interrupt status: a stop under `-icount …,sleep=off` warps virtual \
             time to the next timer deadline, so it does not stop at the NMI). At `Reset` it sends LOCKSTEP \
             before the guest runs on (the firmware takes it on its first pass), waits until the \
             firmware is silent, and goes on with the flight {} steps later ({:.0} ms: the unit \
             taken to be down, its sensor frames not sent; the resume bridges them), counting \
             bytes afresh. Recovery is timed from the step the unit reset in: to the first frame \
             that says aligned (goal ≤ 1 s), and to the frame from which every later one in the \
             window is within twice the nominal 3σ on each axis (goal ≤ 10 s with the observer, \
             2 s with the MEKF); nominal: the undisturbed flight's attitude error 3σ (|mean| + 3 \
             std) after settling, {a:.2} / {b:.2} / {c:.2}″.\n",
            RESET_DOWN_STEPS,
            RESET_DOWN_STEPS as f64 * 5.0
        );
        let _ = writeln!(
            s,
            "Cost: {n} flips in {} QEMU flights, {:.0} s of wall time with {} job(s) side by side \
             (job j draws with seed + j) ({:.0} flips an hour on this host): a flip whose outputs stay identical costs its quiet time, and the next flip goes \
             into the same flight (so does one whose outputs changed within the bound and were \
             identical again for the quiet time: tolerated); any other flip is followed for the \
             window and ends its flight (the next one starts QEMU from the guest's state saved by the first flight \
             before the first flip time, `-incoming`, instead of booting and converging again). \
             Placing a flip costs a few milliseconds in straight-line code and up to some tenths of a second deep in a pass's loops (the single steps). 1,000 flips at this rate take {:.1} h. A corruption that stays invisible for the quiet time and shows \
             later is charged to a later flip of the same flight: of the changed flips below, {} had \
             earlier flips before them in their flight; {} flights stopped with no flip being \
             watched (every flip in them already classed masked or tolerated).{}\n",
            self.flights,
            self.wall_s,
            self.jobs,
            self.flips_per_hour(),
            1000.0 / self.flips_per_hour().max(1e-9),
            self.flips.iter().filter(|f| f.outcome != Outcome::Masked && f.earlier_in_flight > 0).count(),
            self.latent,
            self.runs_text()
        );
        s.push_str(&self.outcomes());
        let changed: Vec<&Flip> = self.flips.iter().filter(|f| f.outcome != Outcome::Masked).collect();
        if changed.is_empty() {
            let _ = writeln!(s, "No flip changed an output.");
        } else {
            let _ = writeln!(s, "Every flip that changed an output:\n");
            let _ = writeln!(
                s,
                "| step (s) | instruction | at | bit | outcome | worst error ″ | recovery s | reset: aligned s | reset: within 2× 3σ s | events | cause |"
            );
            let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|");
            let opt = |v: Option<f64>| v.map_or(String::new(), |r| format!("{r:.2}"));
            for f in changed {
                let _ = writeln!(
                    s,
                    "| {:.3} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {} |",
                    f.step as f64 * 0.005,
                    f.instr,
                    f.at.replace('|', "/"),
                    f.target.describe(),
                    f.outcome.name(),
                    f.worst_arcsec,
                    opt(f.recovery_s),
                    opt(f.reset_aligned_s),
                    opt(f.reset_nominal_s),
                    f.events.join(", "),
                    cause(f)
                );
            }
        }
        s
    }

    /// The outcome table by target class, the per-population table and the details
    /// (Markdown).
    fn outcomes(&self) -> String {
        let n = self.flips.len();
        let mut s = String::new();
        let classes: Vec<&str> = [
            "stack",
            "statics",
            "core register",
            "sp/pc",
            "FPU register",
            "double: adjacent bits",
            "double: adjacent words",
            "device register",
            "snapshot, then reset",
            "forced reset",
        ]
        .into_iter()
        .filter(|c| self.flips.iter().any(|f| f.target.class() == *c))
        .collect();
        let _ = writeln!(s, "| outcome | flips | share [95 % interval] | {} |", classes.join(" | "));
        let _ = writeln!(s, "|---|---|---|{}", "---|".repeat(classes.len()));
        for row in ROWS {
            let k = self.count(row, None);
            let per: Vec<String> = classes.iter().map(|c| self.count(row, Some(c)).to_string()).collect();
            let _ = writeln!(s, "| {row} | {k} | {} | {} |", Interval::clopper_pearson(k, n).pct(), per.join(" | "));
        }
        let totals: Vec<String> =
            classes.iter().map(|c| self.flips.iter().filter(|f| f.target.class() == *c).count().to_string()).collect();
        let _ = writeln!(s, "| all | {n} | | {} |\n", totals.join(" | "));
        s.push_str(&self.populations());
        s.push_str(&self.details());
        s
    }
}

impl Campaign {
    /// The launch vehicle's campaign document (Markdown): its method, bounds and classes,
    /// then the tables the spacecraft's document has.
    fn document_lv(&self, command: &str, lv: LvBounds) -> String {
        let o = &self.options;
        let n = self.flips.len();
        let mut s = String::new();
        let _ = writeln!(s, "# Upset campaign on the launch-vehicle firmware in QEMU\n");
        let _ = writeln!(
            s,
            "Written by `ssis-qemu-upset` (host-tests/runner/src/upset/, the spacecraft's campaign \
             runner: docs/UPSET-CAMPAIGN-QEMU.md describes its method, populations and classes) on a \
             launch-vehicle ascent. Command (from host-tests/):\n\n```\n{command}\n```\n"
        );
        let [bp, bv, ba] = lv.bound;
        let [up, uv, ua] = lv.undisturbed_max;
        let _ = writeln!(
            s,
            "Scenario `{}` on `ssis-fw-lv-test` in QEMU mps2-an500, lockstep at 1.25 ms, `-icount \
             shift=0,sleep=off`; the FOG table and the pad block in flash as `ssis-qemu` loads them. \
             What differs from the spacecraft's campaign is only what the runner feeds and judges: each \
             step sends the FOG bus (UART1), the accelerometer bus (UART3) and the GNSS receiver \
             (UART4) and a STEP naming the byte totals; the step's first instruction is that of the \
             inlined `FlightCore::step_with` ({:#x}, from the ELF's DWARF), whose hook runs the \
             navigation step; a pass runs from there to the loop's next `wfi`, through the outputs and \
             the navigation's filter work (the covariance propagation every 80 steps, the GNSS update \
             once a second: these passes are traced as the spacecraft's star-update passes are, the \
             column \"in star-update steps\" below counts flips in passes with filter work); the RAM \
             in use is the live stack from SP to {:#x} and the statics {:#x}..{:#x} (from the ELF); \
             the undisturbed run is the in-process `LvCore` (the same `FlightCore` and `NavUnit`) on \
             the same bytes, bit-identical to the firmware. The populations are the spacecraft's \
             (the device population draws from the same mps2 registers: UARTs 3 and 4, the \
             accelerometer bus and the GNSS receiver, are not in it). First flip at {} s into the \
             ascent, seed {}.\n",
            self.name, self.entry, self.stack_top, self.statics.0, self.statics.1, o.first_s, o.seed
        );
        let _ = writeln!(
            s,
            "Judgement. A navigation output frame (UART2) **claims a good solution** when it carries \
             neither `NAV_FAULT` (the step refused and the state held, or the navigation lost after a \
             reset) nor `ACCEL_FAULT` (the accelerometer increment missing or refused, the last one \
             held); `GNSS_OUTAGE` alone is free inertial navigation, a solution the unit stands \
             behind with its σ grown. It is **beyond the bound** when, against truth, its position \
             error exceeds max({bp:.2} m, 3 × its own position σ), its velocity error max({bv:.4} m/s, \
             3 × its velocity σ), or its attitude error {ba:.1}″ (the frame carries no attitude σ). \
             The bounds are twice the undisturbed flight's largest errors over the scenario \
             ({up:.2} m, {uv:.4} m/s, {ua:.1}″), floored at {:.0} m, {:.2} m/s and {:.0}″. The flight \
             output frame (UART0, the core's attitude) counts as an output too: it is compared with \
             the undisturbed frame (changed or not), and while it claims a good attitude (converged, \
             not degraded, no parity alarm) its attitude must lie within max({}″, its own 3σ) of the \
             undisturbed frame's. Classes as the spacecraft's: **masked** every output and event \
             frame identical to the undisturbed run's for {} s; **tolerated** changed, no frame \
             beyond its bound; **detected and recovered** beyond it only in frames that do not claim \
             a good solution, and back before the window ends ({} s after the flip); **reset and \
             recovered** the unit reset and came back, every claimed-good frame within the bound and \
             the last frames within it by the window's end; **silent** a claimed-good frame beyond \
             its bound (the flip's run ends there); **crash** QEMU ended, the guest stopped at a \
             breakpoint instruction, no output for {} s of QEMU's processor time, or a reset not \
             back within the bound by the window's end (a unit stopped for good). The worst error \
             in the table below is the largest ratio of an error to its bound (above 1 in a \
             claimed-good frame: silent), with the largest navigation errors beside it.\n",
            super::lv::FLOOR[0],
            super::lv::FLOOR[1],
            super::lv::FLOOR[2],
            super::BOUND_ARCSEC,
            o.quiet_s,
            o.window_s,
            super::HANG_CPU_S
        );
        let _ = writeln!(
            s,
            "Following a reset: as the spacecraft's (LOCKSTEP at `Reset`, the firmware followed back \
             into lockstep), the unit taken to be down 100 ms (80 steps, their sensor frames not \
             sent; the navigation's resume bridges them from its snapshot, `ssis::nav::snapshot`). \
             Recovery is timed from the step the unit reset in: to the first navigation frame that \
             claims a good solution, and to the frame from which every later one is within the \
             bound.\n"
        );
        let _ = writeln!(
            s,
            "Cost: {n} flips in {} QEMU flights, {:.0} s of wall time with {} job(s) side by side (job \
             j draws with seed + j) ({:.0} flips an hour on this host). Of the changed flips below, {} \
             had earlier flips before them in their flight; {} flights stopped with no flip being \
             watched.{}\n",
            self.flights,
            self.wall_s,
            self.jobs,
            self.flips_per_hour(),
            self.flips.iter().filter(|f| f.outcome != Outcome::Masked && f.earlier_in_flight > 0).count(),
            self.latent,
            self.runs_text()
        );
        s.push_str(&self.outcomes());
        let changed: Vec<&Flip> = self.flips.iter().filter(|f| f.outcome != Outcome::Masked).collect();
        if changed.is_empty() {
            let _ = writeln!(s, "No flip changed an output.");
            return s;
        }
        let _ = writeln!(s, "Every flip that changed an output:\n");
        let _ = writeln!(
            s,
            "| step (s) | instruction | at | bit | outcome | worst / bound | position m | velocity m/s | attitude ″ | recovery s | reset: claims good s | reset: within the bound s | events | cause |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|");
        let opt = |v: Option<f64>| v.map_or(String::new(), |r| format!("{r:.2}"));
        for f in changed {
            let ([p, v, a], r) = f.nav_worst.unwrap_or(([f64::NAN; 3], f.worst_arcsec));
            let _ = writeln!(
                s,
                "| {:.4} | {} | {} | {} | {} | {r:.2} | {p:.2} | {v:.4} | {a:.1} | {} | {} | {} | {} | {} |",
                f.step as f64 * self.dt_s,
                f.instr,
                f.at.replace('|', "/"),
                f.target.describe(),
                f.outcome.name(),
                opt(f.recovery_s),
                opt(f.reset_aligned_s),
                opt(f.reset_nominal_s),
                f.events.join(", "),
                cause(f)
            );
        }
        s
    }
}

/// A flip's cause column: a crash's reason, or what reset it.
fn cause(f: &Flip) -> String {
    match (&f.outcome, &f.reset_cause) {
        (Outcome::Crash(w), _) => w.replace('|', "/"),
        (_, Some(c)) => c.replace('|', "/"),
        _ => String::new(),
    }
}

impl Campaign {
    /// The table per population (Markdown): its flips by outcome, silent and crash with
    /// their exact 95 % intervals, and the traced paths' lengths.
    fn populations(&self) -> String {
        let mut s = String::new();
        let pops: Vec<super::Population> =
            super::Population::ALL.into_iter().filter(|p| self.flips.iter().any(|f| f.population == *p)).collect();
        if pops.is_empty() {
            return s;
        }
        let mix: Vec<String> = self.mix.0.iter().map(|(p, w)| format!("{} {w}", p.name())).collect();
        let _ = writeln!(
            s,
            "Per population (drawn per flip with weights {}):
",
            mix.join(", ")
        );
        let _ = writeln!(
            s,
            "| population | flips | masked | tolerated | detected | reset and recovered | silent [95 % CP] | crash [95 % CP] | in star-update steps |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
        for p in pops {
            let of: Vec<&Flip> = self.flips.iter().filter(|f| f.population == p).collect();
            let n = of.len();
            let c = |row: &str| of.iter().filter(|f| f.outcome.name() == row).count();
            let detected = c("detected and recovered") + c("detected, not recovered in the window");
            let (silent, crash) = (c("silent"), c("crash"));
            let _ = writeln!(
                s,
                "| {} | {n} | {} | {} | {detected} | {} | {silent}: {} | {crash}: {} | {} |",
                p.name(),
                c("masked"),
                c("tolerated"),
                c("reset and recovered"),
                Interval::clopper_pearson(silent, n).pct(),
                Interval::clopper_pearson(crash, n).pct(),
                of.iter().filter(|f| f.star).count()
            );
        }
        let lens: Vec<String> = self.path_lens.iter().map(|(k, l)| format!("{k:?} {l}")).collect();
        let _ = writeln!(
            s,
            "
Traced paths (instructions): {}.
",
            lens.join(", ")
        );
        s
    }

    /// When the flips landed, the recovery times, the events logged and the crashes'
    /// causes (Markdown paragraphs).
    fn details(&self) -> String {
        let mut s = String::new();
        let mut t: Vec<f64> = self.flips.iter().map(|f| f.step as f64 * self.dt_s).collect();
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
        let resets: Vec<&Flip> = self.flips.iter().filter(|f| f.reset_cause.is_some()).collect();
        if !resets.is_empty() {
            let mut causes: Vec<(String, usize)> = Vec::new();
            for f in &resets {
                let c = f.reset_cause.as_deref().unwrap_or("");
                let c = if c.starts_with("HardFault") { "HardFault" } else { c };
                match causes.iter_mut().find(|(n, _)| n == c) {
                    Some((_, k)) => *k += 1,
                    None => causes.push((c.to_string(), 1)),
                }
            }
            let list: Vec<String> = causes.iter().map(|(n, k)| format!("{n} {k}")).collect();
            let mut al: Vec<f64> = resets.iter().filter_map(|f| f.reset_aligned_s).collect();
            let mut nom: Vec<f64> = resets.iter().filter_map(|f| f.reset_nominal_s).collect();
            al.sort_by(f64::total_cmp);
            nom.sort_by(f64::total_cmp);
            let (aligned, nominal) = match self.lv {
                Some(_) => ("Claiming a good solution again", "within the bound"),
                None => ("Aligned again", "within twice the nominal 3σ"),
            };
            let _ = writeln!(
                s,
                "Resets: {} flips reset the unit ({}). {aligned} after median {:.2} s, worst {:.2} s \
                 ({} of {} aligned in the window); {nominal} after median {:.2} s, \
                 worst {:.2} s ({} of {} back within it by the window's end).\n",
                resets.len(),
                list.join(", "),
                q(&al, 0.5),
                q(&al, 1.0),
                al.len(),
                resets.len(),
                q(&nom, 0.5),
                q(&nom, 1.0),
                nom.len(),
                resets.len()
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
                let c = if w.starts_with("hang") && w.contains("idle after WFI") {
                    "no output: the loop idles, never taking the STEP (lockstep stalled)"
                } else if w.starts_with("hang") {
                    "no output (hang)"
                } else if w.contains("Lockup") {
                    "lockup (QEMU ends)"
                } else if w.starts_with("reset") {
                    "reset, not back in the window"
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
    use super::{Campaign, Interval};
    use crate::upset::{Flip, Mix, Outcome, Population, Target, UpsetOptions};

    /// A campaign of one run: `seed`, `jobs` side by side, `n` masked flips, on the
    /// firmware whose ELF hashes to `elf_hash`.
    fn run(seed: u64, jobs: usize, n: usize, elf_hash: u64) -> Campaign {
        let flip = Flip {
            population: Population::State,
            star: false,
            step: 2400,
            instr: 10,
            at: "0x100 (f)".into(),
            target: Target::Static { addr: 0x2000_8000, bit: 3 },
            outcome: Outcome::Masked,
            worst_arcsec: 2.0,
            silent_arcsec: 0.0,
            recovery_s: None,
            reset_cause: None,
            reset_after_s: None,
            reset_aligned_s: None,
            reset_nominal_s: None,
            events: Vec::new(),
            earlier_in_flight: 0,
            nav_worst: None,
        };
        Campaign {
            name: "qemu-flight".into(),
            options: UpsetOptions::new("fw.elf".into(), n, seed),
            flips: vec![flip; n],
            flights: 2,
            wall_s: 100.0,
            entry: 0x23ac,
            path_len: 8000,
            path_lens: Vec::new(),
            mix: Mix::all(),
            failed_flights: 0,
            latent: 0,
            stack_top: 0x2000_8000,
            statics: (0x2000_8000, 0x2000_8600),
            nominal_3sigma_arcsec: [2.0; 3],
            jobs,
            dt_s: 0.005,
            lv: None,
            elf_hash,
            runs: Vec::new(),
        }
    }

    /// Runs saved apart (JSON, as `--save` writes) merge into one campaign: the flips and
    /// wall times add up and each run is named; runs of another firmware, or whose seeds
    /// overlap (the same flips drawn again), are refused.
    #[test]
    fn saved_runs_merge_into_one_campaign() {
        let saved = |c: &Campaign| serde_json::from_str::<Campaign>(&serde_json::to_string(c).unwrap()).unwrap();
        let m = Campaign::merge(vec![saved(&run(40, 2, 5, 7)), saved(&run(42, 2, 3, 7))]).unwrap();
        assert_eq!((m.flips.len(), m.flights, m.wall_s, m.options.flips), (8, 4, 200.0, 8));
        assert_eq!(m.runs.iter().map(|r| (r.seed, r.jobs, r.flips)).collect::<Vec<_>>(), [(40, 2, 5), (42, 2, 3)]);
        assert!(m.document("merge").contains("Merged from 2 runs"));
        // A merged campaign merges on.
        let m3 = Campaign::merge(vec![m.clone(), run(50, 1, 1, 7)]).unwrap();
        assert_eq!((m3.flips.len(), m3.runs.len()), (9, 3));
        let e = Campaign::merge(vec![run(40, 2, 5, 7), run(42, 2, 3, 8)]).unwrap_err();
        assert!(e.to_string().contains("another firmware"), "{e}");
        let e = Campaign::merge(vec![run(40, 2, 5, 7), run(41, 2, 3, 7)]).unwrap_err();
        assert!(e.to_string().contains("overlap"), "{e}");
        let e = Campaign::merge(vec![m, run(41, 1, 1, 7)]).unwrap_err();
        assert!(e.to_string().contains("overlap"), "{e}");
    }

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

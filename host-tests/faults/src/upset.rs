//! The upset campaign: one random bit of the [`FlightCore`] value flipped between two
//! steps of a flight after convergence, each flip flown on in its own process, and the
//! rest of the flight classed against truth and the undisturbed flight.
//!
//! The parent flies the scenario once undisturbed (the reference: every output, the
//! downlink's bytes, the attitude error, the events), then flies it again and, at each
//! flip's step (sorted), forks: the child flips its bit through a raw pointer into its
//! copy of the core (the core itself stays safe code), flies to the end, compares every
//! step with the reference and writes its verdict to a pipe. A child that dies (a signal,
//! a panic, no verdict within the timeout) is a crash, not the end of the campaign. At
//! most `jobs` children run at once. Flips are drawn from a seed, so a campaign (and any
//! prefix of it) is reproducible.
//!
//! In-step mode ([`Settings::in_step`]): the bit is flipped inside the flip's step instead,
//! at a numbered point between the state guard's check and its seal drawn uniformly
//! ([`ssis::flight::probe`], through the test-only `FlightCore::step_probed`; a point a
//! step does not reach, a per-sample one in a step without a sample, falls to the next
//! point it reaches), and only into the attitude and the estimator's state
//! ([`IN_STEP_FIELDS`]).
//!
//! Outcomes ([`Outcome`]), in this order of precedence:
//! - **crash**: the child died (signal, panic, hang);
//! - **silent**: a frame that claims a good attitude ([`claims_good`]: converged, not
//!   degraded, no parity alarm) with an attitude error beyond the bound (the largest
//!   axis against truth over max(20″, the undisturbed unit's own 3σ at that step));
//! - **detected**: the error went beyond the bound, and every such frame was flagged;
//!   recovered when the error came back within 2× the nominal 3σ (the undisturbed
//!   flight's |mean| + 3 std after settling) and stayed there to the end;
//! - **tolerated**: outputs changed, the error stayed within the bound;
//! - **masked**: every output (the step's output and every downlink byte) identical to the
//!   undisturbed flight.

use std::collections::BTreeMap;
use std::io::Read;
use std::os::fd::FromRawFd;

use anyhow::{bail, Context, Result};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use ssis::flight::{flags, probe, FlightCore, FogLinks, Links, StepOutput};
use ssis::state_map::{locate, StateField};
use ssis::telemetry::events::EventRecord;
use ssis_common::downlink::{Down, Downlink};
use ssis_common::mock::{MockLink, MockSink};
use ssis_common::ARCSEC_PER_RAD;
use ssis_sim::harness::{step_on_mock_links, Evaluator, Observed, Simulation};
use ssis_sim::scenario::Scenario;

/// The error every unit may have, arcsec: the tolerated bound is the larger of this and
/// the unit's own 3σ.
pub const TOLERATED_ARCSEC: f64 = 20.0;

/// Events a verdict carries at most (the pipe holds the verdict whole).
const MAX_EVENTS: usize = 16;

/// Whether a frame claims a good attitude: converged, not degraded, no parity alarm.
pub fn claims_good(out: &StepOutput) -> bool {
    out.flags & flags::CONVERGED != 0 && out.flags & (flags::DEGRADED | flags::FDI_ALARM) == 0
}

/// The scenario in flight: simulator, evaluator, core and links, as the main job flies it
/// (`ssis_sim::harness::run`).
pub struct Flight {
    sim: Simulation,
    eval: Evaluator,
    /// The flight core.
    pub core: FlightCore,
    fog_links: [MockLink; 4],
    star_link: MockLink,
    out_link: MockSink,
    downlink: Downlink,
    /// Steps flown.
    pub n: usize,
    /// A flip to make inside the next step: at the first probe point at or after the
    /// first, bit `.2` of byte `.1`.
    in_step: Option<(u8, usize, u8)>,
}

/// Flips bit `bit` of byte `byte` of `core`'s value.
fn flip_core(core: &mut FlightCore, byte: usize, bit: u8) {
    assert!(byte < std::mem::size_of::<FlightCore>() && bit < 8, "flip outside the core");
    let p = std::ptr::from_mut(core).cast::<u8>();
    // SAFETY: `byte` is within the `FlightCore` value (checked above), which the caller
    // holds exclusively; the byte is read and written as plain memory (a padding byte
    // reads as whatever it holds). What the core makes of the flipped value is what the
    // campaign measures, in a child process of its own.
    unsafe {
        let b = p.add(byte);
        b.write_volatile(b.read_volatile() ^ (1 << bit));
    }
}

/// What one step of a [`Flight`] gave.
pub struct Stepped {
    /// The step's output.
    pub out: StepOutput,
    /// The bytes it sent on the output link (output frame, event frames).
    pub down: Vec<u8>,
    /// Time of the output, s.
    pub t_s: f64,
    /// Attitude error per axis against truth, arcsec (`None`: no truth for it).
    pub err_arcsec: Option<[f64; 3]>,
    /// The event records the step's event frames carried.
    pub events: Vec<EventRecord>,
}

impl Flight {
    /// The scenario at power-on.
    pub fn new(sc: &Scenario) -> Result<Self> {
        let sim = Simulation::new(sc)?;
        let eval = Evaluator::new(&sim);
        let mut core = FlightCore::new(sim.profile, &sim.table, false).map_err(|e| anyhow::anyhow!("core: {e:?}"))?;
        if sim.needs_pad_alignment() {
            core.align(sim.initial_q());
        }
        let seed = sc.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        Ok(Flight {
            fog_links: [0u64, 1, 2, 3].map(|i| MockLink::new(sc.links.fog, seed ^ (i + 1))),
            star_link: MockLink::new(sc.links.star, seed ^ 99),
            out_link: MockSink::default(),
            downlink: Downlink::new(),
            sim,
            eval,
            core,
            n: 0,
            in_step: None,
        })
    }

    /// Flies one step (`None`: the flight is over).
    pub fn step(&mut self) -> Option<Stepped> {
        let input = self.sim.next_step()?;
        if let Some(t) = input.truth {
            self.eval.push_truth(t);
        }
        let fogs = self.sim.profile.fogs;
        let out = match self.in_step.take() {
            None => step_on_mock_links(
                &mut self.core,
                &mut self.fog_links,
                &mut self.star_link,
                &mut self.out_link,
                &input,
                fogs,
            ),
            Some((point, byte, bit)) => {
                // `step_on_mock_links`, the step probed.
                for l in self.fog_links.iter_mut() {
                    l.tick();
                }
                self.star_link.tick();
                for (i, (link, f)) in self.fog_links.iter_mut().zip(input.fog_frames.iter()).enumerate() {
                    if fogs.contains(i) && input.present.contains(i) {
                        link.send(f);
                    }
                }
                self.star_link.send(&input.st_bytes);
                let mut links = Links {
                    fog: FogLinks::PerFog(self.fog_links.each_mut()),
                    star: &mut self.star_link,
                    out: &mut self.out_link,
                };
                let mut done = false;
                self.core.step_probed(&mut links, |core, at| {
                    if at >= point && !done {
                        flip_core(core, byte, bit);
                        done = true;
                    }
                })
            }
        };
        self.core.send_events(&mut self.out_link);
        let down = std::mem::take(&mut self.out_link.bytes);
        let mut events = Vec::new();
        self.downlink.push(&down, |d| {
            if let Down::Events(e) = d {
                events.extend(e.iter().copied());
            }
        });
        let rec = self.eval.evaluate(&Observed::from(&out));
        self.n += 1;
        Some(Stepped { t_s: out.time_us as f64 * 1e-6, err_arcsec: rec.map(|r| r.att_err_arcsec), out, down, events })
    }

    /// Attitude error statistics after settling so far, arcsec ("3σ": |mean| + 3 std).
    pub fn att_three_sigma_arcsec(&self) -> [f64; 3] {
        self.eval.att.three_sigma()
    }

    /// Flips bit `bit` of byte `byte` of the core value.
    pub fn flip(&mut self, byte: usize, bit: u8) {
        flip_core(&mut self.core, byte, bit);
    }

    /// Flips bit `bit` of byte `byte` of the core inside the next step, at the first
    /// probe point at or after `point` ([`probe`]).
    pub fn flip_in_step(&mut self, point: u8, byte: usize, bit: u8) {
        assert!(byte < std::mem::size_of::<FlightCore>() && bit < 8, "flip outside the core");
        self.in_step = Some((point, byte, bit));
    }
}

/// The undisturbed flight, step by step.
pub struct Reference {
    /// Per step (index: steps flown before it).
    pub steps: Vec<Stepped>,
    /// Index of the first step whose output says converged.
    pub converged_step: usize,
    /// The flight's attitude error 3σ after settling, largest axis, arcsec.
    pub nominal_3sigma_arcsec: f64,
}

impl Reference {
    /// Flies `sc` undisturbed.
    pub fn fly(sc: &Scenario) -> Result<Self> {
        let mut f = Flight::new(sc)?;
        let steps: Vec<Stepped> = std::iter::from_fn(|| f.step()).collect();
        let converged_step = steps
            .iter()
            .position(|s| s.out.flags & flags::CONVERGED != 0)
            .context("the undisturbed flight never converged")?;
        let nominal_3sigma_arcsec = f.att_three_sigma_arcsec().into_iter().fold(0.0, f64::max);
        Ok(Reference { steps, converged_step, nominal_3sigma_arcsec })
    }

    /// The tolerated bound at step `i`, arcsec: max(20″, the unit's own 3σ then, largest axis).
    pub fn bound_arcsec(&self, i: usize) -> f64 {
        let own = self
            .steps
            .get(i)
            .map_or(0.0, |s| s.out.att_sigma_rad.iter().fold(0.0f64, |m, v| m.max(3.0 * v * ARCSEC_PER_RAD)));
        TOLERATED_ARCSEC.max(own)
    }
}

/// One flip: before step `step` (after `step` steps), bit `bit` of byte `byte` of the core,
/// and with a double [`Pattern`] its second bit; with a `point`, inside that step at that
/// probe point ([`probe`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Flip {
    /// Steps flown before the flip.
    pub step: usize,
    /// Byte of the `FlightCore` value.
    pub byte: usize,
    /// Bit of that byte (0: least significant).
    pub bit: u8,
    /// Inside the step, at this probe point (`None`: between two steps).
    #[serde(default)]
    pub point: Option<u8>,
    /// One bit, or two in a multi-cell upset's pattern.
    #[serde(default)]
    pub pattern: Pattern,
}

/// The bits one upset flips: one, or two as a multi-cell upset flips them (cells next to
/// each other in the array: the next bit of the same word, or the same bit of the
/// neighbouring 32-bit or 64-bit word).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Pattern {
    /// One bit.
    #[default]
    Single,
    /// The bit and the next one up (bit 7 of a byte: bit 0 of the next byte).
    AdjacentBits,
    /// The same bit of the next 32-bit word (4 bytes on).
    SameBitWord32,
    /// The same bit of the next 64-bit word (8 bytes on).
    SameBitWord64,
}

impl Pattern {
    /// Every pattern, the report's order.
    pub const ALL: [Pattern; 4] =
        [Pattern::Single, Pattern::AdjacentBits, Pattern::SameBitWord32, Pattern::SameBitWord64];

    /// The double patterns, drawn uniformly for a double-bit flip.
    pub const DOUBLE: [Pattern; 3] = [Pattern::AdjacentBits, Pattern::SameBitWord32, Pattern::SameBitWord64];

    /// As the report names it.
    pub fn name(self) -> &'static str {
        match self {
            Pattern::Single => "single bit",
            Pattern::AdjacentBits => "two adjacent bits",
            Pattern::SameBitWord32 => "same bit, adjacent 32-bit words",
            Pattern::SameBitWord64 => "same bit, adjacent 64-bit words",
        }
    }
}

impl Flip {
    /// The bits flipped (byte, bit): the drawn one, then the pattern's second (kept in a
    /// core of `size` bytes: a second bit past its end is taken before the first).
    pub fn bits(&self, size: usize) -> ([(usize, u8); 2], usize) {
        let first = (self.byte, self.bit);
        let second = match self.pattern {
            Pattern::Single => return ([first, first], 1),
            Pattern::AdjacentBits if self.bit < 7 => (self.byte, self.bit + 1),
            Pattern::AdjacentBits => (self.byte + 1, 0),
            Pattern::SameBitWord32 => (self.byte + 4, self.bit),
            Pattern::SameBitWord64 => (self.byte + 8, self.bit),
        };
        let second = if second.0 < size {
            second
        } else {
            // Below the first: the same distance the other way.
            match self.pattern {
                Pattern::AdjacentBits if self.bit > 0 => (self.byte, self.bit - 1),
                Pattern::AdjacentBits => (self.byte.saturating_sub(1), 7),
                _ => (self.byte.saturating_sub(second.0 - self.byte), self.bit),
            }
        };
        ([first, second], 2)
    }

    /// The field the flipped byte belongs to, outside in ("(padding)" for none), and the
    /// byte's offset within the innermost field.
    pub fn field(&self) -> (String, usize) {
        field_of(FlightCore::state_map(), self.byte)
    }
}

/// The path of the field holding byte `byte` of a value mapped by `map`, and the byte's
/// offset in it.
pub fn field_of(map: &'static [StateField], byte: usize) -> (String, usize) {
    let Some(path) = locate::<4>(map, byte) else { return ("(padding)".into(), 0) };
    let mut off = byte;
    let mut fields = map;
    for name in &path {
        if let Some(f) = fields.iter().find(|f| f.name == *name) {
            off -= f.offset;
            fields = f.parts;
        }
    }
    (path.join("."), off)
}

/// `n` flips drawn from `seed`: a step after convergence (uniform to the end), a byte, a
/// bit; a share `double_share` of them double-bit patterns ([`Pattern::DOUBLE`], drawn
/// uniformly). The first k of n flips are the k flips of a campaign of k (with the same
/// share); with no doubles the draws are those of the single-bit campaign.
pub fn draw_flips(seed: u64, n: usize, reference: &Reference, double_share: f64) -> Vec<Flip> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (first, end) = (reference.converged_step + 1, reference.steps.len());
    let size = std::mem::size_of::<FlightCore>();
    let double_share = if double_share.is_finite() { double_share.clamp(0.0, 1.0) } else { 0.0 };
    (0..n)
        .map(|_| {
            let (step, byte, bit) = (rng.random_range(first..end), rng.random_range(0..size), rng.random_range(0..8));
            let pattern = if double_share > 0.0 && rng.random_bool(double_share) {
                Pattern::DOUBLE[rng.random_range(0..Pattern::DOUBLE.len())]
            } else {
                Pattern::Single
            };
            Flip { step, byte, bit, point: None, pattern }
        })
        .collect()
}

/// The fields an in-step flip hits: the attitude Λ, its twin, and the estimator's state
/// (the drift estimate Δω, the last update's time and Λ, the convergence state, the
/// re-acquisition streak, the estimator's gains and covariance).
pub const IN_STEP_FIELDS: [&str; 8] = [
    "attitude.q",
    "twin",
    "observer.drift_rad_s",
    "observer.last_update_tag_us",
    "observer.last_q",
    "observer.conv",
    "observer.streak",
    "observer.filter",
];

/// `n` in-step flips drawn from `seed`: a step after convergence (uniform to the end), a
/// probe point (uniform), a field of [`IN_STEP_FIELDS`] (uniform: the estimator's 752
/// bytes would otherwise take three flips in four), a byte of it and a bit (uniform). The
/// first k of n flips are the k flips of a campaign of k.
pub fn draw_in_step_flips(seed: u64, n: usize, reference: &Reference) -> Vec<Flip> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (first, end) = (reference.converged_step + 1, reference.steps.len());
    let spans: Vec<(usize, usize)> =
        IN_STEP_FIELDS.iter().map(|f| field_span(f).unwrap_or_else(|| panic!("{f} in the state map"))).collect();
    (0..n)
        .map(|_| {
            let step = rng.random_range(first..end);
            let point = rng.random_range(0..probe::COUNT);
            let (off, size) = spans[rng.random_range(0..spans.len())];
            let byte = off + rng.random_range(0..size);
            Flip { step, byte, bit: rng.random_range(0..8), point: Some(point), pattern: Pattern::Single }
        })
        .collect()
}

/// How a flip ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    /// Every output identical to the undisturbed flight.
    Masked,
    /// Outputs changed; the error stayed within the bound.
    Tolerated,
    /// Beyond the bound only in flagged frames, and back within 2× the nominal 3σ.
    DetectedRecovered,
    /// Beyond the bound only in flagged frames, not back within 2× the nominal 3σ by the end.
    DetectedNotRecovered,
    /// A frame claiming a good attitude beyond the bound.
    Silent,
    /// The child died: a signal, a panic, or no verdict within the timeout.
    Crash,
}

impl Outcome {
    /// Every outcome, in the document's order.
    pub const ALL: [Outcome; 6] = [
        Outcome::Masked,
        Outcome::Tolerated,
        Outcome::DetectedRecovered,
        Outcome::DetectedNotRecovered,
        Outcome::Silent,
        Outcome::Crash,
    ];

    /// Its key in the JSON output (`--json`).
    pub fn key(self) -> &'static str {
        match self {
            Outcome::Masked => "masked",
            Outcome::Tolerated => "tolerated",
            Outcome::DetectedRecovered => "detected_recovered",
            Outcome::DetectedNotRecovered => "detected_not_recovered",
            Outcome::Silent => "silent",
            Outcome::Crash => "crash",
        }
    }

    /// Its name in the tables.
    pub fn name(self) -> &'static str {
        match self {
            Outcome::Masked => "masked",
            Outcome::Tolerated => "tolerated",
            Outcome::DetectedRecovered => "detected, recovered",
            Outcome::DetectedNotRecovered => "detected, not recovered",
            Outcome::Silent => "silent",
            Outcome::Crash => "crash",
        }
    }
}

/// What a flip's flight showed (the child's verdict; for a crash, what the parent saw).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Verdict {
    /// The flip.
    pub flip: Flip,
    /// The outcome.
    pub outcome: Outcome,
    /// Time from the flip to the first output that differed, s.
    pub first_change_s: Option<f64>,
    /// Largest attitude error after the flip (largest axis), arcsec.
    pub max_err_arcsec: f64,
    /// Largest error in a frame claiming a good attitude beyond the bound, arcsec.
    pub worst_silent_arcsec: f64,
    /// Frames claiming a good attitude beyond the bound.
    pub silent_frames: u64,
    /// Frames beyond the bound, flagged.
    pub flagged_frames: u64,
    /// Time from the flip until the error was back within 2× the nominal 3σ for good, s
    /// (`None`: not back by the end; 0: never left).
    pub recovered_after_s: Option<f64>,
    /// Events the unit logged after the flip that the undisturbed flight did not: name
    /// and seconds after the flip (at most 16).
    pub new_events: Vec<(String, f64)>,
    /// Why it crashed (signal, panic message, timeout).
    pub crash: Option<String>,
}

/// Flies the rest of the flight after the flip and classes it against `reference`.
pub fn fly_flipped(flight: &mut Flight, flip: Flip, reference: &Reference) -> Verdict {
    match flip.point {
        None => {
            let (bits, n) = flip.bits(std::mem::size_of::<FlightCore>());
            for &(byte, bit) in bits.iter().take(n) {
                flight.flip(byte, bit);
            }
        }
        Some(p) => flight.flip_in_step(p, flip.byte, flip.bit),
    }
    let t0 = reference.steps.get(flip.step).map_or(0.0, |s| s.t_s);
    let recover_arcsec = 2.0 * reference.nominal_3sigma_arcsec;
    let mut v = Verdict {
        flip,
        outcome: Outcome::Masked,
        first_change_s: None,
        max_err_arcsec: 0.0,
        worst_silent_arcsec: 0.0,
        silent_frames: 0,
        flagged_frames: 0,
        recovered_after_s: Some(0.0),
        new_events: Vec::new(),
        crash: None,
    };
    let (mut beyond, mut changed) = (false, false);
    while let Some(s) = flight.step() {
        let i = flight.n - 1;
        let Some(r) = reference.steps.get(i) else { break };
        // Times from the undisturbed flight's clock (a flip may corrupt the unit's).
        let t_s = r.t_s;
        if s.out != r.out || s.down != r.down {
            changed = true;
            v.first_change_s.get_or_insert(t_s - t0);
        }
        for e in &s.events {
            let known =
                r.events.iter().any(|x| x.event == e.event && x.time_us == e.time_us && x.a == e.a && x.b == e.b);
            if !known && v.new_events.len() < MAX_EVENTS {
                v.new_events.push((e.event.name().to_string(), e.time_us as f64 * 1e-6 - t0));
            }
        }
        let Some(err) = s.err_arcsec else { continue };
        // A NaN attitude is beyond every bound.
        let e = err.iter().fold(0.0f64, |m, x| if x.is_nan() || m.is_nan() { f64::NAN } else { m.max(x.abs()) });
        let e = if e.is_nan() { f64::INFINITY } else { e };
        v.max_err_arcsec = v.max_err_arcsec.max(e);
        if e > recover_arcsec {
            v.recovered_after_s = None;
        } else if v.recovered_after_s.is_none() {
            v.recovered_after_s = Some(t_s - t0);
        }
        if e > reference.bound_arcsec(i) {
            beyond = true;
            if claims_good(&s.out) {
                v.silent_frames += 1;
                v.worst_silent_arcsec = v.worst_silent_arcsec.max(e);
            } else {
                v.flagged_frames += 1;
            }
        }
    }
    v.outcome = if v.silent_frames > 0 {
        Outcome::Silent
    } else if beyond && v.recovered_after_s.is_some() {
        Outcome::DetectedRecovered
    } else if beyond {
        Outcome::DetectedNotRecovered
    } else if changed {
        Outcome::Tolerated
    } else {
        Outcome::Masked
    };
    v
}

/// The campaign's settings.
#[derive(Debug, Clone, Copy)]
pub struct Settings {
    /// Flips.
    pub flips: usize,
    /// Seed of the flips.
    pub seed: u64,
    /// Children at once.
    pub jobs: usize,
    /// A child with no verdict after this long is a hang, s.
    pub timeout_s: u32,
    /// Flips inside the step ([`draw_in_step_flips`]) instead of between two steps.
    pub in_step: bool,
    /// Between two steps: the share of double-bit patterns ([`draw_flips`]).
    pub double_share: f64,
}

/// A child at work: its flip and the read end of its pipe.
struct Child {
    flip: Flip,
    fd: i32,
}

/// Runs the campaign on `sc`: the reference, then every drawn flip in a child of its
/// own ([`run_flips`]); `on_done` is called after each verdict. Returns the reference and
/// the verdicts in the order of the drawn flips.
pub fn campaign(sc: &Scenario, set: &Settings, on_done: impl FnMut(&Verdict)) -> Result<(Reference, Vec<Verdict>)> {
    let reference = Reference::fly(sc)?;
    let flips = if set.in_step {
        draw_in_step_flips(set.seed, set.flips, &reference)
    } else {
        draw_flips(set.seed, set.flips, &reference, set.double_share)
    };
    let verdicts = run_flips(sc, &reference, &flips, set, on_done)?;
    Ok((reference, verdicts))
}

/// Flies `sc` again and every flip of `flips` in a child of its own (forked at the flip's
/// step, at most `set.jobs` at once); `on_done` is called after each verdict. Returns the
/// verdicts in the order of `flips`.
pub fn run_flips(
    sc: &Scenario,
    reference: &Reference,
    flips: &[Flip],
    set: &Settings,
    mut on_done: impl FnMut(&Verdict),
) -> Result<Vec<Verdict>> {
    let mut order: Vec<usize> = (0..flips.len()).collect();
    order.sort_by_key(|&i| (flips[i].step, i));
    let mut verdicts: Vec<Option<Verdict>> = vec![None; flips.len()];
    let mut running: BTreeMap<i32, (usize, Child)> = BTreeMap::new();
    let mut flight = Flight::new(sc)?;
    let mut reap = |running: &mut BTreeMap<i32, (usize, Child)>, verdicts: &mut Vec<Option<Verdict>>| -> Result<()> {
        let (idx, v) = reap_one(running)?;
        on_done(&v);
        verdicts[idx] = Some(v);
        Ok(())
    };
    for &idx in &order {
        let flip = flips[idx];
        if flip.step >= reference.steps.len() || flip.byte >= std::mem::size_of::<FlightCore>() || flip.bit >= 8 {
            bail!("flip {flip:?} outside the flight or the core");
        }
        while flight.n < flip.step {
            let s = flight.step().context("the flight ended before a flip")?;
            let r = &reference.steps[flight.n - 1];
            if s.out != r.out || s.down != r.down {
                bail!(
                    "the second flight differs from the first at step {}: the scenario is not reproducible",
                    flight.n
                );
            }
        }
        while running.len() >= set.jobs.max(1) {
            reap(&mut running, &mut verdicts)?;
        }
        let (pid, fd) = spawn(&mut flight, flip, reference, set.timeout_s)?;
        running.insert(pid, (idx, Child { flip, fd }));
    }
    while !running.is_empty() {
        reap(&mut running, &mut verdicts)?;
    }
    verdicts.into_iter().map(|v| v.context("a flip without a verdict")).collect()
}

/// Forks a child that flies `flip` on its copy of `flight` and writes its verdict (JSON)
/// to a pipe; returns its pid and the pipe's read end.
fn spawn(flight: &mut Flight, flip: Flip, reference: &Reference, timeout_s: u32) -> Result<(i32, i32)> {
    let mut fds = [0i32; 2];
    // SAFETY: plain pipe(2) into a two-element array.
    if unsafe { libc::pipe(fds.as_mut_ptr()) } != 0 {
        bail!("pipe: {}", std::io::Error::last_os_error());
    }
    // SAFETY: the child is a copy of this thread only; it computes, writes to its pipe and
    // leaves with _exit (the allocator's locks are reset by fork; the tool is
    // single-threaded, the tests may fork from several threads).
    let pid = unsafe { libc::fork() };
    if pid < 0 {
        bail!("fork: {}", std::io::Error::last_os_error());
    }
    if pid == 0 {
        // SAFETY: in the child: its own copy of everything; it never returns.
        unsafe {
            libc::close(fds[0]);
            libc::alarm(timeout_s);
        }
        child(flight, flip, reference, fds[1]);
    }
    // SAFETY: the parent's copy of the write end.
    unsafe { libc::close(fds[1]) };
    Ok((pid, fds[0]))
}

/// The child: flies the flip, writes the verdict (or the panic's message) to `fd`, exits.
fn child(flight: &mut Flight, flip: Flip, reference: &Reference, fd: i32) -> ! {
    let message = std::sync::Arc::new(std::sync::Mutex::new(String::new()));
    let m = message.clone();
    std::panic::set_hook(Box::new(move |info| {
        if let Ok(mut s) = m.lock() {
            *s = info.to_string();
        }
    }));
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| fly_flipped(flight, flip, reference)));
    let v = r.unwrap_or_else(|_| {
        let text = message.lock().map(|s| s.clone()).unwrap_or_default();
        Verdict { outcome: Outcome::Crash, crash: Some(format!("panic: {text}")), ..crashed(flip) }
    });
    let text = serde_json::to_vec(&v).unwrap_or_default();
    // SAFETY: `fd` is this child's write end; the process ends without running the
    // parent's destructors or flushing its buffers.
    unsafe {
        let mut f = std::fs::File::from_raw_fd(fd);
        let _ = std::io::Write::write_all(&mut f, &text);
        drop(f);
        libc::_exit(0)
    }
}

/// A crash verdict for `flip`, before its cause is known.
fn crashed(flip: Flip) -> Verdict {
    Verdict {
        flip,
        outcome: Outcome::Crash,
        first_change_s: None,
        max_err_arcsec: 0.0,
        worst_silent_arcsec: 0.0,
        silent_frames: 0,
        flagged_frames: 0,
        recovered_after_s: None,
        new_events: Vec::new(),
        crash: None,
    }
}

/// Waits for one of `running` to end (its pipe closes when it exits or dies); its
/// verdict (a crash when it died without one). Only these children are waited for, so
/// campaigns in other threads keep theirs.
fn reap_one(running: &mut BTreeMap<i32, (usize, Child)>) -> Result<(usize, Verdict)> {
    let mut polled: Vec<libc::pollfd> =
        running.values().map(|(_, c)| libc::pollfd { fd: c.fd, events: libc::POLLIN, revents: 0 }).collect();
    let ready = loop {
        // SAFETY: poll(2) on the read ends this parent owns, `polled.len()` entries.
        let n = unsafe { libc::poll(polled.as_mut_ptr(), polled.len() as libc::nfds_t, -1) };
        if n > 0 {
            break polled.iter().find(|p| p.revents != 0).map(|p| p.fd);
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            bail!("poll: {e}");
        }
    };
    let Some(pid) = running.iter().find(|(_, (_, c))| Some(c.fd) == ready).map(|(&pid, _)| pid) else {
        bail!("poll: no child ready")
    };
    let Some((idx, c)) = running.remove(&pid) else { bail!("poll: an unknown child {pid}") };
    let mut text = Vec::new();
    // SAFETY: the read end of this child's pipe, owned by the parent and closed here.
    let mut f = unsafe { std::fs::File::from_raw_fd(c.fd) };
    // To the end: the child has closed its end (exited or died).
    f.read_to_end(&mut text).context("reading a child's verdict")?;
    let mut status = 0;
    // SAFETY: waitpid on this child.
    if unsafe { libc::waitpid(pid, &mut status, 0) } != pid {
        bail!("waitpid {pid}: {}", std::io::Error::last_os_error());
    }
    let died = if libc::WIFSIGNALED(status) {
        let sig = libc::WTERMSIG(status);
        Some(if sig == libc::SIGALRM { "hang (timeout)".to_string() } else { signal_name(sig) })
    } else if libc::WIFEXITED(status) && libc::WEXITSTATUS(status) != 0 {
        Some(format!("exit status {}", libc::WEXITSTATUS(status)))
    } else {
        None
    };
    let v = match (died, serde_json::from_slice::<Verdict>(&text)) {
        (None, Ok(v)) if v.flip == c.flip => v,
        (died, _) => Verdict { crash: Some(died.unwrap_or_else(|| "no verdict".into())), ..crashed(c.flip) },
    };
    Ok((idx, v))
}

/// SIGSEGV and the others by name.
fn signal_name(sig: i32) -> String {
    match sig {
        libc::SIGSEGV => "SIGSEGV".into(),
        libc::SIGBUS => "SIGBUS".into(),
        libc::SIGILL => "SIGILL".into(),
        libc::SIGABRT => "SIGABRT".into(),
        libc::SIGFPE => "SIGFPE".into(),
        libc::SIGKILL => "SIGKILL".into(),
        s => format!("signal {s}"),
    }
}

/// The exact (Clopper–Pearson) two-sided 95 % interval of a proportion `k` of `n`.
pub fn clopper_pearson(k: u64, n: u64) -> (f64, f64) {
    use statrs::distribution::{Beta, ContinuousCDF};
    if n == 0 {
        return (0.0, 1.0);
    }
    let (kf, nf) = (k as f64, n as f64);
    let beta = |a: f64, b: f64, p: f64| Beta::new(a, b).map_or(f64::NAN, |d| d.inverse_cdf(p));
    let lo = if k == 0 { 0.0 } else { beta(kf, nf - kf + 1.0, 0.025) };
    let hi = if k == n { 1.0 } else { beta(kf + 1.0, nf - kf, 0.975) };
    (lo, hi)
}

/// Counts per outcome.
pub fn counts(verdicts: &[Verdict]) -> BTreeMap<Outcome, u64> {
    let mut m: BTreeMap<Outcome, u64> = Outcome::ALL.iter().map(|&o| (o, 0)).collect();
    for v in verdicts {
        *m.entry(v.outcome).or_default() += 1;
    }
    m
}

/// The field a verdict's flip hit, to `depth` levels ("observer.filter" at 2).
fn field_at(v: &Verdict, depth: usize) -> String {
    let (path, _) = v.flip.field();
    path.split('.').take(depth).collect::<Vec<_>>().join(".")
}

/// A percentage with its 95 % interval.
fn share(k: u64, n: u64) -> String {
    let (lo, hi) = clopper_pearson(k, n);
    let p = if n == 0 { 0.0 } else { k as f64 / n as f64 };
    format!("{:.2} % | {:.2}–{:.2} %", 100.0 * p, 100.0 * lo, 100.0 * hi)
}

/// The campaign's tables as Markdown: outcomes with 95 % intervals, recovery times,
/// per field, and every silent and crash flip.
pub fn report(reference: &Reference, verdicts: &[Verdict]) -> String {
    use std::fmt::Write;
    let n = verdicts.len() as u64;
    let c = counts(verdicts);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Undisturbed flight: converged at {:.2} s, attitude error 3σ after settling {:.2}″ (largest axis); \
         tolerated bound max({TOLERATED_ARCSEC}″, the unit's own 3σ), recovery within 2 × {:.2}″ = {:.2}″. \
         `FlightCore` is {} bytes.\n",
        reference.steps.get(reference.converged_step).map_or(0.0, |s| s.t_s),
        reference.nominal_3sigma_arcsec,
        reference.nominal_3sigma_arcsec,
        2.0 * reference.nominal_3sigma_arcsec,
        std::mem::size_of::<FlightCore>()
    );
    let _ = writeln!(s, "| outcome | flips | share | 95 % interval |\n|---|---|---|---|");
    for o in Outcome::ALL {
        let k = c[&o];
        let _ = writeln!(s, "| {} | {k} | {} |", o.name(), share(k, n));
    }
    let _ = writeln!(s, "| all | {n} | | |\n");
    // Per pattern, when the campaign drew double-bit ones.
    if verdicts.iter().any(|v| v.flip.pattern != Pattern::Single) {
        let _ = writeln!(s, "Per pattern (silent with its 95 % interval):\n");
        let _ = write!(s, "| pattern | flips |");
        for o in Outcome::ALL {
            let _ = write!(s, " {} |", o.name());
        }
        let _ = writeln!(s, " silent, 95 % interval |\n|---|---|{}---|", "---|".repeat(Outcome::ALL.len()));
        for p in Pattern::ALL {
            let of: Vec<&Verdict> = verdicts.iter().filter(|v| v.flip.pattern == p).collect();
            let _ = write!(s, "| {} | {} |", p.name(), of.len());
            for o in Outcome::ALL {
                let _ = write!(s, " {} |", of.iter().filter(|v| v.outcome == o).count());
            }
            let k = of.iter().filter(|v| v.outcome == Outcome::Silent).count() as u64;
            let (lo, hi) = clopper_pearson(k, of.len() as u64);
            let _ = writeln!(s, " {:.2}–{:.2} % |", 100.0 * lo, 100.0 * hi);
        }
        let _ = writeln!(s);
    }
    let mut rec: Vec<f64> = verdicts
        .iter()
        .filter(|v| v.outcome == Outcome::DetectedRecovered)
        .filter_map(|v| v.recovered_after_s)
        .collect();
    rec.sort_by(f64::total_cmp);
    if !rec.is_empty() {
        let _ = writeln!(
            s,
            "Recovery (detected, back within {:.2}″ for good), s after the flip: median {:.2}, largest {:.2} ({} flips).\n",
            2.0 * reference.nominal_3sigma_arcsec,
            rec[rec.len() / 2],
            rec[rec.len() - 1],
            rec.len()
        );
    }
    // Events the unit logged that the undisturbed flight did not, per outcome.
    let _ =
        writeln!(s, "Events logged after a flip that the undisturbed flight did not log (flips that logged each):\n");
    let _ = writeln!(s, "| outcome | events |\n|---|---|");
    for o in Outcome::ALL {
        let mut ev: BTreeMap<&str, u64> = BTreeMap::new();
        for v in verdicts.iter().filter(|v| v.outcome == o) {
            let mut names: Vec<&str> = v.new_events.iter().map(|(e, _)| e.as_str()).collect();
            names.sort_unstable();
            names.dedup();
            for e in names {
                *ev.entry(e).or_default() += 1;
            }
        }
        let list: Vec<String> = ev.iter().map(|(e, k)| format!("{e} {k}")).collect();
        let _ = writeln!(s, "| {} | {} |", o.name(), if list.is_empty() { "none".into() } else { list.join(", ") });
    }
    // Per field.
    let _ = writeln!(s, "\nPer field of `FlightCore` (two levels; bytes: the field's size):\n");
    let _ = write!(s, "| field | bytes | flips |");
    for o in Outcome::ALL {
        let _ = write!(s, " {} |", o.name());
    }
    let _ = writeln!(s, "\n|---|---|---|{}", "---|".repeat(Outcome::ALL.len()));
    let mut per: BTreeMap<String, BTreeMap<Outcome, u64>> = BTreeMap::new();
    for v in verdicts {
        *per.entry(field_at(v, 2)).or_default().entry(v.outcome).or_default() += 1;
    }
    for (f, m) in &per {
        let size = field_span(f).map(|(_, b)| b);
        let total: u64 = m.values().sum();
        let _ = write!(s, "| {f} | {} | {total} |", size.map_or(String::new(), |b| b.to_string()));
        for o in Outcome::ALL {
            let _ = write!(s, " {} |", m.get(&o).copied().unwrap_or(0));
        }
        let _ = writeln!(s);
    }
    let bad: Vec<&Verdict> =
        verdicts.iter().filter(|v| matches!(v.outcome, Outcome::Silent | Outcome::Crash)).collect();
    if !bad.is_empty() {
        let _ = writeln!(s, "\nEvery silent and crash flip (byte of the field, bit; the flip's time in the flight):\n");
        let _ = writeln!(
            s,
            "| outcome | field | byte, bit | at, s | worst claimed-good error, ″ | claimed-good frames | largest error, ″ \
             | back within 2× 3σ after, s | why |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
        let mut bad = bad;
        bad.sort_by_key(|v| (v.outcome, v.flip.field().0, v.flip.byte, v.flip.bit));
        for v in bad {
            let (f, off) = v.flip.field();
            let silent = v.outcome == Outcome::Silent;
            let shown = |x: String| if silent { x } else { String::new() };
            let back = match v.recovered_after_s {
                None => "not by the end".into(),
                Some(t) => format!("{t:.2}"),
            };
            let _ = writeln!(
                s,
                "| {} | {f} | {off}, {}{} | {:.3} | {} | {} | {} | {} | {} |",
                v.outcome.name(),
                v.flip.bit,
                match v.flip.pattern {
                    Pattern::Single => String::new(),
                    p => format!(" ({})", p.name()),
                },
                reference.steps.get(v.flip.step).map_or(0.0, |s| s.t_s),
                shown(format!("{:.0}", v.worst_silent_arcsec)),
                shown(v.silent_frames.to_string()),
                shown(format!("{:.0}", v.max_err_arcsec)),
                shown(back),
                v.crash.as_deref().unwrap_or("")
            );
        }
    }
    s
}

/// Where the field at `path` ("attitude.q") lies in the core: offset from the start of
/// the `FlightCore` value and size, bytes.
pub fn field_span(path: &str) -> Option<(usize, usize)> {
    let mut fields = FlightCore::state_map();
    let (mut offset, mut size) = (0, None);
    for name in path.split('.') {
        let f = fields.iter().find(|f| f.name == name)?;
        offset += f.offset;
        size = Some(f.size);
        fields = f.parts;
    }
    size.map(|s| (offset, s))
}

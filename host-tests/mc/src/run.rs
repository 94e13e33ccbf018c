//! Run i of a campaign, a pure function of (campaign, i): the draw of its dispersions and
//! faults ([`draw`]), the open-loop flight through the simulator and the flight core
//! ([`run`]: the harness's `Simulation`, mock links and [`FlightCore::step`](ssis::flight::FlightCore::step), as `ssis-sim
//! run` flies them), and its indices.
//!
//! **Random streams.** Every drawn quantity has its own ChaCha20 stream: the key is the
//! XXH3-64 of the quantity's name seeded with the campaign's seed, the stream number is
//! the run number i, and the position is 0 (a counter-based generator: run i's numbers do
//! not depend on any other run, nor on what else the campaign disperses). The sensor noise
//! of run i (`noise = "per-run"`) is the scenario seed drawn from the stream named
//! `noise` (its first 64-bit word, shifted right by one). Nothing else is random, so a run gives the same bits on any machine, in any
//! order, alone or in a batch.

use anyhow::{anyhow, Context, Result};
use rand::{Rng, RngCore, SeedableRng};
use rand_chacha::ChaCha20Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use ssis::calib::{CalibrationTable, N_FOG};
use ssis::combination::FogSet;
use ssis::flight::snapshot::Snapshot;
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::fog::TrueErrors;
use ssis_sim::harness::{step_on_mock_links, Evaluator, Observed, Simulation};
use ssis_sim::scenario::Scenario;

use crate::campaign::{set_scenario_number, Campaign, CoreCache, Dist, FaultKind, Loop, Noise, Target};
use crate::indices::Indices;

/// The random stream of quantity `name` in run `run` of a campaign seeded `seed`.
pub fn stream(seed: u64, name: &str, run: u64) -> ChaCha20Rng {
    let mut r = ChaCha20Rng::seed_from_u64(xxhash_rust::xxh3::xxh3_64_with_seed(name.as_bytes(), seed));
    r.set_stream(run);
    r
}

/// One number of `dist` from `r`.
pub fn sample(dist: &Dist, r: &mut ChaCha20Rng) -> f64 {
    match *dist {
        Dist::Normal { mean, sigma } => mean + sigma * r.sample::<f64, _>(StandardNormal),
        Dist::Uniform { low, high } => low + (high - low) * r.random::<f64>(),
        Dist::TruncatedNormal { mean, sigma, bound_sigma } => {
            // Redrawn until inside: at least 8 % of draws are for bound_sigma ≥ 0.1, so 1000
            // tries fail with probability below 1e-36; the bound then.
            let mut z = bound_sigma;
            for _ in 0..1000 {
                let w: f64 = r.sample(StandardNormal);
                if w.abs() <= bound_sigma {
                    z = w;
                    break;
                }
            }
            mean + sigma * z
        }
    }
}

/// A fault drawn to happen in a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FaultEvent {
    /// What.
    pub kind: FaultKind,
    /// When, s.
    pub t_s: f64,
    /// Which FOG (`fog-lost`).
    pub fog: usize,
    /// How long, s (`star-outage`, `reset`).
    pub duration_s: f64,
}

/// What run i draws: its parameters, the dispersed scenario, its faults, and the table the
/// unit flies.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Draw {
    /// The run number.
    pub run: u64,
    /// (name, value) in the order of [`Campaign::params`]: each quantity's offset δ, each
    /// fault's `.occurs` (0 or 1), `.t_s` and `.fog` (NaN when it does not occur).
    pub params: Vec<(String, f64)>,
    /// The scenario of this run: the base with every δ applied, its seed the run's noise
    /// seed, star-tracker outages added.
    pub scenario: Scenario,
    /// The faults that occur, in campaign order.
    pub faults: Vec<FaultEvent>,
    /// The unit's table (the base scenario's for this run: dispersions change the truth,
    /// not what the unit knows).
    pub table: CalibrationTable,
}

/// Draws run `i` of `c`.
pub fn draw(c: &Campaign, i: u64) -> Result<Draw> {
    anyhow::ensure!(i < c.runs, "run {i}: the campaign has runs 0..{}", c.runs);
    let mut sc = c.scenario.clone();
    if c.noise == Noise::PerRun {
        // 63 bits: the scenario keeps a TOML form (whose integers are signed).
        sc.seed = stream(c.seed, "noise", i).next_u64() >> 1;
    }
    // The unit's table as the undispersed scenario flies it in this run.
    let table = Simulation::new(&sc).context("the base scenario")?.table;
    let mut params = Vec::with_capacity(c.params.len());
    let mut truth: Option<CalibrationTable> = None;
    let mut value: Option<toml::Value> = None;
    for q in &c.quantities {
        let d = sample(&q.dist, &mut stream(c.seed, &q.name, i));
        params.push((q.name.clone(), d));
        match &q.target {
            Target::Table(fields) => {
                let t = truth.get_or_insert_with(|| {
                    let mut t = CalibrationTable::DEFAULT;
                    if let Some(e) = &sc.fog.errors {
                        t.fog = e.fog;
                        t.misalignment = e.misalignment;
                    }
                    t
                });
                for name in fields {
                    let f = ssis_common::table::field_named(name).ok_or_else(|| anyhow!("no table field {name}"))?;
                    f.set(t, f.get(t) + d);
                }
            }
            Target::Scenario(path) => {
                let v = match &mut value {
                    Some(v) => v,
                    None => value.insert(toml::Value::try_from(&sc)?),
                };
                let base = crate::campaign::scenario_number(v, path)?;
                set_scenario_number(v, path, base + d)?;
            }
        }
    }
    if let Some(v) = value {
        let base_dir = sc.base_dir.clone();
        sc = v.try_into().context("the dispersed scenario")?;
        sc.base_dir = base_dir;
    }
    if let Some(t) = truth {
        sc.fog.errors = Some(TrueErrors { fog: t.fog, misalignment: t.misalignment });
    }
    let mut faults = Vec::new();
    for x in &c.faults {
        let mut r = stream(c.seed, &x.name, i);
        let (u, v, w): (f64, f64, f64) = (r.random(), r.random(), r.random());
        let occurs = u < x.probability;
        let t_s = x.window_s[0] + (x.window_s[1] - x.window_s[0]) * v;
        let fog = x.fog.unwrap_or(((w * N_FOG as f64) as usize).min(N_FOG - 1));
        let nan_unless = |y: f64| if occurs { y } else { f64::NAN };
        params.push((format!("{}.occurs", x.name), f64::from(u8::from(occurs))));
        params.push((format!("{}.t_s", x.name), nan_unless(t_s)));
        if x.kind == FaultKind::FogLost {
            params.push((format!("{}.fog", x.name), nan_unless(fog as f64)));
        }
        if occurs {
            if x.kind == FaultKind::StarOutage {
                sc.star_tracker.outages.push([t_s, t_s + x.duration_s]);
            }
            faults.push(FaultEvent { kind: x.kind, t_s, fog, duration_s: x.duration_s });
        }
    }
    sc.check().with_context(|| format!("run {i}: the dispersed scenario"))?;
    Ok(Draw { run: i, params, scenario: sc, faults, table })
}

/// A run's knowledge error, decimated.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Series {
    /// Time of each sample, s.
    pub t_s: Vec<f64>,
    /// Knowledge error per axis (estimated against true attitude, ICS), arcsec.
    pub err_arcsec: Vec<[f64; 3]>,
}

/// What run i gives.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunOutput {
    /// The run number.
    pub run: u64,
    /// Its drawn parameters ([`Draw::params`]).
    pub params: Vec<(String, f64)>,
    /// Per index and axis, its statistic over time (key order: [`Campaign::index_keys`]), arcsec.
    pub indices: Vec<(String, f64)>,
    /// Every `series_every`-th evaluated output (from the start), when asked for.
    pub series: Option<Series>,
    /// Steps flown.
    pub steps: u64,
    /// Outputs compared with truth.
    pub evaluated: u64,
    /// When the unit first reported convergence, s.
    pub converged_at_s: Option<f64>,
}

impl RunOutput {
    /// XXH3-64 of every bit of the output (parameters, indices, series): equal digests,
    /// equal runs.
    pub fn digest(&self) -> u64 {
        let mut b = Vec::new();
        b.extend_from_slice(&self.run.to_le_bytes());
        for (k, v) in self.params.iter().chain(&self.indices) {
            b.extend_from_slice(k.as_bytes());
            b.extend_from_slice(&v.to_bits().to_le_bytes());
        }
        if let Some(s) = &self.series {
            for (t, e) in s.t_s.iter().zip(&s.err_arcsec) {
                for v in [*t, e[0], e[1], e[2]] {
                    b.extend_from_slice(&v.to_bits().to_le_bytes());
                }
            }
        }
        b.extend_from_slice(&self.steps.to_le_bytes());
        b.extend_from_slice(&self.evaluated.to_le_bytes());
        xxhash_rust::xxh3::xxh3_64(&b)
    }
}

/// Steps between two snapshots when a run has a reset (the firmware's `SNAPSHOT_STEPS`).
const SNAPSHOT_STEPS: u64 = 80;

/// Flies run `i` of `c` in open loop; `series_every` > 0 keeps every that-many-th output's
/// error.
pub fn run(c: &Campaign, i: u64, series_every: u64) -> Result<RunOutput> {
    anyhow::ensure!(
        c.loop_ == Loop::Open,
        "{}: loop = \"closed\": its runs fly in Basilisk (Python: ssis.mc); this flies open-loop runs only",
        c.origin
    );
    let d = draw(c, i)?;
    let (t_s, err, out) = fly(&d, c.indices.from_s, series_every, &c.cores).with_context(|| format!("run {i}"))?;
    let indices = Indices::compute(&c.indices, &t_s, &err);
    Ok(RunOutput { run: i, params: d.params, indices, ..out })
}

/// The open-loop flight of a draw: the times and errors from `from_s` on, and the rest of
/// the output (params and indices empty); its cores come from `cores`.
pub fn fly(
    d: &Draw,
    from_s: f64,
    series_every: u64,
    cores: &CoreCache,
) -> Result<(Vec<f64>, Vec<[f64; 3]>, RunOutput)> {
    let sc = &d.scenario;
    let mut sim = Simulation::new(sc)?;
    sim.table = d.table;
    let mut eval = Evaluator::new(&sim);
    let profile = sim.profile;
    let dt_s = profile.dt_s();
    let table = sim.table;
    let new_core = || cores.core(profile, &table);
    let mut core = new_core()?;
    if sim.needs_pad_alignment() {
        core.align(sim.initial_q());
    }
    // The links as the harness makes them (`ssis_sim::harness::run`).
    let seed = sc.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    let fresh_links = || {
        (
            [0u64, 1, 2, 3].map(|k| MockLink::new(sc.links.fog, seed ^ (k + 1))),
            MockLink::new(sc.links.star, seed ^ 99),
            MockSink::default(),
        )
    };
    let (mut fog_links, mut star_link, mut out_link) = fresh_links();
    let step_of = |t: f64| (t / dt_s).ceil().max(1.0) as u64;
    let mut fogs = profile.fogs;
    let lost: Vec<(u64, usize)> =
        d.faults.iter().filter(|f| f.kind == FaultKind::FogLost).map(|f| (step_of(f.t_s), f.fog)).collect();
    let resets: Vec<(u64, u64)> = d
        .faults
        .iter()
        .filter(|f| f.kind == FaultKind::Reset)
        .map(|f| (step_of(f.t_s), ((f.duration_s / dt_s).round() as u64).max(2)))
        .collect();
    let mut snap = Snapshot::default();
    let n_keep = (sim.steps as f64 * ((sc.duration_s - from_s) / sc.duration_s).clamp(0.0, 1.0)) as usize + 1;
    let (mut t_s, mut err) = (Vec::with_capacity(n_keep), Vec::with_capacity(n_keep));
    let mut series = (series_every > 0).then(Series::default);
    let mut evaluated = 0u64;
    while let Some(input) = sim.next_step() {
        let n = input.n;
        if let Some(t) = input.truth {
            eval.push_truth(t);
        }
        for &(at, k) in &lost {
            if n == at {
                fogs = FogSet(fogs.0 & !(1 << k));
            }
        }
        if let Some(&(at, down)) = resets.iter().find(|(at, down)| (*at..*at + down).contains(&n)) {
            // Down: nothing stepped; at the last step down, the unit boots and resumes.
            if n == at + down - 1 {
                core = new_core()?;
                (fog_links, star_link, out_link) = fresh_links();
                let _ = core.resume(&snap);
            }
            continue;
        }
        let out = step_on_mock_links(&mut core, &mut fog_links, &mut star_link, &mut out_link, &input, fogs);
        core.send_events(&mut out_link);
        out_link.bytes.clear();
        if !resets.is_empty() && n.is_multiple_of(SNAPSHOT_STEPS) {
            core.snapshot_into(&mut snap);
        }
        if let Some(rec) = eval.evaluate(&Observed::from(&out)) {
            if let Some(s) = series.as_mut().filter(|_| evaluated.is_multiple_of(series_every)) {
                s.t_s.push(rec.t_s);
                s.err_arcsec.push(rec.att_err_arcsec);
            }
            evaluated += 1;
            if rec.t_s >= from_s {
                t_s.push(rec.t_s);
                err.push(rec.att_err_arcsec);
            }
        }
    }
    let out = RunOutput {
        run: d.run,
        params: Vec::new(),
        indices: Vec::new(),
        series,
        steps: sim.steps,
        evaluated,
        converged_at_s: eval.converged_at_s,
    };
    Ok((t_s, err, out))
}

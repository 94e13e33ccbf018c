//! `ssis-bench`: host replay speed of `FlightCore::step()`.
//!
//! Pre-generates the frames of a flight (Earth pointing, the paper's sensors, star
//! tracker at 4 Hz) in memory, then replays them through the same `step()` the firmware
//! runs, on in-memory links that cost next to nothing, and reports steps per second and
//! simulated hours per wall second (best of `--repeat` runs, one core).
//!
//! `--log LOG.csv`: where the time of `ssis-sim replay LOG.csv` goes: the log read into
//! steps alone (`ssis_sim::recorded::LogStream`), then the whole streamed replay
//! (`ssis_sim::streamed`: reading, conventions check, encoding, `step()`, the evidence);
//! CPU time of the process (user + system) beside the wall time of each.
//! `--write-log SCENARIO --out LOG.csv [--duration S]` writes such a log of a spacecraft
//! scenario (`ssis_sim::sc_record`: the frames its FOGs and star tracker send, and truth).

use std::convert::Infallible;
use std::time::Instant;

use clap::Parser;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;
use ssis::calib::CalibrationTable;
use ssis::flight::{FlightCore, FogLinks, Links, Profile};
use ssis_sim::fog::{FogModel, FogSpec};
use ssis_sim::star::{StarModel, StarSpec};
use ssis_sim::truth::{MotionSpec, Truth};

#[derive(Parser)]
#[command(name = "ssis-bench", about = "Host replay speed of the flight step")]
struct Args {
    /// Steps to replay (200 Hz: 720,000 = 1 h).
    #[arg(long, default_value_t = 720_000)]
    steps: usize,
    /// Replays; the best is reported.
    #[arg(long, default_value_t = 3)]
    repeat: usize,
    /// A recorded spacecraft log (CSV): time its reading and its streamed replay instead.
    #[arg(long)]
    log: Option<std::path::PathBuf>,
    /// Write a spacecraft log of this scenario to `--out` instead (the benchmark's logs).
    #[arg(long, requires = "out")]
    write_log: Option<std::path::PathBuf>,
    /// The log `--write-log` writes (refused if it exists).
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// `--write-log`: seconds of the scenario (default: its duration).
    #[arg(long)]
    duration: Option<f64>,
    /// `--write-log`: truth on every N-th row.
    #[arg(long, default_value_t = 2)]
    truth_every: u64,
}

/// `--write-log`: a spacecraft log of `scenario`, compact (time and increments per FOG,
/// the star tracker, truth on every `truth_every`-th row).
fn write_log(
    scenario: &std::path::Path,
    out: &std::path::Path,
    duration: Option<f64>,
    truth_every: u64,
) -> anyhow::Result<()> {
    let mut sc = ssis_sim::scenario::Scenario::from_file(scenario)?;
    if let Some(d) = duration {
        anyhow::ensure!(d > 0.0 && d.is_finite(), "--duration must be > 0");
        sc.duration_s = d;
    }
    let mut sim = ssis_sim::harness::Simulation::new(&sc)?;
    anyhow::ensure!(
        sim.profile.dt_us == Profile::SPACECRAFT.dt_us,
        "{}: a spacecraft scenario is needed",
        scenario.display()
    );
    let steps = sim.steps;
    let mut f = std::io::BufWriter::with_capacity(1 << 20, ssis_common::output::create(out)?);
    ssis_sim::sc_record::write_log(&mut sim, steps, truth_every, false, &mut f)?;
    f.into_inner().map_err(|e| anyhow::anyhow!("{}: cannot write: {}", out.display(), e.error()))?.commit()?;
    println!("wrote {} ({steps} steps of 5 ms)", out.display());
    Ok(())
}

/// CPU time of this process so far (user + system), s, from /proc/self/stat.
fn cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit_once(')').map_or("", |(_, a)| a);
    let f: Vec<f64> = after.split_whitespace().skip(11).take(2).filter_map(|v| v.parse().ok()).collect();
    f.iter().sum::<f64>() / 100.0
}

/// `--log`: the log's reading alone, then its streamed replay, each timed.
fn bench_log(path: &std::path::Path) -> anyhow::Result<()> {
    use ssis_sim::recorded::LogStream;
    let time = |what: &str, steps: u64, t0: Instant, c0: f64| {
        let (wall, cpu) = (t0.elapsed().as_secs_f64(), cpu_s() - c0);
        println!(
            "{what:<44} {steps} steps  wall {wall:.2} s ({:.0} steps/s)  CPU {cpu:.2} s ({:.0} steps/s)",
            steps as f64 / wall,
            steps as f64 / cpu.max(1e-9)
        );
        cpu
    };
    let (t0, c0) = (Instant::now(), cpu_s());
    let mut stream = LogStream::open(path)?;
    while stream.next_step()?.is_some() {}
    let read_cpu = time("read (CSV rows into steps)", stream.steps, t0, c0);
    let (t0, c0) = (Instant::now(), cpu_s());
    let table = CalibrationTable::DEFAULT;
    let s = ssis_sim::streamed::replay_stream(LogStream::open(path)?, &table, 60.0, |_| {}, |_, _| {})?;
    let all_cpu = time("streamed replay (read, check, step, evidence)", s.summary.steps, t0, c0);
    println!(
        "of the replay's CPU time: reading {:.0} %, the rest {:.0} %",
        100.0 * read_cpu / all_cpu,
        100.0 * (1.0 - read_cpu / all_cpu)
    );
    Ok(())
}

/// A receive link over pre-recorded bytes; `release` makes the next step's bytes readable.
struct Replay {
    bytes: Vec<u8>,
    ends: Vec<usize>,
    pos: usize,
    limit: usize,
    step: usize,
}

impl Replay {
    fn new() -> Self {
        Replay { bytes: Vec::new(), ends: Vec::new(), pos: 0, limit: 0, step: 0 }
    }
    fn record(&mut self, b: &[u8]) {
        self.bytes.extend_from_slice(b);
        self.ends.push(self.bytes.len());
    }
    fn release(&mut self) {
        self.limit = self.ends.get(self.step).copied().unwrap_or(self.bytes.len());
        self.step += 1;
    }
    fn rewind(&mut self) {
        self.pos = 0;
        self.limit = 0;
        self.step = 0;
    }
}

impl embedded_io::ErrorType for Replay {
    type Error = Infallible;
}
impl embedded_io::ReadReady for Replay {
    fn read_ready(&mut self) -> Result<bool, Infallible> {
        Ok(self.pos < self.limit)
    }
}
impl embedded_io::Read for Replay {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Infallible> {
        let n = buf.len().min(self.limit - self.pos);
        buf[..n].copy_from_slice(&self.bytes[self.pos..self.pos + n]);
        self.pos += n;
        Ok(n)
    }
}

/// An output link that counts bytes.
struct Count(usize);
impl embedded_io::ErrorType for Count {
    type Error = Infallible;
}
impl embedded_io::WriteReady for Count {
    fn write_ready(&mut self) -> Result<bool, Infallible> {
        Ok(true)
    }
}
impl embedded_io::Write for Count {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Infallible> {
        self.0 += buf.len();
        Ok(buf.len())
    }
    fn flush(&mut self) -> Result<(), Infallible> {
        Ok(())
    }
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    if let (Some(sc), Some(out)) = (&args.write_log, &args.out) {
        return write_log(sc, out, args.duration, args.truth_every);
    }
    if let Some(log) = &args.log {
        return bench_log(log);
    }
    let profile = Profile::SPACECRAFT;
    let dt = profile.dt_s();
    let mut rng = ChaCha20Rng::seed_from_u64(1);
    let mut truth = Truth::new(MotionSpec::earth_pointing(5640.0, Vec::new()));
    let mut fogs = FogModel::new(&FogSpec::paper_post_calibration(), &mut rng);
    let table = CalibrationTable::DEFAULT;
    let mut star = StarModel::new(&StarSpec::default(), profile.dt_us, table.st_mount());
    let mut fog = [0, 1, 2, 3].map(|_| Replay::new());
    let mut star_link = Replay::new();
    eprintln!("generating {} steps of frames...", args.steps);
    for n in 1..=args.steps as u64 {
        let ts = truth.advance(dt);
        let s = fogs.sample(&ts.dtheta_rad, ts.t_s, dt, &mut rng);
        for (l, f) in fog.iter_mut().zip(s.frames.iter()) {
            l.record(&f.to_bytes());
        }
        let b = star.step(n, n * u64::from(profile.dt_us), &ts.q, &ts.rate_rad_s, &mut rng);
        star_link.record(&b);
    }
    let mut best = f64::INFINITY;
    for _ in 0..args.repeat.max(1) {
        for l in fog.iter_mut() {
            l.rewind();
        }
        star_link.rewind();
        let mut links = Links { fog: FogLinks::PerFog(fog.each_mut()), star: &mut star_link, out: Count(0) };
        let mut core = FlightCore::new(profile, &table, false).expect("core");
        let t0 = Instant::now();
        for _ in 0..args.steps {
            if let FogLinks::PerFog(ls) = &mut links.fog {
                for l in ls.iter_mut() {
                    l.release();
                }
            }
            links.star.release();
            std::hint::black_box(core.step(&mut links));
        }
        let wall = t0.elapsed().as_secs_f64();
        best = best.min(wall);
        assert_eq!(core.counters().fog_frames_rejected, 0);
    }
    let sps = args.steps as f64 / best;
    let sim_h = args.steps as f64 * dt / 3600.0;
    println!("steps: {}  best wall: {:.3} s", args.steps, best);
    println!("step() replay: {:.0} steps/s  ({:.3} µs/step)", sps, 1e6 / sps);
    println!("simulated hours per wall second: {:.2}  (a day at 200 Hz in {:.1} s)", sim_h / best, 17_280_000.0 / sps);
    Ok(())
}

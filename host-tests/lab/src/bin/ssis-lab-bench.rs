//! `ssis-lab-bench`: the model lab's benchmark: CSV ingest in MB/s, and `compare`
//! + `diagnose` on 10 million samples of 4 FOGs (goal: ≤ 10 s on one core).
//!
//! The session is a thermal rate table at 100 Hz (10 M rows = 27.8 h: the rate table's 24
//! settings up to ±10 °/s, one minute each, inside the chamber's temperature cycle) with a
//! hidden temperature-rate effect, written once with a logger's precision (10 significant
//! digits for rates, 0.0001 °C) and reused. The lab runs single-threaded, as the CLI does.
//! Each phase is timed in wall seconds and in CPU seconds of the process (user + system,
//! `getrusage`): on a shared machine the CPU figure is the one-core cost.
//!
//! ```console
//! $ cargo run --release --bin ssis-lab-bench                 # 10 M rows
//! $ cargo run --release --bin ssis-lab-bench -- --rows 1000000
//! ```

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Parser;
use ssis_common::DEG_H_PER_RAD_S;
use ssis_lab::diagnose::{candidate_terms, diagnose, diagnose_digest, Options};
use ssis_lab::fit::{compare, complete, fit_digest, held_out_rms, spec_for, DEFAULT_BLOCKS};
use ssis_lab::model::{Kind, Model};
use ssis_lab::session::RowReader;
use ssis_lab::simulate::{generate_with, Hidden, Motion, Spec, Thermal};
use ssis_lab::stream::{digest, Source};

#[derive(Parser)]
#[command(name = "ssis-lab-bench", about = "Model lab benchmark: CSV ingest, compare and diagnose on a large session")]
struct Cli {
    /// Rows of the session.
    #[arg(long, default_value_t = 10_000_000)]
    rows: usize,
    /// Directory of the session file (default: `lab-bench` in the cargo target directory).
    #[arg(long)]
    dir: Option<PathBuf>,
    /// Time the ingest only.
    #[arg(long)]
    ingest_only: bool,
    /// Skip `compare` and `diagnose` as separate commands (time the one pass only).
    #[arg(long)]
    one_pass_only: bool,
    /// Skip the ingest figure (to profile the pass alone).
    #[arg(long)]
    no_ingest: bool,
    /// Print a hash of everything the one pass computed (the digest's sums, kept rows and
    /// extremes, the fit, held-out RMS and diagnosis, as `{:?}` prints them: the shortest
    /// digits that give back each number's bits), so a change meant to be faster only can
    /// be checked to give the same numbers bit for bit.
    #[arg(long)]
    hash: bool,
}

/// Hashes what is written to it.
struct HashWriter(std::collections::hash_map::DefaultHasher);

impl std::fmt::Write for HashWriter {
    fn write_str(&mut self, s: &str) -> std::fmt::Result {
        std::hash::Hasher::write(&mut self.0, s.as_bytes());
        Ok(())
    }
}

/// The target directory: the executable is `<target>/<triple>/<profile>/ssis-lab-bench` or
/// `<target>/<profile>/ssis-lab-bench`.
fn target_dir() -> PathBuf {
    let exe = std::env::current_exe().unwrap_or_default();
    let profile_dir = exe.parent().map(Path::to_path_buf).unwrap_or_default();
    let up = profile_dir.parent().map(Path::to_path_buf).unwrap_or_default();
    if up.file_name().is_some_and(|n| n.to_string_lossy().contains('-')) {
        up.parent().map(Path::to_path_buf).unwrap_or(up)
    } else {
        up
    }
}

/// CPU time of this process so far (user + system), s.
fn cpu_s() -> f64 {
    // SAFETY: getrusage writes the struct it is given; a zeroed rusage is a valid value.
    let mut u: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `u` is a valid, writable rusage.
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut u) } != 0 {
        return f64::NAN;
    }
    let s = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    s(u.ru_utime) + s(u.ru_stime)
}

/// Wall and CPU time since a start.
struct Clock(Instant, f64);

impl Clock {
    fn start() -> Clock {
        Clock(Instant::now(), cpu_s())
    }

    /// (wall s, CPU s).
    fn read(&self) -> (f64, f64) {
        (self.0.elapsed().as_secs_f64(), cpu_s() - self.1)
    }
}

fn spec(rows: usize) -> Spec {
    Spec {
        seed: 1,
        dt_s: 0.01,
        rows,
        motion: Motion::RateTable { dwell_rows: 6000, peak_deg_s: 10.0 },
        thermal: Thermal::Chamber,
        field_columns: false,
        field: ssis_lab::session::FieldModel::default(),
        hidden: Hidden::TempRate,
    }
}

/// Writes the session once (temporary file, then renamed).
fn write_session(path: &Path, rows: usize) -> Result<()> {
    let tmp = path.with_extension("partial");
    let f = std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?;
    let mut w = std::io::BufWriter::with_capacity(1 << 20, f);
    let mut err = None;
    let pb = indicatif::ProgressBar::new(rows as u64);
    let mut n = 0u64;
    let (header, _) = generate_with(&spec(rows), |r| {
        if err.is_some() {
            return;
        }
        if n == 0 {
            let res = writeln!(w, "t_s,fog0_rad_s,fog1_rad_s,fog2_rad_s,fog3_rad_s,fog0_t_degc,fog1_t_degc,fog2_t_degc,fog3_t_degc,ref_x_rad_s,ref_y_rad_s,ref_z_rad_s,chamber_rh_pct");
            err = res.err();
        }
        // t, 4 rates, 4 temperatures, 3 reference rates, humidity.
        let res = writeln!(
            w,
            "{:.2},{:.9e},{:.9e},{:.9e},{:.9e},{:.4},{:.4},{:.4},{:.4},{:.9e},{:.9e},{:.9e},{:.3}",
            r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10], r[11], r[12]
        );
        err = err.take().or(res.err());
        n += 1;
        if n.is_multiple_of(100_000) {
            pb.set_position(n);
        }
    });
    pb.finish_and_clear();
    if let Some(e) = err {
        return Err(e).with_context(|| format!("cannot write {}", tmp.display()));
    }
    anyhow::ensure!(header.len() == 13, "unexpected session columns {header:?}");
    w.flush()?;
    drop(w);
    std::fs::rename(&tmp, path).with_context(|| format!("cannot rename to {}", path.display()))?;
    Ok(())
}

fn main() -> Result<()> {
    ssis_lab::session::exit_plainly_on_truncated_map();
    let cli = Cli::parse();
    let dir = cli.dir.unwrap_or_else(|| target_dir().join("lab-bench"));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(format!("session-{}.csv", cli.rows));
    if !path.exists() {
        let t = Instant::now();
        println!("writing {} ({} rows, once) ...", path.display(), cli.rows);
        write_session(&path, cli.rows)?;
        println!("  written in {:.1} s", t.elapsed().as_secs_f64());
    }
    let bytes = std::fs::metadata(&path)?.len();
    let mb = bytes as f64 / 1e6;
    println!("session {} : {} rows, 4 FOGs, 13 columns, {:.1} MB", path.display(), cli.rows, mb);

    let (ingest_s, ingest_cpu) = ingest(&path, mb, cli.no_ingest)?;

    let t = Clock::start();
    let shape = Source::File(&path).shape()?;
    let (pre_s, pre_cpu) = t.read();
    println!(
        "pre-pass (header, first 1,000 rows, count of the rest): {pre_s:.2} s (CPU {pre_cpu:.2} s) for {} samples",
        shape.samples
    );
    if cli.ingest_only {
        return Ok(());
    }
    let kinds: Vec<Kind> = ["bias", "scale_factor", "misalignment", "thermal_t1"]
        .iter()
        .map(|k| Kind::parse_arg(k))
        .collect::<Result<_, _>>()?;
    let model = Model::new(&kinds);
    let (compare_s, diagnose_s, two_cpu) =
        if cli.one_pass_only { (f64::NAN, f64::NAN, f64::NAN) } else { two_commands(&model, &path)? };
    let (one_pass_s, one_pass_cpu) = one_pass(&model, &path, cli.hash)?;
    let ingest_text = if cli.no_ingest {
        "ingest not timed".to_string()
    } else {
        format!("ingest {:.0} MB/s (CPU: {:.0} MB/s)", mb / ingest_s, mb / ingest_cpu)
    };
    println!(
        "compare + diagnose as two commands: {:.2} s (CPU {two_cpu:.2} s), in one pass: {one_pass_s:.2} s, CPU \
         {one_pass_cpu:.2} s (goal <= 10 s on one core); {ingest_text}",
        compare_s + diagnose_s,
    );
    Ok(())
}

/// Ingest: reads, splits and parses every value (what every pass costs before any model
/// work); the wall and CPU seconds (not run with `no_ingest`).
fn ingest(path: &Path, mb: f64, no_ingest: bool) -> Result<(f64, f64)> {
    let t = Clock::start();
    let mut rr = RowReader::open(path)?;
    let (mut rows, mut check) = (0u64, 0.0);
    if !no_ingest {
        while let Some(r) = rr.next_row()? {
            rows += 1;
            check += r[1];
        }
    }
    let (ingest_s, ingest_cpu) = t.read();
    if !no_ingest {
        println!(
        "ingest (read + parse + check, {rows} rows): {ingest_s:.2} s = {:.0} MB/s, {:.0} ns/row; CPU {ingest_cpu:.2} s = \
         {:.0} MB/s (checksum {check:.3e})",
        mb / ingest_s,
        ingest_s / rows as f64 * 1e9,
        mb / ingest_cpu
    );
    }
    Ok((ingest_s, ingest_cpu))
}

/// Compare, then diagnose, as two commands (two passes); their wall seconds and their CPU
/// seconds together.
fn two_commands(model: &Model, path: &Path) -> Result<(f64, f64, f64)> {
    let t = Clock::start();
    let c = compare(model, Source::File(path), false, DEFAULT_BLOCKS, None)?;
    let (compare_s, compare_cpu) = t.read();
    println!(
        "compare (fit bias, scale_factor, misalignment, thermal_t1; held-out RMS; largest |residual| over every \
         row, {} rows read again for it): {compare_s:.2} s (CPU {compare_cpu:.2} s)",
        c.fitted.max_rows_read_again
    );
    for (i, s) in c.fitted.summary.iter().enumerate() {
        println!(
        "  FOG{i}: error {:.4} deg/h, residual {:.4} deg/h, max {:.4} deg/h (over {} rows), explained {:.2} %, held-out {:.4} deg/h",
        s.rms_error_rad_s * DEG_H_PER_RAD_S,
        s.rms_residual_rad_s * DEG_H_PER_RAD_S,
        s.max_abs_residual_rad_s * DEG_H_PER_RAD_S,
        c.fitted.max_over_rows,
        100.0 * s.explained,
        c.held_out_rad_s[i] * DEG_H_PER_RAD_S
    );
    }

    let t = Clock::start();
    let d = diagnose(model, Source::File(path), &Options::default())?;
    let (diagnose_s, diagnose_cpu) = t.read();
    println!(
        "diagnose ({} candidates tested, {} training / {} test samples): {diagnose_s:.2} s (CPU {diagnose_cpu:.2} s)",
        d.candidates.len(),
        d.n_train,
        d.n_test
    );
    for c in d.candidates.iter().take(3) {
        println!(
            "  {:<28} p {:.2e}  held-out {:.4} -> {:.4} deg/h {}",
            c.kind.label(),
            c.p_value,
            c.before_rad_s * DEG_H_PER_RAD_S,
            c.after_rad_s * DEG_H_PER_RAD_S,
            if c.significant { "significant" } else { "" }
        );
    }
    Ok((compare_s, diagnose_s, compare_cpu + diagnose_cpu))
}

/// Compare and diagnose from one pass: the fit, held-out RMS and diagnosis from the same
/// sums, the largest |residual| proved from the pass's extremes (a second pass only if it
/// cannot be); with `hash`, the hashes of the results. The wall and CPU seconds.
fn one_pass(model: &Model, path: &Path, hash: bool) -> Result<(f64, f64)> {
    let t = Clock::start();
    let header = Source::File(path).header()?;
    let opt = Options::default();
    let dg = digest(Source::File(path), &spec_for(model, &candidate_terms(&header), opt.n_blocks), None)?;
    let f = complete(fit_digest(model, &dg)?, Source::File(path), &dg)?;
    let ho = held_out_rms(&model.kinds(), &dg)?;
    let d1 = diagnose_digest(model, &dg, &opt)?;
    let (one_pass_s, one_pass_cpu) = t.read();
    println!(
        "compare + diagnose in one pass: {one_pass_s:.2} s, CPU {one_pass_cpu:.2} s (FOG0 residual {:.4} deg/h, max {:.4} deg/h over {} rows, held-out {:.4} deg/h; top candidate {})",
        f.summary[0].rms_residual_rad_s * DEG_H_PER_RAD_S,
        f.summary[0].max_abs_residual_rad_s * DEG_H_PER_RAD_S,
        f.max_over_rows,
        ho[0] * DEG_H_PER_RAD_S,
        d1.candidates[0].kind.label()
    );
    println!("  largest |residual|: {} rows read again", f.max_rows_read_again);
    for c in d1.candidates.iter().take(3) {
        println!(
            "  candidate {:<28} p {:.2e}, removes {:.4} deg/h{}",
            c.kind.label(),
            c.p_value,
            c.removed_rad_s().0 * DEG_H_PER_RAD_S,
            if c.significant { ", significant" } else { "" }
        );
    }
    if hash {
        let hash = |x: &dyn std::fmt::Debug| -> Result<u64> {
            let mut h = HashWriter(std::collections::hash_map::DefaultHasher::new());
            std::fmt::Write::write_fmt(&mut h, format_args!("{x:?}"))?;
            Ok(std::hash::Hasher::finish(&h.0))
        };
        println!(
            "  hashes of the pass's results: digest {:016x}, fit {:016x}, held-out {:016x}, diagnosis {:016x}",
            hash(&dg)?,
            hash(&f)?,
            hash(&ho)?,
            hash(&d1)?
        );
        let max: Vec<f64> = f.summary.iter().map(|s| s.max_abs_residual_rad_s).collect();
        println!("  largest |residual| per FOG, rad/s: {max:?}");
        if let Some(p) = std::env::var_os("SSIS_LAB_BENCH_DUMP") {
            std::fs::write(&p, format!("{dg:#?}\n{f:#?}\n{ho:#?}\n{d1:#?}\n"))?;
        }
    }
    Ok((one_pass_s, one_pass_cpu))
}

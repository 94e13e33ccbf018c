//! `ssis-cal`: the paper's calibration methods on ground-test sessions and on flight
//! telemetry (`docs/TUTORIAL-CALIBRATION.md`). One subcommand per method; each
//! prints a table, writes an SVG plot and, with `--table`, updates the calibration table
//! (TOML, atomic; an unreadable existing table is refused, never overwritten; a missing one
//! is refused unless `--new-table`).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use ssis::calib::{CalibrationTable, Field, FogTerm};
use ssis_common::cli::{self, json};
use ssis_common::output::{self, Origin, Own};
use ssis_common::table::TableDoc;
use ssis_common::update;
use ssis_common::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};
use ssis_methods::{self as methods, allan, magnetic, misalign_sins, misalign_turns, orbital, thermal_anova, Series};
use ssis_session::read_session;

#[derive(Parser)]
#[command(
    name = "ssis-cal",
    about = "The paper's calibration methods on ground sessions and telemetry (docs/TUTORIAL-CALIBRATION.md)"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    #[command(flatten)]
    flags: cli::Flags,
    /// With --table: start a nominal table there (refused where a file exists).
    #[arg(long, global = true)]
    new_table: bool,
}

/// The Earth-field model of a simulated magnetic test.
#[derive(Clone, Copy, ValueEnum)]
enum FieldArg {
    /// WMM2025 (the real field).
    Wmm,
    /// The paper's dipole tilt.
    Paper,
}

impl FieldArg {
    fn model(self) -> ssis_session::FieldModel {
        match self {
            FieldArg::Wmm => ssis_session::FieldModel::Wmm2025,
            FieldArg::Paper => ssis_session::FieldModel::PaperDipole,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Batch {
    /// Temperature and gradient effects (the paper's first batch).
    BatchI,
    /// Only the gradient effect (the paper's second batch).
    BatchII,
}

#[derive(Subcommand)]
enum Cmd {
    /// Simulated sessions with known truth.
    Simulate {
        #[command(subcommand)]
        what: Sim,
    },
    /// Magnetic sensitivity, eqs. (1)-(3): unscreened minus screened over 25 azimuths.
    Magnetic {
        /// Unscreened session.
        #[arg(long)]
        unscreened: PathBuf,
        /// Screened session (same azimuths).
        #[arg(long)]
        screened: PathBuf,
        /// SVG of Δf_x, Δf_y and α_x, α_y against ψ.
        #[arg(long, default_value = "magnetic.svg")]
        plot: PathBuf,
        /// The site, `LAT_DEG,LON_DEG[,HEIGHT_M]` (WGS 84): with `--date`, the predicted phase
        /// uses the World Magnetic Model's field there (the real field) instead of the session's
        /// field columns.
        #[arg(long, requires = "date")]
        site: Option<String>,
        /// Date of the test, `YYYY-DDD` (day of the year), for `--site`.
        #[arg(long, requires = "site")]
        date: Option<String>,
        /// Predict the phase from the paper's dipole-tilt field at Kharkov (to reproduce its
        /// worked example) instead of WMM2025 at `--site`/`--date` or the session's columns.
        #[arg(long, conflicts_with_all = ["site", "date"])]
        paper_field: bool,
    },
    /// Two-factor ANOVA of Tables 1-2, and the thermal model when it is worth building.
    Thermal {
        /// Simulated batch in the paper's Table 1 design (N = 240 000 at 5 ms).
        #[arg(long, value_enum, required_unless_present = "session", conflicts_with = "session")]
        simulate: Option<Batch>,
        /// A chamber session (docs/SESSION-FORMAT.md) with the FOG's temperature column:
        /// samples are sorted into the T × G levels.
        #[arg(long)]
        session: Option<PathBuf>,
        /// T levels of the design, °C, comma-separated.
        #[arg(long, value_delimiter = ',', default_value = "10,20,30,40")]
        t_levels_degc: Vec<f64>,
        /// G levels of the design, °C/min, comma-separated (`-0.25,0,0.25` and
        /// `=-0.25,0,0.25` both work).
        #[arg(long, value_delimiter = ',', allow_hyphen_values = true, default_value = "-0.25,0,0.25")]
        g_levels_degc_min: Vec<f64>,
        /// Seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// FOG whose table entry receives the model (0-3).
        #[arg(long, default_value_t = 0, value_parser = fog_index)]
        fog: usize,
        /// SVG of the cell means against T, one line per G level.
        #[arg(long, default_value = "thermal.svg")]
        plot: PathBuf,
        /// Calibration table (TOML) to update with the model, when it is built.
        #[arg(long)]
        table: Option<PathBuf>,
    },
    /// Overlapping Allan deviation of a static session: ARW, bias instability, RRW.
    Allan {
        /// Static session.
        #[arg(long)]
        session: PathBuf,
        /// FOG column (fogN_...), 0-3.
        #[arg(long, default_value_t = 0, value_parser = fog_index)]
        fog: usize,
        /// SVG (log10 σ against log10 τ).
        #[arg(long, default_value = "allan.svg")]
        plot: PathBuf,
        /// Calibration table (TOML) whose observer ARW and RRW are set.
        #[arg(long)]
        table: Option<PathBuf>,
    },
    /// Misalignment, first method: δ12 … δ43 from three calibration turns.
    Turns {
        /// Turntable session (`ssis-cal simulate turns` writes one).
        #[arg(long)]
        session: PathBuf,
        /// SVG of the equation residuals.
        #[arg(long, default_value = "turns.svg")]
        plot: PathBuf,
        /// Calibration table (TOML) whose misalignment angles are set.
        #[arg(long)]
        table: Option<PathBuf>,
    },
    /// Misalignment, second method: the six triad angles from SINS runs over 180° reversals.
    Sins {
        /// Turntable session (`ssis-cal simulate sins` writes one).
        #[arg(long)]
        session: PathBuf,
        /// SVG of the deflection residuals before and after.
        #[arg(long, default_value = "sins.svg")]
        plot: PathBuf,
        /// Calibration table (TOML): its misalignment (the first method's) is the start and
        /// is replaced; without it the start is nominal.
        #[arg(long)]
        table: Option<PathBuf>,
    },
    /// Orbital calibration on telemetry: observer bias, 360° maneuvers, star-tracker mount.
    Orbital {
        /// Output-link capture (`ssis-cal simulate orbital` writes OUTDIR/output.bin).
        #[arg(long)]
        output: PathBuf,
        /// Star-tracker-link capture (OUTDIR/star.bin).
        #[arg(long)]
        star: PathBuf,
        /// Calibration table (TOML) the unit flew with; the bias, scale factors and star-tracker
        /// mount found are written into it.
        #[arg(long)]
        table: PathBuf,
        /// SVG of the observer's drift estimate over time with the averaging window.
        #[arg(long, default_value = "orbital.svg")]
        plot: PathBuf,
    },
}

#[derive(Subcommand)]
enum Sim {
    /// Magnetic test at Kharkov: two sessions, unscreened and screened.
    Magnetic {
        /// Unscreened session to write.
        unscreened: PathBuf,
        /// Screened session to write.
        screened: PathBuf,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// The Earth field at Kharkov: `wmm` (WMM2025 on 2025-001, the real field) or `paper`
        /// (the paper's dipole tilt, to reproduce its example).
        #[arg(long, value_enum, default_value_t = FieldArg::Wmm)]
        field: FieldArg,
    },
    /// Static session (1-s means of FOG0) for the Allan variance.
    Static {
        /// Session to write.
        out: PathBuf,
        /// Length, hours.
        #[arg(long, default_value_t = 300.0)]
        hours: f64,
        /// ARW, °/√h.
        #[arg(long, default_value_t = 0.005)]
        arw: f64,
        /// RRW, °/h/√h.
        #[arg(long, default_value_t = 0.01)]
        rrw: f64,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Turntable session of the first misalignment method (Z, X, Y up; 360° turns).
    Turns {
        /// Session to write.
        out: PathBuf,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Turntable session of the second misalignment method (Z, X, Y up; ±180° reversals).
    Sins {
        /// Session to write.
        out: PathBuf,
        /// Seed.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Calibration flight through the flight core (example unit): output and star links.
    ///
    /// Inertial hold, then 360° maneuvers about X, Y, Z and the FOG4 axis; writes
    /// OUTDIR/output.bin, OUTDIR/star.bin (the link bytes) and OUTDIR/flown.toml (the table
    /// flown), and prints the truth.
    Orbital {
        /// Directory to write the captures and the table flown into.
        outdir: PathBuf,
        /// Inertial hold before the maneuvers, s (default: five of the observer's slowest time
        /// constants for the table flown, plus 1000 s, rounded up to 1000 s: the bias average
        /// needs the observer settled).
        #[arg(long)]
        hold_s: Option<f64>,
        /// Seed.
        #[arg(long, default_value_t = 6)]
        seed: u64,
        /// Calibration table (TOML) the unit flies with (default: nominal).
        #[arg(long)]
        table: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    ssis_session::exit_plainly_on_truncated_map();
    let cli = Cli::parse();
    let started = cli.flags.start("ssis-cal").and_then(|()| files(&cli.cmd, cli.new_table));
    cli::finish_unit(started.and_then(|()| run(cli)))
}

/// `--fog N`: a FOG of the unit (0-3), refused before any work.
fn fog_index(s: &str) -> std::result::Result<usize, String> {
    match s.parse::<usize>() {
        Ok(i) if i <= 3 => Ok(i),
        _ => Err(format!("`{s}`: the unit has FOGs 0-3")),
    }
}

/// Registers the command's inputs and claims its outputs (`ssis_common::output`): a
/// refusal comes before any work. A plot at its default name is replaced when it is one of
/// ours (its title); the table a method updates is both input and output.
fn files(cmd: &Cmd, new_table: bool) -> Result<()> {
    let plot = |p: &Path, default: &str, title: &str| {
        let o = if p == Path::new(default) { Origin::Default(Own::Svg(title.into())) } else { Origin::Named };
        output::claim(p, o)
    };
    let table = |t: &Path| -> Result<()> {
        match (t.exists(), new_table) {
            (false, false) => {
                bail!("{}: no such table: refused (--new-table starts a nominal table there)", t.display())
            }
            (true, true) => bail!(
                "{}: exists: --new-table starts a table only where none is (without it the table is updated)",
                t.display()
            ),
            // An existing table must parse before any work: a method never prints its
            // figures or writes its plot and then fails on the table.
            (true, false) => {
                output::update(t)?;
                Ok(ssis_common::table::read_doc(t).map(drop)?)
            }
            (false, true) => output::update(t),
        }
    };
    let named = |p: &Path| output::claim(p, Origin::Named);
    let name = match cmd {
        Cmd::Simulate { what: Sim::Magnetic { unscreened, screened, .. } } => {
            named(unscreened)?;
            named(screened)?;
            "simulate magnetic"
        }
        Cmd::Simulate { what: Sim::Static { out, .. } } => named(out).map(|()| "simulate static")?,
        Cmd::Simulate { what: Sim::Turns { out, .. } } => named(out).map(|()| "simulate turns")?,
        Cmd::Simulate { what: Sim::Sins { out, .. } } => named(out).map(|()| "simulate sins")?,
        Cmd::Simulate { what: Sim::Orbital { outdir, table, .. } } => {
            table.iter().for_each(|t| output::input(t));
            for f in ["output.bin", "star.bin", "flown.toml"] {
                output::claim(&outdir.join(f), Origin::Default(Own::Nothing))?;
            }
            "simulate orbital"
        }
        Cmd::Magnetic { unscreened, screened, plot: p, .. } => {
            output::input(unscreened);
            output::input(screened);
            plot(p, "magnetic.svg", "Magnetic component").map(|()| "magnetic")?
        }
        Cmd::Thermal { plot: p, table: t, session, .. } => {
            session.iter().for_each(|s| output::input(s));
            t.as_deref().map(table).transpose()?;
            plot(p, "thermal.svg", "Thermal test: cell means").map(|()| "thermal")?
        }
        Cmd::Allan { session, plot: p, table: t, .. } => {
            output::input(session);
            t.as_deref().map(table).transpose()?;
            plot(p, "allan.svg", "Overlapping Allan deviation").map(|()| "allan")?
        }
        Cmd::Turns { session, plot: p, table: t } => {
            output::input(session);
            t.as_deref().map(table).transpose()?;
            plot(p, "turns.svg", "First method: equation residuals").map(|()| "turns")?
        }
        Cmd::Sins { session, plot: p, table: t } => {
            output::input(session);
            t.as_deref().map(table).transpose()?;
            plot(p, "sins.svg", "Second method: SINS deflections").map(|()| "sins")?
        }
        Cmd::Orbital { output: o, star, table: t, plot: p } => {
            output::input(o);
            output::input(star);
            table(t)?;
            plot(p, "orbital.svg", "Orbital calibration: observer drift").map(|()| "orbital")?
        }
    };
    cli::report("command", || json!(name));
    Ok(())
}

/// Reads the table to update with its provenance (an existing file must parse: it is never
/// overwritten by a default), or the default when the file does not exist (`--new-table`:
/// [`files`] refuses a missing table without it).
fn load_table(path: &Path) -> Result<TableDoc> {
    if path.exists() {
        Ok(ssis_common::table::read_doc(path)?)
    } else {
        Ok(TableDoc::new(CalibrationTable::DEFAULT))
    }
}

/// Writes `base` with the `set` fields of `proposed` (everything else kept bit for bit, the
/// revision raised by one, the provenance of the set fields recorded) and prints the change
/// field by field.
fn save_table(
    path: &Path,
    base: &TableDoc,
    proposed: &CalibrationTable,
    set: &[Field],
    command: &str,
    session: String,
) -> Result<()> {
    let origin = update::Origin { command: format!("ssis-cal {command}"), session, model: None };
    let (doc, changes) = ssis_common::update::apply(base, proposed, set, &origin)
        .with_context(|| format!("{}: table not written", path.display()))?;
    ssis_common::table::write_doc(path, &doc).with_context(|| format!("{}: table not written", path.display()))?;
    print!("{}", ssis_common::update::report(base, &doc, &changes, &origin));
    println!("updated {} (revision {})", path.display(), doc.table.revision);
    cli::report("table", || json!({"path": path.display().to_string(), "revision": doc.table.revision}));
    Ok(())
}

/// One subcommand, one function.
fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Simulate { what } => simulate(what),
        Cmd::Magnetic { unscreened, screened, plot, site, date, paper_field } => {
            date.as_deref().map(parse_date).transpose()?;
            magnetic_cmd(unscreened, screened, plot, site, date, paper_field)
        }
        Cmd::Thermal { simulate, session, t_levels_degc, g_levels_degc_min, seed, fog, plot, table } => {
            let levels = thermal_anova::Levels { t_degc: t_levels_degc, g_degc_min: g_levels_degc_min };
            let input = match (simulate, session) {
                (_, Some(s)) => ThermalInput::Session(s, levels),
                (Some(b), None) => ThermalInput::Simulate(b, seed),
                (None, None) => bail!("give --session or --simulate"),
            };
            thermal_cmd(input, fog, plot, table)
        }
        Cmd::Allan { session, fog, plot, table } => allan_cmd(session, fog, plot, table),
        Cmd::Turns { session, plot, table } => turns_cmd(session, plot, table),
        Cmd::Sins { session, plot, table } => sins_cmd(session, plot, table),
        Cmd::Orbital { output, star, table, plot } => orbital_cmd(output, star, table, plot),
    }
}

/// `ssis-cal simulate`: one function per simulated session.
fn simulate(what: Sim) -> Result<()> {
    match what {
        Sim::Magnetic { unscreened, screened, seed, field } => simulate_magnetic(unscreened, screened, seed, field),
        Sim::Static { out, hours, arw, rrw, seed } => simulate_static(out, hours, arw, rrw, seed),
        Sim::Turns { out, seed } => simulate_turns(out, seed),
        Sim::Sins { out, seed } => simulate_sins(out, seed),
        Sim::Orbital { outdir, hold_s, seed, table } => simulate_orbital(outdir, hold_s, seed, table),
    }
}

/// `--date YYYY-DDD` (year, day of the year 1-366): refused, saying the form, before any work.
fn parse_date(date: &str) -> Result<(i32, u16)> {
    let bad = || anyhow::anyhow!("--date `{date}`: expected YYYY-DDD, the year and the day of the year (2025-001)");
    let (y, d) = date.split_once('-').ok_or_else(bad)?;
    if y.len() != 4 || d.len() != 3 {
        return Err(bad());
    }
    let (y, d) = (y.parse::<i32>().map_err(|_| bad())?, d.parse::<u16>().map_err(|_| bad())?);
    if !(1..=366).contains(&d) {
        return Err(bad());
    }
    Ok((y, d))
}

/// Magnetic sensitivity from an unscreened and a screened session: the eq. (1)/(2) fits, the field
/// at the site, the plot.
/// The World Magnetic Model's field at `--site` on `--date`, (north, west, up) nT.
fn wmm_at(site: &str, date: &str) -> Result<[f64; 3]> {
    let v: Vec<f64> = site
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|e| anyhow::anyhow!("--site `{site}`: {e} (expected LAT_DEG,LON_DEG[,HEIGHT_M])"))?;
    if !(2..=3).contains(&v.len()) {
        bail!("--site `{site}`: expected LAT_DEG,LON_DEG[,HEIGHT_M]");
    }
    let (y, d) = parse_date(date)?;
    magnetic::wmm_field_nwu_nt(v[0], v[1], v.get(2).copied().unwrap_or(0.0), y, d)
}

fn magnetic_cmd(
    unscreened: PathBuf,
    screened: PathBuf,
    plot: PathBuf,
    site: Option<String>,
    date: Option<String>,
    paper_field: bool,
) -> Result<()> {
    let wmm = match (&site, &date) {
        (Some(s), Some(d)) => Some(wmm_at(s, d)?),
        _ if paper_field => {
            let d = magnetic::DipoleTilt::PAPER;
            Some(d.field_ocs_nt(&d.kharkov()))
        }
        _ => None,
    };
    let model_name =
        if paper_field { "the paper's dipole-tilt field at Kharkov" } else { "the WMM2025 field at the site" };
    let (u, s) = (read_session(&unscreened, None)?, read_session(&screened, None)?);
    let r = magnetic::analyse(&u, &s)?;
    println!("eq. (1)/(2) fits, °/h and degrees        δΩ        S      Δφ     σ(Δφ)   rms");
    for (k, name) in ["X", "Y"].iter().enumerate() {
        for (what, f) in
            [("unscreened", r.unscreened[k]), ("screened", r.screened[k]), ("difference (2)", r.magnetic[k])]
        {
            println!(
                "FOG{name} {what:<16}              {:>8.4} {:>8.4} {:>7.2} {:>7.2} {:>7.4}",
                f.offset_rad_s * DEG_H_PER_RAD_S,
                f.amplitude_rad_s * DEG_H_PER_RAD_S,
                f.phase_rad.to_degrees(),
                f.phase_sigma_rad.to_degrees(),
                f.rms_rad_s * DEG_H_PER_RAD_S
            );
        }
    }
    // The field from the session (its first row, ψ of that row) back to the OCS.
    if let Some(w) = wmm {
        println!(
            "{model_name} (north, west, up) = ({:.0}, {:.0}, {:.0}) nT: predicted Δφ = {:.2}° (used below)",
            w[0],
            w[1],
            w[2],
            magnetic::predicted_phase_rad(w).to_degrees()
        );
        if let Some(note) = field_mismatch(&u, w, model_name) {
            println!("{note}");
        }
    }
    let b0 = match &u.field_nt {
        _ if wmm.is_some() => wmm,
        Some(f) => {
            let psi = u.column("psi_rad").map_or(0.0, |p| p[0]);
            Some(ssis_session::field_nwu_nt(f[0], psi))
        }
        None => None,
    };
    if let Some(b0) = b0 {
        println!(
            "field at the site B0 = ({:.1}, {:.1}, {:.1}) nT: predicted Δφ = −arctg(B0Y/B0X) = {:.2}°",
            b0[0],
            b0[1],
            b0[2],
            magnetic::predicted_phase_rad(b0).to_degrees()
        );
    }
    cli::report("magnetic", || methods::json::magnetic(&r, b0));
    let psi_deg: Vec<f64> = r.psi_rad.iter().map(|p| p.to_degrees()).collect();
    let mut series = Vec::new();
    for (k, (name, form)) in [("x", magnetic::Form::Sin), ("y", magnetic::Form::Cos)].into_iter().enumerate() {
        series.push(Series {
            label: format!("Δf_{name} measured, °/h"),
            points: psi_deg.iter().zip(&r.diff_rad_s[k]).map(|(p, v)| (*p, v * DEG_H_PER_RAD_S)).collect(),
            markers: true,
        });
        series.push(Series {
            label: format!("Δf_{name} eq. (2) fit"),
            points: (0..=360)
                .map(|d| (d as f64, r.magnetic[k].eval(form, (d as f64).to_radians()) * DEG_H_PER_RAD_S))
                .collect(),
            markers: false,
        });
    }
    if let Some(b0) = b0 {
        for (k, name) in ["x", "y"].iter().enumerate() {
            let mut axis = [0.0; 3];
            axis[k] = 1.0;
            series.push(Series {
                label: format!("α_{name} / 1000, deg (eq. 3)"),
                points: (0..=360)
                    .map(|d| {
                        // The plot's azimuth is the paper's ψ_Π = −ψ.
                        let b = magnetic::field_ics_nt(b0, -(d as f64).to_radians());
                        (d as f64, magnetic::alpha_rad(b, axis).to_degrees() / 1000.0)
                    })
                    .collect(),
                markers: false,
            });
        }
    }
    methods::xy_svg(&plot, "Magnetic component, unscreened − screened (eq. 2)", "ψ, deg", "°/h", &series)?;
    println!("wrote {}", plot.display());
    Ok(())
}

/// What the thermal analysis runs on.
enum ThermalInput {
    /// A simulated batch of the paper's design, with its seed.
    Simulate(Batch, u64),
    /// A user's chamber session and the design's levels.
    Session(PathBuf, thermal_anova::Levels),
}

/// What the cells of a chamber session hold and what the balanced design leaves out: the
/// rows between levels and the rows each cell loses when cut to the smallest cell's N
/// (named), in rows and as a share of the session.
fn chamber_summary(path: &Path, fog: usize, c: &thermal_anova::Chamber, levels: &thermal_anova::Levels) -> String {
    let n = c.cells.first().map_or(0, |x| x.y.len());
    let in_cells: usize = c.counts.iter().sum();
    let rows = in_cells + c.outside;
    let used = n * c.cells.len();
    let cut = in_cells - used;
    let smallest = c
        .cells
        .iter()
        .zip(&c.counts)
        .filter(|(_, &k)| k == n)
        .map(|(x, _)| format!("T {} °C, G {} °C/min", levels.t_degc[x.t_level], levels.g_degc_min[x.g_level]))
        .collect::<Vec<_>>()
        .join("; ");
    let pct = |k: usize| 100.0 * k as f64 / rows.max(1) as f64;
    let mut out = format!(
        "{}: FOG{fog}, {rows} rows: {in_cells} in {} cells (held {:?}), {} between levels left out\n",
        path.display(),
        c.cells.len(),
        c.counts,
        c.outside
    );
    out += &format!(
        "the ANOVA uses {used} of {rows} rows ({:.1} %): every cell cut to the smallest cell's N = {n} ({smallest}), \
         {cut} rows ({:.1} %) dropped to balance the design, {} ({:.1} %) between levels\n",
        pct(used),
        pct(cut),
        c.outside,
        pct(c.outside)
    );
    if used * 2 < rows {
        out += &format!(
            "WARNING: {}: the ANOVA uses less than half of the session: dwell longer at the smallest cell's levels\n",
            path.display()
        );
    }
    out
}

/// Cells, samples (T °C, G °C/s, y rad/s), levels and the provenance's name of a thermal run.
type ThermalCells = (Vec<thermal_anova::Cell>, Vec<[f64; 3]>, thermal_anova::Levels, String);

/// The cells and samples of the thermal analysis, its levels and a name for the
/// provenance: a simulated batch, or a chamber session sorted into its cells (with what the
/// balanced design uses and drops printed first).
fn thermal_cells(input: ThermalInput, fog: usize) -> Result<ThermalCells> {
    Ok(match input {
        ThermalInput::Simulate(batch, seed) => {
            let sim = match batch {
                Batch::BatchI => thermal_anova::BatchSim::batch_i(),
                Batch::BatchII => thermal_anova::BatchSim::batch_ii(),
            };
            let (cells, samples) = sim.simulate(seed, 12_000);
            let name = if matches!(batch, Batch::BatchI) { "batch-i" } else { "batch-ii" };
            (cells, samples, thermal_anova::Levels::default(), format!("simulated {name}, seed {seed}"))
        }
        ThermalInput::Session(path, levels) => {
            let s = read_session(&path, None)?;
            let window_s = (2.0 * s.median_dt_s()).max(60.0);
            let c = thermal_anova::chamber_cells(&s, fog, &levels, window_s)?;
            print!("{}", chamber_summary(&path, fog, &c, &levels));
            (c.cells, c.samples, levels, path.display().to_string())
        }
    })
}

/// The two-factor ANOVA of a chamber session (or a simulated batch) and, when T is
/// significant, the thermal model (into the table with `--table`).
fn thermal_cmd(input: ThermalInput, fog: usize, plot: PathBuf, table: Option<PathBuf>) -> Result<()> {
    let (cells, samples, levels, source) = thermal_cells(input, fog)?;
    let t_lo = levels.t_degc.iter().copied().fold(f64::INFINITY, f64::min);
    let t_hi = levels.t_degc.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let t_ref = (t_lo + t_hi) / 2.0;
    let (a, model) =
        thermal_anova::analyse_and_fit_levels(&cells, &samples, (levels.t_degc.len(), levels.g_degc_min.len()), t_ref)?;
    cli::report("thermal", || methods::json::thermal(&a, model.as_ref()));
    println!("two-factor ANOVA (Tables 1-2), {} cells of N = {}", a.n_cells, a.n_per_cell);
    println!("        F      ν1         ν2   crit 5 %  crit 1 %   p          significant");
    for (name, t) in [("F_T ", a.t), ("F_G ", a.g), ("F_TG", a.tg)] {
        println!(
            "{name} {:>7.2} {:>5} {:>10} {:>9.2} {:>9.2}   {:<10.3e} {}",
            t.f,
            t.nu1,
            t.nu2,
            t.crit_5,
            t.crit_1,
            t.p,
            if t.significant_1() {
                "at 1 %"
            } else if t.significant_5() {
                "at 5 %"
            } else {
                "no"
            }
        );
    }
    let mut series = Vec::new();
    for (g, gl) in levels.g_degc_min.iter().enumerate() {
        let pts = cells
            .iter()
            .filter(|c| c.g_level == g)
            .map(|c| {
                let m = c.y.iter().sum::<f64>() / c.y.len() as f64;
                (levels.t_degc[c.t_level], m * DEG_H_PER_RAD_S)
            })
            .collect();
        series.push(Series { label: format!("cell means, G = {gl} °C/min"), points: pts, markers: true });
    }
    match model {
        Some(m) => {
            println!(
                "decision: T significant at 5 %: the thermal model is worth building\n\
                 model: b {:.4} °/h, a1 {:.3e} °/h/°C, a2 {:.3e} °/h/°C², a3 {:.3e} °/h/°C³, g {:.4} °/h per °C/min, h {:.3e}, rms {:.4} °/h",
                m.bias_rad_s * DEG_H_PER_RAD_S,
                m.a_rad_s[0] * DEG_H_PER_RAD_S,
                m.a_rad_s[1] * DEG_H_PER_RAD_S,
                m.a_rad_s[2] * DEG_H_PER_RAD_S,
                m.g_rad_s_per_degc_s * DEG_H_PER_RAD_S / 60.0,
                m.h_rad_s_per_degc2_s * DEG_H_PER_RAD_S / 60.0,
                m.rms_rad_s * DEG_H_PER_RAD_S
            );
            for (g, gl) in levels.g_degc_min.iter().enumerate() {
                let gs = gl / 60.0;
                let pts = (t_lo.floor() as i32..=t_hi.ceil() as i32)
                    .map(|t| {
                        let dt = t as f64 - m.t_ref_degc;
                        let y = m.bias_rad_s
                            + m.a_rad_s[0] * dt
                            + m.a_rad_s[1] * dt * dt
                            + m.a_rad_s[2] * dt.powi(3)
                            + m.g_rad_s_per_degc_s * gs
                            + m.h_rad_s_per_degc2_s * dt * gs;
                        (t as f64, y * DEG_H_PER_RAD_S)
                    })
                    .collect();
                let _ = g;
                series.push(Series { label: format!("model, G = {gl}"), points: pts, markers: false });
            }
            if let Some(path) = table {
                if fog > 3 {
                    bail!("--fog {fog}: the unit has FOGs 0-3");
                }
                let base = load_table(&path)?;
                let mut t = base.table;
                let f = &mut t.fog[fog];
                f.t_ref_degc = m.t_ref_degc;
                f.thermal_t_rad_s = m.a_rad_s;
                f.thermal_g_rad_s_per_degc_s = m.g_rad_s_per_degc_s;
                f.thermal_tg_rad_s_per_degc2_s = m.h_rad_s_per_degc2_s;
                let i = fog as u8;
                let set = [FogTerm::TRef, FogTerm::ThermalT1, FogTerm::ThermalT2, FogTerm::ThermalT3]
                    .into_iter()
                    .chain([FogTerm::ThermalG, FogTerm::ThermalTg])
                    .map(|term| Field::Fog(i, term))
                    .collect::<Vec<_>>();
                save_table(&path, &base, &t, &set, "thermal", source.clone())?;
            }
        }
        None => {
            println!("decision: T not significant at 5 %: no thermal model (the paper: \"inefficient\")");
            if let Some(path) = table {
                if path.exists() {
                    println!("{} left unchanged", path.display());
                } else {
                    println!("no table written: {} not created", path.display());
                }
            }
        }
    }
    methods::xy_svg(&plot, "Thermal test: cell means (Table 1) and model", "T, °C", "°/h", &series)?;
    println!("wrote {}", plot.display());
    Ok(())
}

/// Allan deviation of one FOG of a static session and its noise terms (observer ARW and RRW into
/// the table).
fn allan_cmd(session: PathBuf, fog: usize, plot: PathBuf, table: Option<PathBuf>) -> Result<()> {
    let s = read_session(&session, None)?;
    let rates = allan::static_rates(&s, fog)?;
    let tau0 = s.median_dt_s();
    let pts = allan::overlapping_adev(&rates, tau0, 8).with_context(|| session.display().to_string())?;
    let nt = allan::noise_terms(&pts).with_context(|| session.display().to_string())?;
    cli::report("allan", || methods::json::allan(&pts, &nt));
    println!("tau s        adev °/h     95 % interval");
    for p in &pts {
        println!(
            "{:>10.1}  {:>10.5}  [{:.5}, {:.5}]",
            p.tau_s,
            p.adev_rad_s * DEG_H_PER_RAD_S,
            p.ci95_rad_s.0 * DEG_H_PER_RAD_S,
            p.ci95_rad_s.1 * DEG_H_PER_RAD_S
        );
    }
    let (a, b, k) = (nt.arw_deg_sqrt_h, nt.bias_instability_deg_h, nt.rrw_deg_h_sqrt_h);
    println!("ARW  {} °/√h", a.text(5));
    println!("B    {} °/h at τ = {:.0} s (longest τ {:.0} s)", b.text(5), nt.tau_min_s, nt.tau_max_s);
    println!("RRW  {} °/h/√h", k.text(5));
    let fitted: Vec<(f64, f64)> = pts
        .iter()
        .map(|p| {
            let n = a.value().unwrap_or(0.0) / 60.0 / DEG_H_PER_RAD_S * 3600.0; // °/√h → rad/√s
            let kk = k.value().unwrap_or(0.0) / 3600.0 / 60.0 / DEG_H_PER_RAD_S * 3600.0; // °/h/√h → rad/s/√s
            let v = (n * n / p.tau_s + kk * kk * p.tau_s / 3.0).sqrt();
            (p.tau_s.log10(), (v * DEG_H_PER_RAD_S).log10())
        })
        .collect();
    let series = vec![
        Series {
            label: "σ(τ), °/h".into(),
            points: pts.iter().map(|p| (p.tau_s.log10(), (p.adev_rad_s * DEG_H_PER_RAD_S).log10())).collect(),
            markers: true,
        },
        Series {
            label: "95 % lower".into(),
            points: pts.iter().map(|p| (p.tau_s.log10(), (p.ci95_rad_s.0 * DEG_H_PER_RAD_S).log10())).collect(),
            markers: false,
        },
        Series {
            label: "95 % upper".into(),
            points: pts.iter().map(|p| (p.tau_s.log10(), (p.ci95_rad_s.1 * DEG_H_PER_RAD_S).log10())).collect(),
            markers: false,
        },
        Series { label: "ARW + RRW fit".into(), points: fitted, markers: false },
    ];
    methods::xy_svg(&plot, "Overlapping Allan deviation", "log10 τ, s", "log10 σ, °/h", &series)?;
    println!("wrote {}", plot.display());
    if let Some(path) = table {
        let base = load_table(&path)?;
        let mut t = base.table;
        let mut set = Vec::new();
        for (field, e) in [(Field::Arw, a), (Field::Rrw, k)] {
            match e.value() {
                Some(v) => {
                    field.set(&mut t, v);
                    set.push(field);
                }
                None => println!("{field} kept at the base's value: this session does not resolve it"),
            }
        }
        if set.is_empty() {
            println!("{} left unchanged: the session resolves neither ARW nor RRW", path.display());
        } else {
            save_table(&path, &base, &t, &set, "allan", session.display().to_string())?;
        }
    }
    Ok(())
}

/// Misalignment by the first method (three calibration turns).
fn turns_cmd(session: PathBuf, plot: PathBuf, table: Option<PathBuf>) -> Result<()> {
    let s = read_session(&session, None)?;
    let (turns, lat) = misalign_turns::turns_from_session(&s)?;
    let gamma = match &table {
        Some(p) if p.exists() => load_table(p)?.table.gamma_rad,
        _ => ssis::calib::GAMMA_NOMINAL_RAD,
    };
    let r = misalign_turns::solve(&turns, lat, gamma)?;
    cli::report("turns", || methods::json::turns(&turns, &r));
    println!("turn  up     ψ0 °     Θ_T* °     ω* °/s");
    for (k, t) in turns.iter().enumerate() {
        println!(
            "{:>4}  {}  {:>7.2}  {:>9.4}  {:>8.3}",
            k + 1,
            ["X", "Y", "Z"][t.up],
            t.psi0_rad.to_degrees(),
            t.theta_t_rad.to_degrees(),
            t.omega_rad_s.to_degrees()
        );
    }
    println!("angle   estimate ″");
    for (n, v) in misalign_turns::ANGLE_NAMES.iter().zip(misalign_turns::angles(&r.misalignment)) {
        println!("{n:<6} {:>10.2}", v * ARCSEC_PER_RAD);
    }
    let series = vec![Series {
        label: "residual, ″ (equation index)".into(),
        points: r.residual_rad.iter().enumerate().map(|(k, v)| (k as f64, v * ARCSEC_PER_RAD)).collect(),
        markers: true,
    }];
    methods::xy_svg(&plot, "First method: equation residuals", "equation", "″", &series)?;
    println!("wrote {}", plot.display());
    if let Some(path) = table {
        let base = load_table(&path)?;
        let mut t = base.table;
        t.misalignment = r.misalignment;
        let set = [Field::D12, Field::D13, Field::D21, Field::D23, Field::D31, Field::D32, Field::D42, Field::D43];
        save_table(&path, &base, &t, &set, "turns", session.display().to_string())?;
    }
    Ok(())
}

/// Misalignment by the second method (SINS runs over 180° reversals), from the table's angles or
/// nominal ones.
fn sins_cmd(session: PathBuf, plot: PathBuf, table: Option<PathBuf>) -> Result<()> {
    let s = read_session(&session, None)?;
    let start = match &table {
        Some(p) if p.exists() => Some(load_table(p)?.table),
        _ => None,
    };
    let (m0, gamma, scale, from) = match &start {
        Some(t) => (
            t.misalignment,
            t.gamma_rad,
            [t.fog[0].scale_factor_error, t.fog[1].scale_factor_error, t.fog[2].scale_factor_error],
            "the table's",
        ),
        None => (CalibrationTable::DEFAULT.misalignment, ssis::calib::GAMMA_NOMINAL_RAD, [0.0; 3], "nominal"),
    };
    let revs = misalign_sins::reversals_from_session(&s, scale)?;
    let r = misalign_sins::solve(&revs, &m0, gamma)?;
    cli::report("sins", || methods::json::sins(&m0, from, &r));
    println!("rev  up     ψ0 °     turn °   measured after ″ (h1, h2)   residual ″ start → end");
    for (k, rv) in revs.iter().enumerate() {
        println!(
            "{:>3}  {}  {:>7.2}  {:>8.2}   {:>10.2} {:>10.2}      {:>7.2} {:>7.2} → {:>5.2} {:>5.2}",
            k + 1,
            ["X", "Y", "Z"][rv.up],
            rv.psi0_rad.to_degrees(),
            rv.turn_rad.to_degrees(),
            rv.tilt1_rad[0] * ARCSEC_PER_RAD,
            rv.tilt1_rad[1] * ARCSEC_PER_RAD,
            r.residual_start_rad[2 * k] * ARCSEC_PER_RAD,
            r.residual_start_rad[2 * k + 1] * ARCSEC_PER_RAD,
            r.residual_rad[2 * k] * ARCSEC_PER_RAD,
            r.residual_rad[2 * k + 1] * ARCSEC_PER_RAD
        );
    }
    println!("angle    start ″   estimate ″   1σ ″   (start: {from} misalignment)");
    let (a0, a1) = (misalign_sins::triad_angles(&m0), misalign_sins::triad_angles(&r.misalignment));
    for (k, n) in misalign_sins::TRIAD_NAMES.iter().enumerate() {
        println!(
            "{n:<6} {:>9.2} {:>12.2} {:>7.2}",
            a0[k] * ARCSEC_PER_RAD,
            a1[k] * ARCSEC_PER_RAD,
            r.sigma_rad[k] * ARCSEC_PER_RAD
        );
    }
    let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt() * ARCSEC_PER_RAD;
    println!(
        "{} Gauss-Newton iterations; residual rms {:.2}″ → {:.2}″; d42, d43 kept",
        r.iterations,
        rms(&r.residual_start_rad),
        rms(&r.residual_rad)
    );
    let series = vec![
        Series {
            label: format!("start ({from}), ″"),
            points: r.residual_start_rad.iter().enumerate().map(|(k, v)| (k as f64, v * ARCSEC_PER_RAD)).collect(),
            markers: true,
        },
        Series {
            label: "after the second method, ″".into(),
            points: r.residual_rad.iter().enumerate().map(|(k, v)| (k as f64, v * ARCSEC_PER_RAD)).collect(),
            markers: true,
        },
    ];
    methods::xy_svg(
        &plot,
        "Second method: SINS deflections minus measured (two per reversal)",
        "equation",
        "″",
        &series,
    )?;
    println!("wrote {}", plot.display());
    if let Some(path) = table {
        let base = load_table(&path)?;
        let mut t = base.table;
        t.misalignment = r.misalignment;
        // The second method refines the orthogonal triad only: δ42 and δ43 stay.
        let set = [Field::D12, Field::D13, Field::D21, Field::D23, Field::D31, Field::D32];
        save_table(&path, &base, &t, &set, "sins", session.display().to_string())?;
    }
    Ok(())
}

/// Orbital calibration of a flight's telemetry: bias, scale factors and star-tracker mount written
/// into the table flown.
fn orbital_cmd(output: PathBuf, star: PathBuf, table: PathBuf, plot: PathBuf) -> Result<()> {
    let tel = orbital::Telemetry::read(&output, &star)?;
    let flown_doc = load_table(&table)?;
    let flown = flown_doc.table;
    println!(
        "decoded {} output frames, {} star frames ({} and {} refused)",
        tel.out.len(),
        tel.star.len(),
        tel.bad_frames.0,
        tel.bad_frames.1
    );
    let r = orbital::calibrate(&tel, &flown, &orbital::Settings::default())
        .with_context(|| format!("{} and {} with {}", output.display(), star.display(), table.display()))?;
    let b = &r.bias;
    let tau = orbital::observer_time_constant_s(&flown)?;
    if let Some(t_m) = r.settles_after_first_maneuver(&tel) {
        bail!(
            "{}: the observer settles (convergence + 5τ, τ = {tau:.0} s) only after the first maneuver at \
             {t_m:.0} s: no steady part before the maneuvers; fly a longer hold ({} left unchanged)",
            output.display(),
            table.display()
        );
    }
    cli::report("orbital", || methods::json::orbital(&r, tau));
    let dh = |v: f64| v * DEG_H_PER_RAD_S;
    println!("{} maneuvers found; observer τ = {tau:.0} s", r.maneuvers.len());
    println!(
        "1. zero bias: observer's drift estimate averaged over {:.0}-{:.0} s (steady part)",
        b.window_s.0, b.window_s.1
    );
    println!(
        "   d = {:.4} {:.4} {:.4} °/h (±{:.4} {:.4} {:.4} 1σ); per FOG Δb {} °/h",
        dh(b.drift_rad_s.x),
        dh(b.drift_rad_s.y),
        dh(b.drift_rad_s.z),
        dh(b.sigma_rad_s.x),
        dh(b.sigma_rad_s.y),
        dh(b.sigma_rad_s.z),
        b.fog_delta_rad_s.map(|x| format!("{:+.4}", dh(x))).join(" ")
    );
    match (&r.scale, &r.mount) {
        (Some(sc), Some(m)) => {
            println!("2. scale factors: 360° maneuvers under star-tracker reference");
            println!("   span s          axis (ICS)              |Θ_ST| °     uᵀDu ppm  residual ppm");
            for (a, res) in sc.maneuvers.iter().zip(&sc.residual) {
                let u = a.axis();
                println!(
                    "   {:>6.0}-{:<6.0}  ({:+.3} {:+.3} {:+.3})   {:>9.4}   {:>+8.1}   {:>+8.3}",
                    a.span_s.0,
                    a.span_s.1,
                    u.x,
                    u.y,
                    u.z,
                    a.theta_st_rad.norm().to_degrees(),
                    a.relative_error() * 1e6,
                    res * 1e6
                );
            }
            println!("   Δk ppm per FOG {}", sc.dk.map(|x| format!("{:+.1}", x * 1e6)).join(" "));
            println!(
                "3. star-tracker mount: η = {:.2} {:.2} {:.2}″ (|η| {:.2}″) by RLS over {} star-frame pairs",
                m.eta_rad.x * ARCSEC_PER_RAD,
                m.eta_rad.y * ARCSEC_PER_RAD,
                m.eta_rad.z * ARCSEC_PER_RAD,
                m.eta_rad.norm() * ARCSEC_PER_RAD,
                m.samples
            );
            let u: Vec<String> =
                r.unexplained_rad_per_rad.iter().map(|v| format!("{:.1}", v * ARCSEC_PER_RAD)).collect();
            println!(
                "4. left unexplained by scale factors and mount, per maneuver: {} ″ per radian turned (at most {:.0})",
                u.join(" "),
                orbital::MAX_UNEXPLAINED_RAD_PER_RAD * ARCSEC_PER_RAD
            );
        }
        _ => println!("2., 3.: no maneuvers found: scale factors and mount not estimated"),
    }
    // The drift estimate, one point per 10 s, and its mean over the averaging window.
    let step = ((10.0 / tel.dt_s()).round() as usize).max(1);
    let mut series = Vec::new();
    for (k, name) in ["X", "Y", "Z"].iter().enumerate() {
        series.push(Series {
            label: format!("Δω̂_{name}, °/h"),
            points: tel.out.iter().step_by(step).map(|o| (o.time_us as f64 * 1e-6, dh(o.drift_rad_s[k]))).collect(),
            markers: false,
        });
    }
    for (k, name) in ["X", "Y", "Z"].iter().enumerate() {
        let v = dh(b.drift_rad_s[k]);
        series.push(Series {
            label: format!("mean {name} over the window"),
            points: vec![(b.window_s.0, v), (b.window_s.1, v)],
            markers: true,
        });
    }
    methods::xy_svg(&plot, "Orbital calibration: observer drift estimate", "t, s", "°/h", &series)?;
    println!("wrote {}", plot.display());
    let session = format!("{} + {}", output.display(), star.display());
    save_table(&table, &flown_doc, &r.table, &r.fields_set(), "orbital", session)?;
    Ok(())
}

/// When the session's field columns (its first row, back to north, west, up) are more than
/// 500 nT from the field `w` the prediction uses: a note saying so (a session simulated
/// in one field model and calibrated against another, or a site or date that is not the
/// session's).
fn field_mismatch(u: &ssis_session::Session, w: [f64; 3], model_name: &str) -> Option<String> {
    let f = u.field_nt.as_ref()?.first()?;
    let b = ssis_session::field_nwu_nt(*f, u.column("psi_rad").map_or(0.0, |p| p[0]));
    let d = ((b[0] - w[0]).powi(2) + (b[1] - w[1]).powi(2) + (b[2] - w[2]).powi(2)).sqrt();
    (d > 500.0).then(|| {
        format!(
            "WARNING: {}: the session's field (north, west, up) = ({:.0}, {:.0}, {:.0}) nT is {:.1} µT from {model_name}, \
             which the prediction uses: the session was made in another field model (WMM2025 or the paper's dipole; \
             see `--paper-field`) or at another site or date (predicted Δφ from the session's own field: {:.2}°)",
            u.file,
            b[0],
            b[1],
            b[2],
            d / 1000.0,
            magnetic::predicted_phase_rad(b).to_degrees()
        )
    })
}

/// Writes the unscreened and screened sessions of the Kharkov magnetic test.
fn simulate_magnetic(unscreened: PathBuf, screened: PathBuf, seed: u64, field: FieldArg) -> Result<()> {
    let sim = magnetic::MagneticSim::kharkov_in(field.model())?;
    sim.write(&unscreened, &screened, seed)?;
    let t = sim.truth();
    println!(
        "wrote {} and {} (25 azimuths, {} field ({:.0}, {:.0}, {:.0}) nT north, west, up); truth ΔS_x {:.4} °/h, \
         ΔS_y {:.4} °/h, Δφ {:.2}°",
        unscreened.display(),
        screened.display(),
        field.model().name(),
        sim.b0_nt[0],
        sim.b0_nt[1],
        sim.b0_nt[2],
        t[0].0 * DEG_H_PER_RAD_S,
        t[1].0 * DEG_H_PER_RAD_S,
        t[0].1.to_degrees()
    );
    Ok(())
}

/// Writes a static session (1-s means of FOG0) with known ARW and RRW.
fn simulate_static(out: PathBuf, hours: f64, arw: f64, rrw: f64, seed: u64) -> Result<()> {
    let n = (hours * 3600.0).round() as usize;
    let rates = allan::simulate_static(arw, rrw, 0.3, 1.0, n, seed);
    let rows: Vec<Vec<f64>> = rates.iter().enumerate().map(|(k, w)| vec![(k + 1) as f64, *w, 0.0, 0.0, 0.0]).collect();
    let comment = vec![format!("static FOG0, 1-s means, truth ARW {arw} deg/sqrt(h), RRW {rrw} deg/h/sqrt(h)")];
    methods::write_session_csv(
        &out,
        &comment,
        &["t_s", "fog0_rad_s", "ref_x_rad_s", "ref_y_rad_s", "ref_z_rad_s"],
        &rows,
    )?;
    println!("wrote {} ({n} rows); truth ARW {arw} °/√h, RRW {rrw} °/h/√h", out.display());
    Ok(())
}

/// Writes the turntable session of the first misalignment method.
fn simulate_turns(out: PathBuf, seed: u64) -> Result<()> {
    let sim = misalign_turns::TableSim::first_method(misalign_turns::example_truth());
    let truth = sim.write(&out, seed)?;
    let t = misalign_turns::angles(&truth.misalignment).map(|a| format!("{:.2}", a * ARCSEC_PER_RAD));
    println!("wrote {}; truth (″) {}", out.display(), t.join(" "));
    Ok(())
}

/// Writes the turntable session of the second misalignment method.
fn simulate_sins(out: PathBuf, seed: u64) -> Result<()> {
    let sim = misalign_sins::second_method_sim(misalign_turns::example_truth());
    let truth = sim.write(&out, seed)?;
    let t = misalign_sins::triad_angles(&truth.misalignment).map(|a| format!("{:.2}", a * ARCSEC_PER_RAD));
    println!(
        "wrote {} (Z, X, Y up: ±180° reversals); truth {} (″) {}",
        out.display(),
        misalign_sins::TRIAD_NAMES.join(" "),
        t.join(" ")
    );
    Ok(())
}

/// Flies the calibration flight through the flight core and writes its captures and the table
/// flown.
fn simulate_orbital(outdir: PathBuf, hold_s: Option<f64>, seed: u64, table: Option<PathBuf>) -> Result<()> {
    let flown = match &table {
        // Read here first: a missing or bad table is reported with its file.
        Some(p) => ssis_common::table::read_toml(p)?,
        None => CalibrationTable::DEFAULT,
    };
    let tau = orbital::observer_time_constant_s(&flown)?;
    let hold_s = hold_s.unwrap_or(((5.0 * tau + 1000.0) / 1000.0).ceil() * 1000.0);
    if hold_s < 5.0 * tau + 100.0 {
        eprintln!(
            "warning: --hold-s {hold_s} is shorter than 5τ = {:.0} s: the bias average will have no steady part",
            5.0 * tau
        );
    }
    let (fog, star) = orbital::example_unit(misalign_turns::example_truth());
    let mut sc = orbital::calibration_flight(fog, star, hold_s, 600.0, 200.0);
    sc.seed = seed;
    if let Some(p) = &table {
        sc.table.file = Some(std::fs::canonicalize(p).with_context(|| format!("cannot resolve {}", p.display()))?);
    }
    std::fs::create_dir_all(&outdir).with_context(|| format!("cannot create {}", outdir.display()))?;
    let t0 = std::time::Instant::now();
    let cap = orbital::fly(&sc)?;
    let (o, s, f) = (outdir.join("output.bin"), outdir.join("star.bin"), outdir.join("flown.toml"));
    ssis_common::table::write_atomic(&o, &cap.out)?;
    ssis_common::table::write_atomic(&s, &cap.star)?;
    ssis_common::table::write_toml(&f, &cap.table)?;
    println!(
        "flew {:.0} s ({:.0} s hold: observer τ {:.0} s; 4 × 360° maneuvers) in {:.1} s; wrote {}, {}, {}",
        sc.duration_s,
        hold_s,
        tau,
        t0.elapsed().as_secs_f64(),
        o.display(),
        s.display(),
        f.display()
    );
    let mut truth_table = CalibrationTable::DEFAULT;
    if let Some(e) = sc.fog.errors {
        truth_table.fog = e.fog;
    }
    let (d, dk, eta) = orbital::truth_of(&truth_table, &cap.table, &sc.star_tracker);
    println!(
        "truth: bias d = {:.4} {:.4} {:.4} °/h; Δk ppm {}; star-tracker mount η = {:.2} {:.2} {:.2}″",
        d.x * DEG_H_PER_RAD_S,
        d.y * DEG_H_PER_RAD_S,
        d.z * DEG_H_PER_RAD_S,
        dk.map(|x| format!("{:+.1}", x * 1e6)).join(" "),
        eta.x * ARCSEC_PER_RAD,
        eta.y * ARCSEC_PER_RAD,
        eta.z * ARCSEC_PER_RAD
    );
    Ok(())
}

//! `ssis-cal`: the paper's calibration methods on ground-test sessions (issue 5,
//! `docs/TUTORIAL-CALIBRATION.md`). One subcommand per method; each prints a table, writes
//! an SVG plot and, with `--table`, updates the calibration table (TOML, atomic; an
//! unreadable existing table is refused, never overwritten).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use ssis::calib::CalibrationTable;
use ssis_host::lab::session::read_session;
use ssis_host::methods::{self, allan, magnetic, misalign_turns, thermal_anova, Series};
use ssis_host::{ARCSEC_PER_RAD, DEG_H_PER_RAD_S};

#[derive(Parser)]
#[command(
    name = "ssis-cal",
    about = "The paper's ground calibration methods on sessions (docs/TUTORIAL-CALIBRATION.md)"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
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
    },
    /// Two-factor ANOVA of Tables 1-2, and the thermal model when it is worth building.
    Thermal {
        /// Simulated batch in the paper's Table 1 design (N = 240 000 at 5 ms).
        #[arg(long, value_enum)]
        simulate: Batch,
        /// Seed of the simulation.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// FOG whose table entry receives the model (0-3).
        #[arg(long, default_value_t = 0)]
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
        /// FOG column (fogN_...).
        #[arg(long, default_value_t = 0)]
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
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// Reads the table to update (an existing file must parse: it is never overwritten by a
/// default), or the default when the file does not exist.
fn load_table(path: &Path) -> Result<CalibrationTable> {
    if path.exists() {
        ssis_host::table::read_toml(path)
    } else {
        Ok(CalibrationTable::DEFAULT)
    }
}

fn save_table(path: &Path, t: &mut CalibrationTable) -> Result<()> {
    t.revision = t.revision.wrapping_add(1);
    ssis_host::table::write_toml(path, t).with_context(|| format!("{}: table not written", path.display()))?;
    println!("updated {} (revision {})", path.display(), t.revision);
    Ok(())
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Cmd::Simulate { what } => simulate(what),
        Cmd::Magnetic { unscreened, screened, plot } => {
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
            let b0 = match &u.field_nt {
                Some(f) => {
                    let psi = u.column("psi_rad").map_or(0.0, |p| p[0]);
                    let (sn, c) = psi.sin_cos();
                    let b = f[0];
                    Some([b[0] * c - b[1] * sn, b[0] * sn + b[1] * c, b[2]])
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
                                let b = magnetic::field_ics_nt(b0, (d as f64).to_radians());
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
        Cmd::Thermal { simulate, seed, fog, plot, table } => {
            let sim = match simulate {
                Batch::BatchI => thermal_anova::BatchSim::batch_i(),
                Batch::BatchII => thermal_anova::BatchSim::batch_ii(),
            };
            let (cells, samples) = sim.simulate(seed, 12_000);
            let (a, model) = thermal_anova::analyse_and_fit(&cells, &samples, 25.0)?;
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
            for (g, gl) in thermal_anova::TABLE1_G_DEGC_MIN.iter().enumerate() {
                let pts = cells
                    .iter()
                    .filter(|c| c.g_level == g)
                    .map(|c| {
                        let m = c.y.iter().sum::<f64>() / c.y.len() as f64;
                        (thermal_anova::TABLE1_T_DEGC[c.t_level], m * DEG_H_PER_RAD_S)
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
                    for (g, gl) in thermal_anova::TABLE1_G_DEGC_MIN.iter().enumerate() {
                        let gs = gl / 60.0;
                        let pts = (10..=40)
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
                        let mut t = load_table(&path)?;
                        let f = &mut t.fog[fog];
                        f.t_ref_degc = m.t_ref_degc;
                        f.thermal_t_rad_s = m.a_rad_s;
                        f.thermal_g_rad_s_per_degc_s = m.g_rad_s_per_degc_s;
                        f.thermal_tg_rad_s_per_degc2_s = m.h_rad_s_per_degc2_s;
                        save_table(&path, &mut t)?;
                    }
                }
                None => {
                    println!("decision: T not significant at 5 %: no thermal model (the paper: \"inefficient\")");
                    if let Some(path) = table {
                        println!("{} left unchanged", path.display());
                    }
                }
            }
            methods::xy_svg(&plot, "Thermal test: cell means (Table 1) and model", "T, °C", "°/h", &series)?;
            println!("wrote {}", plot.display());
            Ok(())
        }
        Cmd::Allan { session, fog, plot, table } => {
            let s = read_session(&session, None)?;
            let Some(f) = s.fogs.get(fog) else { bail!("{}: no FOG{fog} column", session.display()) };
            let tau0 = s.median_dt_s();
            let pts = allan::overlapping_adev(&f.rate_rad_s, tau0, 8)?;
            let nt = allan::noise_terms(&pts)?;
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
            println!("ARW  {:.5} °/√h     [{:.5}, {:.5}]", a.0, a.1, a.2);
            println!("B    {:.5} °/h      [{:.5}, {:.5}] at τ = {:.0} s", b.0, b.1, b.2, nt.tau_min_s);
            println!("RRW  {:.5} °/h/√h   [{:.5}, {:.5}]", k.0, k.1, k.2);
            let fitted: Vec<(f64, f64)> = pts
                .iter()
                .map(|p| {
                    let n = a.0 / 60.0 / DEG_H_PER_RAD_S * 3600.0; // °/√h → rad/√s
                    let kk = k.0 / 3600.0 / 60.0 / DEG_H_PER_RAD_S * 3600.0; // °/h/√h → rad/s/√s
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
                let mut t = load_table(&path)?;
                t.observer.arw_deg_sqrt_h = a.0;
                t.observer.rrw_deg_h_sqrt_h = k.0;
                save_table(&path, &mut t)?;
            }
            Ok(())
        }
        Cmd::Turns { session, plot, table } => {
            let s = read_session(&session, None)?;
            let (turns, lat) = misalign_turns::turns_from_session(&s)?;
            let gamma = match &table {
                Some(p) if p.exists() => load_table(p)?.gamma_rad,
                _ => ssis::calib::GAMMA_NOMINAL_RAD,
            };
            let r = misalign_turns::solve(&turns, lat, gamma)?;
            println!("turn  up   ψ0 deg   Θ_T* deg   ω* deg/s");
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
                let mut t = load_table(&path)?;
                t.misalignment = r.misalignment;
                save_table(&path, &mut t)?;
            }
            Ok(())
        }
    }
}

fn simulate(what: Sim) -> Result<()> {
    match what {
        Sim::Magnetic { unscreened, screened, seed } => {
            let sim = magnetic::MagneticSim::kharkov();
            sim.write(&unscreened, &screened, seed)?;
            let t = sim.truth();
            println!(
                "wrote {} and {} (25 azimuths); truth ΔS_x {:.4} °/h, ΔS_y {:.4} °/h, Δφ {:.2}°",
                unscreened.display(),
                screened.display(),
                t[0].0 * DEG_H_PER_RAD_S,
                t[1].0 * DEG_H_PER_RAD_S,
                t[0].1.to_degrees()
            );
        }
        Sim::Static { out, hours, arw, rrw, seed } => {
            let n = (hours * 3600.0).round() as usize;
            let rates = allan::simulate_static(arw, rrw, 0.3, 1.0, n, seed);
            let rows: Vec<Vec<f64>> =
                rates.iter().enumerate().map(|(k, w)| vec![(k + 1) as f64, *w, 0.0, 0.0, 0.0]).collect();
            let comment = vec![format!("static FOG0, 1-s means, truth ARW {arw} deg/sqrt(h), RRW {rrw} deg/h/sqrt(h)")];
            methods::write_session_csv(
                &out,
                &comment,
                &["t_s", "fog0_rad_s", "ref_x_rad_s", "ref_y_rad_s", "ref_z_rad_s"],
                &rows,
            )?;
            println!("wrote {} ({n} rows); truth ARW {arw} °/√h, RRW {rrw} °/h/√h", out.display());
        }
        Sim::Turns { out, seed } => {
            let sim = misalign_turns::TableSim::first_method(misalign_turns::example_truth());
            let truth = sim.write(&out, seed)?;
            let t = misalign_turns::angles(&truth.misalignment).map(|a| format!("{:.2}", a * ARCSEC_PER_RAD));
            println!("wrote {}; truth (″) {}", out.display(), t.join(" "));
        }
    }
    Ok(())
}

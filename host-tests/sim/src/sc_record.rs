//! A spacecraft recorded log (`docs/RECORDED-LOG.md`) written from a scenario
//! (`ssis-bench --write-log`, the long logs of BENCHMARKS.md): the frames its FOGs and star tracker
//! send, as numbers that give the same frames back, and truth. Written as the simulation
//! runs, so a day-long log takes no more memory than a minute's.

use std::io::Write;

use anyhow::Result;
use ssis::frames::fog::FogFrame;
use ssis::frames::star::StarFrame;
use ssis::frames::Frame;

use crate::harness::Simulation;
use crate::lv_replay::decimal;

/// Writes `steps` steps of `sim` as a spacecraft log: truth on every `truth_every`-th row
/// (and the last), and with `full` every FOG's counter, temperature and status.
pub fn write_log(sim: &mut Simulation, steps: u64, truth_every: u64, full: bool, w: &mut impl Write) -> Result<()> {
    let dt_s = sim.profile.dt_s();
    let mut cols: Vec<String> = vec!["t_s".into()];
    for i in 0..4 {
        cols.push(format!("fog{i}_dtheta_rad"));
        if full {
            cols.extend([format!("fog{i}_counter"), format!("fog{i}_t_degc"), format!("fog{i}_status")]);
        }
    }
    cols.extend(["st_t_s", "st_valid", "st_q0", "st_q1", "st_q2", "st_q3"].map(String::from));
    cols.extend(["true_q0", "true_q1", "true_q2", "true_q3"].map(String::from));
    cols.extend(["true_wx_rad_s", "true_wy_rad_s", "true_wz_rad_s"].map(String::from));
    writeln!(
        w,
        "# recorded log: spacecraft scenario `{}` (seed {}), {:.1} s; written by `ssis-bench --write-log`",
        sim.sc.name,
        sim.sc.seed,
        steps as f64 * dt_s
    )?;
    writeln!(w, "# docs/RECORDED-LOG.md: Λ = the body (ICS) in the inertial frame, scalar first; FOG slots 0..3")?;
    writeln!(w, "{}", cols.join(","))?;
    let mut row = String::with_capacity(256);
    for k in 1..=steps {
        let Some(input) = sim.next_step() else { break };
        row.clear();
        row.push_str(&format!("{:.3}", k as f64 * dt_s));
        for (i, bytes) in input.fog_frames.iter().enumerate() {
            row.push(',');
            if !input.present.contains(i) {
                row.push_str(if full { ",,," } else { "" });
                continue;
            }
            let f = FogFrame::decode(bytes).map_err(|e| anyhow::anyhow!("FOG frame: {e:?}"))?;
            row.push_str(&decimal(i64::from(f.dtheta_counts), FogFrame::DTHETA_LSB_RAD));
            if full {
                let t = decimal(i64::from(f.temperature_counts), FogFrame::TEMP_LSB_DEGC);
                row.push_str(&format!(",{},{t},{}", f.counter, f.status));
            }
        }
        // One solution a row (a tracker sends one per period; more would need more rows).
        match input.st_bytes.chunks_exact(StarFrame::LEN).next() {
            Some(c) => {
                let f = StarFrame::decode(c).map_err(|e| anyhow::anyhow!("star-tracker frame: {e:?}"))?;
                let q = f.quaternion();
                row.push_str(&format!(",{:.6},{}", f.time_us as f64 * 1e-6, u8::from(f.valid())));
                for v in q {
                    row.push_str(&format!(",{v}"));
                }
            }
            None => row.push_str(",,,,,,"),
        }
        match input.truth.filter(|_| k % truth_every.max(1) == 0 || k == steps) {
            Some(t) => {
                for v in [t.q.w, t.q.i, t.q.j, t.q.k] {
                    row.push_str(&format!(",{v:.12}"));
                }
                for v in t.rate.iter() {
                    row.push_str(&format!(",{v:.9e}"));
                }
            }
            None => row.push_str(",,,,,,,"),
        }
        writeln!(w, "{row}")?;
    }
    Ok(())
}

//! The command link on the firmware in QEMU (test build `ssis-fw-test`, lockstep): a
//! scripted series of telecommands over UART0, the key loaded into the KEY region like
//! the table. Every output frame and every command report must be bit-identical to the
//! in-process core's, whose command link (the same code, on a copy of the table's flash
//! region) gets the same bytes before the same step; so the table switch happens between
//! the same two steps on the M7 as on the host.
//!
//! The script: a chunk under the wrong key, STATUS, the same STATUS replayed, a chunk
//! with a flipped bit, seven of eight chunks (a truncated upload) then ARM and FIRE, the
//! last chunk, ARM, FIRE naming another CRC, ARM, FIRE, STATUS. The wrong key, the replay,
//! the flipped bit, the truncated upload (ARM, FIRE) and the other CRC are each refused
//! and counted; the unit flies the old table until the right FIRE, and the output frames'
//! counter page shows the counts and the active table's revision and CRC.

use std::path::Path;

use ssis::calib::CalibrationTable;
use ssis::flight::table_crc;
use ssis::frames::telecommand::{command, upload_state, Telecommand};
use ssis::telecommand::auth::{seal, Key};
use ssis::telecommand::upload::{upload_sequence, CHUNKS};
use ssis::telemetry::{page, Counter, PAGED};
use ssis_runner::qemu::{build_firmware, run_qemu, QemuOptions};
use ssis_sim::harness::Simulation;
use ssis_sim::scenario::Scenario;

fn key(seed: u8) -> Key {
    Key { id: 0x2A, bytes: std::array::from_fn(|i| seed ^ (i as u8).wrapping_mul(73)) }
}

fn page_of(c: Counter) -> u8 {
    page::FOG_PAGES + PAGED.iter().position(|p| *p == c).expect("paged") as u8
}

/// The last value page `c` showed at or before `t_us`.
fn shown(pages: &[(u64, u8, u16)], c: Counter, t_us: u64) -> Option<u16> {
    pages.iter().rev().find(|(t, id, _)| *id == page_of(c) && *t <= t_us).map(|(_, _, v)| *v)
}

#[test]
fn telecommands_in_qemu_update_the_table_between_two_steps_and_refuse_the_bad_ones() {
    let elf = build_firmware().expect("test build of the firmware");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let mut sc = Scenario::from_file(&path).expect("scenario");
    sc.duration_s = 4.0;
    sc.settle_s = 1.0;
    let old: CalibrationTable = Simulation::new(&sc).expect("simulation").table;
    let mut new = CalibrationTable { revision: old.revision + 1, ..old };
    // 0.01 °/h more bias on FOG1, a scale factor 20 ppm on FOG3: small, flown at once.
    new.fog[0].bias_rad_s += 0.01_f64.to_radians() / 3600.0;
    new.fog[2].scale_factor_error += 2e-5;
    let k = key(0x5C);
    let seal_k = |tc: Telecommand| seal(&k, tc);
    let status = |seq| seal_k(Telecommand { command: command::STATUS, seq, ..Telecommand::default() });
    let up = upload_sequence(&k, &new, 2);
    let renumber = |tc: Telecommand, seq| seal_k(Telecommand { seq, ..tc });
    let mut flipped = renumber(up[0], 2).to_bytes();
    flipped[20] ^= 0x08;
    let wrong_fire = seal_k(Telecommand {
        command: command::TABLE_FIRE,
        seq: 13,
        table_crc: !table_crc(&new),
        ..Telecommand::default()
    });
    let fire_step = 417u64;
    let mut script: Vec<(u64, Vec<u8>)> = vec![
        (400, upload_sequence(&key(0x5D), &new, 1)[0].to_bytes().to_vec()),
        (401, status(1).to_bytes().to_vec()),
        (402, status(1).to_bytes().to_vec()),
        (403, flipped.to_vec()),
    ];
    for (i, tc) in up[..CHUNKS - 1].iter().enumerate() {
        script.push((404 + i as u64, tc.to_bytes().to_vec()));
    }
    script.extend([
        (411, renumber(up[CHUNKS], 9).to_bytes().to_vec()),
        (412, renumber(up[CHUNKS + 1], 10).to_bytes().to_vec()),
        (413, renumber(up[CHUNKS - 1], 11).to_bytes().to_vec()),
        (414, renumber(up[CHUNKS], 12).to_bytes().to_vec()),
        (415, wrong_fire.to_bytes().to_vec()),
        (416, renumber(up[CHUNKS], 14).to_bytes().to_vec()),
        (fire_step, renumber(up[CHUNKS + 1], 15).to_bytes().to_vec()),
        (418, status(16).to_bytes().to_vec()),
    ]);
    // -icount: the firmware's figures for the command link are instructions (40 a tick).
    let opts = QemuOptions {
        key_record: Some(k.to_record().to_vec()),
        commands: script,
        icount: true,
        ..QemuOptions::lockstep(elf)
    };
    let mut att = Vec::new();
    let s = run_qemu(&sc, &opts, |r| att.push((r.t_s, r.out.q, r.att_err_arcsec))).expect("QEMU run");
    println!("{}", s.report());

    // The same frames as the host's through the switch; the same command reports.
    assert_eq!(s.exit_code, Some(0), "firmware did not end cleanly");
    assert_eq!(s.frames_out, s.steps);
    assert_eq!(s.equal_frames, s.steps, "{} frames differ from the host core's", s.differing_frames);
    assert_eq!(s.frames_out_bad, 0);
    assert_eq!(s.command_reports, s.reference_reports);
    assert_eq!(s.command_reports.len(), 2, "two STATUS accepted, one replayed");
    let (before, after) = (s.command_reports[0], s.command_reports[1]);
    println!("reports: {before:?}\n         {after:?}");
    assert_eq!(
        (before.table_revision, before.table_crc, before.upload),
        (old.revision, table_crc(&old), upload_state::IDLE)
    );
    assert_eq!(
        (after.table_revision, after.table_crc, after.upload),
        (new.revision, table_crc(&new), upload_state::IDLE)
    );
    assert_eq!((after.key_id, after.last_seq, after.accepted), (0x2A, 16, 13));
    assert_eq!(
        after.refused, 5,
        "wrong key, replay, ARM and FIRE of a truncated upload, another CRC; the flipped bit never decoded"
    );

    // The output frames show it: the old table until the step of FIRE, the new after;
    // every refusal counted on its page.
    let t_fire_us = fire_step * 5_000;
    let pages = &s.unit_pages;
    let rev = |t| shown(pages, Counter::TableRevision, t);
    let crc = |t| {
        Some(
            u32::from(shown(pages, Counter::TableCrcLow, t)?)
                | u32::from(shown(pages, Counter::TableCrcHigh, t)?) << 16,
        )
    };
    assert_eq!(rev(t_fire_us - 5_000), Some(old.revision as u16));
    assert_eq!(crc(t_fire_us - 5_000), Some(table_crc(&old)));
    let end = u64::MAX;
    assert_eq!(rev(end), Some(new.revision as u16));
    assert_eq!(crc(end), Some(table_crc(&new)));
    for (c, n) in [
        (Counter::TcUnauthenticated, 1),
        (Counter::TcReplayed, 1),
        (Counter::TcCorrupt, 1),
        (Counter::TcOutOfSequence, 0),
        (Counter::TcRefused, 3),
        (Counter::TcAccepted, 13),
        (Counter::TableActivations, 1),
    ] {
        assert_eq!(shown(pages, c, end), Some(n), "{c:?} on the counter page");
    }

    // No jump in attitude at the switch beyond what the new values imply: those are
    // FOG1's 0.01 °/h and 20 ppm of FOG3's rate, below 1e-4″ a step, so the change of Λ
    // across the switch must stay within the step-to-step spread (FOG noise) of the 200
    // steps before it. (The bit-identical frames above show it is exactly what the host's
    // core does with the new table from that step on.)
    let step_angle = |a: &nalgebra::Quaternion<f64>, b: &nalgebra::Quaternion<f64>| {
        let d = a.conjugate() * b;
        2.0 * d.imag().norm().atan2(d.w.abs()) * 180.0 / std::f64::consts::PI * 3600.0
    };
    let at = att.iter().position(|(t, _, _)| (*t * 1e6).round() as u64 >= t_fire_us).expect("the step of FIRE");
    let per_step = |i: usize| step_angle(&att[i].1, &att[i + 1].1);
    let before: Vec<f64> = (at - 201..at - 1).map(per_step).collect();
    let mean = before.iter().sum::<f64>() / before.len() as f64;
    let spread = before.iter().fold(0.0f64, |m, d| m.max((d - mean).abs()));
    let around: Vec<f64> = (at - 2..at + 3).map(|i| per_step(i) - mean).collect();
    println!("attitude change per step across the switch minus the mean {mean:.6}″: {around:.6?}; spread before ±{spread:.6}″");
    for d in &around {
        assert!(d.abs() <= spread, "a jump of {d:.6}″ at the switch (spread before ±{spread:.6}″)");
    }
    let err = |i: usize| att[i].2.iter().fold(0.0f64, |m, e| m.max(e.abs()));
    assert!(
        err(at + 1) < err(at - 1) + 0.01,
        "attitude error {:.4}″ → {:.4}″ across the switch",
        err(at - 1),
        err(at + 1)
    );
}

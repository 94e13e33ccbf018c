//! A reset during the snapshot write (`FlightCore::snapshot_into`, which the executive
//! runs every `SNAPSHOT_STEPS` over the record a reset does not clear): the record is
//! written in place, field by field in the order of its bytes, and its check word last,
//! so a write cut off anywhere leaves the new bytes before the cut, the old ones after it
//! and the old check word. Every such record is refused at boot (the unit aligns again
//! on the star tracker), unless it is whole: the old record (cut before any byte
//! changed) or the new one.

use std::path::Path;

use ssis::flight::snapshot::{Snapshot, SnapshotError};
use ssis::flight::FlightCore;
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::harness::{step_on_mock_links, Simulation};
use ssis_sim::scenario::Scenario;

/// Steps between two snapshots (the executive's `SNAPSHOT_STEPS`).
const SNAP_STEPS: u64 = ssis::bsp::exec::SNAPSHOT_STEPS as u64;

#[test]
fn a_reset_at_any_byte_of_the_snapshot_write_resumes_a_whole_record_or_none() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/qemu-flight.toml");
    let mut sc = Scenario::from_file(&path).expect("scenario");
    sc.duration_s = 30.0;
    let mut sim = Simulation::new(&sc).expect("simulation");
    let (profile, table) = (sim.profile, sim.table);
    let mut core = FlightCore::new(profile, &table, false).expect("core");
    let mut fog = [1u64, 2, 3, 4].map(|i| MockLink::new(sc.links.fog, i));
    let (mut star, mut out) = (MockLink::new(sc.links.star, 99), MockSink::default());
    let mut snap = Snapshot::default();
    // The last two snapshots: the one a write starts from, and the one it writes.
    let (mut old, mut new) = (None, None);
    while let Some(input) = sim.next_step() {
        let _ = step_on_mock_links(&mut core, &mut fog, &mut star, &mut out, &input, profile.fogs);
        out.bytes.clear();
        if input.n.is_multiple_of(SNAP_STEPS) && core.snapshot_into(&mut snap) {
            old = new.replace(snap);
        }
    }
    let (old, new) = (old.expect("two snapshots"), new.expect("two snapshots"));
    let fresh = || FlightCore::new(profile, &table, false).expect("core");
    assert_eq!(fresh().resume(&old), Ok(()), "the old record resumes");
    assert_eq!(fresh().resume(&new), Ok(()), "the new record resumes");
    let (ob, nb) = ({ old }.bytes_mut().to_vec(), { new }.bytes_mut().to_vec());
    let check_at = ob.len() - 4;
    let (mut refused, mut whole) = (0, 0);
    for cut in 0..=check_at {
        let mut torn = old;
        torn.bytes_mut()[..cut].copy_from_slice(&nb[..cut]);
        let t = { torn }.bytes_mut().to_vec();
        if t == ob || t == nb {
            whole += 1;
            continue;
        }
        let r = fresh().resume(&torn);
        assert!(
            matches!(r, Err(SnapshotError::BadCrc | SnapshotError::Implausible | SnapshotError::Absent)),
            "a write cut after {cut} bytes resumed: {r:?}"
        );
        refused += 1;
    }
    assert!(refused > check_at / 2, "{refused} refused, {whole} whole of {} cuts", check_at + 1);
}

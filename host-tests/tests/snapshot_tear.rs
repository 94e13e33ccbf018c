//! A reset during the snapshot write (`FlightCore::snapshot_into`, which the executive
//! runs every `SNAPSHOT_STEPS` over the record a reset does not clear): the record is
//! written in place, field by field in the order of its bytes, and its check word last,
//! so a write cut off anywhere leaves the new bytes before the cut, the old ones after it
//! and the old check word. Every such record is refused at boot (the unit aligns again
//! on the star tracker), unless it is whole: the old record (cut before any byte
//! changed) or the new one. The board keeps two copies and the executive writes them
//! in turn (`Snapshots`): a write cut anywhere, or a bit flipped in the newer copy
//! before a reset, resumes the other copy, one snapshot period older.

use std::path::Path;

use ssis::flight::snapshot::{Snapshot, SnapshotError, Snapshots};
use ssis::flight::FlightCore;
use ssis_common::mock::{MockLink, MockSink};
use ssis_sim::harness::{step_on_mock_links, Simulation};
use ssis_sim::scenario::Scenario;

/// Steps between two snapshots (the executive's `SNAPSHOT_STEPS`).
const SNAP_STEPS: u64 = ssis::bsp::exec::SNAPSHOT_STEPS as u64;

/// The last two snapshots of a 30-s flight of the QEMU scenario (the older, the newer),
/// and a function building a core as the boot does.
fn two_snapshots() -> (Snapshot, Snapshot, impl Fn() -> FlightCore) {
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
    let fresh = move || FlightCore::new(profile, &table, false).expect("core");
    (old.expect("two snapshots"), new.expect("two snapshots"), fresh)
}

/// `old` with its first `cut` bytes from `new`: a write of `new` over `old` cut there.
fn torn(old: Snapshot, new: Snapshot, cut: usize) -> Snapshot {
    let nb = { new }.bytes_mut().to_vec();
    let mut t = old;
    t.bytes_mut()[..cut].copy_from_slice(&nb[..cut]);
    t
}

#[test]
fn a_reset_at_any_byte_of_the_snapshot_write_resumes_a_whole_record_or_none() {
    let (old, new, fresh) = two_snapshots();
    assert_eq!(fresh().resume(&old), Ok(()), "the old record resumes");
    assert_eq!(fresh().resume(&new), Ok(()), "the new record resumes");
    let (ob, nb) = ({ old }.bytes_mut().to_vec(), { new }.bytes_mut().to_vec());
    let check_at = ob.len() - 4;
    let (mut refused, mut whole) = (0, 0);
    for cut in 0..=check_at {
        let t = { torn(old, new, cut) }.bytes_mut().to_vec();
        if t == ob || t == nb {
            whole += 1;
            continue;
        }
        let r = fresh().resume(&torn(old, new, cut));
        assert!(
            matches!(r, Err(SnapshotError::BadCrc | SnapshotError::Implausible | SnapshotError::Absent)),
            "a write cut after {cut} bytes resumed: {r:?}"
        );
        refused += 1;
    }
    assert!(refused > check_at / 2, "{refused} refused, {whole} whole of {} cuts", check_at + 1);
}

/// The sample index a core resumed at (its next snapshot's).
fn resumed_index(core: &FlightCore) -> u64 {
    let mut s = Snapshot::default();
    assert!(core.snapshot_into(&mut s), "the resumed core has a state to snapshot");
    s.index()
}

/// Two copies: the newer being written over the older copy of the period before, cut at
/// every byte, resumes the other copy (or the newer when the cut left it whole); a bit
/// flipped anywhere in the newer copy resumes the older. Neither copy whole: no resume.
#[test]
fn with_two_copies_a_torn_or_flipped_newer_copy_resumes_the_older() {
    let (old, new, fresh) = two_snapshots();
    assert!(new.index() > old.index());
    let pair = |a: Snapshot, b: Snapshot| {
        let mut s = Snapshots::default();
        *s.copy_mut(0).expect("copy 0") = a;
        *s.copy_mut(1).expect("copy 1") = b;
        s
    };
    // The copy being written held the snapshot two periods back: the older copy here
    // stands for the one a period back, the torn one for the write over it.
    let len = { old }.bytes_mut().len();
    for cut in 0..=len {
        let t = torn(old, new, cut);
        let mut core = fresh();
        assert_eq!(core.resume_from(&pair(old, t)), Ok(()), "cut after {cut} bytes");
        let whole_new = { t }.bytes_mut() == { new }.bytes_mut();
        let want = if whole_new { new.index() } else { old.index() };
        assert_eq!(resumed_index(&core), want, "cut after {cut} bytes");
    }
    for bit in 0..8 * len {
        let mut flipped = new;
        flipped.bytes_mut()[bit / 8] ^= 1 << (bit % 8);
        for snaps in [pair(old, flipped), pair(flipped, old)] {
            let mut core = fresh();
            assert_eq!(core.resume_from(&snaps), Ok(()), "bit {bit}");
            // A flip in the index alone may still order the copies either way; the
            // newer whole copy is never taken over the flipped one, and the flipped one
            // is never resumed.
            assert_eq!(resumed_index(&core), old.index(), "bit {bit}");
        }
    }
    let mut spoiled = pair(old, new);
    spoiled.invalidate();
    assert!(fresh().resume_from(&spoiled).is_err(), "both spoiled after a resume: none resumed");
    assert_eq!(fresh().resume_from(&Snapshots::default()), Err(SnapshotError::Absent), "a cold start");
}

//! The command link on the host (`ssis::frames::telecommand`, `ssis::telecommand`): the
//! frame and its CRC-32C, the authenticator (MAC, sequence), the table upload through
//! the two-copy store on a flash in RAM, every refusal counted, and a power loss at every
//! byte the command path writes.

use ssis::calib::store::{self, CalibFlash, FlashError, RamFlash, Slot, REGION_LEN, SLOT_STRIDE};
use ssis::calib::CalibrationTable;
use ssis::flight::{table_crc, FlightCore, Profile};
use ssis::frames::telecommand::{command, upload_state, Telecommand, CRC32C, FRAME_LEN};
use ssis::frames::{DecodeError, Frame};
use ssis::telecommand::auth::{seal, Key};
use ssis::telecommand::upload::{upload_sequence, UploadError, CHUNKS};
use ssis::telecommand::{AuthError, Authenticator, CommandLink, Outcome, Refusal};
use ssis::telemetry::Counter;

fn key(id: u16, seed: u8) -> Key {
    Key { id, bytes: std::array::from_fn(|i| seed.wrapping_mul(31).wrapping_add(i as u8 * 7)) }
}

fn old_table() -> CalibrationTable {
    CalibrationTable { revision: 3, ..CalibrationTable::DEFAULT }
}

fn new_table() -> CalibrationTable {
    let mut t = CalibrationTable { revision: 4, ..CalibrationTable::DEFAULT };
    t.fog[0].bias_rad_s = 2e-7;
    t.fog[2].scale_factor_error = 3e-5;
    t
}

fn core(table: &CalibrationTable) -> FlightCore {
    FlightCore::new(Profile::SPACECRAFT, table, false).expect("core")
}

fn status(key: &Key, seq: u32) -> Telecommand {
    seal(key, Telecommand { command: command::STATUS, seq, ..Telecommand::default() })
}

#[test]
fn crc32c_is_castagnoli_and_the_frame_round_trips() {
    assert_eq!(CRC32C.checksum(b"123456789"), 0xE306_9283);
    let k = key(1, 5);
    let tc = upload_sequence(&k, &new_table(), 7)[3];
    let bytes = tc.to_bytes();
    assert_eq!(bytes.len(), FRAME_LEN);
    assert_eq!(&bytes[..3], &[0xEB, 0x90, 0x50]);
    assert_eq!(Telecommand::decode(&bytes), Ok(tc));
    // Every single-bit error is caught by the CRC-32C (before the MAC is computed).
    for bit in 0..FRAME_LEN * 8 {
        let mut b = bytes;
        b[bit / 8] ^= 1 << (bit % 8);
        assert!(Telecommand::decode(&b).is_err(), "bit {bit}");
    }
    // Fields: an unknown command, and data in a command that carries none.
    let mut odd = Telecommand { command: 9, ..Telecommand::default() }.to_bytes();
    assert_eq!(Telecommand::decode(&odd), Err(DecodeError::BadField));
    odd = Telecommand { command: command::TABLE_ARM, data: [1; 64], ..Telecommand::default() }.to_bytes();
    assert_eq!(Telecommand::decode(&odd), Err(DecodeError::BadField));
}

#[test]
fn the_authenticator_takes_only_the_right_key_and_rising_sequence_numbers() {
    let k = key(7, 1);
    let mut auth = Authenticator::new(&k.to_record());
    assert_eq!(auth.key_id(), 7);
    assert_eq!(auth.check(&status(&k, 5)), Ok(()));
    assert_eq!(auth.check(&status(&k, 5)), Err(AuthError::Replayed));
    assert_eq!(auth.check(&status(&k, 4)), Err(AuthError::OutOfSequence));
    assert_eq!(auth.check(&status(&key(7, 2), 6)), Err(AuthError::Unauthenticated));
    // A flipped MAC bit, or a field changed after sealing (the CRC made good again by the
    // link): not authenticated.
    let mut forged = status(&k, 6);
    forged.mac[15] ^= 0x80;
    assert_eq!(auth.check(&forged), Err(AuthError::Unauthenticated));
    let mut forged = status(&k, 6);
    forged.seq = 60;
    assert_eq!(auth.check(&forged), Err(AuthError::Unauthenticated));
    assert_eq!(auth.check(&status(&k, 9)), Ok(()), "gaps are allowed");
    assert_eq!(auth.last_seq(), 9);
    // Sequence 0 is never valid; no key (erased flash, a damaged record) takes nothing.
    assert_eq!(Authenticator::new(&k.to_record()).check(&status(&k, 0)), Err(AuthError::OutOfSequence));
    let mut rec = k.to_record();
    rec[12] ^= 1;
    let mut none = Authenticator::new(&rec);
    assert_eq!(none.key_id(), 0);
    assert_eq!(none.check(&status(&k, 1)), Err(AuthError::Unauthenticated));
    assert_eq!(Authenticator::new(&[0xFF; 64]).check(&status(&k, 1)), Err(AuthError::Unauthenticated));
}

/// A unit with `old` stored in both slots, its core flying it, and `k` as its key.
struct Unit {
    core: FlightCore,
    link: CommandLink,
    flash: RamFlash,
}

impl Unit {
    fn new(k: &Key, old: &CalibrationTable) -> Unit {
        Unit { core: core(old), link: CommandLink::new(&k.to_record()), flash: RamFlash::new(&store::image(old)) }
    }

    fn send(&mut self, tc: &Telecommand) -> Outcome {
        let mut got = Vec::new();
        self.link.receive(&tc.to_bytes(), &mut self.core, &mut self.flash, |o| got.push(o));
        assert_eq!(got.len(), 1, "one telecommand, one outcome");
        got[0]
    }

    fn count(&self, c: Counter) -> u32 {
        self.core.counter(c)
    }
}

#[test]
fn an_authenticated_upload_switches_the_table_on_fire_and_reports_it() {
    let (k, old, new) = (key(1, 9), old_table(), new_table());
    let mut u = Unit::new(&k, &old);
    let seq = upload_sequence(&k, &new, 100);
    for tc in &seq[..CHUNKS] {
        assert_eq!(u.send(tc), Outcome::Accepted { activated: false });
        assert_eq!(*u.core.table(), old, "nothing changes before FIRE");
    }
    // Staged in the inactive slot with its CRC unwritten: the store still loads the old.
    assert_eq!(store::load(u.flash.region()).table, old);
    assert_eq!(store::decode_slot(u.flash.region(), Slot::B), Err(store::StoreError::BadCrc));
    assert_eq!(u.send(&status(&k, 200)), Outcome::Accepted { activated: false });
    let r = u.link.take_report().expect("a report");
    assert_eq!((r.upload, r.chunks, r.staged_crc), (upload_state::STAGED, 0xFF, table_crc(&new)));
    assert_eq!((r.table_revision, r.table_crc, r.key_id, r.last_seq), (3, table_crc(&old), 1, 200));
    // STATUS came between: sequence numbers go on from 201.
    let seq = upload_sequence(&k, &new, 201 - CHUNKS as u32);
    assert_eq!(u.send(&seq[CHUNKS]), Outcome::Accepted { activated: false });
    assert_eq!(u.send(&seq[CHUNKS + 1]), Outcome::Accepted { activated: true });
    assert_eq!(*u.core.table(), new);
    assert_eq!(u.core.table_crc(), table_crc(&new));
    let l = store::load(u.flash.region());
    assert_eq!((l.table, l.source, l.generation), (new, store::Source::Stored(Slot::B), 2));
    assert_eq!(store::decode_slot(u.flash.region(), Slot::A).map(|(t, _)| t), Ok(old), "the old copy is kept");
    assert_eq!(u.count(Counter::TcAccepted), 11);
    assert_eq!(u.count(Counter::TableActivations), 1);
    assert_eq!(u.count(Counter::TableRevision), 4);
    assert_eq!(u.count(Counter::TableCrcLow) | u.count(Counter::TableCrcHigh) << 16, table_crc(&new));
    // The same sequence replayed: every frame refused (replayed or out of sequence).
    for tc in &seq {
        assert!(matches!(u.send(tc), Outcome::Refused(Refusal::Auth(_))));
    }
    assert_eq!(u.count(Counter::TcAccepted), 11);
    // A new upload of a table of the same revision (a replay after a reset would be one):
    // refused when staged.
    let mut again = Unit::new(&k, &new);
    let seq = upload_sequence(&k, &new, 1);
    for tc in &seq[..CHUNKS - 1] {
        again.send(tc);
    }
    assert_eq!(again.send(&seq[CHUNKS - 1]), Outcome::Refused(Refusal::Upload(UploadError::NotNewer)));
}

#[test]
fn every_bad_command_is_refused_counted_and_changes_nothing() {
    let (k, old, new) = (key(2, 4), old_table(), new_table());
    let mut u = Unit::new(&k, &old);
    let image = u.flash.clone();
    // Wrong key.
    let seq = upload_sequence(&key(2, 5), &new, 1);
    for tc in &seq {
        assert_eq!(u.send(tc), Outcome::Refused(Refusal::Auth(AuthError::Unauthenticated)));
    }
    assert_eq!(u.count(Counter::TcUnauthenticated), seq.len() as u32);
    // Truncated upload: the last chunk never comes; ARM and FIRE refused.
    let seq = upload_sequence(&k, &new, 10);
    for tc in &seq[..CHUNKS - 1] {
        assert_eq!(u.send(tc), Outcome::Accepted { activated: false });
    }
    assert_eq!(u.send(&seq[CHUNKS]), Outcome::Refused(Refusal::Upload(UploadError::NotStaged)));
    assert_eq!(u.send(&seq[CHUNKS + 1]), Outcome::Refused(Refusal::Upload(UploadError::NotArmed)));
    assert_eq!(u.flash, image, "nothing written before the table was whole");
    // A replayed chunk: refused.
    assert_eq!(u.send(&seq[0]), Outcome::Refused(Refusal::Auth(AuthError::OutOfSequence)));
    // The missing chunk, then an activation naming another table's CRC: refused.
    let seq = upload_sequence(&k, &new, 30);
    assert_eq!(u.send(&seq[CHUNKS - 1]), Outcome::Accepted { activated: false });
    assert_eq!(u.send(&seq[CHUNKS]), Outcome::Accepted { activated: false }, "ARM");
    let wrong = seal(
        &k,
        Telecommand { command: command::TABLE_FIRE, seq: 40, table_crc: 0x1234_5678, ..Telecommand::default() },
    );
    assert_eq!(u.send(&wrong), Outcome::Refused(Refusal::Upload(UploadError::WrongCrc)));
    // The wrong FIRE disarmed: the right one now needs a new ARM.
    let fire = seal(&k, Telecommand { seq: 41, ..seq[CHUNKS + 1] });
    assert_eq!(u.send(&fire), Outcome::Refused(Refusal::Upload(UploadError::NotArmed)));
    assert_eq!(*u.core.table(), old);
    assert_eq!(store::load(u.flash.region()).table, old, "staged, never committed");
    // A chunk that disagrees with one received (same table, other bytes).
    let mut other = seq[0];
    other.data[0] ^= 1;
    let other = seal(&k, Telecommand { seq: 50, ..other });
    assert_eq!(u.send(&other), Outcome::Accepted { activated: false }, "a chunk starts a new upload if staged");
    let other2 = seal(&k, Telecommand { seq: 51, data: seq[0].data, ..other });
    assert_eq!(u.send(&other2), Outcome::Refused(Refusal::Upload(UploadError::BadChunk)));
    // A flipped bit on the link: caught by the CRC-32C, counted as corrupt, no outcome.
    let mut bytes = status(&k, 60).to_bytes();
    bytes[40] ^= 0x10;
    let mut outcomes = 0;
    u.link.receive(&bytes, &mut u.core, &mut u.flash, |_| outcomes += 1);
    assert_eq!(outcomes, 0);
    assert_eq!(u.count(Counter::TcCorrupt), 1);
    // A table with a value out of range, whole and correctly sealed: refused when staged.
    let mut bad = new_table();
    bad.fog[1].scale_factor_error = 0.5;
    let seq = upload_sequence(&k, &bad, 70);
    for tc in &seq[..CHUNKS - 1] {
        u.send(tc);
    }
    assert_eq!(u.send(&seq[CHUNKS - 1]), Outcome::Refused(Refusal::Upload(UploadError::TableInvalid)));
    assert_eq!(*u.core.table(), old);
    assert_eq!(u.count(Counter::TableActivations), 0);
    println!(
        "refused: unauthenticated {}, replayed {}, out of sequence {}, upload {}, corrupt {}; accepted {}",
        u.count(Counter::TcUnauthenticated),
        u.count(Counter::TcReplayed),
        u.count(Counter::TcOutOfSequence),
        u.count(Counter::TcRefused),
        u.count(Counter::TcCorrupt),
        u.count(Counter::TcAccepted)
    );
    assert_eq!(u.count(Counter::TcRefused), 6);
    assert_eq!(u.count(Counter::TcOutOfSequence), 1);
}

/// A flash that loses power after `budget` byte writes (an erased byte counts as one):
/// every write after that is lost, as in a power cut between two bytes.
struct CutFlash {
    inner: RamFlash,
    budget: usize,
    written: usize,
}

impl CutFlash {
    fn put(&mut self, offset: usize, b: u8) {
        if self.written < self.budget {
            self.inner.bytes[offset] = b;
        }
        self.written += 1;
    }
}

impl CalibFlash for CutFlash {
    fn region(&self) -> &[u8] {
        &self.inner.bytes
    }

    fn erase(&mut self, slot: Slot) -> Result<(), FlashError> {
        for i in 0..SLOT_STRIDE {
            self.put(slot.offset() + i, 0xFF);
        }
        Ok(())
    }

    fn program(&mut self, offset: usize, bytes: &[u8]) -> Result<(), FlashError> {
        if offset + bytes.len() > REGION_LEN {
            return Err(FlashError::OutOfRange);
        }
        for (i, &b) in bytes.iter().enumerate() {
            self.put(offset + i, b);
        }
        Ok(())
    }
}

/// The whole command path (upload, ARM, FIRE) cut by a power loss after every number of
/// bytes written: the region then loads the old table or the new one, never anything
/// else; the new one only once FIRE's last CRC byte is written.
#[test]
fn a_power_loss_at_any_byte_of_a_commanded_update_leaves_the_old_or_the_new_table() {
    let (k, old, new) = (key(3, 3), old_table(), new_table());
    let seq = upload_sequence(&k, &new, 1);
    let run = |budget: usize| {
        let mut flash = CutFlash { inner: RamFlash::new(&store::image(&old)), budget, written: 0 };
        let mut core = core(&old);
        let mut link = CommandLink::new(&k.to_record());
        for tc in &seq {
            link.receive(&tc.to_bytes(), &mut core, &mut flash, |_| {});
        }
        (store::load(flash.region()), flash.written)
    };
    let (whole, total) = run(usize::MAX);
    assert_eq!(whole.table, new);
    assert_eq!(total, SLOT_STRIDE + store::RECORD_LEN, "erase a slot, program a record");
    let (mut olds, mut news) = (0, 0);
    for budget in 0..=total {
        let (l, _) = run(budget);
        assert_ne!(l.source, store::Source::Default, "cut at {budget}: no copy left");
        if l.table == old {
            olds += 1;
        } else if l.table == new {
            news += 1;
            assert_eq!(budget, total, "the new table loads before its last CRC byte (cut at {budget})");
        } else {
            panic!("cut at {budget}: a table that is neither");
        }
    }
    println!("power cut at each of {} bytes written: old table {olds} times, new {news}", total + 1);
    assert_eq!((olds, news), (total, 1));
}

//! The unit's event log, declared once: when the unit changed state, in unit time.
//!
//! `declare_events!` below is the one list of the unit's state changes. From it come the
//! [`Event`] enum (its wire code, name and what its two detail fields mean), the event
//! table of `docs/ICD.md` ([`write_event_table`]) and the decoder's check of a code
//! ([`Event::from_code`]).
//!
//! Most events are edges of the status the output frame already carries: the step
//! compares its status with the previous one's ([`EventLog::on_status`]), so the log costs
//! the step a few comparisons and records nothing a frame did not show. The others are
//! logged where they happen (a mounting verdict, a command, a table switch, a watchdog
//! warning reported by the board).
//!
//! [`EventLog`] is a bounded ring ([`heapless::Deque`], [`EVENT_LOG`] records): when it
//! is full the oldest record gives way and is counted as lost; every record carries its
//! sequence number, so the ground sees a gap. The board sends the records in event
//! frames ([`crate::frames::event::EventFrame`]) on the output link, only when there is
//! one to send.

use crate::calib::N_FOG;
use crate::frames::output::flags;
use crate::state::Ring;
use crate::state_map::{state_map, StateField};
use crate::telemetry::counters::{page, Counter, Counters, PAGED};
use crate::telemetry::st_status;

/// Records the event log holds before the oldest gives way.
pub const EVENT_LOG: usize = 32;

/// The counter an event declares (`[Counter]` after its name), or none.
macro_rules! event_counter {
    () => {
        None
    };
    ($c:ident) => {
        Some(Counter::$c)
    };
}

/// The unit's events: `code Variant "name" [Counter] "details",` per line; `[Counter]`
/// (optional) is the counter that counts the event: [`EventLog::record`] logs the event
/// and counts it, so the two cannot part.
macro_rules! declare_events {
    ( $( $code:literal $var:ident $name:literal $( [$counter:ident] )? $detail:literal, )* ) => {
        /// A state change of the unit (the event table of `docs/ICD.md`).
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        #[cfg_attr(target_os = "none", derive(defmt::Format))]
        #[repr(u8)]
        pub enum Event {
            $( #[doc = $name] #[doc = ""] #[doc = $detail] $var = $code, )*
        }

        impl Event {
            /// Every event, in declaration order.
            pub const ALL: &'static [Event] = &[$( Event::$var, )*];

            /// The event's code on the wire.
            pub const fn code(self) -> u8 {
                self as u8
            }

            /// The event of wire code `code` (`None`: no such event).
            pub const fn from_code(code: u8) -> Option<Event> {
                match code {
                    $( $code => Some(Event::$var), )*
                    _ => None,
                }
            }

            /// Its name in a timeline (lower case, one word).
            pub const fn name(self) -> &'static str {
                match self {
                    $( Event::$var => $name, )*
                }
            }

            /// What its detail fields `a` and `b` carry.
            pub const fn detail(self) -> &'static str {
                match self {
                    $( Event::$var => $detail, )*
                }
            }

            /// The counter that counts it ([`EventLog::record`]), if it has one.
            pub const fn counter(self) -> Option<Counter> {
                match self {
                    $( Event::$var => event_counter!($($counter)?), )*
                }
            }
        }
    };
}

declare_events! {
    1 Aligned "aligned" "the star tracker aligned the attitude and the mounting check clears it to report (a, b: 0)",
    2 Converged "converged" "the estimator converged (a, b: 0)",
    3 ConvergenceLost "convergence_lost" "the estimator no longer reports converged: restarted, or its error grew (a, b: 0)",
    4 ParityAlarm "parity_alarm" "the four-FOG parity check raised an alarm: a FOG is faulty, not yet isolated (a, b: 0)",
    5 AlarmCleared "alarm_cleared" "a parity alarm cleared without isolation: a transient (a, b: 0)",
    6 Isolated "isolated" [FdiIsolations] "a FOG was isolated: the unit flies on the other three (a: FOG channel, 1-based; b: the cause: 1 the parity check named it, 2 its own checks refused it during a parity alarm, 3 the star tracker named it during a parity alarm, 4 the mounting check found it reversed or alone at odds with the tracker)",
    7 TempSensorFailed "temp_sensor_failed" "a FOG's temperature sensor failed: its compensation holds the predicted temperature (a: FOG channel, 1-based; b: 0)",
    8 MountVerdict "mount_verdict" "the mounting check's verdict (a: 1 reversed, 2 swapped, 3 alone at odds with the tracker; b: the FOG channel, 1-based, and for a swap the second one times 16)",
    9 MountUnverified "mount_unverified" [MountUnverified] "the mounting check could not verify some FOGs in its first 10 s and watches on (a: bit i for FOG channel i + 1; b: 0)",
    10 MountUndecided "mount_undecided" [MountUndecided] "the mounting check ended with FOGs at odds with the tracker and no single flip or swap explaining them (a, b: 0)",
    11 FogsRemapped "fogs_remapped" "the unit flies two FOGs on the corrected assignment (a: the table axis of channel k in bits 2k..2k+1; b: 0)",
    12 TableFallback "table_fallback" "the stored calibration table was invalid: the unit flies on the default table (a, b: 0)",
    13 BitFailed "bit_failed" "the power-on built-in test failed (a, b: 0)",
    14 Reacquired "reacquired" "the estimator re-acquired the star tracker after a streak of gated frames that agreed (a, b: 0)",
    15 OutageStart "outage_start" "no star-tracker frame used for more than 2 s after alignment: the attitude propagates on the gyros alone (a, b: 0)",
    16 OutageEnd "outage_end" "a star-tracker frame was used again after an outage (a, b: 0)",
    17 WatchdogWarning "watchdog_warning" "the board's watchdog warned: the main loop missed one watchdog period (a, b: 0)",
    18 CommandAccepted "command_accepted" "a telecommand was authenticated and acted on (a: command code; b: its sequence number, low 16 bits)",
    19 CommandRefused "command_refused" "a decoded telecommand was refused (a: command code; b: the refusal code of the command report)",
    20 TableSwitched "table_switched" "the unit switched to a calibration table (a: 0; b: its revision, low 16 bits)",
    21 StateRestored "state_restored" [StateRestored] "guarded state changed between two steps (a bit flip) was restored (a: block, 1 attitude, 2 drift/convergence/combiner, 3 estimator and mount, 4+i combiner without FOG i+1; b: 0 from its good copy, 1 the copy took the flip, 2 neither: derived again, re-aligning)",
    22 StateImplausible "state_implausible" [StateImplausible] "guarded state was implausible (a: 1 attitude norm, 2 drift beyond 1000 °/h, 3 covariance): the estimator re-aligns on the next star-tracker frame (b: 0)",
    23 Realigned "realigned" [Realigned] "the star tracker and the propagated attitude disagreed on consecutive frames that agree with each other: the attitude was re-aligned on the tracker, not converged until the estimate converges again (a: the disagreement in whole degrees, saturating; b: in arcsec, saturating at 65,535)",
    24 FogLost "fog_lost" [FogsLost] "a FOG gave no usable sample for 40 in a row (200 ms; not isolated): the unit flies without it (a: FOG channel, 1-based; b: the health bits of its last sample, which say why: missing, device fault, out of range, stuck)",
    25 FogRestored "fog_restored" [FogsRestored] "a lost FOG gave usable samples again, 40 in a row: flown again (a: FOG channel, 1-based; b: 0)",
    26 AlignmentLost "alignment_lost" [AlignmentsLost] "the unit no longer reports aligned (a: the cause: 1 the estimator starts again (a mounting verdict, guarded state derived again), 2 the mounting check finds a FOG at odds with the tracker, 3 the mounting check's evidence starts again and has not yet spanned 2 s; b: 0)",
    41 TableRestored "table_restored" [TablesRestored] "the background check found the calibration table in RAM differing from its CRC: restored from the two-copy store, combiner and gains rebuilt (a: 1 restored, 0 no good copy: flying on as it was, degraded; b: the restored table's revision, low 16 bits)",
    42 KeyRestored "key_restored" [KeysRestored] "the background check found the command key in RAM differing from its protected record: restored from the record (a, b: 0)",
    43 Resumed "resumed" [Resumes] "the unit resumed after a reset from its snapshot in RAM: attitude, drift, time, alignment (a: 0; b: the snapshot's age in steps)",
    44 SnapshotInvalid "snapshot_invalid" [SnapshotsInvalid] "after a reset the snapshot was not resumed: the unit aligns again on the star tracker (a: 1 absent, 2 CRC, 3 other table, 4 implausible, 5 too old; b: 0)",
    45 CodeCorrupt "code_corrupt" [CodeCorrupt] "the background check of the code in flash found its CRC changed since boot (a: 0; b: 0); the unit resets (a reset reloads it)",
    46 SramEcc "sram_ecc" "the board's SRAM ECC reported errors since the last step (a: uncorrected, saturating at 255; b: corrected, saturating)",
    47 RegisterRestored "register_restored" "the board's check of its configuration registers (step tick, interrupt enables and priorities, UARTs, MPU, watchdog, interrupt masks) found some changed and restored them (a: registers restored, saturating; b: 0); a restore that does not hold resets the unit",
}

/// One event with its unit time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct EventRecord {
    /// Unit time of the step it happened in (of the last step, between steps), µs.
    pub time_us: u64,
    /// Sequence number since power-on (wrapping): a gap means records were lost.
    pub seq: u16,
    /// What happened.
    pub event: Event,
    /// First detail field ([`Event::detail`]).
    pub a: u8,
    /// Second detail field ([`Event::detail`]).
    pub b: u16,
}

/// An [`EventRecord`] as the log stores it: plain numbers without padding, the event
/// by its code (a record whose code names no event is skipped when read).
#[derive(Debug, Clone, Copy, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct EventSlot {
    time_us: u64,
    seq: u16,
    code: u8,
    a: u8,
    b: u16,
    _pad: [u8; 2],
}

impl EventSlot {
    #[inline]
    fn of(r: &EventRecord) -> Self {
        EventSlot { time_us: r.time_us, seq: r.seq, code: r.event.code(), a: r.a, b: r.b, _pad: [0; 2] }
    }

    #[inline]
    fn record(self) -> Option<EventRecord> {
        let event = Event::from_code(self.code)?;
        Some(EventRecord { time_us: self.time_us, seq: self.seq, event, a: self.a, b: self.b })
    }
}

/// The status bits of one step's output whose edges are events (the output frame's
/// flags, star-tracker status and fault-logic bits).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatusBits {
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// Star-tracker status bits ([`st_status`]).
    pub st_status: u8,
    /// Fault-logic bits: temperature held (bit i), isolated (bit 4 + i).
    pub fdi: u8,
}

impl StatusBits {
    /// The bits whose edges are events, in one word.
    #[inline]
    fn packed(self) -> u32 {
        u32::from_le_bytes([self.flags & FLAG_EDGES, self.st_status & ST_EDGES, self.fdi, 0])
    }

    /// The inverse of [`StatusBits::packed`].
    fn unpack(w: u32) -> StatusBits {
        let [flags, st_status, fdi, _] = w.to_le_bytes();
        StatusBits { flags, st_status, fdi }
    }
}

/// The event log: a bounded ring of [`EventRecord`], oldest first.
#[derive(Debug, Clone, Copy, Default, bytemuck::AnyBitPattern)]
pub struct EventLog {
    /// The last step's [`StatusBits::packed`].
    last_status: u32,
    ring: Ring<EventSlot, EVENT_LOG>,
    /// Sequence number of the next record.
    next_seq: u16,
    /// Records that gave way to newer ones, saturating.
    lost: u32,
}

impl EventLog {
    /// Where each field lies in the value ([`crate::state_map`]).
    pub const STATE_MAP: &'static [StateField] = state_map!(EventLog {
        last_status: u32,
        ring: Ring<EventSlot, EVENT_LOG>,
        next_seq: u16,
        lost: u32,
    });

    /// An empty log.
    pub fn new() -> Self {
        EventLog { last_status: 0, ring: Ring::new(), next_seq: 0, lost: 0 }
    }

    /// Logs `event` at `time_us` with details `a`, `b`; the oldest record gives way when
    /// the log is full.
    pub fn log(&mut self, time_us: u64, event: Event, a: u8, b: u16) {
        let r = EventRecord { time_us, seq: self.next_seq, event, a, b };
        self.next_seq = self.next_seq.wrapping_add(1);
        if self.ring.push_back_overwrite(EventSlot::of(&r)) {
            self.lost = self.lost.saturating_add(1);
        }
    }

    /// Logs `event` at `time_us` with details `a`, `b` and counts it on its counter
    /// ([`Event::counter`]): the one way the core logs an event that has a counter.
    #[inline(never)]
    pub fn record(&mut self, counters: &mut Counters, time_us: u64, event: Event, a: u8, b: u16) {
        self.record_n(counters, time_us, event, a, b, 1);
    }

    /// [`EventLog::record`], adding `n` to its counter (an event about several FOGs
    /// counts each).
    pub fn record_n(&mut self, counters: &mut Counters, time_us: u64, event: Event, a: u8, b: u16, n: u32) {
        if let Some(c) = event.counter() {
            counters.add(c, n);
        }
        self.log(time_us, event, a, b);
    }

    /// Logs the edges between the previous step's status and this one's, `now`
    /// (alignment, convergence, parity alarm, temperature sensors, FOG
    /// remapping, fallback table, failed built-in test, re-acquisition, outage), at this
    /// step's unit time `time_us`. `fog_map`: the table axis each FOG channel flies on.
    /// One comparison a step when nothing changed.
    #[inline]
    pub fn on_status(&mut self, now: StatusBits, time_us: u64, fog_map: &[usize; N_FOG]) {
        let packed = now.packed();
        if packed != self.last_status {
            let prev = StatusBits::unpack(self.last_status);
            self.last_status = packed;
            self.log_changes(prev, StatusBits::unpack(packed), time_us, fog_map);
        }
    }

    /// [`EventLog::on_status`] once something changed (kept out of line: rare).
    #[inline(never)]
    fn log_changes(&mut self, prev: StatusBits, now: StatusBits, t: u64, fog_map: &[usize; N_FOG]) {
        let rose = |was: u8, is: u8, bit: u8| was & bit == 0 && is & bit != 0;
        for (bit, event) in [(flags::TABLE_DEFAULTED, Event::TableFallback), (flags::BIT_FAILED, Event::BitFailed)] {
            if rose(prev.flags, now.flags, bit) {
                self.log(t, event, 0, 0);
            }
        }
        if rose(prev.flags, now.flags, flags::FOGS_REMAPPED) {
            let packed = fog_map.iter().enumerate().fold(0u8, |acc, (k, &axis)| acc | ((axis as u8 & 3) << (2 * k)));
            self.log(t, Event::FogsRemapped, packed, 0);
        }
        if rose(prev.st_status, now.st_status, st_status::ALIGNED) {
            self.log(t, Event::Aligned, 0, 0);
        }
        if rose(prev.flags, now.flags, flags::CONVERGED) {
            self.log(t, Event::Converged, 0, 0);
        } else if rose(now.flags, prev.flags, flags::CONVERGED) {
            self.log(t, Event::ConvergenceLost, 0, 0);
        }
        if rose(prev.flags, now.flags, flags::FDI_ALARM) {
            self.log(t, Event::ParityAlarm, 0, 0);
        }
        let newly_isolated = now.fdi & !prev.fdi & 0xF0;
        if rose(now.flags, prev.flags, flags::FDI_ALARM) && newly_isolated == 0 {
            self.log(t, Event::AlarmCleared, 0, 0);
        }
        for i in 0..N_FOG as u8 {
            if rose(prev.fdi, now.fdi, 1 << i) {
                self.log(t, Event::TempSensorFailed, i + 1, 0);
            }
        }
        if rose(prev.st_status, now.st_status, st_status::REACQUIRED) {
            self.log(t, Event::Reacquired, 0, 0);
        }
        let aligned = now.st_status & st_status::ALIGNED != 0;
        if rose(prev.st_status, now.st_status, st_status::OUTAGE) && aligned {
            self.log(t, Event::OutageStart, 0, 0);
        }
        if rose(now.st_status, prev.st_status, st_status::OUTAGE) && prev.st_status & st_status::ALIGNED != 0 {
            self.log(t, Event::OutageEnd, 0, 0);
        }
    }

    /// The records not yet sent, oldest first.
    pub fn pending(&self) -> impl Iterator<Item = EventRecord> + '_ {
        self.ring.iter().filter_map(EventSlot::record)
    }

    /// Records not yet sent.
    pub fn len(&self) -> usize {
        self.pending().count()
    }

    /// Whether every record has been sent.
    pub fn is_empty(&self) -> bool {
        self.pending().next().is_none()
    }

    /// Drops the oldest `n` records (they were sent), and the unreadable ones among them.
    pub fn drop_sent(&mut self, n: usize) {
        let mut left = n;
        for _ in 0..EVENT_LOG {
            if left == 0 {
                break;
            }
            match self.ring.pop_front() {
                Some(slot) if slot.record().is_some() => left -= 1,
                Some(_) => {}
                None => break,
            }
        }
    }

    /// Takes the oldest record.
    pub fn pop(&mut self) -> Option<EventRecord> {
        for _ in 0..EVENT_LOG {
            if let Some(r) = self.ring.pop_front()?.record() {
                return Some(r);
            }
        }
        None
    }

    /// Records that gave way to newer ones before they were sent (saturating).
    pub fn lost(&self) -> u32 {
        self.lost
    }
}

/// Flag bits whose edges are events (degraded and a dropped frame change from step to
/// step and are counted, not logged).
const FLAG_EDGES: u8 = !(flags::DEGRADED | flags::OUTPUT_DROPPED | flags::ST_IN_USE);

/// Star-tracker status bits whose edges are events (the others change from step to step).
const ST_EDGES: u8 = st_status::ALIGNED | st_status::OUTAGE | st_status::REACQUIRED;

/// Writes the event table of `docs/ICD.md` (markdown rows `| code | event | details |`).
pub fn write_event_table(w: &mut impl core::fmt::Write) -> core::fmt::Result {
    writeln!(w, "| code | event | counter (page id) | details |")?;
    writeln!(w, "|---|---|---|---|")?;
    for e in Event::ALL {
        write!(w, "| {} | `{}` | ", e.code(), e.name())?;
        match e.counter() {
            Some(c) => match PAGED.iter().position(|p| *p == c) {
                Some(k) => write!(w, "`{:?}` ({})", c, usize::from(page::FOG_PAGES) + k)?,
                None => write!(w, "`{:?}`", c)?,
            },
            None => write!(w, "—")?,
        }
        writeln!(w, " | {} |", e.detail())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn out(time_us: u64, flags: u8, st: u8, fdi: u8) -> (StatusBits, u64) {
        (StatusBits { flags, st_status: st, fdi }, time_us)
    }

    fn step(log: &mut EventLog, prev: (StatusBits, u64), now: (StatusBits, u64), map: &[usize; N_FOG]) {
        log.last_status = prev.0.packed();
        log.on_status(now.0, now.1, map);
    }

    #[test]
    fn codes_round_trip_and_are_unique() {
        for (k, e) in Event::ALL.iter().enumerate() {
            assert_eq!(Event::from_code(e.code()), Some(*e));
            assert!(Event::ALL.iter().skip(k + 1).all(|o| o.code() != e.code() && o.name() != e.name()));
        }
        assert_eq!(Event::from_code(0), None);
    }

    #[test]
    fn full_log_drops_the_oldest_and_counts_it() {
        let mut log = EventLog::new();
        for k in 0..(EVENT_LOG as u64 + 3) {
            log.log(k, Event::Reacquired, 0, 0);
        }
        assert_eq!(log.len(), EVENT_LOG);
        assert_eq!(log.lost(), 3);
        let first = log.pending().next();
        assert_eq!(first.map(|r| (r.time_us, r.seq)), Some((3, 3)));
        log.drop_sent(EVENT_LOG + 10);
        assert!(log.is_empty());
        log.log(99, Event::Aligned, 0, 0);
        assert_eq!(log.pop().map(|r| r.seq), Some(EVENT_LOG as u16 + 3));
    }

    #[test]
    fn sequence_wraps_without_loss_of_order() {
        let mut log = EventLog { next_seq: u16::MAX, ..EventLog::new() };
        log.log(1, Event::Aligned, 0, 0);
        log.log(2, Event::Converged, 0, 0);
        let seqs: [u16; 2] = [log.pop().map_or(1, |r| r.seq), log.pop().map_or(1, |r| r.seq)];
        assert_eq!(seqs, [u16::MAX, 0]);
    }

    #[test]
    fn edges_of_the_output_are_logged_once() {
        let mut log = EventLog::new();
        let map = [0, 1, 2, 3];
        let a = out(5_000, 0, st_status::OUTAGE, 0);
        let b = out(10_000, flags::FDI_ALARM, st_status::ALIGNED, 0);
        step(&mut log, a, b, &map);
        step(&mut log, b, b, &map);
        let c = out(15_000, 0, st_status::ALIGNED, 0x20);
        step(&mut log, b, c, &map);
        let got: [(u64, Event, u8); 2] =
            core::array::from_fn(|_| log.pop().map_or((0, Event::BitFailed, 0), |r| (r.time_us, r.event, r.a)));
        assert_eq!(got, [(10_000, Event::Aligned, 0), (10_000, Event::ParityAlarm, 0)]);
        assert!(
            log.is_empty(),
            "a cleared alarm with an isolation is no transient (the isolation is recorded where it is decided, with \
             its cause); the power-on outage is no outage"
        );
    }

    #[test]
    fn an_outage_after_alignment_has_a_start_and_an_end() {
        let mut log = EventLog::new();
        let map = [0, 1, 2, 3];
        let aligned = out(1, 0, st_status::ALIGNED, 0);
        let silent = out(2, 0, st_status::ALIGNED | st_status::OUTAGE, 0);
        let back = out(3, 0, st_status::ALIGNED | st_status::UPDATED, 0);
        step(&mut log, aligned, silent, &map);
        step(&mut log, silent, back, &map);
        assert_eq!(log.pop().map(|r| (r.time_us, r.event)), Some((2, Event::OutageStart)));
        assert_eq!(log.pop().map(|r| (r.time_us, r.event)), Some((3, Event::OutageEnd)));
    }

    #[test]
    fn a_remap_carries_the_assignment() {
        let mut log = EventLog::new();
        let now = out(7, flags::FOGS_REMAPPED, 0, 0);
        step(&mut log, out(0, 0, 0, 0), now, &[1, 0, 2, 3]);
        assert_eq!(log.pop().map(|r| (r.event, r.a)), Some((Event::FogsRemapped, 0b11_10_00_01)));
    }

    /// An event that declares a counter is counted by [`EventLog::record`], by the
    /// amount given; one without is only logged.
    #[test]
    fn recording_an_event_counts_it_on_its_counter() {
        let mut log = EventLog::new();
        let mut c = Counters::default();
        log.record(&mut c, 1, Event::Isolated, 2, 1);
        log.record_n(&mut c, 2, Event::MountUnverified, 0b101, 0, 2);
        log.record(&mut c, 3, Event::Aligned, 0, 0);
        assert_eq!((c.fdi_isolations, c.mount_unverified), (1, 2));
        assert_eq!(Event::Aligned.counter(), None);
        assert_eq!(log.len(), 3);
    }

    #[test]
    fn the_table_lists_every_event() {
        let mut s = heapless::String::<8192>::new();
        assert!(write_event_table(&mut s).is_ok());
        assert_eq!(s.lines().count(), 2 + Event::ALL.len());
    }
}

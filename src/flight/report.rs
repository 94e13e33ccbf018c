//! What the core reports and what it is told between steps: the counters (its own and
//! the board's and the command link's), the counter page of the output frame, and the
//! event log and its frames on the output link.

use super::propagate::Integrated;
use super::FlightCore;
use crate::frames::event::{EventFrame, RECORDS};
use crate::frames::Frame;
use crate::link::OutPort;
use crate::telemetry::events::{Event, EventLog, EventRecord};
use crate::telemetry::{flags, page, st_status, Counter, Counters, StepOutput};

impl FlightCore {
    /// Command link and board: one more event of counter `c` (the telecommand counters;
    /// the counters the core derives itself are not changed by it).
    pub fn note(&mut self, c: Counter) {
        self.telemetry.counters.bump(c);
    }

    /// Logs `event` with details `a`, `b` at the unit time of the last step (the command
    /// link's outcomes; the core logs its own state changes).
    pub fn log_event(&mut self, event: Event, a: u8, b: u16) {
        self.events.log(self.last_output.time_us, event, a, b);
    }

    /// The board's background check of the code in flash found its CRC changed: logged
    /// (`code_corrupt`) and counted.
    pub fn note_code_corrupt(&mut self) {
        self.events.record(&mut self.telemetry.counters, self.last_output.time_us, Event::CodeCorrupt, 0, 0);
    }

    /// The board's SRAM ECC reported `corrected` single-bit and `uncorrected` double-bit
    /// errors since the last step: counted, and logged (`sram_ecc`).
    pub fn note_sram_ecc(&mut self, corrected: u32, uncorrected: u32) {
        let c = &mut self.telemetry.counters;
        c.add(Counter::SramEccCorrected, corrected);
        c.add(Counter::SramEccUncorrected, uncorrected);
        let a = u8::try_from(uncorrected).unwrap_or(u8::MAX);
        let b = u16::try_from(corrected).unwrap_or(u16::MAX);
        self.events.log(self.last_output.time_us, Event::SramEcc, a, b);
    }

    /// The background check of the command key found it changed and restored it from
    /// its record (`telecommand::CommandLink::check_key`): logged (`key_restored`) and
    /// counted.
    pub fn note_key_restored(&mut self) {
        self.events.record(&mut self.telemetry.counters, self.last_output.time_us, Event::KeyRestored, 0, 0);
    }

    /// Board: the watchdog warned (the main loop missed a watchdog period).
    pub fn note_watchdog_warning(&mut self) {
        self.log_event(Event::WatchdogWarning, 0, 0);
    }

    /// The event log (records not yet sent).
    pub fn events(&self) -> &EventLog {
        &self.events
    }

    /// Takes the oldest record not yet sent (host tools that read the log directly).
    pub fn take_event(&mut self) -> Option<EventRecord> {
        self.events.pop()
    }

    /// Board, after the step: sends the oldest records not yet sent (up to four) in one
    /// event frame on `out`; nothing when there is none. Records the link does not take
    /// stay for the next call. Returns whether a frame was sent.
    pub fn send_events<O: OutPort>(&mut self, out: &mut O) -> bool {
        if self.events.is_empty() {
            return false;
        }
        let mut frame =
            EventFrame { lost: u16::try_from(self.events.lost()).unwrap_or(u16::MAX), records: [None; RECORDS] };
        for (slot, r) in frame.records.iter_mut().zip(self.events.pending()) {
            *slot = Some(r);
        }
        let n = frame.iter().count();
        let mut scratch = [0u8; EventFrame::LEN];
        let sent = out.send_frame(&mut scratch, EventFrame::LEN, |buf| frame.encode_into(buf).is_ok());
        if sent {
            self.events.drop_sent(n);
        }
        sent
    }

    /// Records a failed power-on built-in test: flagged in every output frame from now on.
    pub fn note_bit_failure(&mut self) {
        self.fixed_flags |= flags::BIT_FAILED;
    }

    /// Counters so far.
    pub fn counters(&self) -> Counters {
        self.telemetry.counters
    }

    /// Counter `c` so far. The table's figures are read from the table in use; the others
    /// are the telemetry stage's.
    pub fn counter(&self, c: Counter) -> u32 {
        match c {
            Counter::TableRevision => self.table.revision,
            Counter::TableCrcLow => self.table_crc & 0xFFFF,
            Counter::TableCrcHigh => self.table_crc >> 16,
            _ => self.telemetry.counters.get(c),
        }
    }

    /// The counter that the output frame's page `id` carries ([`page`]).
    pub(super) fn page_value(&self, id: u8) -> u32 {
        match page::entry(id) {
            Some(page::Entry::Fog(i, c)) => self.telemetry.counters.fog.get(i).map_or(0, |f| f.get(c)),
            Some(page::Entry::Unit(c)) => self.counter(c),
            None => 0,
        }
    }

    /// Board: the previous step overran its deadline.
    pub fn note_overrun(&mut self) {
        self.telemetry.counters.bump(Counter::Overruns);
    }

    /// Board: a control frame arrived and was ignored (a flight build has no test hooks).
    pub fn note_control_ignored(&mut self) {
        self.telemetry.counters.bump(Counter::ControlIgnored);
    }

    /// Board: how long the previous step took, in board ticks (goes into the frame).
    pub fn set_step_ticks(&mut self, ticks: u16) {
        self.telemetry.set_step_ticks(ticks);
    }

    /// Telemetry: the step's output at `now_us`, with star-tracker status `st`, from
    /// what the samples gave (`acc`); each stage's status bits assembled: the fixed
    /// flags, the fault logic's, the temperature sensors', degraded (and the timed hold
    /// after a table restore), converged, the previous frame dropped, and the attitude's
    /// validity derived from them ([`FlightCore::attitude_valid`]).
    #[inline(always)]
    pub(super) fn assemble_output(&mut self, now_us: u64, st: u8, acc: &Integrated, dt_s: f64) -> StepOutput {
        let mut status_flags = self.fixed_flags;
        if self.scrub.degraded() {
            status_flags |= flags::DEGRADED;
        }
        let mut fdi_bits = 0u8;
        if let Some(fdi) = self.fdi.as_ref() {
            let (f, b) = fdi.status_bits();
            status_flags |= f;
            fdi_bits |= b;
        }
        fdi_bits |= self.temp_failed_bits;
        if acc.degraded || st & st_status::OUTAGE != 0 && self.observer.aligned() {
            status_flags |= flags::DEGRADED;
        }
        if self.observer.converged() {
            status_flags |= flags::CONVERGED;
        }
        if self.telemetry.output_dropped_last() {
            status_flags |= flags::OUTPUT_DROPPED;
        }
        let (att_sigma_rad, drift_sigma_rad_s) = self.observer.sigmas(now_us);
        let st = if self.attitude_valid(st, status_flags, acc) { st | st_status::VALID } else { st };
        StepOutput {
            time_us: now_us,
            q: self.attitude.quaternion(),
            rate_rad_s: acc.rate_dtheta / dt_s,
            drift_rad_s: self.observer.drift_rad_s(),
            parity_rad: acc.parity_rad,
            fog_health: acc.fog_health,
            st_status: st,
            flags: status_flags,
            fogs_used: acc.used,
            fdi: fdi_bits,
            att_sigma_rad,
            drift_sigma_rad_s,
        }
    }

    /// The attitude is good to use (`st_status::VALID`, `docs/ICD.md` "Attitude
    /// valid"): the one validity the unit states, derived here from the other status
    /// bits of the same step (`st`, `status_flags`) and nothing else of the step
    /// (`acc`): aligned (star-tracker status: the estimator aligned and the mounting check
    /// clears the unit), converged (the estimate converged and the propagated attitude
    /// not in doubt), no parity alarm (a faulty FOG's error would be in the attitude and
    /// not in its σ), the built-in test passed, a sample integrated in the step and every
    /// one on a usable gyro set (a held increment's error is not in σ either; a step that
    /// waits for an owed sample has propagated nothing), and no resume from a snapshot
    /// waiting for its confirmation. Degraded otherwise (three FOGs, a tracker outage)
    /// is not invalid: the reported σ grows with it.
    #[inline(always)]
    fn attitude_valid(&self, st: u8, status_flags: u8, acc: &Integrated) -> bool {
        st & st_status::ALIGNED != 0
            && status_flags & (flags::CONVERGED | flags::FDI_ALARM | flags::BIT_FAILED) == flags::CONVERGED
            && acc.integrated > 0
            && !acc.held
            && self.resumed_at.get().is_none()
    }
}

//! The unit's counters, declared once.
//!
//! `declare_counters!` below, with the counters the events declare
//! ([`crate::telemetry::event_list`]: an event's counter is declared on the event's line,
//! once), is the one list of what the unit counts. From it come the
//! [`Counter`], [`FogCounter`] and [`NavCounter`] enums, the [`Counters`],
//! [`FogCounters`] and [`NavCounters`] storage (named fields, saturating; the
//! navigation stage's, [`crate::nav::unit`], are reported by the launch-vehicle
//! firmware at the end of a run and are not on the counter page), the output frame's counter page ([`page`]) and the page
//! table of `docs/ICD.md` ([`write_page_table`]; a host test compares the two).
//!
//! Every count goes through [`Counters::add`] / [`FogCounters::add`] /
//! [`NavCounters::add`] (or `bump`).

use crate::calib::N_FOG;
use crate::integrity::parity::FdiState;
use crate::telemetry::event_list::events_table;

/// One set of counters: the enum naming them, its storage with one named field per
/// counter (plus `$extra` fields), `add` and `get`.
macro_rules! counter_set {
    (
        $(#[doc = $edoc:literal])* enum $enum:ident;
        $(#[doc = $sdoc:literal])* struct $store:ident { $( $(#[doc = $xdoc:literal])* $xfield:ident: $xty:ty, )* }
        $( $var:ident $field:ident $desc:literal, )*
    ) => {
        $(#[doc = $edoc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq)]
        pub enum $enum {
            $( #[doc = $desc] $var, )*
        }

        impl $enum {
            /// Every counter of the set, in declaration order.
            pub const ALL: &'static [$enum] = &[$( $enum::$var, )*];

            /// What the counter counts (the page table's text).
            pub const fn describe(self) -> &'static str {
                match self {
                    $( $enum::$var => $desc, )*
                }
            }
        }

        $(#[doc = $sdoc])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, bytemuck::Pod, bytemuck::Zeroable)]
        #[repr(C)]
        pub struct $store {
            $( #[doc = $desc] pub $field: u32, )*
            $( $(#[doc = $xdoc])* pub $xfield: $xty, )*
        }

        impl $store {
            /// Adds `n` to counter `c`, saturating.
            #[inline]
            pub fn add(&mut self, c: $enum, n: u32) {
                let v = match c {
                    $( $enum::$var => &mut self.$field, )*
                };
                *v = v.saturating_add(n);
            }

            /// Counter `c`.
            #[inline]
            pub fn get(&self, c: $enum) -> u32 {
                match c {
                    $( $enum::$var => self.$field, )*
                }
            }
        }
    };
}

/// The unit's counters: per FOG, for the unit (those of the `unit` list, then those the
/// events declare, [`crate::telemetry::event_list`]), which unit counters the page carries,
/// and the navigation stage's.
macro_rules! declare_counters {
    (
        fog { $( $fvar:ident $ffield:ident $fdesc:literal, )* }
        unit { $( $uvar:ident $ufield:ident $udesc:literal, )* }
        paged [ $( $pvar:ident, )* ]
        nav { $( $nvar:ident $nfield:ident $ndesc:literal, )* }
        events { $( $code:literal $evar:ident $ename:literal $( [$cvar:ident $cfield:ident $cdesc:literal] )? $edetail:literal, )* }
    ) => {
        counter_set! {
            /// A per-FOG counter (one of each per FOG slot).
            enum FogCounter;
            /// One FOG's counters (saturating).
            struct FogCounters {}
            $( $fvar $ffield $fdesc, )*
        }

        counter_set! {
            /// A counter of the unit as a whole.
            enum Counter;
            /// The unit's counters (saturating), per FOG in [`Counters::fog`].
            struct Counters {
                /// Per FOG slot.
                fog: [FogCounters; N_FOG],
            }
            $( $uvar $ufield $udesc, )*
            $( $( $cvar $cfield $cdesc, )? )*
        }

        /// The unit counters the page carries after the per-FOG ones, in page order.
        pub const PAGED: &[Counter] = &[$( Counter::$pvar, )*];

        counter_set! {
            /// A counter of the launch-vehicle navigation stage ([`crate::nav::unit`]).
            enum NavCounter;
            /// The navigation stage's counters (saturating).
            struct NavCounters {}
            $( $nvar $nfield $ndesc, )*
        }
    };
}

events_table!(declare_counters {
    fog {
        Rejected rejected "frames rejected (CRC, format, wrong id)",
        Missing missing "samples missing (not there in time)",
        OutOfRange out_of_range "samples not finite or outside the measuring range",
        Stuck stuck "samples refused as stuck",
        DeviceFault device_fault "samples with the FOG's own fault bits (light source, loop lock)",
        TempFailures temp_failures "temperature sensor failures (reported, out of −60…+100 °C, or a jump of more than 3 °C)",
        Spikes spikes "samples dropped as parity spikes",
    }
    unit {
        FogFramesRejected fog_frames_rejected "FOG frames rejected by the decoders (all FOGs)",
        FogSamplesMissing fog_samples_missing "FOG samples that did not arrive in time (all FOGs)",
        StFramesAccepted st_frames_accepted "star-tracker frames that updated the observer",
        StFramesRejected st_frames_rejected "star-tracker frames rejected as bad (decoder, invalid flag, not a unit quaternion)",
        StUpdatesGated st_updates_gated "star-tracker frames refused by the observer's gate",
        Overruns overruns "steps that overran their deadline (reported by the board)",
        FdiAlarms fdi_alarms "parity alarms raised",
        FdiTransients fdi_transients "parity alarms that cleared without isolation (transients)",
        StFrozen st_frozen "star-tracker frames refused as frozen",
        StReacquired st_reacquired "star-tracker re-acquisitions",
        StOutages st_outages "star-tracker outages begun",
        IoErrors io_errors "link driver errors",
        OutputDropped output_dropped "output frames dropped",
        FogSamplesStale fog_samples_stale "FOG samples that came too late and were discarded",
        StFramesLate st_frames_late "star-tracker frames older than the attitude history (came late, or the unit bridged past them)",
        StFramesEarly st_frames_early "star-tracker frames too far ahead of the unit's clock (more than 1 s, or more than the pending queue holds)",
        ControlIgnored control_ignored "control frames (LOCKSTEP, STEP, END, STALL, TICK_STOP) ignored: a flight build has no test hooks",
        TcAccepted tc_accepted "telecommands accepted (authenticated, in sequence) and acted on",
        TcCorrupt tc_corrupt "telecommand frames rejected by the decoder (CRC-32C, malformed fields)",
        TcUnauthenticated tc_unauthenticated "telecommands refused: the MAC does not verify (wrong key, forged, no key provisioned)",
        TcReplayed tc_replayed "telecommands refused: the sequence number of the last accepted one (replayed)",
        TcOutOfSequence tc_out_of_sequence "telecommands refused: a sequence number below the last accepted one",
        TcRefused tc_refused "authenticated telecommands refused by the table upload (chunk, table, arm or fire not valid now)",
        TableActivations table_activations "calibration tables activated by command",
        TableRevision table_revision "the active calibration table's revision (saturating)",
        TableCrcLow table_crc_low "the active calibration table's CRC-32, low 16 bits",
        TableCrcHigh table_crc_high "the active calibration table's CRC-32, high 16 bits",
        MountIsolated mount_isolated "FOGs isolated by the mounting check: reversed polarity against the star tracker's rotation, or alone at odds with it",
        MountSwapped mount_swapped "pairs of FOGs found swapped in their mounts by the mounting check (flown on the corrected assignment)",
        SramEccCorrected sram_ecc_corrected "single-bit errors the board's SRAM ECC corrected (STM32H7 RAMECC)",
        SramEccUncorrected sram_ecc_uncorrected "double-bit errors the board's SRAM ECC detected and could not correct (STM32H7 RAMECC)",
    }
    paged [
        FdiAlarms,
        FdiTransients,
        FdiIsolations,
        StFrozen,
        StReacquired,
        StOutages,
        IoErrors,
        OutputDropped,
        FogSamplesStale,
        StFramesLate,
        StFramesEarly,
        ControlIgnored,
        TcAccepted,
        TcCorrupt,
        TcUnauthenticated,
        TcReplayed,
        TcOutOfSequence,
        TcRefused,
        TableActivations,
        TableRevision,
        TableCrcLow,
        TableCrcHigh,
        MountIsolated,
        MountSwapped,
        MountUnverified,
        MountUndecided,
    ]
    nav {
        AccelFramesRejected accel_frames_rejected "accelerometer frames rejected by the decoder (CRC, kind, field)",
        AccelStepsHeld accel_steps_held "navigation steps in which at least one accelerometer sample was missing or faulty (previous increment held)",
        GnssFramesRejected gnss_frames_rejected "GNSS frames rejected by the decoder",
        NavFaults nav_faults "navigation steps refused (state held)",
        TwinMismatches nav_twin_mismatches "navigation steps whose two computations disagreed (a third decided, or the step was refused)",
        StateRestored nav_state_restored "navigation state or covariance restored from its shadow (a bit flipped between steps)",
        GnssFixesSuperseded gnss_fixes_superseded "valid GNSS fixes replaced by a newer one before the filter work used them",
        OutputDropped output_dropped "navigation output frames that could not be written",
        IoErrors io_errors "navigation link driver errors (accelerometer and GNSS links)",
    }
});

impl Counters {
    /// Adds one to counter `c`, saturating.
    #[inline]
    pub fn bump(&mut self, c: Counter) {
        self.add(c, 1);
    }

    /// Adds `n` to FOG slot `i`'s counter `c`, saturating.
    #[inline]
    pub fn add_fog(&mut self, i: usize, c: FogCounter, n: u32) {
        if let Some(f) = self.fog.get_mut(i) {
            f.add(c, n);
        }
    }

    /// Adds one to FOG slot `i`'s counter `c`, saturating.
    #[inline]
    pub fn bump_fog(&mut self, i: usize, c: FogCounter) {
        self.add_fog(i, c, 1);
    }

    /// Counts the parity fault logic's change of state from `before` to `after` (one
    /// call of it): an alarm raised, an alarm cleared without isolation (a transient).
    /// An isolation is counted with its event, wherever it is decided (the core's one
    /// isolation routine, `Event::Isolated`).
    #[inline]
    pub fn count_fdi(&mut self, before: FdiState, after: FdiState) {
        match (before, after) {
            (FdiState::Watching, FdiState::Alarm) => self.bump(Counter::FdiAlarms),
            (FdiState::Alarm, FdiState::Watching) => self.bump(Counter::FdiTransients),
            _ => {}
        }
    }
}

/// The output frame's counter page: `page_id` → counter. Ids `0..FOG_PAGES` are per FOG
/// (FOG i's counter k at `PER_FOG`·i + k, k in [`FogCounter::ALL`] order); then
/// [`PAGED`] in order.
pub mod page {
    use super::{Counter, FogCounter, N_FOG, PAGED};

    /// Counters per FOG.
    pub const PER_FOG: u8 = FogCounter::ALL.len() as u8;
    /// Page ids of the per-FOG counters.
    pub const FOG_PAGES: u8 = PER_FOG * N_FOG as u8;
    /// Page ids in the cycle.
    pub const COUNT: u8 = FOG_PAGES + PAGED.len() as u8;

    /// What one page id carries.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub enum Entry {
        /// Counter of FOG slot `.0` (0-based).
        Fog(usize, FogCounter),
        /// A unit counter.
        Unit(Counter),
    }

    /// The counter page `id` carries (`None` past [`COUNT`]).
    #[inline]
    pub fn entry(id: u8) -> Option<Entry> {
        if id < FOG_PAGES {
            let c = FogCounter::ALL.get(usize::from(id % PER_FOG))?;
            return Some(Entry::Fog(usize::from(id / PER_FOG), *c));
        }
        PAGED.get(usize::from(id - FOG_PAGES)).map(|c| Entry::Unit(*c))
    }
}

/// Writes the counter page table of `docs/ICD.md` (markdown rows `| id | counter |`).
pub fn write_page_table(w: &mut impl core::fmt::Write) -> core::fmt::Result {
    writeln!(w, "| id | counter |")?;
    writeln!(w, "|---|---|")?;
    for (k, c) in FogCounter::ALL.iter().enumerate() {
        writeln!(w, "| {}·i + {} | {} |", page::PER_FOG, k, c.describe())?;
    }
    for (k, c) in PAGED.iter().enumerate() {
        writeln!(w, "| {} | {} |", usize::from(page::FOG_PAGES) + k, c.describe())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One alarm that clears, one that ends in an isolation: two alarms, one transient;
    /// an isolation is not counted here (it is counted with its event) and staying in a
    /// state counts nothing more.
    #[test]
    fn the_fault_logic_is_counted_by_its_changes_of_state() {
        use FdiState::{Alarm, Isolated, Watching};
        let mut c = Counters::default();
        for (before, after) in [
            (Watching, Watching),
            (Watching, Alarm),
            (Alarm, Alarm),
            (Alarm, Watching),
            (Watching, Alarm),
            (Alarm, Isolated(2)),
            (Isolated(2), Isolated(2)),
            (Watching, Isolated(0)),
        ] {
            c.count_fdi(before, after);
        }
        assert_eq!((c.fdi_alarms, c.fdi_transients, c.fdi_isolations), (2, 1, 0));
    }
}

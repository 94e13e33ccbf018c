//! The one list of the unit's events, each with the counter that counts it (if any):
//! [`crate::telemetry::events`] builds the [`crate::telemetry::events::Event`] enum from
//! it and [`crate::telemetry::counters`] the event counters, so neither module takes the
//! list from the other.

/// The one list of the unit's events: `code Variant "name" [Counter field "what it
/// counts"] "details",` per line. The bracket (optional) declares the counter that counts
/// the event: [`crate::telemetry::events::EventLog::record`] logs the event and counts it, so the two cannot part,
/// and the counter exists only here ([`crate::telemetry::counters`] takes it from this
/// list). `events_table!(callback { args })` calls `callback! { args events { list } }`.
macro_rules! events_table {
    ($cb:ident { $($args:tt)* }) => {
        $cb! {
            $($args)*
            events {
                1 Aligned "aligned" "the star tracker aligned the attitude and the mounting check clears it to report (a, b: 0)",
                2 Converged "converged" "the estimator converged (a, b: 0)",
                3 ConvergenceLost "convergence_lost" "the estimator no longer reports converged: restarted, or its error grew (a, b: 0)",
                4 ParityAlarm "parity_alarm" "the four-FOG parity check raised an alarm: a FOG is faulty, not yet isolated (a, b: 0)",
                5 AlarmCleared "alarm_cleared" "a parity alarm cleared without isolation: a transient (a, b: 0)",
                6 Isolated "isolated" [FdiIsolations fdi_isolations "FOGs isolated"] "a FOG was isolated: the unit flies on the other three (a: FOG channel, 1-based; b: the cause: 1 the parity check named it, 2 its own checks refused it during a parity alarm, 3 the star tracker named it during a parity alarm, 4 the mounting check found it reversed or alone at odds with the tracker)",
                7 TempSensorFailed "temp_sensor_failed" "a FOG's temperature sensor failed: its compensation holds the predicted temperature (a: FOG channel, 1-based; b: 0)",
                8 MountVerdict "mount_verdict" "the mounting check's verdict (a: 1 reversed, 2 swapped, 3 alone at odds with the tracker; b: the FOG channel, 1-based, and for a swap the second one times 16)",
                9 MountUnverified "mount_unverified" [MountUnverified mount_unverified "FOGs the mounting check could not verify in its first 10 s (no turn about their axes; watched on)"] "the mounting check could not verify some FOGs in its first 10 s and watches on (a: bit i for FOG channel i + 1; b: 0)",
                10 MountUndecided "mount_undecided" [MountUndecided mount_undecided "mounting checks that ended with FOGs at odds with the star tracker and no single flip or swap explaining them"] "the mounting check ended with FOGs at odds with the tracker and no single flip or swap explaining them (a, b: 0)",
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
                21 StateRestored "state_restored" [StateRestored state_restored "guarded state found changed between two steps (a bit flip) and restored from its good copy"] "guarded state changed between two steps (a bit flip) was restored (a: block, 1 attitude and sample clock, 2 drift and convergence, 3 estimator state a star-tracker frame changes, 4+i combiner without FOG i+1, 8 Λ or Δω inside a step, against its twin, 9 combiner and profile, 10 noise figures, acquisition gains and tracker mount; b: 0 from its good copy, 1 the copy took the flip, 2 neither: derived again, re-aligning)",
                22 StateImplausible "state_implausible" [StateImplausible state_implausible "guarded state found implausible (attitude norm, drift, covariance): the estimator re-aligned on the star tracker"] "guarded state was implausible (a: 1 attitude norm, 2 drift beyond 1000 °/h, 3 covariance): the estimator re-aligns on the next star-tracker frame (b: 0)",
                23 Realigned "realigned" [Realigned realigned "re-alignments on the star tracker after a persistent disagreement with the propagated attitude (or a state found corrupted)"] "the star tracker and the propagated attitude disagreed on consecutive frames that agree with each other: the attitude was re-aligned on the tracker, not converged until the estimate converges again (a: the disagreement in whole degrees, saturating; b: in arcsec, saturating at 65,535)",
                24 FogLost "fog_lost" [FogsLost fogs_lost "FOGs lost: no usable sample 40 in a row, not isolated (event fog_lost)"] "a FOG gave no usable sample for 40 in a row (200 ms; not isolated): the unit flies without it (a: FOG channel, 1-based; b: the health bits of its last sample, which say why: missing, device fault, out of range, stuck)",
                25 FogRestored "fog_restored" [FogsRestored fogs_restored "lost FOGs restored: usable samples again, 40 in a row (event fog_restored)"] "a lost FOG gave usable samples again, 40 in a row: flown again (a: FOG channel, 1-based; b: 0)",
                26 AlignmentLost "alignment_lost" [AlignmentsLost alignments_lost "losses of the aligned status (event alignment_lost names the cause)"] "the unit no longer reports aligned (a: the cause: 1 the estimator starts again (a mounting verdict, guarded state derived again), 2 the mounting check finds a FOG at odds with the tracker, 3 the mounting check's evidence starts again and has not yet spanned 2 s; b: 0)",
                41 TableRestored "table_restored" [TablesRestored tables_restored "calibration tables in RAM found corrupt by the background check and restored from the store"] "the background check found the calibration table in RAM differing from its CRC: restored from the two-copy store, combiner and gains rebuilt (a: 1 restored, 0 no good copy: flying on as it was, degraded; b: the restored table's revision, low 16 bits)",
                42 KeyRestored "key_restored" [KeysRestored keys_restored "command keys in RAM found corrupt by the background check and restored from the record"] "the background check found the command key in RAM differing from its protected record: restored from the record (a, b: 0)",
                43 Resumed "resumed" [Resumes resumes "resets resumed from the snapshot in RAM"] "the unit resumed after a reset from its snapshot in RAM: attitude, drift, time, alignment (a: 0; b: the snapshot's age in steps)",
                44 SnapshotInvalid "snapshot_invalid" [SnapshotsInvalid snapshots_invalid "snapshots not resumed after a reset (absent, corrupt, another table, implausible, too old)"] "after a reset the snapshot was not resumed: the unit aligns again on the star tracker (a: 1 absent, 2 CRC, 3 other table, 4 implausible, 5 too old; b: 0)",
                45 CodeCorrupt "code_corrupt" [CodeCorrupt code_corrupt "background checks of the code in flash that found its CRC changed"] "the background check of the code in flash found its CRC changed since boot (a: 0; b: 0); the unit resets (a reset reloads it)",
                46 SramEcc "sram_ecc" "the board's SRAM ECC reported errors since the last step (a: uncorrected, saturating at 255; b: corrected, saturating)",
                47 RegisterRestored "register_restored" "the board's check of its configuration registers (step tick, interrupt enables and priorities, UARTs, MPU, watchdog, interrupt masks) found some changed and restored them (a: registers restored, saturating; b: 0); a restore that does not hold resets the unit",
            }
        }
    };
}
pub(crate) use events_table;

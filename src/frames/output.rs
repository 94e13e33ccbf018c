//! Output frame (kind 0x30, 97 bytes): the unit's state after each step.
//!
//! | off | size | field | type | scaling |
//! |---|---|---|---|---|
//! | 0 | 2 | sync | `EB 90` | |
//! | 2 | 1 | kind | `0x30` | |
//! | 3 | 1 | flags | u8 | [`flags`] bits; bit 7 sent as zero |
//! | 4 | 2 | counter | u16 | output frame counter, wraps |
//! | 6 | 8 | time_tag | u64 | µs of unit time at the end of the step |
//! | 14 | 16 | q0..q3 | 4 × i32 | ICS in 2ECS, scalar first, LSB 2^-31 |
//! | 30 | 12 | rate x,y,z | 3 × i32 | ICS angular rate, LSB 2^-30 rad/s |
//! | 42 | 12 | drift x,y,z | 3 × i32 | drift estimate, LSB 2^-40 rad/s |
//! | 54 | 4 | parity | i32 | parity residual, LSB 2^-36 rad |
//! | 58 | 4 | fog_health | 4 × u8 | per-FOG health bits |
//! | 62 | 1 | st_status | u8 | star-tracker status bits |
//! | 63 | 14 | counters | 7 × u16 | see [`OutputCounters`] |
//! | 77 | 1 | fdi | u8 | bits 0–3: FOG i flies on a held temperature (sensor failed); bits 4–7: FOG i isolated by the fault logic |
//! | 78 | 1 | page_id | u8 | which counter `page_value` carries (`crate::telemetry::page`); cycles through all, one a frame |
//! | 79 | 2 | page_value | u16 | that counter, saturating |
//! | 81 | 6 | att_sigma x,y,z | 3 × u16 | the estimator's attitude-error 1σ, LSB 0.01″; 65535: unknown or larger |
//! | 87 | 6 | drift_sigma x,y,z | 3 × u16 | its drift-error 1σ, LSB 1e-4 °/h; 65535: unknown or larger |
//! | 93 | 4 | crc | u32 | CRC-32C over bytes 0..93 |
//!
//! The decoder checks only the envelope: every field value is accepted.

use super::{counts_i32, counts_u16, kind, DecodeError, FieldReader, FieldWriter, Frame};

/// Length of an output frame in bytes: 3 (header) + 1 + 2 + 8 + 16 + 12 + 12 + 4 + 4 +
/// 1 + 14 + 1 + 1 + 2 + 6 + 6 + 4 (CRC).
pub const FRAME_LEN: usize = 97;
const _: () = assert!(FRAME_LEN == 3 + 1 + 2 + 8 + 16 + 12 + 12 + 4 + 4 + 1 + 14 + 1 + 1 + 2 + 6 + 6 + 4);

/// FOG slots in the frame (FOG1..FOG4).
pub const FOG_SLOTS: usize = 4;

/// Counters in the frame.
pub const N_COUNTERS: usize = 7;

/// LSB of a quaternion component: 2^-31.
pub const Q_LSB: f64 = 1.0 / 2_147_483_648.0;
/// LSB of the angular rate: 2^-30 rad/s (range ±2 rad/s).
pub const RATE_LSB_RAD_S: f64 = 1.0 / 1_073_741_824.0;
/// LSB of the drift estimate: 2^-40 rad/s (range ±2^-9 rad/s, about ±403 °/h).
pub const DRIFT_LSB_RAD_S: f64 = 1.0 / 1_099_511_627_776.0;
/// LSB of the parity residual: 2^-36 rad.
pub const PARITY_LSB_RAD: f64 = 1.0 / 68_719_476_736.0;
/// LSB of the attitude-error 1σ: 0.01″ in rad (range 0 … 655.34″).
pub const ATT_SIGMA_LSB_RAD: f64 = 0.01 * core::f64::consts::PI / 180.0 / 3600.0;
/// LSB of the drift-error 1σ: 1e-4 °/h in rad/s (range 0 … 6.5534 °/h).
pub const DRIFT_SIGMA_LSB_RAD_S: f64 = 1e-4 * core::f64::consts::PI / 180.0 / 3600.0;
/// A 1σ field's count for "unknown (not aligned) or beyond the range".
pub const SIGMA_UNKNOWN: u16 = u16::MAX;

/// Bits of the output flags byte.
pub mod flags {
    /// Star tracker fitted and in use.
    pub const ST_IN_USE: u8 = 1 << 0;
    /// Degraded: fewer than the fitted FOGs (four on the spacecraft unit) combined.
    pub const DEGRADED: u8 = 1 << 1;
    /// Observer converged.
    pub const CONVERGED: u8 = 1 << 2;
    /// Flying on the default calibration table.
    pub const TABLE_DEFAULTED: u8 = 1 << 3;
    /// The output frame of the previous step was dropped.
    pub const OUTPUT_DROPPED: u8 = 1 << 4;
    /// The power-on built-in test ([`crate::bit::power_on`]) failed.
    pub const BIT_FAILED: u8 = 1 << 5;
    /// Parity alarm: a FOG is faulty and not yet isolated (the output is degraded).
    pub const FDI_ALARM: u8 = 1 << 6;
    /// Two FOGs were found swapped in their mounts at power-on: the unit flies on the
    /// corrected assignment.
    pub const FOGS_REMAPPED: u8 = 1 << 7;
}

/// The counters at the end of the output frame, in frame order (saturating u16 each).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct OutputCounters {
    /// FOG frames rejected by the decoders (all FOGs).
    pub fog_frames_rejected: u16,
    /// FOG samples that did not arrive in time (all FOGs).
    pub fog_samples_missing: u16,
    /// Star-tracker frames that updated the observer.
    pub st_frames_accepted: u16,
    /// Star-tracker frames rejected.
    pub st_frames_rejected: u16,
    /// Star-tracker updates refused by the observer's gate.
    pub st_updates_gated: u16,
    /// Steps that overran their deadline.
    pub overruns: u16,
    /// Time the previous step took, board ticks.
    pub step_ticks: u16,
}

impl OutputCounters {
    /// From the counters in frame order.
    pub const fn from_array(c: [u16; N_COUNTERS]) -> Self {
        let [fog_frames_rejected, fog_samples_missing, st_frames_accepted, st_frames_rejected, st_updates_gated, overruns, step_ticks] =
            c;
        OutputCounters {
            fog_frames_rejected,
            fog_samples_missing,
            st_frames_accepted,
            st_frames_rejected,
            st_updates_gated,
            overruns,
            step_ticks,
        }
    }

    /// The counters in frame order.
    pub const fn to_array(&self) -> [u16; N_COUNTERS] {
        [
            self.fog_frames_rejected,
            self.fog_samples_missing,
            self.st_frames_accepted,
            self.st_frames_rejected,
            self.st_updates_gated,
            self.overruns,
            self.step_ticks,
        ]
    }
}

impl From<[u16; N_COUNTERS]> for OutputCounters {
    fn from(c: [u16; N_COUNTERS]) -> Self {
        OutputCounters::from_array(c)
    }
}

/// One output frame (raw counts).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub struct OutputFrame {
    /// Flag bits ([`flags`]).
    pub flags: u8,
    /// Output frame counter (wraps).
    pub counter: u16,
    /// Unit time at the end of the step, µs.
    pub time_us: u64,
    /// Λ, the ICS in 2ECS, scalar first, counts of [`Q_LSB`].
    pub q_counts: [i32; 4],
    /// Angular rate of the ICS (drift removed), counts of [`RATE_LSB_RAD_S`].
    pub rate_counts: [i32; 3],
    /// Drift (bias) estimate, counts of [`DRIFT_LSB_RAD_S`].
    pub drift_counts: [i32; 3],
    /// Parity residual, counts of [`PARITY_LSB_RAD`].
    pub parity_counts: i32,
    /// Health bits per FOG slot (`docs/ICD.md`).
    pub fog_health: [u8; FOG_SLOTS],
    /// Star-tracker status bits (`docs/ICD.md`).
    pub st_status: u8,
    /// Counters.
    pub counters: OutputCounters,
    /// Fault-logic bits: FOG i on a held temperature (bit i), FOG i isolated (bit 4 + i).
    pub fdi: u8,
    /// Which counter `page_value` carries ([`crate::telemetry::page`]).
    pub page_id: u8,
    /// The paged counter.
    pub page_value: u16,
    /// The estimator's attitude-error 1σ per ICS axis, counts of [`ATT_SIGMA_LSB_RAD`]
    /// ([`SIGMA_UNKNOWN`]: unknown or beyond the range).
    pub att_sigma_counts: [u16; 3],
    /// The estimator's drift-error 1σ per ICS axis, counts of [`DRIFT_SIGMA_LSB_RAD_S`].
    pub drift_sigma_counts: [u16; 3],
}

impl OutputFrame {
    /// Frame length in bytes (same as [`Frame::LEN`]).
    pub const LEN: usize = FRAME_LEN;

    /// A frame from physical values: every scaled value is rounded to the nearest count
    /// and saturated to the field's range; NaN gives 0. Bit fields and counters are
    /// taken as they are (`counters` in frame order, e.g. a `[u16; 7]`); the fault-logic
    /// byte and the counter page start at zero (set the fields).
    #[allow(clippy::too_many_arguments)]
    pub fn from_physical(
        flags: u8,
        counter: u16,
        time_us: u64,
        q: [f64; 4],
        rate_rad_s: [f64; 3],
        drift_rad_s: [f64; 3],
        parity_rad: f64,
        fog_health: [u8; FOG_SLOTS],
        st_status: u8,
        counters: impl Into<OutputCounters>,
    ) -> Self {
        OutputFrame {
            flags,
            counter,
            time_us,
            q_counts: q.map(|c| counts_i32(c, Q_LSB)),
            rate_counts: rate_rad_s.map(|c| counts_i32(c, RATE_LSB_RAD_S)),
            drift_counts: drift_rad_s.map(|c| counts_i32(c, DRIFT_LSB_RAD_S)),
            parity_counts: counts_i32(parity_rad, PARITY_LSB_RAD),
            fog_health,
            st_status,
            counters: counters.into(),
            fdi: 0,
            page_id: 0,
            page_value: 0,
            att_sigma_counts: [SIGMA_UNKNOWN; 3],
            drift_sigma_counts: [SIGMA_UNKNOWN; 3],
        }
    }

    /// Sets the 1σ fields from the estimator's figures (rad, rad/s; rounded, saturated:
    /// an infinite σ, unknown, gives [`SIGMA_UNKNOWN`]).
    pub fn set_sigmas(&mut self, att_rad: [f64; 3], drift_rad_s: [f64; 3]) {
        self.att_sigma_counts = att_rad.map(|s| counts_u16(s, ATT_SIGMA_LSB_RAD));
        self.drift_sigma_counts = drift_rad_s.map(|s| counts_u16(s, DRIFT_SIGMA_LSB_RAD_S));
    }

    /// The attitude-error 1σ per axis, rad (infinite where [`SIGMA_UNKNOWN`]).
    pub fn att_sigma_rad(&self) -> [f64; 3] {
        self.att_sigma_counts.map(|c| sigma_of(c, ATT_SIGMA_LSB_RAD))
    }

    /// The drift-error 1σ per axis, rad/s (infinite where [`SIGMA_UNKNOWN`]).
    pub fn drift_sigma_rad_s(&self) -> [f64; 3] {
        self.drift_sigma_counts.map(|c| sigma_of(c, DRIFT_SIGMA_LSB_RAD_S))
    }

    /// Λ, scalar first (as sent, not renormalised).
    pub fn quaternion(&self) -> [f64; 4] {
        self.q_counts.map(|c| f64::from(c) * Q_LSB)
    }

    /// Angular rate of the ICS, rad/s.
    pub fn rate_rad_s(&self) -> [f64; 3] {
        self.rate_counts.map(|c| f64::from(c) * RATE_LSB_RAD_S)
    }

    /// Drift estimate, rad/s.
    pub fn drift_rad_s(&self) -> [f64; 3] {
        self.drift_counts.map(|c| f64::from(c) * DRIFT_LSB_RAD_S)
    }

    /// Parity residual, rad.
    pub fn parity_rad(&self) -> f64 {
        f64::from(self.parity_counts) * PARITY_LSB_RAD
    }

    /// Whether flag bit(s) `mask` ([`flags`]) are all set.
    pub fn flag(&self, mask: u8) -> bool {
        self.flags & mask == mask
    }

    /// The frame's bytes.
    pub fn to_bytes(&self) -> [u8; Self::LEN] {
        let mut out = [0u8; Self::LEN];
        // Cannot fail: `out` is exactly one frame long.
        let _ = self.encode_into(&mut out);
        out
    }
}

impl Frame for OutputFrame {
    const KIND: u8 = kind::OUTPUT;
    const LEN: usize = FRAME_LEN;

    // Inlined into the frame's one encoder, where its length is a constant.
    #[inline(always)]
    fn write_fields(&self, w: &mut FieldWriter<'_>) {
        w.u8(self.flags);
        w.u16(self.counter);
        w.u64(self.time_us);
        for c in self.q_counts {
            w.i32(c);
        }
        for c in self.rate_counts {
            w.i32(c);
        }
        for c in self.drift_counts {
            w.i32(c);
        }
        w.i32(self.parity_counts);
        w.bytes(self.fog_health);
        w.u8(self.st_status);
        for c in self.counters.to_array() {
            w.u16(c);
        }
        w.u8(self.fdi);
        w.u8(self.page_id);
        w.u16(self.page_value);
        for c in self.att_sigma_counts {
            w.u16(c);
        }
        for c in self.drift_sigma_counts {
            w.u16(c);
        }
    }

    fn read_fields(r: &mut FieldReader<'_>) -> Result<Self, DecodeError> {
        // Fields are read in the order written, which is the frame's order.
        Ok(OutputFrame {
            flags: r.u8()?,
            counter: r.u16()?,
            time_us: r.u64()?,
            q_counts: [r.i32()?, r.i32()?, r.i32()?, r.i32()?],
            rate_counts: [r.i32()?, r.i32()?, r.i32()?],
            drift_counts: [r.i32()?, r.i32()?, r.i32()?],
            parity_counts: r.i32()?,
            fog_health: r.bytes::<FOG_SLOTS>()?,
            st_status: r.u8()?,
            counters: OutputCounters::from_array([
                r.u16()?,
                r.u16()?,
                r.u16()?,
                r.u16()?,
                r.u16()?,
                r.u16()?,
                r.u16()?,
            ]),
            fdi: r.u8()?,
            page_id: r.u8()?,
            page_value: r.u16()?,
            att_sigma_counts: [r.u16()?, r.u16()?, r.u16()?],
            drift_sigma_counts: [r.u16()?, r.u16()?, r.u16()?],
        })
    }
}

/// A 1σ count in physical units: infinite for [`SIGMA_UNKNOWN`].
fn sigma_of(count: u16, lsb: f64) -> f64 {
    if count == SIGMA_UNKNOWN {
        f64::INFINITY
    } else {
        f64::from(count) * lsb
    }
}

//! Integrity: what the unit does about sensors that fail or lie.
//!
//! Before compensation every FOG sample passes the per-channel checks ([`channel`]); between combination and attitude the four-FOG parity residual is
//! watched for a fault that the channel checks cannot see ([`parity`]), which is then
//! isolated with the star tracker's help and the failed gyro dropped from the
//! combination. The star tracker's own gate (χ², outage, re-acquisition) is part of
//! the observer ([`crate::observer`]).
//!
//! | concern | module | in → out |
//! |---|---|---|
//! | stuck output, temperature sensor | [`channel`] | raw FOG frame → usable or not, temperature reading trusted or not |
//! | parity FDI | [`parity`] | compensated increments, parity residual, star-tracker mismatch → alarm, isolated FOG |

pub mod channel;
pub mod parity;

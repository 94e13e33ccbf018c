//! Integrity: what the unit does about sensors that fail or lie.
//!
//! Before compensation every FOG sample passes the per-channel checks ([`channel`]); between combination and attitude the four-FOG parity residual is
//! watched for a fault that the channel checks cannot see ([`parity`]), which is then
//! isolated with the star tracker's help and the failed gyro dropped from the
//! combination. From power-on, each FOG's increments are compared with the rotation the
//! star tracker sees, for a FOG mounted backwards or two FOGs swapped ([`mounting`]). The star tracker's own gate (χ², outage, re-acquisition) is part of
//! the observer ([`crate::observer`]).
//!
//! | concern | module | in → out |
//! |---|---|---|
//! | stuck output, temperature sensor | [`channel`] | raw FOG frame → usable or not, temperature reading trusted or not |
//! | parity FDI | [`parity`] | compensated increments, parity residual, star-tracker mismatch → alarm, isolated FOG |
//! | mounting, from power-on | [`mounting`] | compensated increments, star-tracker attitudes → flipped FOG, swapped pair |

pub mod channel;
pub mod mounting;
pub mod parity;

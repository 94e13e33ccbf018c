//! Intake: what arrived on the input links, put in the order the step uses it.
//!
//! | link | module | in → out |
//! |---|---|---|
//! | FOGs (per FOG or one bus) | [`fog`] | bytes → one frame per FOG for the sample due, or missing; sample clock |
//! | star tracker | [`star`] | bytes → frames due at the unit's time; frozen frames; outage |

pub mod fog;
pub mod star;

pub use fog::{Arrival, FogIntake, FogLinks, FOG_QUEUE, MAX_RX_BYTES_PER_STEP, MAX_WAIT_STEPS};
pub use star::{Pending, StarIntake, ST_MAX_LEAD_US, ST_OUTAGE_US, ST_PENDING};

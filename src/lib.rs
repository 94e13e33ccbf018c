//! # ssis — flight core of a strapdown stellar-inertial attitude unit
//!
//! After Zlatkin et al., *The development of a high-precision strapdown inertial system
//! based on medium-accuracy fiber-optic gyroscopes* (Hartron-Arkos). `no_std`, no heap,
//! no panics: every fallible path returns a typed error and is counted.
//!
//! The modules follow the data through one fixed step ([`flight::FlightCore::step`]):
//!
//! | stage | module | in → out |
//! |---|---|---|
//! | links, frames | [`link`], [`frames`] | RS-422 bytes → [`frames::fog::FogFrame`], [`frames::star::StarFrame`] |
//! | intake | [`intake`] | frames → the FOG sample due (per FOG: frame or missing), star-tracker frames due; outage |
//! | integrity, per channel | [`integrity::channel`] | FOG frame → stuck or not, temperature reading trusted or not |
//! | compensation | [`compensation`] | raw angle increment, T, G → compensated increment per FOG |
//! | integrity, parity | [`integrity::parity`] | compensated increments → spike dropped, faulty FOG isolated |
//! | combination | [`combination`] | 4 (or any 3) skewed axes → body increment + parity residual |
//! | attitude | [`attitude`] | body increment → quaternion Λ (2ECS ← ICS), coning-corrected |
//! | observer | [`observer`] | star-tracker Λ* → corrected Λ, drift estimate Δω (eq. 6) |
//! | telemetry | [`telemetry`] | status bits, counters → output frame ([`frames::output`]) |
//!
//! The calibration table ([`calib`]) parameterises compensation, combination and the
//! observer; it is the one definition shared with the simulator and the model lab.
//! Conventions (frames, quaternion product, units) are in `docs/CONVENTIONS.md`.
//! [`bit`] is the unit's built-in test (known answers at power-on, a replay digest). It
//! stays in the core, portable: the same code gives the digest on the host and on the
//! target (`ssis-selftest` in `firmware/`), so equal digests compare the core, not two
//! copies of a test.
//! [`nav`] is the launch-vehicle unit's strapdown navigation (ECEF, WGS-84 with J2).
//! [`telecommand`] is the command link: authenticated telecommands, the in-flight table
//! update.
//! [`bsp`] is the board seam: the [`bsp::Board`] trait and the boot policy every board
//! shares. The board code itself (Cortex-M7, QEMU `mps2-an500`, STM32H7) and the
//! firmware binaries are crates of their own (`firmware/`, `boards/`): this crate is
//! portable, safe code, and `cargo test` at the root runs its unit tests on the host.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing, clippy::panic))]

pub mod attitude;
pub mod bit;
pub mod bsp;
pub mod calib;
pub mod combination;
pub mod compensation;
pub mod flight;
pub mod frames;
pub mod intake;
pub mod integrity;
pub mod link;
pub mod math;
pub mod nav;
pub mod observer;
pub mod shadow;
pub mod state;
pub mod state_map;
pub mod telecommand;
pub mod telemetry;

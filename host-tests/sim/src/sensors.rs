//! The spacecraft unit's sensors in one run: the four FOGs ([`crate::fog`]) and the star
//! tracker ([`crate::star`]) drawing on one random stream, seeded once, in the order the
//! harness draws them (the FOGs' errors at power-on; then each step the FOG sample, then
//! the star tracker's frame). The harness's [`crate::harness::Simulation`] and the Python
//! package's Basilisk module (`ssis.basilisk`, through `ssis._ssis.Sensors`) both fly
//! these, so the same seed and truth give the same frames on either path.

use nalgebra::Quaternion;
use rand::SeedableRng;
use rand_chacha::ChaCha20Rng;

use crate::fog::{FogModel, FogSample, FogSpec};
use crate::star::{StarModel, StarSpec};
use crate::truth::TruthStep;

/// The FOGs and the star tracker of a run, on one random stream.
pub struct Sensors {
    /// The FOGs (their true errors: `fogs.truth`).
    pub fogs: FogModel,
    star: StarModel,
    rng: ChaCha20Rng,
}

/// What the sensors send in one step.
#[derive(Debug, Clone)]
pub struct SensorStep {
    /// The four FOGs' sample.
    pub fog: FogSample,
    /// The star tracker's bytes delivered in this step (whole frames, maybe none).
    pub st_bytes: Vec<u8>,
}

impl Sensors {
    /// Draws the FOGs' errors of `fog` from the stream of `seed`; the star tracker then
    /// comes from `star_for`, given the FOGs' true table (a scenario's unit table may be
    /// that table, and the tracker's mount is the unit table's).
    pub fn new<E>(
        fog: &FogSpec,
        seed: u64,
        star_for: impl FnOnce(&FogModel) -> Result<StarModel, E>,
    ) -> Result<Self, E> {
        let mut rng = ChaCha20Rng::seed_from_u64(seed);
        let fogs = FogModel::new(fog, &mut rng);
        let star = star_for(&fogs)?;
        Ok(Sensors { fogs, star, rng })
    }

    /// For a unit flying its table's true errors (`fog.errors`): the star tracker of `star`
    /// on the table's mount `st_mount`, steps of `dt_us`.
    pub fn with_star(fog: &FogSpec, star: &StarSpec, dt_us: u32, st_mount: Quaternion<f64>, seed: u64) -> Self {
        let ok: Result<Self, std::convert::Infallible> =
            Sensors::new(fog, seed, |_| Ok(StarModel::new(star, dt_us, st_mount)));
        match ok {
            Ok(s) => s,
            Err(e) => match e {},
        }
    }

    /// Step `n` (from 1) of `dt_s`, ending at `now_us` on the unit's clock: the truth
    /// `ts` of the interval (its body increment; Λ and body rate at its end, `ts.t_s` on
    /// the truth's clock).
    pub fn step(&mut self, n: u64, now_us: u64, dt_s: f64, ts: &TruthStep) -> SensorStep {
        let fog = self.fogs.sample(&ts.dtheta_rad, ts.t_s, dt_s, &mut self.rng);
        let st_bytes = self.star.step(n, now_us, &ts.q, &ts.rate_rad_s, &mut self.rng);
        SensorStep { fog, st_bytes }
    }
}

//! Passes over a session: every row turned into a small basis vector per FOG and summed
//! into per-block Gram matrices, so a fit never holds the rows.
//!
//! Every model term is linear in its coefficients and every regressor is a linear function
//! of a few per-row quantities, the **basis** z of FOG i ([`Basis`], [`Q`]): 1; ω_ref (x, y,
//! z), rad/s; |r_i| and r_i² with r_i = s_i⁰·ω_ref; (t − t₀)/3600; ΔT, ΔT², ΔT³, G, ΔT·G
//! (ΔT = T_i − T_ref, G = dT_i/dt); B_x, B_y, B_z, nT; sin and cos 2πft per sinusoid; the
//! value of each expression or user column; and last y_i = ω_i,raw − r_i. A pass carries only
//! the quantities its terms use. The scale factor is then s_i⁰ on the ω slots, a
//! misalignment angle ∂s_i/∂δ there, the magnetic term u_i or v_i on the field slots
//! ([`Basis::functionals`]). The pass sums z zᵀ per FOG and
//! per time block ([`Digest`]): m × m numbers per block, whatever the number of rows. Any
//! fit, residual sum of squares or correlation over any union of blocks follows from those
//! sums (`super::fit`). For conditioning, z is summed shifted by its value on the first row
//! (slot 0 stays 1): the shift is a change of basis the functionals undo exactly
//! ([`Digest::shifted`]).
//!
//! G = dT/dt needs the samples up to half a window ahead ([`temperature_rate`]):
//! the pass holds that many rows back, never more. A systematic sample of at most `keep`
//! rows (every row when the session is that short) is kept with its basis vectors for what
//! needs rows: plots, the spectral search, the T × G analysis of variance.
//!
//! One file per job: `basis.rs` (the basis and its functionals), `lookahead.rs` (G over a
//! stream), `gram.rs` (the inner sums), `digest.rs` (the pass), `extremes.rs` (the provable
//! largest residual), `units.rs` (the unit check), `blocks.rs` (blocks, sums and bins).

mod basis;
mod blocks;
mod digest;
mod extremes;
mod gram;
mod lookahead;
mod units;

pub use basis::*;
pub use blocks::*;
pub use digest::*;
pub use extremes::*;
use gram::*;
pub use lookahead::*;
use units::*;

use std::path::Path;

use exmex::Express;
use indicatif::ProgressBar;

use super::lsq::{design_gram, lstsq_gram, residual_functional, Gram};
use super::model::{loop_plane, misalignment_partials, Catalog, Kind};
use super::session::{
    median_interval_s, nominal_axes, write_record, Converter, Header, RowReader, SampleRef, Session, Shape,
};
use super::{LabError, LabResult, ModelErrorKind};

/// Rows kept by default for plots, the spectral search and the ANOVA.
pub const DEFAULT_KEEP: usize = 40_000;

/// Where a pass reads its samples.
#[derive(Debug, Clone, Copy)]
pub enum Source<'a> {
    /// A session file, streamed.
    File(&'a Path),
    /// A session in memory.
    Memory(&'a Session),
}

impl Source<'_> {
    /// The session's header alone (a file's first lines: no pre-pass over its rows).
    pub fn header(&self) -> LabResult<Header> {
        match self {
            Source::File(p) => Ok(RowReader::open(p)?.header().clone()),
            Source::Memory(s) => Ok(Header::parse(&s.file, s.names.clone(), 1)?),
        }
    }

    /// The session's header, size and sample interval (a quick look at a file).
    pub fn shape(&self) -> LabResult<Shape> {
        match self {
            Source::File(p) => Ok(super::session::shape(p)?),
            Source::Memory(s) => {
                let header = Header::parse(&s.file, s.names.clone(), 1)?;
                let t = s.t_s();
                Ok(Shape {
                    header,
                    samples: t.len(),
                    t_span_s: [t[0], t[t.len() - 1]],
                    dt_s: median_interval_s(t),
                    bytes: 0,
                })
            }
        }
    }

    /// Calls `f` with the record of every sample in order ([`SampleRef`]), until it
    /// returns `false`.
    fn for_each(&self, progress: Option<&ProgressBar>, mut f: impl FnMut(&[f64]) -> LabResult<bool>) -> LabResult<()> {
        let mut rec = Vec::new();
        match self {
            Source::File(p) => {
                let mut rr = RowReader::open(p)?;
                let mut conv = Converter::new(&rr.header().layout);
                let mut rows = 0u64;
                while let Some(row) = rr.next_row()? {
                    if conv.convert(row, &mut rec) && !f(&rec)? {
                        break;
                    }
                    rows += 1;
                    if let Some(pb) = progress.filter(|_| rows.is_multiple_of(65_536)) {
                        pb.set_position(rr.bytes());
                    }
                }
            }
            Source::Memory(s) => {
                let t = s.t_s();
                for j in 0..s.len() {
                    write_record(
                        &mut rec,
                        t[j],
                        s.fogs.iter().map(|fog| fog.rate_rad_s[j]),
                        s.fogs.iter().map(|fog| fog.t_degc.as_ref().map_or(f64::NAN, |c| c[j])),
                        s.ref_rad_s[j],
                        s.field_nt.as_ref().map_or([0.0; 3], |b| b[j]),
                        s.cols.iter().map(|c| c[j]),
                    );
                    if !f(&rec)? {
                        break;
                    }
                }
            }
        }
        Ok(())
    }
}

//! The model lab: compare the FOG error model with ground-test sessions, find the
//! physical effect it lacks, add it, and watch the held-out error fall.
//!
//! Capabilities (one file per concern):
//! - [`session`]: the session reader (the `ssis-session` crate, shared with the calibration
//!   methods and the fuzzer): a session CSV (`docs/SESSION-FORMAT.md`) streamed line by line
//!   with an in-place number parser; a bad file is refused with its file, line and column.
//! - [`stream`]: one pass over a session: a small basis vector per row and FOG, summed into
//!   per-block Gram matrices (memory independent of the number of rows), G = dT/dt over a
//!   bounded look-ahead, a systematic sample of rows kept for plots.
//! - [`framelog`]: the firmware's own logs as sessions: a raw capture of the output link
//!   (output frames, bad frames counted) and the per-step CSV of `ssis-qemu`.
//! - [`import`]: a logger's own CSV (its column names and units) mapped onto a session.
//! - [`model`]: the error model as data, a versioned TOML file (`ssis-error-model/1`) with a
//!   list of effect terms (the catalog: bias, scale factor, asymmetry, nonlinearity,
//!   misalignment, thermal polynomial, temperature rate G, ΔT·G, magnetic (the paper's
//!   eqs. 1–3), aging; plus sinusoids and user expressions over session columns).
//! - [`lsq`]: the least-squares algebra on sums: Gram matrices, a design's normal
//!   equations, their Cholesky solution with rank-deficient regressors dropped.
//! - [`fit`]: a model fitted to a session from the pass's sums (which regressors were
//!   dropped, reported), held-out time blocks.
//! - [`noise`]: the residual's noise model (white + a bank of Gauss–Markov processes, fitted
//!   by Whittle's likelihood), the GLS sums and the held-out improvement's interval under it.
//! - [`diagnose`]: candidate terms tested by nested-model F-tests on held-out blocks,
//!   Benjamini–Hochberg FDR control, the paper's two-factor ANOVA (T × G, Tables 1–2).
//! - [`plot`]: residual plots (SVG) and the history of model versions.
//! - [`export`]: the calibration table the firmware loads, from the onboard terms.
//! - [`simulate`]: a session generator with known effects, for tests and demos.
//! - [`report`]: one self-contained HTML page of a session's loop.
//! - [`json`]: the `--json` form of the summaries (docs/JSON.md).
//! - [`replay`]: a session turned into FOG frames and replayed through the flight core
//!   (`FlightCore::step`) with a calibration table: the round trip from the lab to flight.

pub mod detectable;
pub mod diagnose;
pub mod export;
pub mod fit;
pub mod framelog;
pub mod import;
pub mod json;
pub mod lsq;
pub mod model;
pub mod noise;
pub mod plot;
pub mod replay;
pub mod report;
pub mod simulate;
pub mod spectral;
pub mod stream;

pub use ssis_session as session;

/// Errors of the lab library. Each names the file (and line, column) where it can.
#[derive(Debug, thiserror::Error)]
pub enum LabError {
    /// A session file that cannot be read or is malformed.
    #[error(transparent)]
    Session(#[from] session::SessionError),
    /// A model file that is malformed, or a term the session cannot feed ([`ModelError`]).
    #[error(transparent)]
    Model(ModelError),
    /// A file that cannot be written, or may not be (`ssis_common::output`); the message
    /// names it.
    #[error("{0}")]
    Write(String),
    /// An argument the lab cannot use (an import mapping, a reference given twice).
    #[error("{0}")]
    Usage(String),
    /// Anything the numerics refuse (too few samples, nothing to fit).
    #[error("{0}")]
    Numeric(String),
}

/// What is wrong with a model file or one of its terms.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ModelErrorKind {
    /// The model file cannot be read.
    Io,
    /// Not the model's TOML form: its syntax, a key, the `format` line.
    Syntax,
    /// A term the lab does not know, or one listed twice or already in the model.
    Term,
    /// An expression that does not parse, or does not evaluate on a row.
    Expression,
    /// A term the session cannot feed (a column it lacks).
    Unfed,
    /// A value out of its range (the G window, the version, a coefficient), or a model the
    /// calibration table cannot take.
    Value,
}

/// A refused model or term: its kind, and the words (naming the file where there is one).
#[derive(Debug, Clone, thiserror::Error)]
#[error("{message}")]
pub struct ModelError {
    /// What is wrong.
    pub kind: ModelErrorKind,
    /// Plain words.
    pub message: String,
}

impl LabError {
    /// A [`LabError::Model`] of `kind`.
    pub fn model(kind: ModelErrorKind, message: impl Into<String>) -> LabError {
        LabError::Model(ModelError { kind, message: message.into() })
    }
}

/// Result of the lab library.
pub type LabResult<T> = Result<T, LabError>;

/// Writes `bytes` to `path` through a temporary file and a rename (never a half file),
/// under the output rules of `ssis_common::output`.
pub fn write_atomic(path: &std::path::Path, bytes: &[u8]) -> LabResult<()> {
    ssis_common::table::write_atomic(path, bytes).map_err(|e| LabError::Write(format!("{e:#}")))
}

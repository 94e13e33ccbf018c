//! Session files: CSV with a header naming each column and its unit (`docs/SESSION-FORMAT.md`).
//!
//! [`RowReader`] streams the file line by line, through a memory map of a regular file or a
//! fixed buffer for anything else (never read whole into memory), and parses each number in
//! place ([`parse_number`]: correctly rounded, so every value is the one `str::parse::<f64>`
//! gives). [`Converter`] turns a row into a sample's flat record, read through
//! [`SampleRef`] (rates from increments, the reference rate from the turntable geometry). The model lab's passes over a
//! session (`ssis_lab::stream`) read it this way; [`read_session`] keeps it in memory as `f64` columns
//! for the tools that want every row (replay, tests). Every refusal names the file, the line
//! and, where there is one, the column (1-based, with its header name).
//!
//! One file per job: `columns.rs` (names, roles, ranges, refusals), `header.rs`, `number.rs`
//! (the parser), `reader.rs` (the streaming reader), `record.rs` (a sample's record),
//! `memory.rs` (a session in memory), `earth.rs` (the Earth's rate and field at the site).

mod columns;
mod earth;
mod header;
mod memory;
mod number;
mod reader;
mod record;

pub use columns::*;
pub use earth::*;
pub use header::*;
pub use memory::*;
pub use number::*;
pub use reader::*;
pub use record::*;

use std::io::Read;
use std::path::Path;

use indicatif::ProgressBar;
use ssis::calib::{Misalignment, GAMMA_NOMINAL_RAD};

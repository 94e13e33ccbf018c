//! A spacecraft CSV log replayed while it is read (`ssis-sim replay`, `ssis.replay`), in
//! memory bounded whatever the log's length (`docs/RECORDED-LOG.md`, "Long logs").
//!
//! The conventions check (`crate::conventions`) needs the FOGs' motion between star-tracker
//! solutions, so it runs first, on the log's first [`CHECK_SPAN_S`] held in memory (a
//! shorter log whole: the very report of a log read whole); a log's conventions are how it
//! was written, the same at every row. Those steps are then replayed, and the rest of the
//! log follows as [`LogStream`] reads it, in three stages on threads of their own a few
//! batches apart: reading the log, stepping the unit (`FlightCore::step`), reading what
//! it sent. Nothing else grows with the log but the counts.

use anyhow::Result;
use ssis::calib::CalibrationTable;
use ssis::flight::Profile;
use ssis::frames::output::OutputFrame;

use crate::accuracy::Record;
use crate::conventions::{check_conventions, ConventionReport};
use crate::recorded::{LogStep, LogStream, Problems, Recorded};
use crate::replay::{LogInfo, OutputSide, ReplaySummary, Replayer, Sent, UnitSide};

/// The span at a log's start that the conventions check reads, s (the unit's steps held
/// in memory meanwhile: 120,000 at 5 ms).
pub const CHECK_SPAN_S: f64 = 600.0;

/// Steps handed from one stage of a replay to the next at a time.
const BATCH_STEPS: usize = 1024;
/// Batches in flight between two stages (the memory the overlap costs: a few MB).
const BATCHES_IN_FLIGHT: usize = 4;

/// Up to [`BATCH_STEPS`] of the next steps of `stream` (fewer at its end).
fn read_batch(stream: &mut LogStream) -> Result<Vec<LogStep>> {
    let mut batch = Vec::with_capacity(BATCH_STEPS);
    while batch.len() < BATCH_STEPS {
        match stream.next_step()? {
            Some(s) => batch.push(s),
            None => break,
        }
    }
    Ok(batch)
}

/// A batch of steps the unit took: the steps, the bytes it sent and where each step's are.
struct Stepped {
    steps: Vec<LogStep>,
    bytes: Vec<u8>,
    sent: Vec<Sent>,
}

/// The steps `head` then the rest of `stream` (`Err`: the log ended within the head, the
/// stream given back as it is) replayed in three stages on threads of their own, a batch
/// of steps at a time, up to [`BATCHES_IN_FLIGHT`] batches between two stages: one reads
/// the log (parsing the CSV), one steps the unit (`unit`), and this one reads what the
/// unit sent (`output`, `on_frame`). Returns the stream at its end (its counts), or the
/// error that stopped it.
fn replay_beside(
    head: Vec<LogStep>,
    stream: Result<LogStream, LogStream>,
    unit: &mut UnitSide,
    output: &mut OutputSide,
    on_frame: &mut impl FnMut(&OutputFrame, Option<&Record>),
) -> Result<LogStream> {
    std::thread::scope(|scope| {
        let (to_unit, unit_rx) = std::sync::mpsc::sync_channel::<Vec<LogStep>>(BATCHES_IN_FLIGHT);
        let (to_output, output_rx) = std::sync::mpsc::sync_channel::<Stepped>(BATCHES_IN_FLIGHT);
        let reader = scope.spawn(move || -> Result<LogStream> {
            let mut head = head.into_iter().peekable();
            while head.peek().is_some() {
                if to_unit.send(head.by_ref().take(BATCH_STEPS).collect()).is_err() {
                    break;
                }
            }
            let mut stream = match stream {
                Ok(s) => s,
                Err(s) => return Ok(s),
            };
            loop {
                let batch = read_batch(&mut stream)?;
                let last = batch.len() < BATCH_STEPS;
                if !batch.is_empty() && to_unit.send(batch).is_err() || last {
                    return Ok(stream);
                }
            }
        });
        scope.spawn(move || {
            for steps in unit_rx {
                let mut bytes = Vec::with_capacity(steps.len() * 160);
                let sent = steps.iter().map(|s| unit.step(s, &mut bytes)).collect();
                if to_output.send(Stepped { steps, bytes, sent }).is_err() {
                    return;
                }
            }
        });
        for b in output_rx {
            for (step, sent) in b.steps.iter().zip(&b.sent) {
                output.take(step, sent, &b.bytes, on_frame);
            }
        }
        reader.join().map_err(|_| anyhow::anyhow!("the log's reading thread panicked"))?
    })
}

/// What a streamed replay found.
#[derive(Debug, Clone)]
pub struct Streamed {
    /// The replay.
    pub summary: ReplaySummary,
    /// The conventions check (on the first [`CHECK_SPAN_S`] of a longer log).
    pub conventions: ConventionReport,
    /// What was counted of the log.
    pub info: LogInfo,
    /// The star tracker's latency as logged (median), s.
    pub st_latency_s: f64,
}

/// A log's first [`CHECK_SPAN_S`] (a shorter log whole), held in memory, and its
/// conventions checked on it.
pub struct Head {
    /// The steps read, as a log read whole (its counts are the head's only).
    pub rec: Recorded,
    /// The step after the head (`None`: the log ended within it).
    pub next: Option<LogStep>,
    /// The conventions check on the head (`span_s` set when the log goes on).
    pub conventions: ConventionReport,
}

/// Reads the head of the log `stream` reads and checks its conventions against `table`
/// (`ssis-sim replay`, `ssis-qemu --replay`).
pub fn read_head(stream: &mut LogStream, table: &CalibrationTable) -> Result<Head> {
    let profile = Profile::SPACECRAFT;
    let span_steps = (CHECK_SPAN_S / profile.dt_s()).round() as usize;
    let mut head = Vec::with_capacity(span_steps.min(1 << 16));
    while head.len() < span_steps {
        match stream.next_step()? {
            Some(s) => head.push(s),
            None => break,
        }
    }
    let next = if head.len() == span_steps { stream.next_step()? } else { None };
    let rec = Recorded {
        origin: stream.origin().to_string(),
        steps: head,
        fogs: stream.fogs(),
        t0_s: stream.t0_s().unwrap_or(0.0),
        problems: Problems::default(),
        has_truth: stream.has_truth,
        unit: stream.unit,
        init: None,
    };
    let mut conventions = check_conventions(&rec, table, profile.dt_us)?;
    if next.is_some() {
        conventions.span_s = Some(CHECK_SPAN_S);
    }
    Ok(Head { rec, next, conventions })
}

impl LogInfo {
    /// What `stream` counted of the log it read.
    pub fn of_stream(stream: &LogStream) -> LogInfo {
        LogInfo {
            fog_samples: stream.fog_samples,
            fogs: stream.fogs(),
            st_count: stream.st_count,
            has_truth: stream.has_truth,
            problems: stream.problems.clone(),
        }
    }
}

/// The conventions of the log `stream` reads, checked on its first [`CHECK_SPAN_S`]
/// against `table`: the report, given to `on_conventions` before any step, and the
/// replay of the whole log through `FlightCore::step` (statistics from `settle_s`;
/// `on_frame` sees every output frame and its record against truth).
pub fn replay_stream(
    mut stream: LogStream,
    table: &CalibrationTable,
    settle_s: f64,
    on_conventions: impl FnOnce(&ConventionReport),
    mut on_frame: impl FnMut(&OutputFrame, Option<&Record>),
) -> Result<Streamed> {
    let Head { rec, next, conventions } = read_head(&mut stream, table)?;
    on_conventions(&conventions);
    let mut r = Replayer::new(table, settle_s)?;
    let more = next.is_some();
    let mut head = rec.steps;
    head.extend(next);
    let stream = if more { Ok(stream) } else { Err(stream) };
    let stream = replay_beside(head, stream, &mut r.unit, &mut r.output, &mut on_frame)?;
    Ok(Streamed {
        summary: r.finish(stream.origin().to_string()),
        conventions,
        info: LogInfo::of_stream(&stream),
        st_latency_s: stream.st_latency_s(),
    })
}

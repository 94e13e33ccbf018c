//! The unit's output link as the ground reads it: a stream of several frame kinds (output
//! frames, event frames, command reports), and the unit's events as a timeline.
//!
//! [`Downlink`] runs one stream decoder per kind over the same bytes; a byte is bad only
//! if no decoder accepted a frame containing it ([`Downlink::bad_bytes`]), so the frames
//! of one kind are not counted as garbage by the decoder of another.

use ssis::frames::decoder::StreamDecoder;
use ssis::frames::event::EventFrame;
use ssis::frames::output::OutputFrame;
use ssis::frames::telecommand::CommandReport;
use ssis::telemetry::events::{Event, EventRecord};
use ssis::telemetry::health;

use crate::cli::{json, Value};

/// One frame of the output link.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Down {
    /// A step's output frame.
    Output(OutputFrame),
    /// Records of the event log.
    Events(EventFrame),
    /// A command report.
    Report(CommandReport),
}

/// Decoder of the output link: every frame kind the unit sends on it.
#[derive(Default)]
pub struct Downlink {
    output: StreamDecoder<OutputFrame, 256>,
    events: StreamDecoder<EventFrame, 128>,
    reports: StreamDecoder<CommandReport, 64>,
    pushed: u64,
}

impl Downlink {
    /// A decoder that has seen nothing.
    pub fn new() -> Downlink {
        Downlink::default()
    }

    /// Decodes a chunk of the link, calling `on_frame` with every frame in it (the output
    /// frames of the chunk first, then its event frames, then its command reports).
    pub fn push(&mut self, bytes: &[u8], mut on_frame: impl FnMut(Down)) {
        self.pushed += bytes.len() as u64;
        self.output.push_slice(bytes, |r| {
            if let Ok(f) = r {
                on_frame(Down::Output(f));
            }
        });
        self.events.push_slice(bytes, |r| {
            if let Ok(f) = r {
                on_frame(Down::Events(f));
            }
        });
        self.reports.push_slice(bytes, |r| {
            if let Ok(f) = r {
                on_frame(Down::Report(f));
            }
        });
    }

    /// Bytes in no accepted frame of any kind (less those a decoder still holds as the
    /// start of a frame).
    pub fn bad_bytes(&self) -> u64 {
        let ok = |n: u32, len: usize| u64::from(n) * len as u64;
        let accepted = ok(self.output.stats().frames_ok, OutputFrame::LEN)
            + ok(self.events.stats().frames_ok, EventFrame::LEN)
            + ok(self.reports.stats().frames_ok, CommandReport::LEN);
        let held = self.output.buffered().max(self.events.buffered()).max(self.reports.buffered()) as u64;
        self.pushed.saturating_sub(accepted + held)
    }
}

/// The details of `r` in words (empty when the event has none).
pub fn details(r: &EventRecord) -> String {
    let fogs = |bits: u8| {
        let v: Vec<String> = (0..4).filter(|i| bits & (1 << i) != 0).map(|i| format!("FOG{}", i + 1)).collect();
        v.join(" ")
    };
    match r.event {
        Event::TempSensorFailed | Event::FogRestored => format!("FOG{}", r.a),
        Event::Isolated => {
            let why = match r.b {
                1 => "by the parity check",
                2 => "refused by its own checks during a parity alarm",
                3 => "named by the star tracker during a parity alarm",
                4 => "by the mounting check",
                _ => "",
            };
            format!("FOG{} {why}", r.a)
        }
        Event::FogLost => {
            let h = r.b as u8;
            let why: Vec<&str> = [
                (health::MISSING, "missing"),
                (health::DEVICE_FAULT, "device fault"),
                (health::OUT_OF_RANGE, "out of range"),
                (health::STUCK, "stuck"),
                (health::REJECTED, "frames rejected"),
            ]
            .iter()
            .filter(|(bit, _)| h & bit != 0)
            .map(|(_, w)| *w)
            .collect();
            format!("FOG{}: {}", r.a, why.join(", "))
        }
        Event::AlignmentLost => match r.a {
            1 => "the estimator starts again".to_string(),
            2 => "a FOG at odds with the star tracker (mounting check)".to_string(),
            3 => "the mounting check's evidence starts again".to_string(),
            k => format!("cause {k}"),
        },
        Event::MountVerdict => match r.a {
            1 => format!("FOG{} reversed", r.b & 0xF),
            2 => format!("FOG{} and FOG{} swapped", r.b & 0xF, r.b >> 4),
            3 => format!("FOG{} alone at odds with the star tracker", r.b & 0xF),
            k => format!("verdict {k}, FOGs {:#x}", r.b),
        },
        Event::MountUnverified => format!("not verified: {}", fogs(r.a)),
        Event::FogsRemapped => {
            let v: Vec<String> = (0..4).map(|k| format!("FOG{}→axis {}", k + 1, ((r.a >> (2 * k)) & 3) + 1)).collect();
            v.join(", ")
        }
        Event::CommandAccepted => format!("command {:#04x}, sequence …{}", r.a, r.b),
        Event::CommandRefused => format!("command {:#04x}, refusal code {}", r.a, r.b),
        Event::TableSwitched => format!("revision {}", r.b),
        _ => String::new(),
    }
}

/// The events as a timeline: one line each, `time  event  details`, time in s of unit time.
pub fn timeline(events: &[EventRecord], lost: u16) -> String {
    let mut s = format!("events ({}):\n", events.len());
    if events.is_empty() {
        s.push_str("  none\n");
    }
    for r in events {
        let line = format!("  {:>10.3} s  {:<20} {}", r.time_us as f64 * 1e-6, r.event.name(), details(r));
        s.push_str(line.trim_end());
        s.push('\n');
    }
    if lost > 0 {
        s.push_str(&format!("  ({lost} events lost: the unit's log was full)\n"));
    }
    s
}

/// The events as `--json` values (docs/JSON.md, `events`).
pub fn events_json(events: &[EventRecord]) -> Value {
    Value::Array(
        events
            .iter()
            .map(|r| {
                json!({
                    "time_s": r.time_us as f64 * 1e-6,
                    "seq": r.seq,
                    "event": r.event.name(),
                    "a": r.a,
                    "b": r.b,
                    "details": details(r),
                })
            })
            .collect(),
    )
}

/// The records of `frames` in order, and the largest loss count they report.
pub fn records(frames: &[EventFrame]) -> (Vec<EventRecord>, u16) {
    let lost = frames.iter().map(|f| f.lost).max().unwrap_or(0);
    (frames.iter().flat_map(|f| f.iter().copied()).collect(), lost)
}

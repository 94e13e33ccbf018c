//! The command link: telecommands from the ground ([`Telecommand`], `docs/ICD.md`),
//! decoded, authenticated and acted on between two steps.
//!
//! Every byte that arrives on the output link's receive line goes to
//! [`CommandLink::receive`] (the control frames of a test build share the line; each
//! decoder passes over the other's frames). A telecommand is, in order:
//!
//! 1. decoded: sync, kind, CRC-32C, fields; a frame that fails is counted
//!    ([`Counter::TcCorrupt`]) and never looked at again;
//! 2. authenticated ([`auth::Authenticator`]): the truncated HMAC-SHA-256 under the key
//!    in protected flash, then the sequence number; refused and counted as
//!    unauthenticated, replayed or out of sequence;
//! 3. acted on: the table upload ([`upload`]) or a command report; a command the upload
//!    cannot take now is refused and counted ([`Counter::TcRefused`]).
//!
//! Nothing that is refused changes anything but the counters (an accepted but refused
//! command uses up its sequence number). The work is bounded: one HMAC a complete
//! frame, one CRC a candidate, and at the end of an upload one table decode and one
//! flash write of a record.

pub mod auth;
pub mod upload;

use crate::calib::store::CalibFlash;
use crate::flight::FlightCore;
use crate::frames::decoder::StreamDecoder;
use crate::frames::telecommand::{command, CommandReport, Telecommand};
use crate::frames::DecodeError;
use crate::telemetry::events::Event;
use crate::telemetry::Counter;

pub use auth::{AuthError, Authenticator, Key};
pub use upload::{Upload, UploadError};

/// Why a decoded telecommand was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Refusal {
    /// Not authenticated, replayed or out of sequence.
    Auth(AuthError),
    /// Authenticated, but the upload cannot take it now.
    Upload(UploadError),
}

impl Refusal {
    /// The code in the command report's `last_refusal` (0 is none): 1 unauthenticated,
    /// 2 replayed, 3 out of sequence, 4… the [`UploadError`] codes.
    pub fn code(self) -> u8 {
        match self {
            Refusal::Auth(AuthError::Unauthenticated) => 1,
            Refusal::Auth(AuthError::Replayed) => 2,
            Refusal::Auth(AuthError::OutOfSequence) => 3,
            Refusal::Upload(e) => e as u8,
        }
    }

    /// The counter it is counted in.
    pub fn counter(self) -> Counter {
        match self {
            Refusal::Auth(AuthError::Unauthenticated) => Counter::TcUnauthenticated,
            Refusal::Auth(AuthError::Replayed) => Counter::TcReplayed,
            Refusal::Auth(AuthError::OutOfSequence) => Counter::TcOutOfSequence,
            Refusal::Upload(_) => Counter::TcRefused,
        }
    }
}

/// What one decoded telecommand came to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Accepted and acted on; `activated`: it switched the flying table.
    Accepted {
        /// The table was switched.
        activated: bool,
    },
    /// Refused.
    Refused(Refusal),
}

/// The command link of one unit.
#[derive(Clone)]
pub struct CommandLink {
    decoder: StreamDecoder<Telecommand, 128>,
    auth: Authenticator,
    upload: Upload,
    report: Option<CommandReport>,
    last_refusal: u8,
    accepted: u16,
    refused: u16,
}

impl CommandLink {
    /// A link whose key is the record in `key_record` (the KEY region).
    pub fn new(key_record: &[u8]) -> Self {
        CommandLink {
            decoder: StreamDecoder::new(),
            auth: Authenticator::new(key_record),
            upload: Upload::default(),
            report: None,
            last_refusal: 0,
            accepted: 0,
            refused: 0,
        }
    }

    /// The provisioned key's id (0: none).
    pub fn key_id(&self) -> u16 {
        self.auth.key_id()
    }

    /// The background check of the key in RAM against its record in the KEY region
    /// ([`Authenticator::check_key`]); true when it was restored.
    pub fn check_key(&mut self, key_record: &[u8]) -> bool {
        self.auth.check_key(key_record)
    }

    /// The authenticator (the key and the last sequence number).
    pub fn authenticator(&self) -> &Authenticator {
        &self.auth
    }

    /// Takes the bytes that arrived on the command line: every telecommand completed by
    /// them is checked and acted on (`core` switched, `flash` written, counters counted
    /// in `core`), calling `on_command` with each outcome.
    ///
    /// Never inlined: the main loop calls it only when bytes arrived, and kept out of the
    /// loop's body it leaves the inlined step's code as it was without a command link.
    #[inline(never)]
    pub fn receive<F: CalibFlash + ?Sized>(
        &mut self,
        bytes: &[u8],
        core: &mut FlightCore,
        flash: &mut F,
        mut on_command: impl FnMut(Outcome),
    ) {
        let mut frames = heapless::Vec::<Telecommand, 4>::new();
        // The bytes go in runs of one frame's length, each completing at most a few
        // frames, which are acted on after the run (the decoder is not borrowed then).
        let mut rest = bytes;
        // Frames rejected as corrupt (CRC, fields; a wrong kind byte is not a command).
        let mut corrupt = 0u32;
        // Bounded: every pass takes at least one byte.
        while !rest.is_empty() {
            let (now, later) = rest.split_at(rest.len().min(Telecommand::LEN));
            self.decoder.push_slice(now, |r| match r {
                Ok(tc) => {
                    let _ = frames.push(tc);
                }
                Err(DecodeError::BadKind) => {}
                Err(DecodeError::BadCrc | DecodeError::BadField | DecodeError::BadSync | DecodeError::BadLength) => {
                    corrupt = corrupt.saturating_add(1);
                }
            });
            rest = later;
            for tc in frames.iter() {
                let outcome = self.handle(tc, core, flash);
                on_command(outcome);
            }
            frames.clear();
        }
        for _ in 0..corrupt.min(64) {
            core.note(Counter::TcCorrupt);
        }
    }

    /// A command report asked for by STATUS, once.
    pub fn take_report(&mut self) -> Option<CommandReport> {
        self.report.take()
    }

    /// One decoded telecommand: authenticated, then acted on.
    pub fn handle<F: CalibFlash + ?Sized>(
        &mut self,
        tc: &Telecommand,
        core: &mut FlightCore,
        flash: &mut F,
    ) -> Outcome {
        let outcome = match self.act(tc, core, flash) {
            Ok(activated) => Outcome::Accepted { activated },
            Err(r) => Outcome::Refused(r),
        };
        match outcome {
            Outcome::Accepted { activated } => {
                self.accepted = self.accepted.saturating_add(1);
                core.note(Counter::TcAccepted);
                core.log_event(Event::CommandAccepted, tc.command, tc.seq as u16);
                if activated {
                    core.note(Counter::TableActivations);
                }
            }
            Outcome::Refused(r) => {
                self.refused = self.refused.saturating_add(1);
                self.last_refusal = r.code();
                core.note(r.counter());
                core.log_event(Event::CommandRefused, tc.command, u16::from(r.code()));
            }
        }
        if tc.command == command::STATUS && matches!(outcome, Outcome::Accepted { .. }) {
            self.report = Some(self.report(core));
        }
        outcome
    }

    fn act<F: CalibFlash + ?Sized>(
        &mut self,
        tc: &Telecommand,
        core: &mut FlightCore,
        flash: &mut F,
    ) -> Result<bool, Refusal> {
        self.auth.check(tc).map_err(Refusal::Auth)?;
        if tc.command != command::TABLE_FIRE {
            self.upload.disarm();
        }
        let up = match tc.command {
            command::TABLE_CHUNK => self.upload.chunk(tc, core, flash),
            command::TABLE_ARM => self.upload.arm(tc.table_crc),
            command::TABLE_FIRE => {
                return self.upload.fire(tc.table_crc, core, flash).map(|()| true).map_err(Refusal::Upload)
            }
            _ => Ok(()),
        };
        up.map(|()| false).map_err(Refusal::Upload)
    }

    /// The command report as of now.
    fn report(&self, core: &FlightCore) -> CommandReport {
        let (upload, chunks, staged_crc) = self.upload.report();
        CommandReport {
            upload,
            last_seq: self.auth.last_seq(),
            chunks,
            last_refusal: self.last_refusal,
            staged_crc,
            table_revision: core.table().revision,
            table_crc: core.table_crc(),
            key_id: self.auth.key_id(),
            accepted: self.accepted,
            refused: self.refused,
        }
    }
}

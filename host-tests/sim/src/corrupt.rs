//! Frame corruption trials: valid frames are corrupted (bit flips, byte
//! substitutions, truncations, insertions) and streamed through the flight
//! [`StreamDecoder`] between intact frames; every accepted frame is checked against the
//! frames actually sent.
//!
//! One trial, for one frame type `F` (every kind of the ICD in turn, [`FRAME_TYPES`]): the
//! stream `before · corrupted · after1 · after2` of random valid frames, where
//! `corrupted` is a random valid frame damaged by one [`Corruption`] (always changing it:
//! flipped bits are distinct, a substituted byte differs, insertions are strictly inside
//! the frame, a truncation keeps 0..LEN−1 bytes), goes through a fresh decoder. Then:
//! - an accepted frame whose bytes are none of the frames sent (`before`, `after1` or
//!   `after2` at their own positions, or the undamaged `corrupted`) is a **corrupted frame
//!   accepted** (only possible through a CRC-32C collision plus fields that pass their
//!   checks); the undamaged frame accepted is counted as **recovered** (the damage only
//!   moved a boundary, e.g. a truncated last byte equal to the next frame's first);
//! - `after1` not decoded is a **frame lost to resynchronisation**; `after2` not decoded
//!   means the decoder was not back in sync within one frame.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use ssis::frames::accel::AccelFrame;
use ssis::frames::control::ControlFrame;
use ssis::frames::decoder::StreamDecoder;
use ssis::frames::fog::FogFrame;
use ssis::frames::gnss::GnssFrame;
use ssis::frames::navout::NavOutputFrame;
use ssis::frames::output::OutputFrame;
use ssis::frames::star::StarFrame;
use ssis::frames::telecommand::CommandReport;
use ssis::frames::Frame;

/// How a frame is damaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Corruption {
    /// 1 to 5 distinct bits flipped (the CRC-32C detects every such error at every frame
    /// length of the ICD: Hamming distance 6, 8 for the 18-byte frames).
    FewBits,
    /// 6 to 16 distinct bits flipped anywhere in the frame.
    ManyBits,
    /// One burst of up to 32 bits (the CRC-32C detects every burst of length ≤ 32).
    Burst,
    /// 1 to 4 bytes replaced by different random values.
    Substitution,
    /// The frame cut to 0..LEN−1 bytes (the next frame follows at once).
    Truncation,
    /// 1 to 4 random bytes inserted strictly inside the frame.
    Insertion,
}

impl Corruption {
    /// All kinds, in the order trials cycle through them.
    pub const ALL: [Corruption; 6] = [
        Corruption::FewBits,
        Corruption::ManyBits,
        Corruption::Burst,
        Corruption::Substitution,
        Corruption::Truncation,
        Corruption::Insertion,
    ];

    /// Whether the CRC-32C alone guarantees detection of this kind inside one frame.
    pub fn guaranteed_by_crc(self) -> bool {
        matches!(self, Corruption::FewBits | Corruption::Burst)
    }
}

/// Counts for one (frame type, corruption) cell.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Cell {
    /// Trials run.
    pub trials: u64,
    /// Accepted frames that were not sent as they were (corrupted frames accepted).
    pub corrupted_accepted: u64,
    /// Trials where the frame after the corrupted one was not decoded.
    pub next_lost: u64,
    /// Trials where the second frame after it was not decoded (not back in sync within
    /// one frame).
    pub second_lost: u64,
    /// Trials where an intact frame (before, after1, after2) was lost while no corrupted
    /// frame was accepted (the decoder's guarantee says never).
    pub lost_without_collision: u64,
    /// Trials where the damaged frame was still accepted as sent (the damage only moved
    /// a boundary: its bytes in the stream were the frame's bytes, e.g. a truncated last
    /// byte equal to the next frame's first byte; the next frame then lost that byte).
    pub recovered: u64,
}

impl Cell {
    fn add(&mut self, o: &Cell) {
        self.trials += o.trials;
        self.corrupted_accepted += o.corrupted_accepted;
        self.next_lost += o.next_lost;
        self.second_lost += o.second_lost;
        self.lost_without_collision += o.lost_without_collision;
        self.recovered += o.recovered;
    }
}

/// Frame types in the order trials cycle through them.
pub const FRAME_TYPES: [&str; N_TYPES] =
    ["fog", "accel", "star", "gnss", "output", "nav output", "control", "command report"];

/// Number of frame types.
pub const N_TYPES: usize = 8;

/// The whole result: `cells[frame type][corruption]`.
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Per frame type (see [`FRAME_TYPES`]) and corruption ([`Corruption::ALL`]).
    pub cells: [[Cell; 6]; N_TYPES],
}

impl Report {
    /// Sum over every cell.
    pub fn total(&self) -> Cell {
        let mut t = Cell::default();
        self.cells.iter().flatten().for_each(|c| t.add(c));
        t
    }

    /// Sum over frame types for one corruption kind.
    pub fn by_kind(&self, k: usize) -> Cell {
        let mut t = Cell::default();
        self.cells.iter().for_each(|row| t.add(&row[k]));
        t
    }

    /// A Markdown table of the counts.
    pub fn table(&self) -> String {
        let mut s = String::from(
            "| frame | corruption | trials | corrupted accepted | next frame lost | second frame lost | sent frame recovered |\n|---|---|---|---|---|---|---|\n",
        );
        for (f, row) in FRAME_TYPES.iter().zip(&self.cells) {
            for (k, c) in Corruption::ALL.iter().zip(row) {
                s += &format!(
                    "| {f} | {k:?} | {} | {} | {} | {} | {} |\n",
                    c.trials, c.corrupted_accepted, c.next_lost, c.second_lost, c.recovered
                );
            }
        }
        let t = self.total();
        s += &format!(
            "| all | all | {} | {} | {} | {} | {} |\n",
            t.trials, t.corrupted_accepted, t.next_lost, t.second_lost, t.recovered
        );
        s
    }
}

fn encode<F: Frame>(f: &F) -> Vec<u8> {
    let mut v = vec![0u8; F::LEN];
    let n = f.encode_into(&mut v).unwrap_or(0);
    v.truncate(n);
    v
}

fn unit_q(rng: &mut ChaCha8Rng) -> [f64; 4] {
    let mut q = [0.0; 4];
    for c in &mut q {
        *c = rng.random_range(-1.0..1.0);
    }
    let n = q.iter().map(|c| c * c).sum::<f64>().sqrt().max(1e-9);
    q.map(|c| c / n)
}

/// One random frame of type `t` ([`FRAME_TYPES`]), as bytes; the decoders may refuse it.
fn random_frame(rng: &mut ChaCha8Rng, t: usize) -> (Vec<u8>, bool) {
    fn enc<F: Frame>(f: &F) -> (Vec<u8>, bool) {
        let b = encode(f);
        let ok = F::decode(&b).is_ok();
        (b, ok)
    }
    let r3 = |rng: &mut ChaCha8Rng, s: f64| [0; 3].map(|_: i32| rng.random_range(-s..s));
    let q = |rng: &mut ChaCha8Rng| unit_q(rng).map(|c| (c * 2_147_483_647.0) as i32);
    match t {
        0 => enc(&FogFrame::from_physical(
            rng.random_range(0..4),
            rng.random(),
            0,
            rng.random_range(-1e-3..1e-3),
            rng.random_range(-40.0..80.0),
        )),
        1 => enc(&AccelFrame::from_physical(
            rng.random_range(0..3),
            rng.random(),
            0,
            rng.random_range(-0.1..0.1),
            rng.random_range(-40.0..80.0),
        )),
        2 => enc(&StarFrame::from_physical(rng.random_range(0..2), rng.random(), rng.random(), unit_q(rng))),
        3 => enc(&GnssFrame {
            status: rng.random_range(0..8),
            counter: rng.random(),
            satellites: rng.random(),
            time_tag_us: rng.random(),
            r_counts: rng.random(),
            v_counts: rng.random(),
            sigma_pos_counts: rng.random(),
            sigma_vel_counts: rng.random(),
        }),
        4 => enc(&OutputFrame::from_physical(
            0,
            rng.random(),
            rng.random(),
            unit_q(rng),
            r3(rng, 0.01),
            r3(rng, 1e-5),
            rng.random_range(-1e-5..1e-5),
            [0; 4],
            0,
            [0u16; 7].map(|_| rng.random()),
        )),
        5 => enc(&NavOutputFrame {
            flags: rng.random_range(0..16),
            counter: rng.random(),
            time_tag_us: rng.random(),
            q_counts: q(rng),
            v_counts: rng.random(),
            r_counts: rng.random(),
            sigma_pos_counts: rng.random(),
            sigma_vel_counts: rng.random(),
            fixes_used: rng.random(),
            fixes_refused: rng.random(),
        }),
        6 => enc(&ControlFrame {
            command: rng.random_range(1..=4),
            fog_bytes: rng.random(),
            st_bytes: rng.random(),
            arg: 0,
        }),
        _ => enc(&CommandReport {
            upload: rng.random_range(0..4),
            last_seq: rng.random(),
            chunks: rng.random(),
            last_refusal: rng.random_range(0..12),
            staged_crc: rng.random(),
            table_revision: rng.random(),
            table_crc: rng.random(),
            key_id: rng.random(),
            accepted: rng.random(),
            refused: rng.random(),
        }),
    }
}

/// A pool of `n` random frames of every type that the decoders accept (their bytes).
fn pools(rng: &mut ChaCha8Rng, n: usize) -> [Vec<Vec<u8>>; N_TYPES] {
    let mut out: [Vec<Vec<u8>>; N_TYPES] = Default::default();
    for (t, p) in out.iter_mut().enumerate() {
        while p.len() < n {
            let (bytes, ok) = random_frame(rng, t);
            if ok {
                p.push(bytes);
            }
        }
    }
    out
}

/// `frame` damaged by `kind` (never equal to `frame`).
pub fn corrupt(rng: &mut ChaCha8Rng, frame: &[u8], kind: Corruption) -> Vec<u8> {
    let mut v = frame.to_vec();
    let bits = v.len() * 8;
    let flip_distinct = |rng: &mut ChaCha8Rng, v: &mut Vec<u8>, n: usize| {
        let mut chosen: Vec<usize> = Vec::with_capacity(n);
        while chosen.len() < n {
            let b = rng.random_range(0..bits);
            if !chosen.contains(&b) {
                chosen.push(b);
                v[b / 8] ^= 1 << (b % 8);
            }
        }
    };
    match kind {
        Corruption::FewBits => {
            let n = rng.random_range(1..=5);
            flip_distinct(rng, &mut v, n);
        }
        Corruption::ManyBits => {
            let n = rng.random_range(6..=16);
            flip_distinct(rng, &mut v, n);
        }
        Corruption::Burst => {
            // A burst of length L: first and last bit flipped, the ones between random.
            let len = rng.random_range(1..=32usize);
            let start = rng.random_range(0..=bits - len);
            for (k, b) in (start..start + len).enumerate() {
                if k == 0 || k + 1 == len || rng.random::<bool>() {
                    v[b / 8] ^= 1 << (b % 8);
                }
            }
        }
        Corruption::Substitution => {
            let n = rng.random_range(1..=4usize);
            let mut chosen: Vec<usize> = Vec::with_capacity(n);
            while chosen.len() < n {
                let i = rng.random_range(0..v.len());
                if !chosen.contains(&i) {
                    chosen.push(i);
                    v[i] ^= rng.random_range(1..=255u8);
                }
            }
        }
        Corruption::Truncation => {
            let keep = rng.random_range(0..v.len());
            v.truncate(keep);
        }
        Corruption::Insertion => {
            let n = rng.random_range(1..=4);
            for _ in 0..n {
                let at = rng.random_range(1..v.len());
                v.insert(at, rng.random());
            }
        }
    }
    v
}

/// One trial of frame type `F` (pool `pool`): the counts it adds.
fn trial<F: Frame>(rng: &mut ChaCha8Rng, pool: &[Vec<u8>], kind: Corruption) -> Cell {
    let pick = |rng: &mut ChaCha8Rng| &pool[rng.random_range(0..pool.len())];
    let (before, target, after1, after2) = (pick(rng), pick(rng), pick(rng), pick(rng));
    let damaged = corrupt(rng, target, kind);
    let mut stream = Vec::with_capacity(before.len() + damaged.len() + after1.len() + after2.len());
    stream.extend_from_slice(before);
    stream.extend_from_slice(&damaged);
    let end_before = before.len() - 1;
    stream.extend_from_slice(after1);
    let end_after1 = stream.len() - 1;
    stream.extend_from_slice(after2);
    let end_after2 = stream.len() - 1;
    let mut dec: StreamDecoder<F, 128> = StreamDecoder::new();
    let (mut got_before, mut got1, mut got2, mut recovered, mut bad) = (false, false, false, false, 0u64);
    for (i, &b) in stream.iter().enumerate() {
        if let Some(Ok(f)) = dec.push(b) {
            let bytes = encode(&f);
            let genuine = |end: usize, sent: &[u8]| i == end && bytes == sent;
            if genuine(end_before, before) {
                got_before = true;
            } else if genuine(end_after1, after1) {
                got1 = true;
            } else if genuine(end_after2, after2) {
                got2 = true;
            } else if bytes == *target {
                // The damage only moved a frame boundary (a truncated last byte equal to
                // the next frame's first, an inserted byte equal to its neighbour): the
                // frame accepted is the one that was sent.
                recovered = true;
            } else {
                bad += 1;
            }
        }
    }
    let lost = !got_before || !got1 || !got2;
    Cell {
        trials: 1,
        corrupted_accepted: bad,
        next_lost: u64::from(!got1),
        second_lost: u64::from(!got2),
        lost_without_collision: u64::from(lost && bad == 0 && !recovered),
        recovered: u64::from(recovered),
    }
}

/// Runs `n` trials with seed `seed`, cycling through frame types and corruption kinds.
pub fn run_trials(n: u64, seed: u64) -> Report {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let pools = pools(&mut rng, 256);
    let mut r = Report::default();
    let n_types = N_TYPES as u64;
    for t in 0..n {
        let f = (t % n_types) as usize;
        let k = ((t / n_types) % 6) as usize;
        let kind = Corruption::ALL[k];
        let pool = &pools[f];
        let c = match f {
            0 => trial::<FogFrame>(&mut rng, pool, kind),
            1 => trial::<AccelFrame>(&mut rng, pool, kind),
            2 => trial::<StarFrame>(&mut rng, pool, kind),
            3 => trial::<GnssFrame>(&mut rng, pool, kind),
            4 => trial::<OutputFrame>(&mut rng, pool, kind),
            5 => trial::<NavOutputFrame>(&mut rng, pool, kind),
            6 => trial::<ControlFrame>(&mut rng, pool, kind),
            _ => trial::<CommandReport>(&mut rng, pool, kind),
        };
        r.cells[f][k].add(&c);
    }
    r
}

/// [`run_trials`] split over `threads` threads (seeds `seed`, `seed + 1`, ...), summed.
pub fn run_trials_parallel(n: u64, seed: u64, threads: u64) -> Report {
    let threads = threads.max(1);
    let parts: Vec<Report> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..threads)
            .map(|k| {
                let share = n / threads + u64::from(k < n % threads);
                s.spawn(move || run_trials(share, seed.wrapping_add(k)))
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap_or_default()).collect()
    });
    let mut r = Report::default();
    for p in &parts {
        for (row, prow) in r.cells.iter_mut().zip(&p.cells) {
            for (c, pc) in row.iter_mut().zip(prow) {
                c.add(pc);
            }
        }
    }
    r
}

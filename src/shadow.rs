//! Shadowed words: a shadow copy and a checksum of a block of state, so that a bit
//! flipped in RAM (a single-event upset) is found and the block restored bit for bit. The
//! flight core's state guard (`flight::guard`) keeps its blocks this way.
//!
//! A block is a fixed sequence of words that a `visit` function walks in order (the
//! state's declaration names each field's blocks once, [`Guarded`],
//! `state_map::state_struct!`); the same walk
//!
//! - saves: each word into the block's [`Shadow`] and into its checksum ([`Shadow::save`]),
//! - checks: the checksum of the live words ([`Sum`]) against the stored one
//!   ([`Shadow::check`]),
//! - restores: each word from the shadow ([`Restore`]).
//!
//! The checksum ([`CheckWord`]) is the block's 128-bit interleaved parity: two 64-bit
//! lanes, the exclusive or of the even-numbered words and of the odd-numbered ones. Read
//! as a code, it is the cyclic code of generator x¹²⁸ + 1 over the block's bits in walk
//! order, so it finds every error burst up to 128 bits long: any pattern of flips within
//! one 64-bit word (adjacent bits among them), and any within two neighbouring words of
//! the walk (the same bit of two adjacent words, the multi-cell upset a plain XOR of the
//! words misses), as well as any odd number of flips in one bit position of a lane. What
//! it cannot see: an even number of flips in the same bit of the same lane, i.e. the same
//! bit of two words 2k words apart (k ≥ 1) in the walk. It costs what the plain XOR did,
//! three instructions a word on the Cortex-M7 (one double load, two `eor`): the lanes
//! swap places each word, which unrolled code does by register naming alone. On a
//! mismatch the shadow's own checksum says which copy is good: the shadow (restore it),
//! or the live words (the flip hit the stored checksum or the shadow: save again); when
//! neither agrees the block is lost ([`Check::Lost`]) and its owner starts it again.

use nalgebra::{Quaternion, Vector3};

/// Kinds of block a state's guard has at most ([`Blocks::KINDS`]).
pub const MAX_KINDS: usize = 6;

/// A state's guard blocks: one value of each kind (blocks of one kind, as one per FOG
/// slot, hold the same words of the same fields).
pub trait Blocks: Copy + 'static {
    /// One block of each kind, in kind order (at most [`MAX_KINDS`]).
    const KINDS: &'static [Self];
}

/// A field type's words in the guard blocks of `B`: how many in each kind of block
/// ([`Blocks::KINDS`], at most: a variant may hold fewer), and their walk.
pub trait Guarded<B: Blocks> {
    /// Words in each kind of block.
    const WORDS: [usize; MAX_KINDS];
    /// A plain value: its words go into whichever block its field's declaration names.
    /// (A stage holds its own words in its own blocks, and none in the others.)
    const PLAIN: bool = false;
    /// Its words in `block`, in order.
    fn visit_block<V: Visit>(&mut self, block: B, v: &mut V);
}

impl<B: Blocks> Guarded<B> for f64 {
    const WORDS: [usize; MAX_KINDS] = [1; MAX_KINDS];
    const PLAIN: bool = true;
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, _: B, v: &mut V) {
        v.f64(self);
    }
}

impl<B: Blocks, const N: usize> Guarded<B> for [f64; N] {
    const WORDS: [usize; MAX_KINDS] = [N; MAX_KINDS];
    const PLAIN: bool = true;
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, _: B, v: &mut V) {
        v.f64s(self);
    }
}

impl<B: Blocks> Guarded<B> for Vector3<f64> {
    const WORDS: [usize; MAX_KINDS] = [3; MAX_KINDS];
    const PLAIN: bool = true;
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, _: B, v: &mut V) {
        v.f64s(self.as_mut_slice());
    }
}

impl<B: Blocks> Guarded<B> for Quaternion<f64> {
    const WORDS: [usize; MAX_KINDS] = [4; MAX_KINDS];
    const PLAIN: bool = true;
    #[inline(always)]
    fn visit_block<V: Visit>(&mut self, _: B, v: &mut V) {
        v.f64s(self.coords.as_mut_slice());
    }
}

/// One pass over a block's words, in the block's fixed order.
pub trait Visit {
    /// Whether the pass writes the words back (a restore).
    const WRITES: bool;

    /// One 64-bit word.
    fn word(&mut self, w: &mut u64);

    /// An `f64`, by its bits.
    #[inline(always)]
    fn f64(&mut self, x: &mut f64) {
        let mut b = x.to_bits();
        self.word(&mut b);
        if Self::WRITES {
            *x = f64::from_bits(b);
        }
    }

    /// A run of `f64` (a matrix's or a quaternion's storage).
    #[inline(always)]
    fn f64s(&mut self, xs: &mut [f64]) {
        for x in xs {
            self.f64(x);
        }
    }

    /// A `u32`.
    #[inline(always)]
    fn u32(&mut self, x: &mut u32) {
        let mut b = u64::from(*x);
        self.word(&mut b);
        if Self::WRITES {
            *x = u32::try_from(b).unwrap_or(u32::MAX);
        }
    }

    /// An optional unit time, µs (`None` as `u64::MAX`, never a time).
    #[inline(always)]
    fn opt_u64(&mut self, x: &mut crate::state::Maybe<u64>) {
        let mut b = x.get().unwrap_or(u64::MAX);
        self.word(&mut b);
        if Self::WRITES {
            x.set((b != u64::MAX).then_some(b));
        }
    }
}

/// A block's checksum: its 128-bit interleaved parity (module doc). Lane `b` holds the
/// exclusive or of the words whose number in the walk has the parity of the last word's
/// plus one, lane `a` the others: after each word the lanes swap, so the word goes into
/// the lane that then becomes `b`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct CheckWord {
    a: u64,
    b: u64,
}

impl CheckWord {
    /// The checksum of no words.
    pub const ZERO: CheckWord = CheckWord { a: 0, b: 0 };

    /// The next word of the walk.
    #[inline(always)]
    pub fn push(&mut self, w: u64) {
        let t = self.a ^ w;
        self.a = self.b;
        self.b = t;
    }

    /// Word `i` of a run: the even-numbered into lane `a`, the odd into `b`, no swap
    /// ([`CheckWord::end_run`] makes up for them).
    #[inline(always)]
    fn run_word(&mut self, i: usize, w: u64) {
        if i & 1 == 0 {
            self.a ^= w;
        } else {
            self.b ^= w;
        }
    }

    /// The end of a run of `len` words taken by [`CheckWord::run_word`]: the lanes as
    /// `len` pushes leave them (swapped after an odd number).
    #[inline(always)]
    fn end_run(&mut self, len: usize) {
        if len & 1 == 1 {
            core::mem::swap(&mut self.a, &mut self.b);
        }
    }

    /// A run of `f64`, as that many pushes leave the lanes: two words a turn, the first
    /// into lane `a` and the second into `b`, so no swap is made until the run ends
    /// (swapped after an odd number).
    #[inline(always)]
    fn run_f64s(&mut self, xs: &[f64]) {
        let (mut a, mut b) = (self.a, self.b);
        let mut pairs = xs.chunks_exact(2);
        for p in &mut pairs {
            if let [x, y] = p {
                a ^= x.to_bits();
                b ^= y.to_bits();
            }
        }
        (self.a, self.b) = match pairs.remainder() {
            [x] => (b, a ^ x.to_bits()),
            _ => (a, b),
        };
    }

    /// The checksum of the bits of `xs`, in order.
    #[inline(always)]
    pub fn of_f64s(xs: &[f64]) -> Self {
        let mut c = CheckWord::ZERO;
        c.run_f64s(xs);
        c
    }

    /// Flips bit `bit` (0..128: lane `a`, then lane `b`; tests: an upset in a stored
    /// checksum).
    #[cfg(test)]
    pub(crate) fn flip_bit(&mut self, bit: u32) {
        match bit {
            0..64 => self.a ^= 1 << bit,
            _ => self.b ^= 1u64.checked_shl(bit - 64).unwrap_or(0),
        }
    }

    /// The checksum of `words`, in order.
    #[inline(always)]
    pub fn of(words: &[u64]) -> Self {
        let mut c = CheckWord::ZERO;
        for (i, &w) in words.iter().enumerate() {
            c.run_word(i, w);
        }
        c.end_run(words.len());
        c
    }
}

/// The checksum of the words visited.
#[derive(Debug, Clone, Copy)]
pub struct Sum(pub CheckWord);

impl Default for Sum {
    fn default() -> Self {
        Sum(CheckWord::ZERO)
    }
}

impl Visit for Sum {
    const WRITES: bool = false;

    #[inline(always)]
    fn word(&mut self, w: &mut u64) {
        self.0.push(*w);
    }

    #[inline(always)]
    fn f64s(&mut self, xs: &mut [f64]) {
        self.0.run_f64s(xs);
    }
}

/// Copies the words visited into a shadow and sums them ([`Shadow::save`]).
#[derive(Debug)]
pub struct Save<'a> {
    /// The shadow's words not yet written.
    words: &'a mut [u64],
    sum: CheckWord,
}

impl Save<'_> {
    /// The next `n` words of the shadow (fewer if it holds fewer: the unit tests check
    /// that every block fits its shadow), taken off the words not yet written.
    #[inline(always)]
    fn take(&mut self, n: usize) -> &mut [u64] {
        let words = core::mem::take(&mut self.words);
        let len = words.len();
        let (head, rest) = words.split_at_mut_checked(n.min(len)).unwrap_or_default();
        self.words = rest;
        head
    }
}

impl Visit for Save<'_> {
    const WRITES: bool = false;

    #[inline(always)]
    fn word(&mut self, w: &mut u64) {
        if let Some((s, rest)) = core::mem::take(&mut self.words).split_first_mut() {
            *s = *w;
            self.words = rest;
        }
        self.sum.push(*w);
    }

    /// The run copied into the shadow and summed in one loop, two words a turn as
    /// [`CheckWord`]'s runs take them.
    #[inline(always)]
    fn f64s(&mut self, xs: &mut [f64]) {
        let (mut a, mut b) = (self.sum.a, self.sum.b);
        let dst = self.take(xs.len());
        let mut pairs = xs.chunks_exact(2);
        let mut slots = dst.chunks_exact_mut(2);
        for (p, s) in (&mut pairs).zip(&mut slots) {
            if let ([x, y], [sx, sy]) = (p, s) {
                let (x, y) = (x.to_bits(), y.to_bits());
                *sx = x;
                *sy = y;
                a ^= x;
                b ^= y;
            }
        }
        (self.sum.a, self.sum.b) = match (pairs.remainder(), slots.into_remainder()) {
            ([x], [s]) => {
                *s = x.to_bits();
                (b, a ^ x.to_bits())
            }
            _ => (a, b),
        };
    }
}

/// Writes the shadow's words back into the words visited ([`Shadow::restore`]).
#[derive(Debug)]
pub struct Restore<'a> {
    /// The shadow's words not yet written back.
    words: core::slice::Iter<'a, u64>,
}

impl Visit for Restore<'_> {
    const WRITES: bool = true;

    #[inline(always)]
    fn word(&mut self, w: &mut u64) {
        if let Some(s) = self.words.next() {
            *w = *s;
        }
    }
}

/// Any of the three passes, for the blocks checked rarely: one compiled walk of the block
/// serves them all (flash), where the blocks of every step get one walk each (time).
#[derive(Debug)]
pub enum Pass<'a> {
    /// [`Sum`].
    Sum(Sum),
    /// [`Save`].
    Save(Save<'a>),
    /// [`Restore`].
    Restore(Restore<'a>),
}

impl Visit for Pass<'_> {
    /// The sum and the save write back what they read (the same bits).
    const WRITES: bool = true;

    /// Out of line, and the runs below too: a rarely checked block's walk is a call a
    /// field, not code a word.
    #[inline(never)]
    fn word(&mut self, w: &mut u64) {
        match self {
            Pass::Sum(s) => s.word(w),
            Pass::Save(s) => s.word(w),
            Pass::Restore(r) => r.word(w),
        }
    }

    fn f64(&mut self, x: &mut f64) {
        let mut b = x.to_bits();
        self.word(&mut b);
        *x = f64::from_bits(b);
    }

    /// One pass over a run: the pass chosen once, not a word.
    #[inline(never)]
    fn f64s(&mut self, xs: &mut [f64]) {
        match self {
            Pass::Sum(s) => s.f64s(xs),
            Pass::Save(s) => s.f64s(xs),
            Pass::Restore(r) => xs.iter_mut().for_each(|x| {
                let mut b = x.to_bits();
                r.word(&mut b);
                *x = f64::from_bits(b);
            }),
        }
    }
}

/// Counts the words of a block (its shadow must hold them all: the unit tests check).
#[derive(Debug, Default)]
pub struct Count(pub usize);

impl Visit for Count {
    const WRITES: bool = false;

    fn word(&mut self, _: &mut u64) {
        self.0 += 1;
    }
}

/// Flips bit `bit` of word `at` of a block (tests and the upset campaign's reasoning).
#[derive(Debug)]
pub struct Flip {
    /// Word index in the block.
    pub at: usize,
    /// Bit of that word, 0..64.
    pub bit: u32,
    seen: usize,
}

impl Flip {
    /// Flips bit `bit` of word `at`.
    pub fn new(at: usize, bit: u32) -> Self {
        Flip { at, bit, seen: 0 }
    }
}

impl Visit for Flip {
    const WRITES: bool = true;

    fn word(&mut self, w: &mut u64) {
        if self.seen == self.at {
            *w ^= 1u64.checked_shl(self.bit).unwrap_or(0);
        }
        self.seen += 1;
    }
}

/// What a check found ([`Shadow::check`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Check {
    /// The live words match the stored checksum.
    Intact,
    /// The flip hit the shadow or the stored checksum: the live words are good and were
    /// saved again by the caller's next save; nothing to restore.
    ShadowRepaired,
    /// The live words are bad, the shadow good: restore it ([`Shadow::restore`]).
    Restore,
    /// Neither copy agrees with the checksum: the block cannot be restored.
    Lost,
}

/// The good copy of a block of `N` words and its checksum.
#[derive(Debug, Clone, Copy, bytemuck::AnyBitPattern)]
pub struct Shadow<const N: usize> {
    sum: CheckWord,
    words: [u64; N],
    /// Words the last save held (a block with a variant, the estimator, may hold fewer).
    len: u32,
}

impl<const N: usize> Default for Shadow<N> {
    fn default() -> Self {
        Shadow { sum: CheckWord::ZERO, words: [0; N], len: 0 }
    }
}

impl<const N: usize> Shadow<N> {
    /// Saves the block `visit` walks.
    #[inline(always)]
    pub fn save(&mut self, visit: impl FnOnce(&mut Save<'_>)) {
        let mut s = Save { words: &mut self.words, sum: CheckWord::ZERO };
        visit(&mut s);
        let (left, sum) = (s.words.len(), s.sum);
        self.seal(left, sum);
    }

    /// The save's length (`left` words of the shadow not written) and checksum.
    #[inline(always)]
    fn seal(&mut self, left: usize, sum: CheckWord) {
        self.len = u32::try_from(N.saturating_sub(left)).unwrap_or(u32::MAX);
        self.sum = sum;
    }

    /// [`Shadow::save`] through a [`Pass`].
    pub fn save_pass(&mut self, visit: impl FnOnce(&mut Pass<'_>)) {
        let mut pass = Pass::Save(Save { words: &mut self.words, sum: CheckWord::ZERO });
        visit(&mut pass);
        if let Pass::Save(s) = pass {
            let (left, sum) = (s.words.len(), s.sum);
            self.seal(left, sum);
        }
    }

    /// [`Shadow::restore`] through a [`Pass`].
    pub fn restore_pass(&self, visit: impl FnOnce(&mut Pass<'_>)) {
        visit(&mut Pass::Restore(Restore { words: self.words.iter() }));
    }

    /// The stored checksum against the live words' `live` ([`Sum`]).
    #[inline(always)]
    pub fn check(&mut self, live: CheckWord) -> Check {
        if live == self.sum {
            return Check::Intact;
        }
        self.check_cold(live)
    }

    #[inline(always)]
    fn check_cold(&mut self, live: CheckWord) -> Check {
        check_words(&self.words, self.len, &mut self.sum, live)
    }

    /// Writes the shadow back into the block `visit` walks.
    pub fn restore(&self, visit: impl FnOnce(&mut Restore<'_>)) {
        let mut r = Restore { words: self.words.iter() };
        visit(&mut r);
    }

    /// Flips bit `bit` of the shadow's word `at` (tests: an upset in the shadow).
    #[cfg(test)]
    pub fn flip_word(&mut self, at: usize, bit: u32) {
        self.words[at] ^= 1 << bit;
    }

    /// Whether `other` holds the same words as this shadow, bit for bit (two saves
    /// compared: the navigation's step computed twice, `nav::unit`).
    #[inline(never)]
    pub fn same_words(&self, other: &Self) -> bool {
        // Word by word (a byte-wise `memcmp` would take eight times the instructions).
        self.len == other.len && self.words.iter().zip(other.words.iter()).all(|(a, b)| a == b)
    }

    /// Words the shadow can hold.
    pub const CAPACITY: usize = N;
}

/// [`Shadow::check`]'s mismatch: which copy is good, from the shadow's `words` (the first
/// `len` hold the block), its checksum `sum` and the live words' `live` (one copy for
/// every block size).
#[inline(never)]
#[cold]
fn check_words(words: &[u64], len: u32, sum: &mut CheckWord, live: CheckWord) -> Check {
    let n = usize::try_from(len).unwrap_or(usize::MAX).min(words.len());
    let own = CheckWord::of(words.get(..n).unwrap_or(words));
    if own == *sum {
        Check::Restore
    } else if own == live {
        // The stored checksum took the flip: the shadow and the live words agree.
        *sum = live;
        Check::ShadowRepaired
    } else {
        Check::Lost
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn visit<V: Visit>(v: &mut V, block: &mut [f64; 3], n: &mut u32) {
        v.f64s(block);
        v.u32(n);
    }

    /// Every single flip in the live words, the shadow or the checksum is found and the
    /// block comes back bit for bit.
    #[test]
    fn every_flip_is_found_and_undone() {
        let good = ([1.5, -2.25e-7, f64::MIN_POSITIVE], 41u32);
        for word in 0..4 {
            // The last word is a u32: its upper 32 bits are not stored.
            for bit in 0..if word == 3 { 32 } else { 64 } {
                let (mut b, mut n) = good;
                let mut sh = Shadow::<4>::default();
                sh.save(|s| visit(s, &mut b, &mut n));
                visit(&mut Flip::new(word, bit), &mut b, &mut n);
                let mut live = Sum::default();
                visit(&mut live, &mut b, &mut n);
                assert_eq!(sh.check(live.0), Check::Restore, "word {word} bit {bit}");
                sh.restore(|r| visit(r, &mut b, &mut n));
                assert_eq!(b.map(f64::to_bits), good.0.map(f64::to_bits));
                assert_eq!(n, good.1);
            }
        }
        // A flip in the stored checksum: the live words are good.
        let (mut b, mut n) = good;
        let mut sh = Shadow::<4>::default();
        sh.save(|s| visit(s, &mut b, &mut n));
        sh.sum.a ^= 1 << 17;
        let mut live = Sum::default();
        visit(&mut live, &mut b, &mut n);
        assert_eq!(sh.check(live.0), Check::ShadowRepaired);
        assert_eq!(sh.check(live.0), Check::Intact);
        // Two copies disagreeing with the checksum: lost.
        sh.words[0] ^= 1;
        b[1] = 3.0;
        let mut live = Sum::default();
        visit(&mut live, &mut b, &mut n);
        assert_eq!(sh.check(live.0), Check::Lost);
    }

    /// The double patterns of a multi-cell upset, in the live words: two adjacent bits of
    /// a word, and the same bit of two adjacent words (which a plain XOR of the words
    /// misses), each found and undone; and the one blind spot the module doc states, the
    /// same bit two words apart.
    #[test]
    fn double_flips_within_two_words_are_found_and_undone() {
        let good = [1.5f64, -2.25e-7, f64::MIN_POSITIVE, 6.02e23, -0.0];
        let n = good.len();
        let flips = |at: &[(usize, u32)]| {
            let mut b = good;
            let mut sh = Shadow::<5>::default();
            sh.save(|s| s.f64s(&mut b));
            for &(word, bit) in at {
                Flip::new(word, bit).f64s(&mut b);
            }
            let mut live = Sum::default();
            live.f64s(&mut b);
            let c = sh.check(live.0);
            if c == Check::Restore {
                sh.restore(|r| r.f64s(&mut b));
            }
            (c, b.map(f64::to_bits) == good.map(f64::to_bits))
        };
        for word in 0..n {
            for bit in 0..64 {
                if bit < 63 {
                    assert_eq!(
                        flips(&[(word, bit), (word, bit + 1)]),
                        (Check::Restore, true),
                        "word {word} bits {bit}, +1"
                    );
                }
                if word + 1 < n {
                    assert_eq!(
                        flips(&[(word, bit), (word + 1, bit)]),
                        (Check::Restore, true),
                        "words {word}, +1 bit {bit}"
                    );
                }
            }
        }
        // Two words apart, the same bit: the same lane, unseen (stated, not hidden).
        assert_eq!(flips(&[(0, 9), (2, 9)]), (Check::Intact, false));
    }
}

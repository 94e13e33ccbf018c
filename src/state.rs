//! State types every bit pattern of which is a valid value, handled without reading
//! outside a buffer (a single-event upset flips bits of the state in RAM).
//!
//! The flight core's state ([`crate::flight::FlightCore`]) is built from these and from
//! plain numbers only, and the compiler checks it: the state derives
//! [`bytemuck::AnyBitPattern`], which `bool`, enums, `Option`, references and the
//! `heapless` containers (whose indices are trusted) do not have.
//!
//! | type | replaces | any bit pattern means |
//! |---|---|---|
//! | [`Flag`] | `bool` | nonzero: set |
//! | [`Maybe`] | `Option<T>` | a value and a [`Flag`] saying it is there |
//! | [`Ring`] | `heapless::Deque` | a power-of-two ring: indices masked, length clamped to the capacity |
//! | [`Bytes`] | `heapless::Vec<u8, N>` | length clamped to the capacity |
//! | [`Quad`] | `[T; 4]` of a type with padding (bytemuck's arrays need `Pod`) | four values |
//!
//! Small enums of the state are stored as a `u8` code with a total decoder beside the
//! enum (an unknown code decodes to the safe value the enum's module names).

// The AnyBitPattern derive bounds a generic parameter once more in its impl.
#![allow(clippy::multiple_bound_locations)]

use bytemuck::{AnyBitPattern, Pod, Zeroable};

/// A flag in one byte: nonzero is set (`bool` has two valid bit patterns of 256).
#[derive(Clone, Copy, PartialEq, Eq, Default, Pod, Zeroable)]
#[repr(transparent)]
pub struct Flag(u8);

impl Flag {
    /// Clear (false).
    pub const CLEAR: Flag = Flag(0);
    /// Set (true).
    pub const SET: Flag = Flag(1);

    /// `b` as a flag.
    #[inline(always)]
    pub const fn new(b: bool) -> Flag {
        Flag(b as u8)
    }

    /// Whether the flag is set (any nonzero byte).
    #[inline(always)]
    pub const fn get(self) -> bool {
        self.0 != 0
    }

    /// Sets it to `b`.
    #[inline(always)]
    pub fn set(&mut self, b: bool) {
        self.0 = b as u8;
    }

    /// Its value, clearing it.
    #[inline(always)]
    pub fn take(&mut self) -> bool {
        core::mem::take(self).get()
    }
}

impl From<bool> for Flag {
    #[inline(always)]
    fn from(b: bool) -> Flag {
        Flag::new(b)
    }
}

impl core::fmt::Debug for Flag {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.get().fmt(f)
    }
}

/// An optional value: the value and a [`Flag`] saying whether it is there (an `Option`'s
/// tag has two valid bit patterns). Absent, the value is all zero.
#[derive(Clone, Copy, AnyBitPattern)]
pub struct Maybe<T> {
    value: T,
    present: Flag,
}

impl<T: Copy + Zeroable> Maybe<T> {
    /// Absent.
    #[inline(always)]
    pub fn none() -> Self {
        Maybe { value: T::zeroed(), present: Flag::CLEAR }
    }

    /// Present: `value`.
    #[inline(always)]
    pub const fn some(value: T) -> Self {
        Maybe { value, present: Flag::SET }
    }

    /// `o` stored.
    #[inline(always)]
    pub fn from_option(o: Option<T>) -> Self {
        match o {
            Some(v) => Maybe::some(v),
            None => Maybe::none(),
        }
    }

    /// The value, if present.
    #[inline(always)]
    pub fn get(&self) -> Option<T> {
        self.present.get().then_some(self.value)
    }

    /// A reference to the value, if present.
    #[inline(always)]
    pub fn as_ref(&self) -> Option<&T> {
        self.present.get().then_some(&self.value)
    }

    /// A mutable reference to the value, if present.
    #[inline(always)]
    pub fn as_mut(&mut self) -> Option<&mut T> {
        if self.present.get() {
            Some(&mut self.value)
        } else {
            None
        }
    }

    /// Whether the value is present.
    #[inline(always)]
    pub fn is_some(&self) -> bool {
        self.present.get()
    }

    /// Whether the value is absent.
    #[inline(always)]
    pub fn is_none(&self) -> bool {
        !self.present.get()
    }

    /// Stores `o`.
    #[inline(always)]
    pub fn set(&mut self, o: Option<T>) {
        *self = Maybe::from_option(o);
    }

    /// The value, if present, leaving it absent.
    #[inline(always)]
    pub fn take(&mut self) -> Option<T> {
        let v = self.get();
        *self = Maybe::none();
        v
    }
}

impl<T: Copy + Zeroable> Default for Maybe<T> {
    fn default() -> Self {
        Maybe::none()
    }
}

impl<T: Copy + Zeroable> From<Option<T>> for Maybe<T> {
    fn from(o: Option<T>) -> Self {
        Maybe::from_option(o)
    }
}

impl<T: Copy + Zeroable + core::fmt::Debug> core::fmt::Debug for Maybe<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.as_ref().fmt(f)
    }
}

impl<T: Copy + Zeroable + PartialEq> PartialEq for Maybe<T> {
    fn eq(&self, other: &Self) -> bool {
        self.as_ref() == other.as_ref()
    }
}

/// Four values of a type that cannot be an array of the state (bytemuck's arrays need
/// [`Pod`]: no padding), one per FOG slot.
#[derive(Clone, Copy, Debug, PartialEq, AnyBitPattern)]
pub struct Quad<T> {
    q0: T,
    q1: T,
    q2: T,
    q3: T,
}

impl<T: Default> Default for Quad<T> {
    fn default() -> Self {
        Quad { q0: T::default(), q1: T::default(), q2: T::default(), q3: T::default() }
    }
}

impl<T> Quad<T> {
    /// Four copies of `v` (built in place: no array on the stack first).
    pub fn splat(v: T) -> Self
    where
        T: Copy,
    {
        Quad { q0: v, q1: v, q2: v, q3: v }
    }

    /// Slot `i`, if `i < 4`.
    #[inline(always)]
    pub fn get(&self, i: usize) -> Option<&T> {
        match i {
            0 => Some(&self.q0),
            1 => Some(&self.q1),
            2 => Some(&self.q2),
            3 => Some(&self.q3),
            _ => None,
        }
    }

    /// Slot `i`, mutable, if `i < 4`.
    #[inline(always)]
    pub fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        match i {
            0 => Some(&mut self.q0),
            1 => Some(&mut self.q1),
            2 => Some(&mut self.q2),
            3 => Some(&mut self.q3),
            _ => None,
        }
    }

    /// The four in order.
    #[inline(always)]
    pub fn iter(&self) -> core::array::IntoIter<&T, 4> {
        [&self.q0, &self.q1, &self.q2, &self.q3].into_iter()
    }

    /// The four in order, mutable.
    #[inline(always)]
    pub fn iter_mut(&mut self) -> core::array::IntoIter<&mut T, 4> {
        [&mut self.q0, &mut self.q1, &mut self.q2, &mut self.q3].into_iter()
    }
}

/// A ring of at most `N` values (`N` a power of two) over an array: the front's index is
/// masked with `N − 1` and the length clamped to `N` wherever they are read, so no value
/// of either leaves the array. Values are stored as they are ([`Pod`]: bytemuck's arrays
/// need it); a queue of another type stores a plain form of it.
#[derive(Clone, Copy, AnyBitPattern)]
pub struct Ring<T: Pod, const N: usize> {
    items: [T; N],
    head: u32,
    len: u32,
}

impl<T: Pod, const N: usize> Ring<T, N> {
    const MASK: usize = {
        assert!(N.is_power_of_two() && N <= 1 << 16, "a ring's capacity is a power of two");
        N - 1
    };

    /// Empty.
    pub fn new() -> Self {
        Ring { items: [T::zeroed(); N], head: 0, len: 0 }
    }

    /// Values held (at most `N`, whatever the stored length).
    #[inline(always)]
    pub fn len(&self) -> usize {
        (self.len as usize).min(N)
    }

    /// Whether empty.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether full.
    #[inline(always)]
    pub fn is_full(&self) -> bool {
        self.len() == N
    }

    /// Empties it.
    #[inline(always)]
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
    }

    #[inline(always)]
    fn slot(&self, k: usize) -> usize {
        (self.head as usize).wrapping_add(k) & Self::MASK
    }

    /// The `k`-th value from the front.
    #[inline(always)]
    pub fn get(&self, k: usize) -> Option<T> {
        if k < self.len() {
            self.items.get(self.slot(k)).copied()
        } else {
            None
        }
    }

    /// The front value.
    #[inline(always)]
    pub fn front(&self) -> Option<T> {
        self.get(0)
    }

    /// Takes the front value.
    #[inline(always)]
    pub fn pop_front(&mut self) -> Option<T> {
        let v = self.front()?;
        self.head = (self.slot(1)) as u32;
        self.len = (self.len() - 1) as u32;
        Some(v)
    }

    /// Appends `v`; gives it back when full.
    #[inline(always)]
    pub fn push_back(&mut self, v: T) -> Result<(), T> {
        let n = self.len();
        if n == N {
            return Err(v);
        }
        let i = self.slot(n);
        if let Some(s) = self.items.get_mut(i) {
            *s = v;
        }
        self.head = self.slot(0) as u32;
        self.len = (n + 1) as u32;
        Ok(())
    }

    /// Puts `v` at the back, written straight into its slot (no value handed back); does
    /// nothing when full.
    #[inline(always)]
    pub fn push_back_in_place(&mut self, v: T) {
        let n = self.len();
        if n < N {
            let i = self.slot(n);
            if let Some(s) = self.items.get_mut(i) {
                *s = v;
            }
            self.head = self.slot(0) as u32;
            self.len = (n + 1) as u32;
        }
    }

    /// Puts `v` in front; gives it back when full.
    #[inline(always)]
    pub fn push_front(&mut self, v: T) -> Result<(), T> {
        let n = self.len();
        if n == N {
            return Err(v);
        }
        let i = (self.head as usize).wrapping_sub(1) & Self::MASK;
        if let Some(s) = self.items.get_mut(i) {
            *s = v;
        }
        self.head = i as u32;
        self.len = (n + 1) as u32;
        Ok(())
    }

    /// Appends `v`, dropping the front value when full; whether one was dropped.
    #[inline(always)]
    pub fn push_back_overwrite(&mut self, v: T) -> bool {
        let full = self.is_full();
        if full {
            let _ = self.pop_front();
        }
        let _ = self.push_back(v);
        full
    }

    /// The values from the front.
    #[inline(always)]
    pub fn iter(&self) -> impl Iterator<Item = T> + '_ {
        (0..self.len()).filter_map(move |k| self.items.get(self.slot(k)).copied())
    }

    /// Every stored value, mutable, in array order (held or not).
    pub fn slots_mut(&mut self) -> core::slice::IterMut<'_, T> {
        self.items.iter_mut()
    }
}

impl<T: Pod, const N: usize> Default for Ring<T, N> {
    fn default() -> Self {
        Ring::new()
    }
}

impl<T: Pod + core::fmt::Debug, const N: usize> core::fmt::Debug for Ring<T, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

/// At most `N` bytes: a buffer and its length, clamped to `N` wherever it is read.
#[derive(Clone, Copy, AnyBitPattern)]
pub struct Bytes<const N: usize> {
    buf: [u8; N],
    len: u32,
}

impl<const N: usize> Bytes<N> {
    /// Empty.
    pub const fn new() -> Self {
        Bytes { buf: [0; N], len: 0 }
    }

    /// Bytes held (at most `N`).
    #[inline(always)]
    pub fn len(&self) -> usize {
        (self.len as usize).min(N)
    }

    /// Whether empty.
    #[inline(always)]
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The bytes held.
    #[inline(always)]
    pub fn as_slice(&self) -> &[u8] {
        self.buf.get(..self.len()).unwrap_or(&[])
    }

    /// Appends `b`; gives it back when full.
    #[inline(always)]
    pub fn push(&mut self, b: u8) -> Result<(), u8> {
        let n = self.len();
        match self.buf.get_mut(n) {
            Some(s) => {
                *s = b;
                self.len = (n + 1) as u32;
                Ok(())
            }
            None => Err(b),
        }
    }

    /// Empties it.
    #[inline(always)]
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Drops the first `n` bytes (all when `n` is more).
    pub fn drop_front(&mut self, n: usize) {
        let len = self.len();
        let n = n.min(len);
        self.buf.copy_within(n..len, 0);
        self.len = (len - n) as u32;
    }
}

impl<const N: usize> Default for Bytes<N> {
    fn default() -> Self {
        Bytes::new()
    }
}

impl<const N: usize> core::fmt::Debug for Bytes<N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        self.as_slice().fmt(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_keeps_order_and_capacity() {
        let mut r: Ring<u32, 4> = Ring::new();
        for k in 0..4 {
            assert!(r.push_back(k).is_ok());
        }
        assert_eq!(r.push_back(9), Err(9));
        assert_eq!(r.pop_front(), Some(0));
        assert!(r.push_front(7).is_ok());
        assert_eq!(r.iter().collect::<std::vec::Vec<_>>(), [7, 1, 2, 3]);
        assert!(r.push_back_overwrite(5));
        assert_eq!(r.iter().collect::<std::vec::Vec<_>>(), [1, 2, 3, 5]);
    }

    #[test]
    fn corrupted_ring_and_bytes_stay_in_bounds() {
        let mut r: Ring<u32, 8> = Ring::new();
        r.head = u32::MAX;
        r.len = 1000;
        assert_eq!(r.len(), 8);
        assert_eq!(r.iter().count(), 8);
        assert_eq!(r.push_back(1), Err(1));
        assert!(r.pop_front().is_some());
        assert!(r.push_back(1).is_ok());
        let mut b: Bytes<4> = Bytes::new();
        b.len = u32::MAX;
        assert_eq!(b.as_slice().len(), 4);
        assert_eq!(b.push(1), Err(1));
        b.drop_front(3);
        assert_eq!(b.len(), 1);
    }

    #[test]
    fn flag_and_maybe_take_any_byte() {
        assert!(bytemuck::cast::<u8, Flag>(0x80).get());
        assert!(!bytemuck::cast::<u8, Flag>(0).get());
        let mut m = Maybe::some(3u32);
        assert_eq!(m.take(), Some(3));
        assert_eq!(m.get(), None);
    }
}

//! Where each part of a state value lies in memory: field name, byte offset, size.
//!
//! An upset campaign flips one bit of the [`crate::flight::FlightCore`] value and names
//! the field the flipped byte belongs to; [`crate::flight::FlightCore::state_map`] is that
//! map, down to the stages (and inside the attitude and the observer). The maps are
//! constants built with [`core::mem::offset_of!`], so the layout the compiler chose is the
//! one they describe; nothing in a step reads them. Bytes no field covers are padding.

/// One field of a state value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StateField {
    /// The field's name in its struct.
    pub name: &'static str,
    /// Offset of its first byte from the start of the struct, bytes.
    pub offset: usize,
    /// Its size, bytes.
    pub size: usize,
    /// Its alignment, bytes (the padding before it is less).
    pub align: usize,
    /// The fields inside it, offsets from its own start (empty: not mapped further).
    pub parts: &'static [StateField],
}

/// The map of `$ty`'s fields: `state_map!(Type { field: FieldType, inner: Inner => Inner::MAP, })`.
/// The field types are checked against the struct (a mismatch does not compile); `=> MAP`
/// maps the field further.
macro_rules! state_map {
    ($ty:ty { $( $field:ident : $fty:ty $( => $parts:expr )? ),* $(,)? }) => {{
        let _field_types = |s: &$ty| {
            $( let _: &$fty = &s.$field; )*
        };
        &[ $( $crate::state_map::StateField {
            name: stringify!($field),
            offset: core::mem::offset_of!($ty, $field),
            size: core::mem::size_of::<$fty>(),
            align: core::mem::align_of::<$fty>(),
            parts: $crate::state_map::state_map!(@parts $( $parts )?),
        }, )* ]
    }};
    (@parts) => { &[] };
    (@parts $parts:expr) => { $parts };
}
pub(crate) use state_map;

/// A field's bits: every bit pattern is a value ([`bytemuck::AnyBitPattern`], the
/// default of [`state_struct!`]).
#[derive(Debug)]
pub struct AnyBits;
/// A field's bits: not every bit pattern is a value (the calibration table: enums and
/// `Option`s; its owner names its bytes, which an upset test does not write).
#[derive(Debug)]
pub struct Raw;

/// The proof [`state_struct!`] asks of each field's type: [`AnyBits`] holds for
/// [`bytemuck::AnyBitPattern`] types only.
pub trait Bits<M> {}
impl<T: bytemuck::AnyBitPattern> Bits<AnyBits> for T {}
impl<T> Bits<Raw> for T {}

/// A field that survives a reset: copied into the snapshot record and back
/// ([`state_struct!`]'s `reset(Keep)`).
#[derive(Debug)]
pub struct Keep;
/// A field that a reset loses (the default): no room in the snapshot record.
#[derive(Debug)]
pub struct Lose;

/// A field that survives a reset in part: the fields its own declaration keeps, as its
/// record ([`KeepRecord`]; a state struct inside another, declared by [`state_struct!`]).
#[derive(Debug)]
pub struct Part;

/// A field's slot in the snapshot record: the value itself ([`Keep`], a plain-old-data
/// type), its own record ([`Part`]) or nothing ([`Lose`]). By value: the record is
/// packed, its fields are not referenced.
pub trait Survive<M> {
    /// What the record holds.
    type Slot: bytemuck::Pod + core::fmt::Debug;
    /// The field's slot.
    fn save(v: &Self) -> Self::Slot;
    /// The slot back into the field.
    fn load(v: &mut Self, slot: Self::Slot);
}

impl<T: bytemuck::Pod + core::fmt::Debug> Survive<Keep> for T {
    type Slot = T;
    #[inline(always)]
    fn save(v: &T) -> T {
        *v
    }
    #[inline(always)]
    fn load(v: &mut T, slot: T) {
        *v = slot;
    }
}

impl<T> Survive<Lose> for T {
    type Slot = ();
    #[inline(always)]
    fn save(_: &T) {}
    #[inline(always)]
    fn load(_: &mut T, _: ()) {}
}

/// A struct declared by [`state_struct!`]: its snapshot record and the copies into it and
/// back.
pub trait KeepRecord {
    /// The record of the fields that survive a reset.
    type Record: bytemuck::Pod + core::fmt::Debug;
    /// The fields that survive a reset, into their record.
    fn save_survivors(&self, r: &mut Self::Record);
    /// The fields that survive a reset, from their record.
    fn load_survivors(&mut self, r: &Self::Record);
}

impl<T: KeepRecord> Survive<Part> for T {
    type Slot = T::Record;
    #[inline(always)]
    fn save(v: &T) -> T::Record {
        let mut r = bytemuck::Zeroable::zeroed();
        v.save_survivors(&mut r);
        r
    }
    #[inline(always)]
    fn load(v: &mut T, slot: T::Record) {
        v.load_survivors(&slot);
    }
}

/// One declaration of a state struct: each field once, with its type, its initial value
/// and what it is to the unit's protections. From it come
///
/// - the struct (`repr` and derives as given) and its constructor, which runs the given
///   body and then builds the value in place from each field's initial value;
/// - the proof that every field's type takes any bit pattern ([`Bits`]; `bits(Raw)`
///   exempts a field, whose bytes its owner names);
/// - the state map ([`StateField`], `STATE_MAP`; `map(Inner::STATE_MAP)` maps a field
///   further);
/// - with a `guard` clause, the field's guard blocks (`guard(Block::Step | Block::Frame)`):
///   the walk of every block's words in declaration order (`Parts::visit`), each block's
///   word count (the shadows' sizes, a `const` array by block kind), and a compile-time
///   check that the field's type holds words in each block it names and in no other
///   ([`crate::shadow::Guarded`]); `GUARD_BLOCKS` lists each field's blocks;
/// - whether it survives a reset (`reset(Keep)`: the value; `reset(Part)`: the fields a
///   state struct inside keeps, its own record): a slot in the snapshot record (a
///   `repr(C, packed)` [`bytemuck::Pod`] struct of the kept fields in declaration
///   order, [`Survive`]) and the copies into it and back (`save_survivors`,
///   `load_survivors`, [`KeepRecord`]).
///
/// ```text
/// state_struct! {
///     #[repr(C)]
///     pub struct Core {
///         /// Λ.
///         attitude: Attitude = Attitude::new(q0), map(Attitude::STATE_MAP), guard(Block::Step);
///         table: Table = *table, bits(Raw);
///         bias_rad: f64 = 0.0, guard(Block::Steady), reset(Keep);
///         @shadows guard: Shadows;
///     }
///     guard { blocks: Block, words: GUARD_WORDS, parts: CoreParts }
///     snapshot { record: Survivors }
///     constructor pub fn new(table: &Table) -> Result<Self, Error> => Ok { let q0 = ...; }
/// }
/// ```
///
/// The struct may take const generics (`pub struct History<const H: usize> { .. }`); such
/// a struct has neither a guard nor a snapshot clause.
///
/// The options come in that order: `bits`, `map`, `guard`, `reset`. The guard's shadows
/// are one field, marked `@shadows` where it lies in the struct, initialised by
/// `Default`. A struct without a guard has neither the `@shadows` field nor the `guard`
/// clause (nor `guard` options); one that keeps nothing over a reset may leave out the
/// `snapshot` clause (and `reset` options).
macro_rules! state_struct {
    (
        $(#[$sm:meta])*
        $svis:vis struct $name:ident $(< $(const $cg:ident : $cgty:ty),+ $(,)? >)? {
            $(
                $(#[$afm:meta])*
                $afield:ident : $afty:ty = $ainit:expr
                $(, bits($abits:ident))?
                $(, map($aparts:expr))?
                $(, guard($agpat:pat))?
                $(, reset($areset:ident))?
                ;
            )*
            @shadows $(#[$gm:meta])* $sfield:ident : $sty:ty;
            $(
                $(#[$bfm:meta])*
                $bfield:ident : $bfty:ty = $binit:expr
                $(, bits($bbits:ident))?
                $(, map($bparts:expr))?
                $(, guard($bgpat:pat))?
                $(, reset($breset:ident))?
                ;
            )*
        }
        $($rest:tt)*
    ) => {
        $(#[$sm])*
        $svis struct $name $(< $(const $cg: $cgty),+ >)? {
            $( $(#[$afm])* $afield: $afty, )*
            $(#[$gm])* $sfield: $sty,
            $( $(#[$bfm])* $bfield: $bfty, )*
        }

        $crate::state_map::state_struct! {
            @items $name [$($(const $cg: $cgty),+)?], shadows [$sfield: $sty];
            fields {
                $(
                    $afield : $afty = $ainit
                    $(, bits($abits))? $(, map($aparts))? $(, guard($agpat))? $(, reset($areset))?;
                )*
                $(
                    $bfield : $bfty = $binit
                    $(, bits($bbits))? $(, map($bparts))? $(, guard($bgpat))? $(, reset($breset))?;
                )*
            }
            $($rest)*
        }
    };
    (
        $(#[$sm:meta])*
        $svis:vis struct $name:ident $(< $(const $cg:ident : $cgty:ty),+ $(,)? >)? {
            $(
                $(#[$afm:meta])*
                $afvis:vis $afield:ident : $afty:ty = $ainit:expr
                $(, bits($abits:ident))?
                $(, map($aparts:expr))?
                $(, reset($areset:ident))?
                ;
            )*
        }
        $($rest:tt)*
    ) => {
        $(#[$sm])*
        $svis struct $name $(< $(const $cg: $cgty),+ >)? {
            $( $(#[$afm])* $afvis $afield: $afty, )*
        }

        $crate::state_map::state_struct! {
            @items $name [$($(const $cg: $cgty),+)?], shadows [];
            fields {
                $(
                    $afield : $afty = $ainit
                    $(, bits($abits))? $(, map($aparts))? $(, reset($areset))?;
                )*
            }
            $($rest)*
        }
    };
    (
        @items $name:ident [$(const $cg:ident : $cgty:ty),*], shadows [$($sfield:ident : $sty:ty)?];
        fields {
            $(
                $field:ident : $fty:ty = $init:expr
                $(, bits($bits:ident))?
                $(, map($parts:expr))?
                $(, guard($gpat:pat))?
                $(, reset($reset:ident))?
                ;
            )*
        }
        $( guard $guard:tt )?
        $( snapshot $snapshot:tt )?
        constructor $(#[$cm:meta])* $cvis:vis fn $new:ident ( $($args:tt)* ) -> $ret:ty => $wrap:path { $($body:tt)* }
    ) => {
        $crate::state_map::state_struct! {
            @guard $name [$(const $cg: $cgty),*]; shadows [$($sfield: $sty)?]; guard [$($guard)?];
            fields { $( $field : $fty $(, guard($gpat))?; )* }
        }

        $crate::state_map::state_struct! {
            @snapshot $name [$(const $cg: $cgty),*]; snapshot [$($snapshot)?];
            fields { $( $field : $fty $(, reset($reset))?; )* }
        }

        impl<$(const $cg: $cgty),*> $name<$($cg),*> {
            /// The proof that every field's type takes any bit pattern ([`Bits`]; checked
            /// when the crate compiles, never called).
            #[allow(dead_code)]
            fn bits_proof() {
                fn proof<T: $crate::state_map::Bits<M>, M>() {}
                $( proof::<$fty, $crate::state_map::state_struct!(@or AnyBits $($bits)?)>(); )*
                $( proof::<$sty, $crate::state_map::AnyBits>(); )?
            }

            /// Where each field lies ([`crate::state_map`]): every field, in order.
            pub const STATE_MAP: &'static [$crate::state_map::StateField] = &[
                $( $crate::state_map::StateField {
                    name: stringify!($field),
                    offset: core::mem::offset_of!(Self, $field),
                    size: core::mem::size_of::<$fty>(),
                    align: core::mem::align_of::<$fty>(),
                    parts: $crate::state_map::state_map!(@parts $( $parts )?),
                }, )*
                $( $crate::state_map::StateField {
                    name: stringify!($sfield),
                    offset: core::mem::offset_of!(Self, $sfield),
                    size: core::mem::size_of::<$sty>(),
                    align: core::mem::align_of::<$sty>(),
                    parts: &[],
                }, )?
            ];

            $(#[$cm])*
            $cvis fn $new($($args)*) -> $ret {
                $($body)*
                $wrap($name { $( $field: $init, )* $( $sfield: Default::default() )? })
            }
        }
    };
    (
        @guard $name:ident []; shadows [$sfield:ident : $sty:ty];
        guard [{ blocks: $bty:ty, words: $words:ident, parts: $pname:ident $(,)? }];
        fields { $( $field:ident : $fty:ty $(, guard($gpat:pat))?; )* }
    ) => {
        /// Words of each kind of guard block ([`crate::shadow::Blocks::KINDS`]): the
        /// shadows' sizes. (Evaluated at compile time: an index out of range fails the build.)
        #[allow(clippy::indexing_slicing)]
        const $words: [usize; $crate::shadow::MAX_KINDS] = {
            let kinds = <$bty as $crate::shadow::Blocks>::KINDS;
            let mut w = [0; $crate::shadow::MAX_KINDS];
            let mut k = 0;
            while k < kinds.len() && k < $crate::shadow::MAX_KINDS {
                $( $(
                    let named = matches!(kinds[k], $gpat);
                    let n = <$fty as $crate::shadow::Guarded<$bty>>::WORDS[k];
                    if named {
                        assert!(n > 0, concat!("`", stringify!($field), "` has no words in a block its guard names"));
                    } else if !<$fty as $crate::shadow::Guarded<$bty>>::PLAIN {
                        assert!(n == 0, concat!("`", stringify!($field), "` has words in a block its guard leaves out"));
                    }
                    if named {
                        w[k] += n;
                    }
                )? )*
                k += 1;
            }
            w
        };

        /// The fields of the struct borrowed apart from its guard's shadows.
        #[allow(dead_code)]
        struct $pname<'a> {
            $( $field: &'a mut $fty, )*
        }

        impl $pname<'_> {
            /// The guarded words of `block`, in declaration order.
            #[inline(always)]
            fn visit<V: $crate::shadow::Visit>(&mut self, block: $bty, v: &mut V) {
                $( $(
                    if matches!(block, $gpat) {
                        $crate::shadow::Guarded::<$bty>::visit_block(&mut *self.$field, block, v);
                    }
                )? )*
            }
        }

        impl $name {
            /// Each field's guard blocks, by kind ([`crate::shadow::Blocks::KINDS`]).
            #[allow(dead_code, clippy::indexing_slicing)]
            const GUARD_BLOCKS: &'static [(&'static str, [bool; $crate::shadow::MAX_KINDS])] = &[
                $( (stringify!($field), $crate::state_map::state_struct!(@kinds $bty $(, $gpat)?)), )*
            ];

            /// The guarded fields and the guard's shadows, borrowed apart.
            #[inline(always)]
            fn guard_split(&mut self) -> ($pname<'_>, &mut $sty) {
                let $name { $( $field, )* $sfield } = self;
                ($pname { $( $field, )* }, $sfield)
            }
        }
    };
    (@guard $name:ident [$($g:tt)*]; shadows []; guard []; fields { $($t:tt)* }) => {};
    (
        @snapshot $name:ident []; snapshot [{ $(#[$rm:meta])* record: $rec:ident $(,)? }];
        fields { $( $field:ident : $fty:ty $(, reset($reset:ident))?; )* }
    ) => {
        $(#[$rm])*
        #[repr(C, packed)]
        #[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
        pub struct $rec {
            $( $( pub(crate) $field: <$fty as $crate::state_map::Survive<$crate::state_map::$reset>>::Slot, )? )*
        }

        impl $name {
            /// The fields that survive a reset, into their record.
            #[allow(dead_code)]
            #[inline(always)]
            pub(crate) fn save_survivors(&self, r: &mut $rec) {
                $( $( r.$field = <$fty as $crate::state_map::Survive<$crate::state_map::$reset>>::save(&self.$field); )? )*
                let _ = r;
            }

            /// The fields that survive a reset, from their record.
            #[allow(dead_code)]
            #[inline(always)]
            pub(crate) fn load_survivors(&mut self, r: &$rec) {
                $( $( <$fty as $crate::state_map::Survive<$crate::state_map::$reset>>::load(&mut self.$field, r.$field); )? )*
                let _ = r;
            }
        }

        impl $crate::state_map::KeepRecord for $name {
            type Record = $rec;
            #[inline(always)]
            fn save_survivors(&self, r: &mut $rec) {
                $name::save_survivors(self, r)
            }
            #[inline(always)]
            fn load_survivors(&mut self, r: &$rec) {
                $name::load_survivors(self, r)
            }
        }
    };
    (@snapshot $name:ident [$($g:tt)*]; snapshot []; fields { $($t:tt)* }) => {};

    (@or $default:ident) => { $crate::state_map::$default };
    (@or $default:ident $given:ident) => { $crate::state_map::$given };
    (@kinds $bty:ty) => { [false; $crate::shadow::MAX_KINDS] };
    (@kinds $bty:ty, $gpat:pat) => {{
        let kinds = <$bty as $crate::shadow::Blocks>::KINDS;
        let mut named = [false; $crate::shadow::MAX_KINDS];
        let mut k = 0;
        while k < kinds.len() && k < $crate::shadow::MAX_KINDS {
            named[k] = matches!(kinds[k], $gpat);
            k += 1;
        }
        named
    }};
}
pub(crate) use state_struct;

/// The innermost field holding byte `offset` of a value mapped by `map`, as the path of
/// field names from the outside in, ending in `"(padding)"` for padding inside a mapped
/// field (`None`: padding of the value itself). Up to `N` levels.
pub fn locate<const N: usize>(map: &'static [StateField], offset: usize) -> Option<heapless::Vec<&'static str, N>> {
    let mut path = heapless::Vec::new();
    let (mut fields, mut off) = (map, offset);
    // Bounded: one level per pass.
    for _ in 0..N {
        let Some(f) = fields.iter().find(|f| off >= f.offset && off < f.offset + f.size) else {
            if !path.is_empty() && !fields.is_empty() {
                path.push("(padding)").ok()?;
            }
            break;
        };
        path.push(f.name).ok()?;
        off -= f.offset;
        fields = f.parts;
    }
    (!path.is_empty()).then_some(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flight::FlightCore;

    /// Every level of `map` lies within `size` bytes, without overlaps, and every byte no
    /// field covers is padding the layout needs: before a field, less than its alignment;
    /// at the end, less than the value's (`align`).
    fn check(map: &[StateField], size: usize, align: usize, path: &str) {
        let mut v: Vec<_> = map.iter().collect();
        v.sort_by_key(|f| f.offset);
        for w in v.windows(2) {
            assert!(w[0].offset + w[0].size <= w[1].offset, "{path}: {} overlaps {}", w[0].name, w[1].name);
        }
        let mut end = 0;
        for f in &v {
            assert!(f.offset + f.size <= size, "{path}.{} beyond the struct", f.name);
            assert!(f.offset - end < f.align, "{path}: {} unmapped bytes before {}", f.offset - end, f.name);
            end = f.offset + f.size;
            check(f.parts, f.size, f.align, &format!("{path}.{}", f.name));
        }
        if !v.is_empty() {
            assert!(size - end < align, "{path}: {} unmapped bytes at the end", size - end);
        }
    }

    #[test]
    fn the_core_map_covers_every_byte_without_overlap() {
        let map = FlightCore::state_map();
        check(map, core::mem::size_of::<FlightCore>(), core::mem::align_of::<FlightCore>(), "FlightCore");
    }

    #[test]
    fn a_byte_of_the_attitude_quaternion_is_located_in_it() {
        let map = FlightCore::state_map();
        let att = map.iter().find(|f| f.name == "attitude").map(|f| f.offset);
        let q = map.iter().find(|f| f.name == "attitude").and_then(|f| f.parts.iter().find(|p| p.name == "q"));
        let (Some(att), Some(q)) = (att, q) else { panic!("attitude.q not in the map") };
        let path = locate::<4>(map, att + q.offset + 7);
        assert_eq!(path.as_deref(), Some(&["attitude", "q"][..]));
    }
}

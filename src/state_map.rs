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
            parts: $crate::state_map::state_map!(@parts $( $parts )?),
        }, )* ]
    }};
    (@parts) => { &[] };
    (@parts $parts:expr) => { $parts };
}
pub(crate) use state_map;

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

    /// Every level of `map` lies within `size` bytes, without overlaps.
    fn check(map: &[StateField], size: usize, path: &str) {
        let mut v: Vec<_> = map.iter().collect();
        v.sort_by_key(|f| f.offset);
        for w in v.windows(2) {
            assert!(w[0].offset + w[0].size <= w[1].offset, "{path}: {} overlaps {}", w[0].name, w[1].name);
        }
        for f in &v {
            assert!(f.offset + f.size <= size, "{path}.{} beyond the struct", f.name);
            check(f.parts, f.size, &format!("{path}.{}", f.name));
        }
    }

    #[test]
    fn the_core_map_covers_its_fields_without_overlap() {
        let map = FlightCore::state_map();
        let size = core::mem::size_of::<FlightCore>();
        check(map, size, "FlightCore");
        let covered: usize = map.iter().map(|f| f.size).sum();
        // Padding between fields is a few bytes per field at most (alignment 8).
        assert!(covered <= size && size - covered < 8 * map.len(), "{covered} of {size} bytes mapped");
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

//! The active-set entry: one triangle in 24 bytes.
//!
//! Each corner is packed into a `u64` as three unsigned 21-bit fields (x in bits 0..21, y in
//! 21..42, z in 42..63), so coordinates must lie in `0..=MAX_COORD_UM` (about 2.1 m). Placed
//! models sit on the bed (all coordinates >= 0), so the packing is lossless for every triangle
//! the slicer accepts; anything else is refused with a typed error before it is stored.

use crate::geom::{Point3, Triangle};

/// Largest coordinate (um) a slicer accepts on any axis: the 21-bit field maximum.
pub const MAX_COORD_UM: i32 = (1 << 21) - 1;

const FIELD_MASK: u64 = (1 << 21) - 1;

/// A triangle in the active set: three packed corners, winding order kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct PackedTriangle([u64; 3]);

/// True when every coordinate of `t` fits the packed fields.
pub(crate) fn is_packable(t: &Triangle) -> bool {
    let ok = |c: i32| (0..=MAX_COORD_UM).contains(&c);
    t.v.iter().all(|p| ok(p.x) && ok(p.y) && ok(p.z))
}

impl PackedTriangle {
    /// An all-zero entry (fills unused capacity).
    pub(crate) const EMPTY: Self = Self([0; 3]);

    /// Packs `t`, or `None` when a coordinate is outside `0..=MAX_COORD_UM`.
    pub(crate) fn pack(t: &Triangle) -> Option<Self> {
        if !is_packable(t) {
            return None;
        }
        // In range: the casts below are lossless.
        Some(Self(t.v.map(|p| p.x as u64 | (p.y as u64) << 21 | (p.z as u64) << 42)))
    }

    /// The three corners in winding order.
    pub(crate) fn corners(&self) -> [Point3; 3] {
        self.0.map(|w| {
            Point3::new(
                (w & FIELD_MASK) as i32,
                (w >> 21 & FIELD_MASK) as i32,
                (w >> 42 & FIELD_MASK) as i32,
            )
        })
    }

    /// Highest z of the three corners (reads only the z fields).
    pub(crate) fn z_max(&self) -> i32 {
        let z = |w: u64| (w >> 42 & FIELD_MASK) as i32;
        z(self.0[0]).max(z(self.0[1])).max(z(self.0[2]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entry_is_24_bytes_and_round_trips() {
        assert_eq!(core::mem::size_of::<PackedTriangle>(), 24);
        let t = Triangle {
            v: [
                Point3::new(0, MAX_COORD_UM, 7),
                Point3::new(MAX_COORD_UM, 1, MAX_COORD_UM),
                Point3::new(123_456, 220_000, 0),
            ],
        };
        let p = PackedTriangle::pack(&t).unwrap();
        assert_eq!(p.corners(), t.v);
        assert_eq!(p.z_max(), MAX_COORD_UM);
    }

    #[test]
    fn out_of_range_coordinates_are_refused() {
        let mut t = Triangle::default();
        t.v[1].y = -1;
        assert_eq!(PackedTriangle::pack(&t), None);
        t.v[1].y = MAX_COORD_UM + 1;
        assert_eq!(PackedTriangle::pack(&t), None);
    }
}

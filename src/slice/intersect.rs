//! Exact triangle/plane intersection in integers.
//!
//! Each corner is classified as below (`z < plane`) or above (`z >= plane`): a corner exactly
//! on the plane counts as above, so neighbouring triangles always agree on which edges cross.
//! A crossing point is computed with the edge's endpoints in canonical (lexicographic x, y, z)
//! order, so the two triangles sharing an edge get bit-identical points and closed meshes
//! chain without any tolerance.

use crate::geom::{Point2, Point3};

/// A directed cut segment in a layer plane (um). The solid lies to its left.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Segment {
    /// Where the segment starts.
    pub start: Point2,
    /// Where it ends.
    pub end: Point2,
}

/// `round(d * t / dz)`, halves rounded up (towards +inf); `dz != 0`. Inputs are bounded by
/// the packed coordinate range (|d|, |t|, |dz| < 2^22), so the products fit `i64`.
fn scale(d: i64, t: i64, dz: i64) -> i64 {
    let (num, den) = if dz < 0 { (-d * t, -dz) } else { (d * t, dz) };
    (2 * num + den).div_euclid(2 * den)
}

/// Where the edge `p`-`q` (one corner below the plane, one above) meets the plane.
fn edge_crossing(p: Point3, q: Point3, plane: i32) -> Point2 {
    // Canonical order: the same edge seen from either triangle gives the same arithmetic.
    let (a, b) = if p <= q { (p, q) } else { (q, p) };
    let dz = i64::from(b.z) - i64::from(a.z);
    let t = i64::from(plane) - i64::from(a.z);
    let at = |a: i32, b: i32| (i64::from(a) + scale(i64::from(b) - i64::from(a), t, dz)) as i32;
    Point2::new(at(a.x, b.x), at(a.y, b.y))
}

/// The segment where the plane `z = plane` cuts triangle `v` (corners in winding order), or
/// `None` when it does not cross or the cut has zero length (a corner on the plane).
///
/// The segment runs from the crossing on the edge leaving the upper side (above -> below, in
/// winding order) to the crossing on the edge entering it (below -> above). For a counter-
/// clockwise outward winding this keeps the solid on the left: outer contours come out
/// counter-clockwise seen from above, holes clockwise.
pub(crate) fn cut(v: &[Point3; 3], plane: i32) -> Option<Segment> {
    let below = [v[0].z < plane, v[1].z < plane, v[2].z < plane];
    let (mut leave, mut enter) = (None, None);
    for (i, j) in [(0, 1), (1, 2), (2, 0)] {
        match (below[i], below[j]) {
            (false, true) => leave = Some(edge_crossing(v[i], v[j], plane)),
            (true, false) => enter = Some(edge_crossing(v[i], v[j], plane)),
            _ => {}
        }
    }
    let (start, end) = (leave?, enter?);
    (start != end).then_some(Segment { start, end })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wall_facing_plus_x_runs_plus_y() {
        // a=(0,0,0), b=(0,1,0), c=(0,0,1) mm: normal +x; the cut at z=0.5 runs from
        // the c->a crossing (y=0) to the b->c crossing (y=0.5).
        let (a, b, c) = (Point3::new(0, 0, 0), Point3::new(0, 1000, 0), Point3::new(0, 0, 1000));
        let s = cut(&[a, b, c], 500).unwrap();
        assert_eq!(s, Segment { start: Point2::new(0, 0), end: Point2::new(0, 500) });
        // Same triangle, rotated winding: same segment.
        assert_eq!(cut(&[b, c, a], 500), Some(s));
        // Reversed winding (normal -x): reversed segment.
        assert_eq!(cut(&[a, c, b], 500), Some(Segment { start: s.end, end: s.start }));
    }

    #[test]
    fn shared_edges_give_identical_points_either_direction() {
        let (p, q) = (Point3::new(3, -7, 1), Point3::new(1_000_003, 500_001, 777_777));
        for plane in [2, 333_333, 777_777, 400_000] {
            assert_eq!(edge_crossing(p, q, plane), edge_crossing(q, p, plane));
        }
        // Endpoint on the plane: exactly that endpoint.
        assert_eq!(edge_crossing(p, q, 777_777), Point2::new(1_000_003, 500_001));
    }

    #[test]
    fn rounding_is_to_nearest_with_halves_up() {
        assert_eq!(scale(1, 1, 2), 1);
        assert_eq!(scale(-1, 1, 2), 0);
        assert_eq!(scale(5, 1, 3), 2);
        assert_eq!(scale(-5, 1, 3), -2);
        assert_eq!(scale(5, -1, -3), 2);
    }

    #[test]
    fn corner_on_plane_counts_as_above() {
        let v = [Point3::new(0, 0, 0), Point3::new(1000, 0, 0), Point3::new(0, 1000, 500)];
        // Apex exactly on the plane, base below: both crossings are the apex -> no segment.
        assert_eq!(cut(&v, 500), None);
        // Base exactly on the plane, apex above: no corner below -> no crossing.
        assert_eq!(cut(&v, 0), None);
        // Horizontal triangle.
        let flat = [Point3::new(0, 0, 9), Point3::new(1, 0, 9), Point3::new(0, 1, 9)];
        assert_eq!((cut(&flat, 9), cut(&flat, 10)), (None, None));
    }
}

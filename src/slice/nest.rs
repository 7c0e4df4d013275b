//! Nesting and orientation of a layer's loops.
//!
//! A loop's depth is the number of other loops that contain it (bounding-box and area
//! prefilter, then an exact integer point-in-polygon test of one of its vertices, skipping
//! vertices that lie on the other loop). Even depth = outer boundary, turned counter-
//! clockwise; odd depth = hole, turned clockwise. The parent is the smallest container. This
//! follows the even-odd rule, so it does not depend on the mesh's winding being right.
//! Cost: O(L^2) box tests for L loops in a layer, plus one point-in-polygon walk of the
//! container per box hit.

use crate::geom::Point2;

use super::LoopInfo;

#[derive(PartialEq, Eq)]
enum Where {
    Inside,
    Outside,
    Boundary,
}

/// Where `p` lies relative to the closed polygon `poly` (crossing number, exact in i64).
fn locate(p: Point2, poly: &[Point2]) -> Where {
    let Some(&last) = poly.last() else { return Where::Outside };
    let mut inside = false;
    let mut a = last;
    for &b in poly {
        let cross = (i64::from(b.x) - i64::from(a.x)) * (i64::from(p.y) - i64::from(a.y))
            - (i64::from(p.x) - i64::from(a.x)) * (i64::from(b.y) - i64::from(a.y));
        if cross == 0
            && (a.x.min(b.x)..=a.x.max(b.x)).contains(&p.x)
            && (a.y.min(b.y)..=a.y.max(b.y)).contains(&p.y)
        {
            return Where::Boundary;
        }
        // Half-open in y; the ray to +x crosses edge a-b when p is left of the upward edge.
        if (a.y > p.y) != (b.y > p.y) && (cross > 0) == (b.y > a.y) {
            inside = !inside;
        }
        a = b;
    }
    if inside {
        Where::Inside
    } else {
        Where::Outside
    }
}

fn points_of<'a>(points: &'a [Point2], l: &LoopInfo) -> &'a [Point2] {
    points.get(l.start as usize..l.start as usize + l.len as usize).unwrap_or(&[])
}

/// True when loop `inner` lies inside loop `outer` (touching allowed).
fn contains(points: &[Point2], outer: &LoopInfo, inner: &LoopInfo) -> bool {
    let boxed = outer.min.x <= inner.min.x
        && outer.min.y <= inner.min.y
        && outer.max.x >= inner.max.x
        && outer.max.y >= inner.max.y;
    if !boxed || outer.area_um2.abs() <= inner.area_um2.abs() {
        return false;
    }
    let poly = points_of(points, outer);
    for &p in points_of(points, inner) {
        match locate(p, poly) {
            Where::Inside => return true,
            Where::Outside => return false,
            Where::Boundary => {}
        }
    }
    false
}

/// Sets `hole` and `parent` of every loop and reverses loops whose orientation disagrees
/// with their depth (outer counter-clockwise, `area_um2 > 0`; holes clockwise, `< 0`).
pub(super) fn orient_and_nest(points: &mut [Point2], loops: &mut [LoopInfo]) {
    for i in 0..loops.len() {
        let (mut depth, mut parent) = (0u32, None::<usize>);
        for j in 0..loops.len() {
            if j != i && contains(points, &loops[j], &loops[i]) {
                depth += 1;
                if parent.map_or(true, |p| loops[j].area_um2.abs() < loops[p].area_um2.abs()) {
                    parent = Some(j);
                }
            }
        }
        loops[i].hole = depth % 2 == 1;
        loops[i].parent = parent.map(|p| p as u32);
    }
    for l in loops.iter_mut() {
        if l.hole == (l.area_um2 > 0) {
            if let Some(pts) = points.get_mut(l.start as usize..l.start as usize + l.len as usize) {
                pts.reverse();
            }
            l.area_um2 = -l.area_um2;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn point_location_is_exact_on_edges_and_corners() {
        let sq = [Point2::new(0, 0), Point2::new(10, 0), Point2::new(10, 10), Point2::new(0, 10)];
        assert!(locate(Point2::new(5, 5), &sq) == Where::Inside);
        assert!(locate(Point2::new(15, 5), &sq) == Where::Outside);
        assert!(locate(Point2::new(-1, 0), &sq) == Where::Outside);
        assert!(locate(Point2::new(10, 5), &sq) == Where::Boundary);
        assert!(locate(Point2::new(0, 0), &sq) == Where::Boundary);
        let mut cw = sq;
        cw.reverse();
        assert!(locate(Point2::new(5, 5), &cw) == Where::Inside);
        assert!(locate(Point2::new(5, 11), &cw) == Where::Outside);
    }
}

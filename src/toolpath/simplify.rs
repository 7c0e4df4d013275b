//! Contour simplification: fewer points, bounded deviation.
//!
//! Sliced mesh contours carry a point every few tens of micrometres on curved surfaces (3DBenchy
//! layers up to ~4,700 points). A stepper resolves 12.5 um, so points closer to a chord than
//! the tolerance only cost time in every later stage. The pass is greedy and forward: from an
//! anchor, the chord is extended point by point while every skipped point stays within `tol`
//! of it (and projects onto it); runs are capped at [`MAX_RUN`] points so the cost stays
//! linear. Works in place (the output never overtakes the input).

use crate::geom::Point2;

use super::poly::{dist2, orient};
use crate::math::isqrt_u64;

/// Longest run of points one chord may replace.
pub const MAX_RUN: usize = 48;

/// True when every point strictly between `a` and `c` lies within `tol` of the chord.
fn chord_ok(pts: &[Point2], a: usize, c: usize, tol: i64) -> bool {
    let n = pts.len();
    let (pa, pc) = (pts[a % n], pts[c % n]);
    let len2 = dist2(pa, pc);
    let len = isqrt_u64(len2 as u64) as i64;
    for j in a + 1..c {
        let q = pts[j % n];
        if len == 0 {
            if dist2(pa, q) > tol * tol {
                return false;
            }
            continue;
        }
        if orient(pa, pc, q).abs() > tol * len {
            return false;
        }
        let along = (i64::from(q.x) - i64::from(pa.x)) * (i64::from(pc.x) - i64::from(pa.x))
            + (i64::from(q.y) - i64::from(pa.y)) * (i64::from(pc.y) - i64::from(pa.y));
        if along < 0 || along > len2 {
            return false;
        }
    }
    true
}

/// The next point kept after anchor `a` (`pts.len()` when the chord reaches the end).
fn next_kept(pts: &[Point2], a: usize, tol: i64) -> usize {
    let mut e = a + 1;
    let limit = (a + MAX_RUN).min(pts.len());
    let mut c = a + 2;
    while c <= limit && chord_ok(pts, a, c, tol) {
        e = c;
        c += 1;
    }
    e
}

/// The closing fix-ups of the `out` points kept at the front of `pts`: a last point
/// repeating the first goes, and the first goes too if the chord around it is close.
fn close_up(pts: &mut [Point2], mut out: usize, tol: i64) -> usize {
    while out > 1 && pts[out - 1] == pts[0] {
        out -= 1;
    }
    if out >= 4 {
        let (prev, next) = (pts[out - 1], pts[1]);
        let probe = [prev, pts[0], next];
        if chord_ok(&probe, 0, 2, tol) {
            pts.copy_within(1..out, 0);
            out -= 1;
        }
    }
    out
}

/// Simplifies the closed loop `pts` in place with tolerance `tol` (um); returns the number
/// of points kept (the prefix of `pts`). Duplicate consecutive points always go.
pub fn simplify_closed(pts: &mut [Point2], tol: i64) -> usize {
    let n = pts.len();
    if n < 3 {
        return n;
    }
    let mut out = 1;
    let mut a = 0;
    while a < n {
        let e = next_kept(pts, a, tol);
        if e < n {
            let p = pts[e];
            if p != pts[out - 1] {
                pts[out] = p;
                out += 1;
            }
        }
        a = e;
    }
    close_up(pts, out, tol)
}

/// Calls `f` with every point of [`simplify_closed`] of `src`, in order, leaving `src` as
/// it is (no scratch: the forward walk runs twice, the first to settle the closing
/// fix-ups). Returns their number.
pub fn simplify_closed_each(src: &[Point2], tol: i64, mut f: impl FnMut(Point2)) -> usize {
    let n = src.len();
    if n < 3 {
        src.iter().for_each(|&p| f(p));
        return n;
    }
    // The walk: point `k` (0 = `src[0]`) of those kept before the fix-ups.
    let walk = |f: &mut dyn FnMut(usize, Point2)| {
        f(0, src[0]);
        let (mut out, mut last, mut a) = (1, src[0], 0);
        while a < n {
            let e = next_kept(src, a, tol);
            if e < n && src[e] != last {
                last = src[e];
                f(out, last);
                out += 1;
            }
            a = e;
        }
        out
    };
    // The fix-ups of `close_up` from the second, last and before-last points (consecutive
    // points differ, so at most the last one repeats the first).
    let (mut second, mut last, mut before) = (src[0], src[0], src[0]);
    let mut end = walk(&mut |k, p| {
        if k == 1 {
            second = p;
        }
        before = last;
        last = p;
    });
    if end > 1 && last == src[0] {
        end -= 1;
        last = before;
    }
    let start = usize::from(end >= 4 && chord_ok(&[last, src[0], second], 0, 2, tol));
    walk(&mut |k, p| {
        if (start..end).contains(&k) {
            f(p);
        }
    });
    end - start
}

#[cfg(test)]
mod tests {
    use super::*;

    fn circle(n: usize, r: f64) -> [Point2; 256] {
        let mut pts = [Point2::default(); 256];
        for (j, p) in pts.iter_mut().enumerate().take(n) {
            let a = 2.0 * core::f64::consts::PI * j as f64 / n as f64;
            *p = Point2::new((r * a.cos()) as i32, (r * a.sin()) as i32);
        }
        pts
    }

    #[test]
    fn collinear_and_duplicate_points_go() {
        let mut pts = [
            Point2::new(0, 0),
            Point2::new(500, 0),
            Point2::new(500, 0),
            Point2::new(1000, 0),
            Point2::new(1000, 1000),
            Point2::new(0, 1000),
            Point2::new(0, 500),
        ];
        let n = simplify_closed(&mut pts, 1);
        assert_eq!(
            &pts[..n],
            &[
                Point2::new(0, 0),
                Point2::new(1000, 0),
                Point2::new(1000, 1000),
                Point2::new(0, 1000)
            ]
        );
    }

    #[test]
    fn out_of_place_matches_in_place() {
        for (n, tol) in [(256, 12), (97, 40), (5, 1), (3, 1000), (2, 1), (40, 100_000)] {
            let src = circle(n, 10_000.0);
            let mut inplace = src;
            let k = simplify_closed(&mut inplace[..n], tol);
            let mut got = [Point2::default(); 256];
            let mut m = 0;
            assert_eq!(simplify_closed_each(&src[..n], tol, |p| (got[m], m) = (p, m + 1)), k);
            assert_eq!(&got[..m], &inplace[..k]);
        }
    }

    #[test]
    fn deviation_stays_within_tolerance_on_a_fine_circle() {
        let mut pts = circle(256, 10_000.0);
        let n = simplify_closed(&mut pts, 12);
        assert!(n < 128 && n > 16, "{n}");
        // Every kept point is on the circle; chords deviate at most tol (+1 rounding).
        for j in 0..n {
            let (a, b) = (pts[j], pts[(j + 1) % n]);
            let mid =
                ((f64::from(a.x) + f64::from(b.x)) / 2.0, (f64::from(a.y) + f64::from(b.y)) / 2.0);
            let r = (mid.0 * mid.0 + mid.1 * mid.1).sqrt();
            assert!(10_000.0 - r <= 14.0, "chord {j} sags {}", 10_000.0 - r);
        }
    }
}

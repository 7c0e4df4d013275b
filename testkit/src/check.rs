//! `f64` geometry oracles, independent of the core's integer code.
//!
//! Areas, distances, winding, the section of a mesh by a plane, and a raster of deposited lines.
//! Coordinates are um (the core's units) unless a name says otherwise.

use std::fmt::Debug;

use strata::geom::{Point2, Triangle};

/// A point as `f64` (um).
pub fn pt(p: Point2) -> (f64, f64) {
    (f64::from(p.x), f64::from(p.y))
}

/// Cross product of `a - o` and `b - o`: positive when o, a, b turn counter-clockwise.
pub fn cross(o: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.0 - o.0) * (b.1 - o.1) - (a.1 - o.1) * (b.0 - o.0)
}

/// Signed area of a polygon (shoelace): positive counter-clockwise.
pub fn signed_area(points: &[(f64, f64)]) -> f64 {
    let n = points.len();
    (0..n).map(|i| cross((0.0, 0.0), points[i], points[(i + 1) % n])).sum::<f64>() / 2.0
}

/// Distance from `p` to the segment a-b.
pub fn point_seg_dist(p: (f64, f64), a: (f64, f64), b: (f64, f64)) -> f64 {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let l2 = dx * dx + dy * dy;
    let t =
        if l2 == 0.0 { 0.0 } else { (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / l2).clamp(0.0, 1.0) };
    ((p.0 - a.0 - t * dx).powi(2) + (p.1 - a.1 - t * dy).powi(2)).sqrt()
}

/// Distance between the segments a-b and c-d (0 if they cross).
pub fn seg_seg_dist(a: (f64, f64), b: (f64, f64), c: (f64, f64), d: (f64, f64)) -> f64 {
    let (d1, d2, d3, d4) = (cross(c, d, a), cross(c, d, b), cross(a, b, c), cross(a, b, d));
    if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
        return 0.0;
    }
    point_seg_dist(a, c, d)
        .min(point_seg_dist(b, c, d))
        .min(point_seg_dist(c, a, b))
        .min(point_seg_dist(d, a, b))
}

/// Non-zero winding of `p` in the loops (each: points, hole flag; holes wind clockwise).
pub fn inside(loops: &[(Vec<Point2>, bool)], p: (f64, f64)) -> bool {
    let mut w = 0;
    for (l, _) in loops {
        for k in 0..l.len() {
            let (a, b) = (pt(l[k]), pt(l[(k + 1) % l.len()]));
            if (a.1 <= p.1) != (b.1 <= p.1) {
                let x = a.0 + (p.1 - a.1) / (b.1 - a.1) * (b.0 - a.0);
                if x > p.0 {
                    w += if b.1 > a.1 { 1 } else { -1 };
                }
            }
        }
    }
    w != 0
}

/// The section of `tris` by the plane at height `z` (um), without chaining.
///
/// Per crossing triangle its cut segment, from where the section enters it (its above->below edge)
/// to where it leaves (its below->above edge), in `f64` um. Corners at `z` count as above, as in
/// the slicer.
pub fn section_segments_f64(tris: &[Triangle], z: f64) -> Vec<[[f64; 2]; 2]> {
    let mut out = Vec::new();
    for t in tris {
        let v = t.v.map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)]);
        let below = v.map(|p| p[2] < z);
        let cross_at = |i: usize, j: usize| {
            let s = (z - v[i][2]) / (v[j][2] - v[i][2]);
            [v[i][0] + s * (v[j][0] - v[i][0]), v[i][1] + s * (v[j][1] - v[i][1])]
        };
        let (mut from, mut to) = (None, None);
        for (i, j) in [(0, 1), (1, 2), (2, 0)] {
            if !below[i] && below[j] {
                from = Some(cross_at(i, j));
            } else if below[i] && !below[j] {
                to = Some(cross_at(i, j));
            }
        }
        if let (Some(a), Some(b)) = (from, to) {
            out.push([a, b]);
        }
    }
    out
}

/// Signed area (um^2) of the section of `tris` by the plane at height `z` (um).
///
/// Each [`section_segments_f64`] segment contributes its cross product (Green's theorem). Also
/// returns the summed segment length (um), a scale for rounding tolerances.
pub fn section_area_f64(tris: &[Triangle], z: f64) -> (f64, f64) {
    let (mut twice, mut length) = (0.0, 0.0);
    for [a, b] in section_segments_f64(tris, z) {
        twice += a[0] * b[1] - b[0] * a[1];
        length += ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
    }
    (twice / 2.0, length)
}

/// Asserts that `area_um2` is the area of the section of `tris` at height `z_um`, plus
/// `extra_um2`.
///
/// The oracle is [`section_area_f64`]; the tolerance 0.1 % or 1 um x the cut's length (the
/// slicer rounds every crossing to the um).
///
/// Messages start with `what`.
pub fn assert_section_area(
    what: &str,
    area_um2: f64,
    tris: &[Triangle],
    z_um: i32,
    extra_um2: f64,
) {
    let (oracle, length) = section_area_f64(tris, f64::from(z_um));
    let tol = (oracle.abs() * 1e-3).max(length) + extra_um2;
    assert!(
        (area_um2 - oracle).abs() <= tol,
        "{what} z {z_um}: area {area_um2} um^2, oracle {oracle} (tol {tol})"
    );
}

/// Asserts that every line a-b lies inside `contours` and at least `min_dist` um from each of their
/// edges (endpoints inside, segment-to-edge distances).
///
/// Returns the lines checked. Messages start with `what` and name the line's `label`.
pub fn assert_lines_inside<L: Debug>(
    what: &str,
    contours: &[(Vec<Point2>, bool)],
    lines: &[(Point2, Point2, L)],
    min_dist: f64,
) -> usize {
    for (a, b, label) in lines {
        let (a, b) = (pt(*a), pt(*b));
        assert!(
            inside(contours, a) && inside(contours, b),
            "{what}: {label:?} {a:?}-{b:?} outside the contour"
        );
        for (c, _) in contours {
            for k in 0..c.len() {
                let d = seg_seg_dist(a, b, pt(c[k]), pt(c[(k + 1) % c.len()]));
                assert!(
                    d >= min_dist,
                    "{what}: {label:?} {a:?}-{b:?} is {d:.1} um from the contour"
                );
            }
        }
    }
    lines.len()
}

/// Cell size of a [`Raster`], um.
pub const CELL_UM: f64 = 50.0;

/// Cells of [`CELL_UM`] over a rectangle (um), each marked when a line covers its centre.
#[derive(Debug, Clone)]
pub struct Raster {
    lo: (f64, f64),
    /// Columns.
    pub nx: usize,
    /// Rows.
    pub ny: usize,
    cells: Vec<bool>,
}

impl Raster {
    /// Unmarked cells over `[lo, hi]`.
    pub fn new(lo: (f64, f64), hi: (f64, f64)) -> Self {
        let nx = ((hi.0 - lo.0) / CELL_UM).ceil() as usize + 1;
        let ny = ((hi.1 - lo.1) / CELL_UM).ceil() as usize + 1;
        Self { lo, nx, ny, cells: vec![false; nx * ny] }
    }

    /// Centre of cell (`i`, `j`).
    pub fn centre(&self, i: usize, j: usize) -> (f64, f64) {
        (self.lo.0 + (i as f64 + 0.5) * CELL_UM, self.lo.1 + (j as f64 + 0.5) * CELL_UM)
    }

    /// Cell (`i`, `j`) is marked.
    pub fn marked(&self, i: usize, j: usize) -> bool {
        self.cells[j * self.nx + i]
    }

    /// Marks the cells whose centre lies in the rectangle of width `w` around segment a-b.
    pub fn line(&mut self, a: (f64, f64), b: (f64, f64), w: f64) {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = (dx * dx + dy * dy).sqrt();
        if len == 0.0 {
            return;
        }
        let (ux, uy) = (dx / len, dy / len);
        let r = w / 2.0;
        let i0 = (((a.0.min(b.0) - r - self.lo.0) / CELL_UM).floor().max(0.0)) as usize;
        let i1 = ((((a.0.max(b.0) + r - self.lo.0) / CELL_UM).ceil()) as usize).min(self.nx - 1);
        let j0 = (((a.1.min(b.1) - r - self.lo.1) / CELL_UM).floor().max(0.0)) as usize;
        let j1 = ((((a.1.max(b.1) + r - self.lo.1) / CELL_UM).ceil()) as usize).min(self.ny - 1);
        for j in j0..=j1 {
            for i in i0..=i1 {
                let c = self.centre(i, j);
                let (px, py) = (c.0 - a.0, c.1 - a.1);
                let along = px * ux + py * uy;
                let across = (px * uy - py * ux).abs();
                if (0.0..=len).contains(&along) && across <= r {
                    self.cells[j * self.nx + i] = true;
                }
            }
        }
    }
}

/// How much of a layer's top surface its lines cover: [`top_coverage`].
#[derive(Debug, Clone)]
pub struct TopCoverage {
    /// Covered share of the top surface's cells (1 when there is no top surface).
    pub fraction: f64,
    /// Area of the top surface, mm^2 (its cells').
    pub area_mm2: f64,
    /// The lines' cells.
    pub raster: Raster,
    /// Per cell: part of the top surface.
    pub top: Vec<bool>,
}

impl TopCoverage {
    /// The raster as a plain PGM picture, top row first: 0 uncovered top surface, 1 not top
    /// surface, 2 covered top surface.
    pub fn pgm(&self) -> String {
        let r = &self.raster;
        let mut img = format!("P2\n{} {}\n2\n", r.nx, r.ny);
        for j in (0..r.ny).rev() {
            for i in 0..r.nx {
                let v = match (self.top[j * r.nx + i], r.marked(i, j)) {
                    (false, _) => "1 ",
                    (true, true) => "2 ",
                    (true, false) => "0 ",
                };
                img.push_str(v);
            }
            img.push('\n');
        }
        img
    }
}

/// Coverage of a layer's top surface (inside `region`, outside `above`, the next layer's
/// region) by `lines`, each a rectangle `width` um wide, on a [`CELL_UM`] raster over the
/// region's bounding box.
pub fn top_coverage(
    region: &[(Vec<Point2>, bool)],
    above: Option<&[(Vec<Point2>, bool)]>,
    lines: &[(Point2, Point2)],
    width: f64,
) -> TopCoverage {
    let pts: Vec<(f64, f64)> = region.iter().flat_map(|(c, _)| c.iter().map(|&p| pt(p))).collect();
    let lo = pts.iter().fold((f64::MAX, f64::MAX), |m, p| (m.0.min(p.0), m.1.min(p.1)));
    let hi = pts.iter().fold((f64::MIN, f64::MIN), |m, p| (m.0.max(p.0), m.1.max(p.1)));
    let mut raster = Raster::new(lo, hi);
    for &(a, b) in lines {
        raster.line(pt(a), pt(b), width);
    }
    let mut top = vec![false; raster.nx * raster.ny];
    let (mut cells, mut covered) = (0usize, 0usize);
    for j in 0..raster.ny {
        for i in 0..raster.nx {
            let c = raster.centre(i, j);
            if inside(region, c) && !above.is_some_and(|n| inside(n, c)) {
                top[j * raster.nx + i] = true;
                cells += 1;
                covered += usize::from(raster.marked(i, j));
            }
        }
    }
    let fraction = if cells == 0 { 1.0 } else { covered as f64 / cells as f64 };
    let area_mm2 = cells as f64 * CELL_UM * CELL_UM / 1e6;
    TopCoverage { fraction, area_mm2, raster, top }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{cuboid, to_um};

    fn square(lo: i32, hi: i32) -> Vec<Point2> {
        [(lo, lo), (hi, lo), (hi, hi), (lo, hi)].map(|(x, y)| Point2::new(x, y)).to_vec()
    }

    #[test]
    fn areas_and_distances() {
        assert_eq!(signed_area(&[(0.0, 0.0), (2.0, 0.0), (2.0, 3.0), (0.0, 3.0)]), 6.0);
        assert_eq!(signed_area(&[(0.0, 0.0), (0.0, 3.0), (2.0, 3.0), (2.0, 0.0)]), -6.0);
        assert_eq!(point_seg_dist((1.0, 1.0), (0.0, 0.0), (2.0, 0.0)), 1.0);
        assert_eq!(seg_seg_dist((0.0, -1.0), (0.0, 1.0), (-1.0, 0.0), (1.0, 0.0)), 0.0);
        assert_eq!(seg_seg_dist((0.0, 2.0), (1.0, 2.0), (-1.0, 0.0), (1.0, 0.0)), 2.0);
    }

    #[test]
    fn a_holed_square_winds_around_its_ring_only() {
        let mut hole = square(40, 60);
        hole.reverse();
        let loops = vec![(square(0, 100), false), (hole, true)];
        assert!(inside(&loops, (10.0, 10.0)));
        assert!(!inside(&loops, (50.0, 50.0)));
        assert!(!inside(&loops, (150.0, 50.0)));
    }

    #[test]
    fn the_section_of_a_box_is_its_footprint() {
        let tris = to_um(&cuboid([10.0, 10.0, 0.0], [30.0, 15.0, 2.0]));
        let (area, length) = section_area_f64(&tris, 1000.0);
        assert!((area - 20_000.0 * 5_000.0).abs() < 1e-3, "{area}");
        assert!((length - 50_000.0).abs() < 1e-6, "{length}");
    }

    #[test]
    fn lines_across_a_square_cover_its_top() {
        let region = vec![(square(0, 1000), false)];
        let lines: Vec<(Point2, Point2)> = (0..=4)
            .map(|k| (Point2::new(0, 100 + 200 * k), Point2::new(1000, 100 + 200 * k)))
            .collect();
        let c = top_coverage(&region, None, &lines, 200.0);
        assert_eq!(c.fraction, 1.0);
        assert!((c.area_mm2 - 1.0).abs() < 0.01, "{}", c.area_mm2);
        let half = top_coverage(&region, None, &lines[..2], 200.0);
        assert!(half.fraction < 0.5, "{}", half.fraction);
        let inner: Vec<_> =
            (1..4).map(|k| (Point2::new(100, 250 * k), Point2::new(900, 250 * k), k)).collect();
        assert_eq!(assert_lines_inside("square", &region, &inner, 100.0), 3);
    }
}

//! Admission control: does the model fit the device's capacities at these settings, and if
//! not, a simplified mesh that does, within a stated maximum deviation.
//!
//! The model's peak needs come from `strata::slice::peak_needs` (the largest active set and
//! the most contour points of any layer) and are compared with the capacities the device
//! announced. A model that does not fit is simplified with `meshopt` (edge collapses onto
//! existing vertices, with an absolute error bound in mm), asking for fewer and fewer
//! triangles until it fits or the error bound stops it. The deviation actually introduced is
//! then measured, not assumed: a two-sided Hausdorff estimate between the original and the
//! simplified surface (original vertices to the simplified mesh, and points sampled on the
//! simplified triangles to the original), which must stay within the bound.

use std::collections::HashMap;

use meshopt::{simplify_decoder, SimplifyOptions};
use strata::geom::{Point3, Triangle};
use strata::protocol::Capacities;
use strata::slice::{peak_needs, PeakNeeds, SliceConfig};

/// What a model needs against what the device has.
#[derive(Debug, Clone, Copy)]
pub struct Fit {
    /// The model's peaks.
    pub needs: PeakNeeds,
    /// True when every peak fits.
    pub fits: bool,
}

/// Checks the model's peak active set and contour points against `caps`.
pub fn check(tris: &[Triangle], config: &SliceConfig, caps: &Capacities) -> Result<Fit, String> {
    let needs = peak_needs(tris, config).map_err(|e| e.to_string())?;
    let fits = needs.active_triangles <= caps.active_triangles
        && needs.contour_points <= caps.contour_points;
    Ok(Fit { needs, fits })
}

/// A simplification that fits.
#[derive(Debug, Clone)]
pub struct Simplified {
    /// The simplified triangles, placed, sorted by lowest z.
    pub triangles: Vec<Triangle>,
    /// Triangles before.
    pub triangles_in: usize,
    /// The simplifier's error bound (meshopt's quadric error, absolute), mm.
    pub error_bound_mm: f64,
    /// Measured deviation (two-sided Hausdorff estimate), mm.
    pub max_deviation_mm: f64,
    /// Needs of the simplified model.
    pub needs: PeakNeeds,
}

/// Largest measured deviation a simplification may have: the nozzle radius, mm.
pub const MAX_MEASURED_DEVIATION_MM: f64 = 0.2;

/// The admission decision.
#[derive(Debug, Clone)]
pub enum Admission {
    /// Fits unchanged.
    Unchanged(PeakNeeds),
    /// Fits after simplification.
    Simplified(Simplified),
}

/// Admits `tris` (placed, sorted by lowest z) on a device with `caps`: unchanged, simplified
/// within `max_deviation_mm`, or refused with a message saying what does not fit.
pub fn admit(
    tris: &[Triangle],
    config: &SliceConfig,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<Admission, String> {
    let fit = check(tris, config, caps)?;
    if fit.fits {
        return Ok(Admission::Unchanged(fit.needs));
    }
    let mesh = Indexed::weld(tris);
    let mut target = tris.len() / 2;
    let mut last_len = tris.len();
    loop {
        let idx = simplify_decoder(
            &mesh.indices,
            &mesh.positions,
            target * 3,
            max_deviation_mm as f32,
            SimplifyOptions::ErrorAbsolute,
            None,
        );
        let mut out = mesh.triangles(&idx);
        out.sort_by_key(Triangle::z_min);
        let fit = check(&out, config, caps)?;
        if fit.fits {
            let (dev, _) = deviation(&mesh, tris, &out, f64::INFINITY);
            if dev > MAX_MEASURED_DEVIATION_MM {
                return Err(format!(
                    "simplifying the model to fit the printer ({} triangles) moves its surface \
                     by {dev:.3} mm, more than the nozzle radius ({MAX_MEASURED_DEVIATION_MM} \
                     mm): refused",
                    out.len()
                ));
            }
            return Ok(Admission::Simplified(Simplified {
                triangles: out,
                triangles_in: tris.len(),
                error_bound_mm: max_deviation_mm,
                max_deviation_mm: dev,
                needs: fit.needs,
            }));
        }
        if out.len() >= last_len || target < 4 {
            return Err(format!(
                "the model does not fit the printer even simplified to a {max_deviation_mm} mm \
                 error: it needs {} active triangles and {} contour points per layer ({} \
                 triangles left), the printer holds {} and {}",
                fit.needs.active_triangles,
                fit.needs.contour_points,
                out.len(),
                caps.active_triangles,
                caps.contour_points
            ));
        }
        last_len = out.len();
        target = out.len() * 2 / 3;
    }
}

/// The deviation between the original `a` (indexed as `mesh`) and the simplification `b`
/// (two-sided estimate, mm) and the original vertices to lock: those farther than `bound`
/// from `b`, and the corners of every triangle of `b` with a sample farther than `bound`
/// from `a`.
fn deviation(mesh: &Indexed, a: &[Triangle], b: &[Triangle], bound: f64) -> (f64, Vec<u32>) {
    let (ga, gb) = (Grid::new(a, 1.0), Grid::new(b, 1.0));
    let mut worst: f64 = 0.0;
    let mut offenders = Vec::new();
    for (i, p) in mesh.points.iter().enumerate() {
        let d = gb.distance(mm(*p));
        worst = worst.max(d);
        if d > bound {
            offenders.push(i as u32);
        }
    }
    for t in b {
        let v = t.v.map(mm);
        let d = BARY
            .iter()
            .map(|w| {
                ga.distance([0, 1, 2].map(|k| w[0] * v[0][k] + w[1] * v[1][k] + w[2] * v[2][k]))
            })
            .fold(0.0, f64::max);
        worst = worst.max(d);
        if d > bound {
            offenders.extend(t.v.iter().filter_map(|p| mesh.index.get(p).copied()));
        }
    }
    (worst, offenders)
}

/// An indexed mesh with welded (bit-identical) vertices, positions in mm.
struct Indexed {
    index: HashMap<Point3, u32>,
    points: Vec<Point3>,
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
}

impl Indexed {
    fn weld(tris: &[Triangle]) -> Self {
        let mut map: HashMap<Point3, u32> = HashMap::new();
        let mut points = Vec::new();
        let mut indices = Vec::with_capacity(tris.len() * 3);
        for t in tris {
            for p in t.v {
                let i = *map.entry(p).or_insert_with(|| {
                    points.push(p);
                    points.len() as u32 - 1
                });
                indices.push(i);
            }
        }
        let positions =
            points.iter().map(|p| [p.x as f32 / 1e3, p.y as f32 / 1e3, p.z as f32 / 1e3]).collect();
        Self { index: map, points, positions, indices }
    }

    /// Triangles of an index list (original vertices, exact um).
    fn triangles(&self, idx: &[u32]) -> Vec<Triangle> {
        idx.chunks_exact(3)
            .map(|c| Triangle { v: [0, 1, 2].map(|k| self.points[c[k] as usize]) })
            .collect()
    }
}

type V = [f64; 3];

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn mm(p: Point3) -> V {
    [p.x as f64 / 1e3, p.y as f64 / 1e3, p.z as f64 / 1e3]
}

/// Squared distance from `p` to triangle `abc` (Ericson, Real-Time Collision Detection 5.1.5).
fn dist2_point_triangle(p: V, a: V, b: V, c: V) -> f64 {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    let closest = |q: V| {
        let d = sub(p, q);
        dot(d, d)
    };
    let lerp = |o: V, d: V, t: f64| [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t];
    if d1 <= 0.0 && d2 <= 0.0 {
        return closest(a);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return closest(b);
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return closest(lerp(a, ab, d1 / (d1 - d3)));
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return closest(c);
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return closest(lerp(a, ac, d2 / (d2 - d6)));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return closest(lerp(b, sub(c, b), w));
    }
    let denom = 1.0 / (va + vb + vc);
    let (v, w) = (vb * denom, vc * denom);
    closest([
        a[0] + ab[0] * v + ac[0] * w,
        a[1] + ab[1] * v + ac[1] * w,
        a[2] + ab[2] * v + ac[2] * w,
    ])
}

/// A uniform grid of triangle bounding boxes for nearest-surface queries.
struct Grid<'a> {
    tris: &'a [Triangle],
    cell: f64,
    cells: HashMap<[i32; 3], Vec<u32>>,
}

impl<'a> Grid<'a> {
    fn new(tris: &'a [Triangle], cell: f64) -> Self {
        let mut cells: HashMap<[i32; 3], Vec<u32>> = HashMap::new();
        for (i, t) in tris.iter().enumerate() {
            let v = t.v.map(mm);
            let lo = [0, 1, 2]
                .map(|k| (v.iter().map(|p| p[k]).fold(f64::MAX, f64::min) / cell).floor() as i32);
            let hi = [0, 1, 2]
                .map(|k| (v.iter().map(|p| p[k]).fold(f64::MIN, f64::max) / cell).floor() as i32);
            for x in lo[0]..=hi[0] {
                for y in lo[1]..=hi[1] {
                    for z in lo[2]..=hi[2] {
                        cells.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
        Self { tris, cell, cells }
    }

    /// Distance from `p` to the surface, capped at one cell (enough for sub-mm deviations).
    fn distance(&self, p: V) -> f64 {
        let c = [0, 1, 2].map(|k| (p[k] / self.cell).floor() as i32);
        let mut best = self.cell * self.cell;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = self.cells.get(&[c[0] + dx, c[1] + dy, c[2] + dz]) else {
                        continue;
                    };
                    for &i in list {
                        let v = self.tris[i as usize].v.map(mm);
                        best = best.min(dist2_point_triangle(p, v[0], v[1], v[2]));
                    }
                }
            }
        }
        best.sqrt()
    }
}

/// Sample points of a triangle (barycentric): corners, edge midpoints, centroid, 6 interior.
const BARY: [[f64; 3]; 13] = [
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [0.5, 0.5, 0.0],
    [0.0, 0.5, 0.5],
    [0.5, 0.0, 0.5],
    [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0],
    [0.6, 0.2, 0.2],
    [0.2, 0.6, 0.2],
    [0.2, 0.2, 0.6],
    [0.1, 0.45, 0.45],
    [0.45, 0.1, 0.45],
    [0.45, 0.45, 0.1],
];

/// Two-sided Hausdorff estimate between two surfaces, mm: every vertex of `a` against `b`,
/// and 13 sample points of every triangle of `b` (corners, edge midpoints, centroid, 6
/// interior) against `a`.
pub fn hausdorff_mm(a: &[Triangle], b: &[Triangle]) -> f64 {
    let mesh = Indexed::weld(a);
    deviation(&mesh, a, b, f64::INFINITY).0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [i32; 3], b: [i32; 3], c: [i32; 3]) -> Triangle {
        let p = |v: [i32; 3]| Point3::new(v[0], v[1], v[2]);
        Triangle { v: [p(a), p(b), p(c)] }
    }

    #[test]
    fn point_triangle_distance() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let d = |p: V| dist2_point_triangle(p, a, b, c).sqrt();
        assert!((d([0.2, 0.2, 0.5]) - 0.5).abs() < 1e-12);
        assert!((d([2.0, 0.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((d([-1.0, -1.0, 0.0]) - 2f64.sqrt()).abs() < 1e-12);
        assert!((d([1.0, 1.0, 0.0]) - 0.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn hausdorff_of_a_plane_and_a_bump() {
        let mut fine = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                let (x, y) = (i * 1000, j * 1000);
                fine.push(tri([x, y, 0], [x + 1000, y, 0], [x + 1000, y + 1000, 0]));
                fine.push(tri([x, y, 0], [x + 1000, y + 1000, 0], [x, y + 1000, 0]));
            }
        }
        let coarse = vec![
            tri([0, 0, 0], [10_000, 0, 0], [10_000, 10_000, 0]),
            tri([0, 0, 0], [10_000, 10_000, 0], [0, 10_000, 0]),
        ];
        assert!(hausdorff_mm(&fine, &coarse) < 1e-9);
        // Raise one inner vertex by 50 um.
        for t in &mut fine {
            for p in &mut t.v {
                if p.x == 5000 && p.y == 5000 {
                    p.z = 50;
                }
            }
        }
        let h = hausdorff_mm(&fine, &coarse);
        assert!((h - 0.05).abs() < 1e-9, "{h}");
    }
}

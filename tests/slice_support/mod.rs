//! Helpers for the slicer tests: analytic meshes, an independent f64 section-area oracle, and
//! a runner that collects every layer into owned data.
#![allow(dead_code)] // each test crate uses a different subset

use std::f64::consts::PI;
use std::path::Path;

use strata::geom::{Point2, Point3, Triangle};
use strata::machine::{MachineConfig, PrintSettings};
use strata::place::{Bounds, Placement};
use strata::slice::{
    LayerRepairs, SliceConfig, SliceError, SliceScratch, SliceStats, SlicedLayer, Slicer,
};

/// A triangle in mm, corners counter-clockwise seen from outside.
pub type TriMm = [[f64; 3]; 3];

/// Walls between consecutive rings (same point count, counter-clockwise from above) plus fan
/// caps at the first and last ring (convex rings). Each ring: (z, points) in mm.
pub fn loft(rings: &[(f64, Vec<[f64; 2]>)]) -> Vec<TriMm> {
    let mut out = Vec::new();
    let p = |r: usize, j: usize| {
        let (z, pts) = &rings[r];
        let [x, y] = pts[j % pts.len()];
        [x, y, *z]
    };
    let n = rings[0].1.len();
    for r in 0..rings.len() - 1 {
        for j in 0..n {
            // east x up = outward
            out.push([p(r, j), p(r, j + 1), p(r + 1, j + 1)]);
            out.push([p(r, j), p(r + 1, j + 1), p(r + 1, j)]);
        }
    }
    let centre = |r: usize| {
        let pts = &rings[r].1;
        let c = pts.iter().fold([0.0, 0.0], |a, q| [a[0] + q[0], a[1] + q[1]]);
        [c[0] / pts.len() as f64, c[1] / pts.len() as f64, rings[r].0]
    };
    let (bottom, top) = (0, rings.len() - 1);
    for j in 0..n {
        out.push([centre(bottom), p(bottom, j + 1), p(bottom, j)]);
        out.push([centre(top), p(top, j), p(top, j + 1)]);
    }
    out
}

/// Regular polygon, counter-clockwise.
pub fn ngon(n: usize, cx: f64, cy: f64, r: f64, phase: f64) -> Vec<[f64; 2]> {
    (0..n)
        .map(|j| {
            let a = phase + 2.0 * PI * j as f64 / n as f64;
            [cx + r * a.cos(), cy + r * a.sin()]
        })
        .collect()
}

/// Axis-aligned box from `min` to `max` (mm).
pub fn cuboid(min: [f64; 3], max: [f64; 3]) -> Vec<TriMm> {
    let ring = vec![[min[0], min[1]], [max[0], min[1]], [max[0], max[1]], [min[0], max[1]]];
    loft(&[(min[2], ring.clone()), (max[2], ring)])
}

/// Four separate holed discs (24-gons 11.8 mm across with 2 mm holes, 12 mm apart) around
/// (`c`, `c`) mm, from z 0 to `height` mm: several islands, holes and travels between them.
pub fn four_holed_discs(c: f64, height: f64) -> Vec<TriMm> {
    let mut plate = Vec::new();
    for (dx, dy) in [(-6.0, -6.0), (6.0, -6.0), (-6.0, 6.0), (6.0, 6.0)] {
        let (hx, hy) = (c + dx, c + dy);
        plate.extend(holed_prism(
            &ngon(24, hx, hy, 5.9, 0.0),
            &ngon(24, hx, hy, 2.0, 0.0),
            0.0,
            height,
        ));
    }
    plate
}

/// Prism over a polygon ring with a same-sized polygon hole (both counter-clockwise, points
/// matched by index) between `z0` and `z1`.
pub fn holed_prism(outer: &[[f64; 2]], inner: &[[f64; 2]], z0: f64, z1: f64) -> Vec<TriMm> {
    let mut out = Vec::new();
    let n = outer.len();
    let at = |ring: &[[f64; 2]], j: usize, z: f64| [ring[j % n][0], ring[j % n][1], z];
    for j in 0..n {
        let (o0, o1, i0, i1) = (j, j + 1, j, j + 1);
        // Outer wall outward, inner wall facing the hole.
        out.push([at(outer, o0, z0), at(outer, o1, z0), at(outer, o1, z1)]);
        out.push([at(outer, o0, z0), at(outer, o1, z1), at(outer, o0, z1)]);
        out.push([at(inner, i0, z0), at(inner, i1, z1), at(inner, i1, z0)]);
        out.push([at(inner, i0, z0), at(inner, i0, z1), at(inner, i1, z1)]);
        // Caps: top faces up, bottom faces down.
        out.push([at(outer, o0, z1), at(outer, o1, z1), at(inner, i1, z1)]);
        out.push([at(outer, o0, z1), at(inner, i1, z1), at(inner, i0, z1)]);
        out.push([at(outer, o0, z0), at(inner, i1, z0), at(outer, o1, z0)]);
        out.push([at(outer, o0, z0), at(inner, i0, z0), at(inner, i1, z0)]);
    }
    out
}

/// A closed parametric surface on a `nu` x `nv` grid: `f(u, v)` with u, v in [0, 1]; u wraps,
/// v wraps too when `wrap_v` (torus) and otherwise runs pole to pole (sphere). Orientation:
/// df/du x df/dv must point outward.
pub fn grid(nu: usize, nv: usize, wrap_v: bool, f: impl Fn(f64, f64) -> [f64; 3]) -> Vec<TriMm> {
    let p = |i: usize, j: usize| f((i % nu) as f64 / nu as f64, j as f64 / nv as f64);
    let mut out = Vec::new();
    for i in 0..nu {
        for j in 0..nv {
            let jw = if wrap_v { (j + 1) % nv } else { j + 1 };
            out.push([p(i, j), p(i + 1, j), p(i + 1, jw)]);
            out.push([p(i, j), p(i + 1, jw), p(i, jw)]);
        }
    }
    out
}

/// UV sphere of radius `r` around `c` (mm).
pub fn sphere(c: [f64; 3], r: f64, nu: usize, nv: usize) -> Vec<TriMm> {
    grid(nu, nv, false, |u, v| {
        let (phi, theta) = (2.0 * PI * u, PI * v - PI / 2.0);
        // Poles exactly on the axis.
        let ring = if v == 0.0 || v == 1.0 { 0.0 } else { r * theta.cos() };
        [c[0] + ring * phi.cos(), c[1] + ring * phi.sin(), c[2] + r * theta.sin()]
    })
}

/// Torus around a vertical axis through `c`: tube radius `r` at distance `big_r`.
pub fn torus(c: [f64; 3], big_r: f64, r: f64, nu: usize, nv: usize) -> Vec<TriMm> {
    grid(nu, nv, true, |u, v| {
        let (phi, psi) = (2.0 * PI * u, 2.0 * PI * v);
        let rho = big_r + r * psi.cos();
        [c[0] + rho * phi.cos(), c[1] + rho * phi.sin(), c[2] + r * psi.sin()]
    })
}

/// The same surface with every triangle's winding reversed (normals inward).
pub fn inverted(mesh: Vec<TriMm>) -> Vec<TriMm> {
    mesh.into_iter().map(|[a, b, c]| [a, c, b]).collect()
}

fn um(mm: f64) -> i32 {
    (mm * 1000.0).round() as i32
}

/// Quantises to um (no offset), drops triangles whose corners coincide after rounding, and
/// sorts by lowest z (stable).
pub fn to_um(mesh: &[TriMm]) -> Vec<Triangle> {
    let mut out: Vec<Triangle> = mesh
        .iter()
        .map(|t| Triangle { v: t.map(|[x, y, z]| Point3::new(um(x), um(y), um(z))) })
        .filter(|t| t.v[0] != t.v[1] && t.v[1] != t.v[2] && t.v[2] != t.v[0])
        .collect();
    out.sort_by_key(Triangle::z_min);
    out
}

/// Highest z of the triangles (the placed model's top).
pub fn top(tris: &[Triangle]) -> i32 {
    tris.iter().map(Triangle::z_max).max().unwrap_or(0)
}

/// The default 0.2 mm config for these triangles, with `min_loop_area_um2` as given.
pub fn config(tris: &[Triangle], min_loop_area_um2: i64) -> SliceConfig {
    let mut c = SliceConfig::new(&PrintSettings::default(), top(tris)).unwrap();
    c.min_loop_area_um2 = min_loop_area_um2;
    c
}

/// Signed area (um^2) of the section of `tris` by plane `z`, computed independently in f64
/// without chaining: each triangle's cut segment (from its above->below edge to its
/// below->above edge) contributes its cross product (Green's theorem). Also returns the
/// summed segment length (um), a scale for rounding tolerances.
pub fn section_area_f64(tris: &[Triangle], z: f64) -> (f64, f64) {
    let (mut twice, mut length) = (0.0, 0.0);
    for t in tris {
        let v: Vec<[f64; 3]> =
            t.v.iter().map(|p| [f64::from(p.x), f64::from(p.y), f64::from(p.z)]).collect();
        let below: Vec<bool> = v.iter().map(|p| p[2] < z).collect();
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
            twice += a[0] * b[1] - b[0] * a[1];
            length += ((b[0] - a[0]).powi(2) + (b[1] - a[1]).powi(2)).sqrt();
        }
    }
    (twice / 2.0, length)
}

/// A loop copied out of a layer.
#[derive(Debug, Clone)]
pub struct OwnedLoop {
    pub points: Vec<Point2>,
    pub hole: bool,
    pub parent: Option<u32>,
    pub area_um2: i64,
}

/// A layer copied out of the sink.
#[derive(Debug, Clone)]
pub struct OwnedLayer {
    pub index: u32,
    pub z_um: i32,
    pub loops: Vec<OwnedLoop>,
    pub repairs: LayerRepairs,
    pub dropped_small_loops: u32,
    pub segments: u32,
    pub active: u32,
}

impl OwnedLayer {
    /// Sum of signed loop areas (outer minus holes), um^2.
    pub fn area_um2(&self) -> i64 {
        self.loops.iter().map(|l| l.area_um2).sum()
    }

    pub fn holes(&self) -> usize {
        self.loops.iter().filter(|l| l.hole).count()
    }
}

/// Runs a `Slicer<ACTIVE, SEGMENTS, LOOPS>` over sorted triangles on a thread with a large
/// stack (the slicer value is big in debug builds) and collects every layer.
pub fn run<const A: usize, const S: usize, const L: usize>(
    tris: &[Triangle],
    config: SliceConfig,
) -> Result<(Vec<OwnedLayer>, SliceStats), SliceError> {
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .stack_size(256 << 20)
            .spawn_scoped(scope, || {
                let mut slicer = Slicer::<A, S, L>::new(config)?;
                let mut work = Box::new(SliceScratch::new());
                let mut layers = Vec::new();
                let mut sink = |l: SlicedLayer<'_, S, SliceScratch<S>>| {
                    let l = l.layer();
                    layers.push(OwnedLayer {
                        index: l.index,
                        z_um: l.z_um,
                        loops: l
                            .loops
                            .iter()
                            .map(|info| OwnedLoop {
                                points: l.loop_points(info).to_vec(),
                                hole: info.hole,
                                parent: info.parent,
                                area_um2: info.area_um2,
                            })
                            .collect(),
                        repairs: l.repairs,
                        dropped_small_loops: l.dropped_small_loops,
                        segments: l.segments,
                        active: l.active_triangles,
                    })
                };
                for t in tris {
                    slicer.push(t, &mut *work, &mut sink)?;
                }
                let stats = slicer.finish(&mut *work, &mut sink)?;
                Ok((layers, stats))
            })
            .expect("spawn slicer thread")
            .join()
            .expect("slicer thread panicked")
    })
}

/// Default test capacities.
pub fn slice(tris: &[Triangle], config: SliceConfig) -> (Vec<OwnedLayer>, SliceStats) {
    run::<8192, 8192, 512>(tris, config).expect("slicing failed")
}

/// Parses and places an STL file like the host does (centred, dropped to z = 0), sorted.
pub fn load_placed(path: &Path, machine: &MachineConfig) -> Vec<Triangle> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut raw = Vec::new();
    let mut bounds = Bounds::EMPTY;
    strata::stl::read_all(&bytes, &mut |t| {
        bounds.include(&t);
        raw.push(t);
    })
    .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let placement = Placement::on_bed(&bounds, machine).expect("place");
    let mut tris: Vec<Triangle> = raw.iter().map(|t| placement.apply(t)).collect();
    tris.sort_by_key(Triangle::z_min);
    tris
}

/// Checks one layer against the oracle: area within 0.1 % (or 1 um x the cut length for
/// slivers), every loop oriented as its `hole` flag says, holes having a parent.
pub fn check_layer(layer: &OwnedLayer, tris: &[Triangle], what: &str) {
    check_layer_within(layer, tris, what, 0.0);
}

/// [`check_layer`] with `extra_um2` more area tolerance (for loops dropped as too small).
pub fn check_layer_within(layer: &OwnedLayer, tris: &[Triangle], what: &str, extra_um2: f64) {
    let (oracle, length) = section_area_f64(tris, f64::from(layer.z_um));
    let got = layer.area_um2() as f64;
    let tol = (oracle.abs() * 1e-3).max(length) + extra_um2;
    assert!(
        (got - oracle).abs() <= tol,
        "{what} layer {} z {}: area {got} um^2, oracle {oracle} (tol {tol})",
        layer.index,
        layer.z_um
    );
    for l in &layer.loops {
        let doubled = strata::geom::doubled_signed_area(&l.points);
        assert_eq!(doubled > 0, !l.hole, "{what} layer {}: orientation", layer.index);
        assert!(l.points.len() >= 3);
        if l.hole {
            assert!(l.parent.is_some(), "{what} layer {}: hole without parent", layer.index);
        }
    }
}

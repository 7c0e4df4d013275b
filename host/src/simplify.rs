//! Quadric error metric edge collapse held within a distance bound.
//!
//! # Model
//!
//! Garland and Heckbert's simplification (SIGGRAPH 1997) on the welded indexed mesh, in mm
//! (`f64`): every vertex carries the sum of the area-weighted plane quadrics of its original
//! faces (plus planes through boundary edges, perpendicular to their face, which keep the
//! boundary line), and the edge whose collapse costs least (the quadric at its best position)
//! goes first, from a heap with lazy invalidation (vertex versions).
//!
//! # Bound
//!
//! The quadric is not a distance, so every collapse is checked against the original surface
//! before it is done, on both sides of the two-sided Hausdorff estimate admission measures:
//! - original to simplified: each face of the simplified mesh keeps the original vertices
//!   nearest to it; every original vertex of the faces around a collapse must lie within the
//!   bound of one of the new faces there (and is reassigned to the nearest). Faces elsewhere do
//!   not change, so every original vertex stays within the bound of its face.
//! - simplified to original: every sample point of the changed faces (corners, edge midpoints,
//!   centroid, 6 interior points: those admission's measurement takes) must lie within the
//!   bound of an original triangle (an R-tree of their boxes, exact distances).
//!
//! Positions are snapped to the um grid before they are checked: the triangles given back are
//! the ones checked.
//!
//! # Guards
//!
//! Vertices on non-manifold or inconsistently wound edges, and boundary vertices where more
//! or fewer than two boundary edges meet, never move. A boundary vertex moves only along a
//! boundary edge; an interior edge between two boundary vertices is kept (it would pinch).
//! The link condition (the endpoints' common neighbours are exactly the edge's opposite
//! corners), a minimum remaining valence of 3 and no duplicate faces keep the topology (genus
//! and manifoldness). A changed face may not turn its normal by more than
//! [`Options::max_normal_turn_deg`], lose its area, or get an angle below
//! [`Options::min_angle_deg`] (or below the smallest angle around the edge before, when that
//! is smaller: a collapse may keep a sliver, not make one).
//!
//! # Slices
//!
//! What the device holds per layer is the triangles crossing a plane (`z_min < p <= z_max`),
//! about `2 L / w` for contour length `L` and triangles `w` wide along it; their count does not
//! depend on the triangles' heights. With [`Options::layers`] the simplifier counts each
//! plane's crossings as it goes and orders the heap by the quadric cost divided by
//! `1 + slice_weight * gain` (gain: crossings a collapse removes, each weighted by its plane's
//! crowding `(count / peak)^heat_power`): collapses along the contours of the crowded planes,
//! which widen their triangles, spend the bound first. The checks are the same.
//!
//! # Placement
//!
//! The quadric's minimum (the 3x3 system) when it is well conditioned and near the edge; the
//! minimum along the edge; the endpoints. The cheapest that passes every check is taken.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rstar::{RTree, RTreeObject, AABB};
use strata::geom::{Point3, Triangle};
use strata::machine::PrintSettings;
use strata::slice::SliceConfig;

/// A point or vector in mm.
pub(crate) type V = [f64; 3];

/// Options of the simplifier.
#[derive(Debug, Clone, Copy, PartialEq)]
#[non_exhaustive]
pub struct Options {
    /// Smallest angle a changed triangle may get, degrees (unless it had a smaller one).
    pub min_angle_deg: f64,
    /// Largest rotation of a changed triangle's normal in one collapse, degrees.
    pub max_normal_turn_deg: f64,
    /// Stop at this many triangles (0: only the bound stops).
    pub target_triangles: usize,
    /// The layers the mesh will be sliced at (`None`: the plain quadric order).
    pub layers: Option<Layers>,
    /// How much a collapse that removes crossings of crowded planes is preferred: its cost is
    /// divided by `1 + slice_weight * gain` (gain: crossings removed, each weighted by its
    /// plane's crowding, see [`Options::heat_power`]), one that adds some multiplied likewise.
    pub slice_weight: f64,
    /// A plane's crowding is `(crossings / peak crossings)^heat_power`: the larger, the more
    /// only the planes near the peak count.
    pub heat_power: i32,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            min_angle_deg: 2.0,
            max_normal_turn_deg: 60.0,
            target_triangles: 0,
            layers: Some(Layers::default()),
            slice_weight: SLICE_WEIGHT,
            heat_power: HEAT_POWER,
        }
    }
}

/// Layer heights, um, as the slicer takes them (`strata::slice::SliceConfig`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layers {
    /// First layer height (its plane at half of it).
    pub first_um: i32,
    /// Every further layer's height.
    pub height_um: i32,
}

impl Default for Layers {
    fn default() -> Self {
        let s = PrintSettings::default();
        Self { first_um: s.first_layer_height_um, height_um: s.layer_height_um }
    }
}

/// Default [`Options::slice_weight`].
pub const SLICE_WEIGHT: f64 = 10.0;
/// Default [`Options::heat_power`].
pub const HEAT_POWER: i32 = 8;

/// Sample points of a triangle (barycentric): corners, edge midpoints, centroid, 6 interior.
pub(crate) const BARY: [[f64; 3]; 13] = [
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

/// Weight of a boundary edge's constraint plane per mm^2 of squared edge length.
const BOUNDARY_WEIGHT: f64 = 10.0;
/// Squared cross-product length (mm^4) below which a face counts as without area.
const TINY_AREA2: f64 = 1e-18;
/// Passes over all edges per [`Simplifier::run`] (a pass retries the edges refused earlier).
const MAX_PASSES: usize = 6;

/// A symmetric 4x4 quadric `x^T A x + 2 b^T x + c`, mm^2 (times the weights).
#[derive(Debug, Clone, Copy, Default)]
struct Quadric {
    /// A as xx, xy, xz, yy, yz, zz.
    a: [f64; 6],
    b: V,
    c: f64,
}

impl Quadric {
    /// `w` times the squared distance to the plane `n . x + d = 0` (`n` unit).
    fn plane(n: V, d: f64, w: f64) -> Self {
        Self {
            a: [
                w * n[0] * n[0],
                w * n[0] * n[1],
                w * n[0] * n[2],
                w * n[1] * n[1],
                w * n[1] * n[2],
                w * n[2] * n[2],
            ],
            b: [w * n[0] * d, w * n[1] * d, w * n[2] * d],
            c: w * d * d,
        }
    }

    fn add(&mut self, o: &Self) {
        for k in 0..6 {
            self.a[k] += o.a[k];
        }
        for k in 0..3 {
            self.b[k] += o.b[k];
        }
        self.c += o.c;
    }

    /// `A x`.
    fn mul(&self, x: V) -> V {
        let a = &self.a;
        [
            a[0] * x[0] + a[1] * x[1] + a[2] * x[2],
            a[1] * x[0] + a[3] * x[1] + a[4] * x[2],
            a[2] * x[0] + a[4] * x[1] + a[5] * x[2],
        ]
    }

    fn eval(&self, x: V) -> f64 {
        (dot(x, self.mul(x)) + 2.0 * dot(self.b, x) + self.c).max(0.0)
    }

    /// The minimum (`A x = -b`, Cramer's rule), `None` when `A` is near singular.
    fn optimum(&self) -> Option<V> {
        let a = &self.a;
        let (r0, r1, r2) = ([a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]);
        let det = dot(r0, cross(r1, r2));
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // Relative to the largest entry cubed: a rank-2 quadric (a crease) is refused.
        if det.is_nan() || det.abs() <= 1e-6 * scale * scale * scale {
            return None;
        }
        let rhs = [-self.b[0], -self.b[1], -self.b[2]];
        let x = [
            dot(rhs, cross(r1, r2)) / det,
            dot(r0, cross(rhs, r2)) / det,
            dot(r0, cross(r1, rhs)) / det,
        ];
        x.iter().all(|v| v.is_finite()).then_some(x)
    }

    /// The minimum on the segment `p q`.
    fn on_segment(&self, p: V, q: V) -> V {
        let e = sub(q, p);
        let ee = dot(e, self.mul(e));
        let t = if ee > 0.0 { -(dot(p, self.mul(e)) + dot(self.b, e)) / ee } else { 0.5 };
        let t = if t.is_finite() { t.clamp(0.0, 1.0) } else { 0.5 };
        lerp(p, e, t)
    }
}

/// An original triangle (its index, corners in mm) in the R-tree by its box.
struct OrigTri(u32, [V; 3]);

impl RTreeObject for OrigTri {
    type Envelope = AABB<V>;

    fn envelope(&self) -> AABB<V> {
        let [a, b, c] = self.1;
        AABB::from_corners(
            [0, 1, 2].map(|k| a[k].min(b[k]).min(c[k])),
            [0, 1, 2].map(|k| a[k].max(b[k]).max(c[k])),
        )
    }
}

/// A candidate collapse in the heap: cheapest first, ties by vertex index.
#[derive(Debug, Clone, Copy)]
struct Entry {
    cost: f64,
    a: u32,
    b: u32,
    versions: (u32, u32),
}

impl PartialEq for Entry {
    fn eq(&self, o: &Self) -> bool {
        self.cmp(o) == Ordering::Equal
    }
}
impl Eq for Entry {}
impl PartialOrd for Entry {
    fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
        Some(self.cmp(o))
    }
}
impl Ord for Entry {
    fn cmp(&self, o: &Self) -> Ordering {
        // Reversed: the max-heap pops the cheapest.
        o.cost.total_cmp(&self.cost).then(o.a.cmp(&self.a)).then(o.b.cmp(&self.b))
    }
}

/// Figures of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Stats {
    /// Collapses done.
    pub collapses: usize,
    /// Candidates refused for the topology (non-manifold, link condition, valence).
    pub refused_topology: usize,
    /// Candidates whose every placement was refused for a shape (normal, area, angle).
    pub refused_shape: usize,
    /// Candidates whose every placement with good shapes was refused for the bound.
    pub refused_bound: usize,
}

/// A mesh being simplified (see the module docs).
pub struct Simplifier {
    pos: Vec<V>,
    orig: Vec<V>,
    quad: Vec<Quadric>,
    vfaces: Vec<Vec<u32>>,
    alive_v: Vec<bool>,
    locked: Vec<bool>,
    boundary: Vec<bool>,
    version: Vec<u32>,
    faces: Vec<[u32; 3]>,
    alive_f: Vec<bool>,
    /// Original vertices each face stands for.
    pts: Vec<Vec<u32>>,
    orig_tris: Vec<[V; 3]>,
    /// The original triangles' boxes.
    index: RTree<OrigTri>,
    bbox: (V, V),
    opts: Options,
    live: usize,
    stats: Stats,
    /// Slicing planes' heights, um, ascending (empty: the plain quadric order).
    planes: Vec<i64>,
    /// Live faces crossing each plane (`z_min < p <= z_max`, as the slicer counts them).
    crossings: Vec<u32>,
    /// The largest of `crossings`.
    peak: u32,
}

/// The faces around a collapse, as they would be.
#[derive(Default)]
struct Ring {
    /// Faces with both endpoints (removed).
    removed: Vec<u32>,
    /// Every other face with an endpoint and its corners after the collapse.
    kept: Vec<(u32, [V; 3])>,
}

impl Simplifier {
    /// A simplifier of the indexed mesh `indices` over `points` (um).
    ///
    /// Triangles with a repeated corner or an index out of range are dropped.
    pub fn new(points: &[Point3], indices: &[u32], opts: Options) -> Self {
        let pos: Vec<V> = points.iter().map(|p| mm(*p)).collect();
        let n = pos.len();
        let faces: Vec<[u32; 3]> = indices
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .filter(|f| {
                f.iter().all(|&i| (i as usize) < n) && f[0] != f[1] && f[1] != f[2] && f[0] != f[2]
            })
            .collect();
        let mut s = Self {
            orig: pos.clone(),
            quad: vec![Quadric::default(); n],
            vfaces: vec![Vec::new(); n],
            alive_v: vec![false; n],
            locked: vec![false; n],
            boundary: vec![false; n],
            version: vec![0; n],
            alive_f: vec![true; faces.len()],
            pts: vec![Vec::new(); faces.len()],
            orig_tris: faces.iter().map(|f| f.map(|i| pos[i as usize])).collect(),
            index: RTree::bulk_load(
                faces
                    .iter()
                    .enumerate()
                    .map(|(i, f)| OrigTri(i as u32, f.map(|v| pos[v as usize])))
                    .collect(),
            ),
            bbox: bbox(&pos),
            live: faces.len(),
            faces,
            pos,
            opts,
            stats: Stats::default(),
            planes: Vec::new(),
            crossings: Vec::new(),
            peak: 0,
        };
        for (fi, f) in s.faces.iter().enumerate() {
            for &v in f {
                if !s.alive_v[v as usize] {
                    s.alive_v[v as usize] = true;
                    s.pts[fi].push(v);
                }
                s.vfaces[v as usize].push(fi as u32);
            }
            let [a, b, c] = f.map(|i| s.pos[i as usize]);
            let nrm = cross(sub(b, a), sub(c, a));
            let len = dot(nrm, nrm).sqrt();
            if len > 0.0 {
                let u = nrm.map(|x| x / len);
                let q = Quadric::plane(u, -dot(u, a), len / 2.0);
                for &v in f {
                    s.quad[v as usize].add(&q);
                }
            }
        }
        s.mark_edges();
        if let Some(layers) = opts.layers {
            s.set_planes(planes_um(points, layers));
        }
        s
    }

    /// Counts the crossings of `planes` (um, ascending) and prefers collapses that lower the
    /// crowded ones from now on.
    pub fn set_planes(&mut self, planes: Vec<i64>) {
        self.planes = planes;
        self.crossings = vec![0; self.planes.len()];
        for f in 0..self.faces.len() {
            if self.alive_f[f] {
                let (a, b) = self.span(&self.corners(f as u32));
                for k in a..b {
                    self.crossings[k] += 1;
                }
            }
        }
        self.peak = self.crossings.iter().copied().max().unwrap_or(0);
    }

    /// The most faces crossing one plane (0 without planes).
    pub fn peak_crossings(&self) -> u32 {
        self.peak
    }

    /// Live faces crossing each plane.
    pub fn crossings(&self) -> &[u32] {
        &self.crossings
    }

    fn corners(&self, f: u32) -> [V; 3] {
        self.faces[f as usize].map(|v| self.pos[v as usize])
    }

    /// The planes `first..after` a face with corners `c` (mm) crosses: `z_min < p <= z_max`.
    fn span(&self, c: &[V; 3]) -> (usize, usize) {
        let z = c.map(|p| (p[2] * 1e3).round() as i64);
        let (lo, hi) = (z[0].min(z[1]).min(z[2]), z[0].max(z[1]).max(z[2]));
        (self.planes.partition_point(|&p| p <= lo), self.planes.partition_point(|&p| p <= hi))
    }

    /// Crossings the collapse `ring` removes (negative: adds), each weighted by its plane's
    /// crowding `(crossings / peak)^heat_power`.
    fn slice_gain(&self, ring: &Ring) -> f64 {
        if self.peak == 0 {
            return 0.0;
        }
        let peak = f64::from(self.peak);
        let heat = |(a, b): (usize, usize)| -> f64 {
            (a..b).map(|k| (f64::from(self.crossings[k]) / peak).powi(self.opts.heat_power)).sum()
        };
        let removed: f64 = ring.removed.iter().map(|&f| heat(self.span(&self.corners(f)))).sum();
        let changed: f64 = ring
            .kept
            .iter()
            .map(|(f, new)| heat(self.span(&self.corners(*f))) - heat(self.span(new)))
            .sum();
        removed + changed
    }

    /// Moves the crossing counts from the faces of `ring` as they are to as they will be.
    fn recount(&mut self, ring: &Ring) {
        if self.planes.is_empty() {
            return;
        }
        let mut lowered_peak = false;
        let old = ring.removed.iter().chain(ring.kept.iter().map(|(f, _)| f));
        let spans: Vec<(usize, usize)> = old.map(|&f| self.span(&self.corners(f))).collect();
        for (a, b) in spans {
            for k in a..b {
                lowered_peak |= self.crossings[k] == self.peak;
                self.crossings[k] -= 1;
            }
        }
        for (_, new) in &ring.kept {
            let (a, b) = self.span(new);
            for k in a..b {
                self.crossings[k] += 1;
                self.peak = self.peak.max(self.crossings[k]);
            }
        }
        if lowered_peak {
            self.peak = self.crossings.iter().copied().max().unwrap_or(0);
        }
    }

    /// Marks boundary and locked vertices and adds the boundary planes.
    fn mark_edges(&mut self) {
        // (low, high, wound low to high) per face edge, sorted: equal edges adjacent.
        let mut edges: Vec<(u32, u32, bool, u32)> = Vec::with_capacity(self.faces.len() * 3);
        for (fi, f) in self.faces.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (f[k], f[(k + 1) % 3]);
                edges.push((a.min(b), a.max(b), a < b, fi as u32));
            }
        }
        edges.sort_unstable();
        let mut boundary_edges = vec![0u32; self.pos.len()];
        let mut i = 0;
        while i < edges.len() {
            let mut j = i + 1;
            while j < edges.len() && edges[j].0 == edges[i].0 && edges[j].1 == edges[i].1 {
                j += 1;
            }
            let (a, b) = (edges[i].0 as usize, edges[i].1 as usize);
            match j - i {
                1 => {
                    boundary_edges[a] += 1;
                    boundary_edges[b] += 1;
                    let f = self.faces[edges[i].3 as usize].map(|v| self.pos[v as usize]);
                    let nrm = cross(sub(f[1], f[0]), sub(f[2], f[0]));
                    let e = sub(self.pos[b], self.pos[a]);
                    let m = cross(e, nrm);
                    let len = dot(m, m).sqrt();
                    if len > 0.0 {
                        let u = m.map(|x| x / len);
                        let w = BOUNDARY_WEIGHT * dot(e, e);
                        let q = Quadric::plane(u, -dot(u, self.pos[a]), w);
                        self.quad[a].add(&q);
                        self.quad[b].add(&q);
                    }
                }
                // Wound once each way: a manifold interior edge.
                2 if edges[i].2 != edges[i + 1].2 => {}
                _ => {
                    self.locked[a] = true;
                    self.locked[b] = true;
                }
            }
            i = j;
        }
        for (v, &n) in boundary_edges.iter().enumerate() {
            self.boundary[v] = n > 0;
            if n != 0 && n != 2 {
                self.locked[v] = true;
            }
        }
    }

    /// Triangles now.
    pub fn triangle_count(&self) -> usize {
        self.live
    }

    /// Figures so far.
    pub fn stats(&self) -> Stats {
        self.stats
    }

    /// Collapses edges while every result stays within `bound_mm` of the original surface
    /// (and above [`Options::target_triangles`]); can be called again with a larger bound.
    pub fn run(&mut self, bound_mm: f64) {
        if bound_mm.is_nan() || bound_mm < 0.0 {
            return;
        }
        for _ in 0..MAX_PASSES {
            let mut heap = BinaryHeap::new();
            for v in 0..self.pos.len() as u32 {
                if self.alive_v[v as usize] {
                    for w in self.neighbours(v) {
                        if v < w {
                            self.push(&mut heap, v, w);
                        }
                    }
                }
            }
            let before = self.stats.collapses;
            while let Some(e) = heap.pop() {
                if self.live <= self.opts.target_triangles {
                    return;
                }
                let (a, b) = (e.a as usize, e.b as usize);
                if !self.alive_v[a]
                    || !self.alive_v[b]
                    || e.versions != (self.version[a], self.version[b])
                {
                    continue;
                }
                if let Some(v) = self.try_collapse(e.a, e.b, bound_mm) {
                    self.stats.collapses += 1;
                    for w in self.neighbours(v) {
                        self.push(&mut heap, v.min(w), v.max(w));
                    }
                }
            }
            if self.stats.collapses == before {
                break;
            }
        }
    }

    /// The triangles (um), in face order.
    pub fn triangles(&self) -> Vec<Triangle> {
        (0..self.faces.len())
            .filter(|&f| self.alive_f[f])
            .map(|f| Triangle { v: self.faces[f].map(|v| um(self.pos[v as usize])) })
            .collect()
    }

    /// The vertices sharing a live face with `v`, sorted.
    fn neighbours(&self, v: u32) -> Vec<u32> {
        let mut out: Vec<u32> = self.vfaces[v as usize]
            .iter()
            .flat_map(|&f| self.faces[f as usize])
            .filter(|&w| w != v)
            .collect();
        out.sort_unstable();
        out.dedup();
        out
    }

    fn push(&self, heap: &mut BinaryHeap<Entry>, a: u32, b: u32) {
        let Some((keep, _)) = self.direction(a, b) else {
            return;
        };
        let gone = a ^ b ^ keep;
        let Some(&(cost, p)) = self.placements(keep, gone).first() else {
            return;
        };
        let w = self.opts.slice_weight;
        let cost = if self.peak > 0 && w > 0.0 {
            let gain = self.slice_gain(&self.ring(keep, gone, p));
            if gain >= 0.0 {
                cost / (1.0 + w * gain)
            } else {
                cost * (1.0 - w * gain)
            }
        } else {
            cost
        };
        heap.push(Entry {
            cost,
            a,
            b,
            versions: (self.version[a as usize], self.version[b as usize]),
        });
    }

    /// Which end of `a b` stays (the other is removed), and whether the kept one may move;
    /// `None` when the edge may not collapse.
    fn direction(&self, a: u32, b: u32) -> Option<(u32, bool)> {
        let (ai, bi) = (a as usize, b as usize);
        let fixed = |i: usize| self.locked[i] || self.boundary[i];
        match (self.locked[ai], self.locked[bi]) {
            (true, true) => None,
            (true, false) => Some((a, false)),
            (false, true) => Some((b, false)),
            _ => match (fixed(ai), fixed(bi)) {
                (true, false) => Some((a, false)),
                (false, true) => Some((b, false)),
                // Both on the boundary: only along a boundary edge (checked when collapsing).
                _ => Some((b, true)),
            },
        }
    }

    /// Placements of the merged vertex (snapped to um, in the model's box) with their
    /// quadric costs, cheapest first.
    fn placements(&self, keep: u32, gone: u32) -> Vec<(f64, V)> {
        let (k, g) = (keep as usize, gone as usize);
        let mut q = self.quad[k];
        q.add(&self.quad[g]);
        let Some((_, free)) = self.direction(keep.min(gone), keep.max(gone)) else {
            return Vec::new();
        };
        let mut cands = vec![self.pos[k]];
        if free {
            let (p, r) = (self.pos[k], self.pos[g]);
            let e = sub(r, p);
            let mid = lerp(p, e, 0.5);
            if let Some(x) = q.optimum() {
                // Near the edge only: a far minimum is a flat quadric's artefact.
                let d = sub(x, mid);
                if dot(d, d) <= dot(e, e) {
                    cands.push(x);
                }
            }
            cands.push(q.on_segment(p, r));
            cands.push(r);
        }
        let mut out: Vec<(f64, V)> = cands
            .into_iter()
            .map(|x| self.snap(x))
            .map(|x| (q.eval(x), x))
            .filter(|(c, _)| c.is_finite())
            .collect();
        out.sort_by(|x, y| x.0.total_cmp(&y.0));
        out.dedup_by(|x, y| x.1 == y.1);
        out
    }

    /// `x` on the um grid, inside the original model's box.
    fn snap(&self, x: V) -> V {
        let (lo, hi) = self.bbox;
        [0, 1, 2].map(|k| ((x[k] * 1e3).round() / 1e3).clamp(lo[k], hi[k]))
    }

    /// Collapses `a b` if a placement passes every check; the kept vertex.
    fn try_collapse(&mut self, a: u32, b: u32, bound: f64) -> Option<u32> {
        let (keep, _) = self.direction(a, b)?;
        let gone = a ^ b ^ keep;
        if !self.topology_ok(keep, gone) {
            self.stats.refused_topology += 1;
            return None;
        }
        let mut shaped = false;
        for (_, p) in self.placements(keep, gone) {
            let ring = self.ring(keep, gone, p);
            if self.shapes_ok(&ring, keep, gone, p) {
                shaped = true;
                if self.within(&ring, bound) {
                    self.commit(keep, gone, p, &ring);
                    return Some(keep);
                }
            }
        }
        if shaped {
            self.stats.refused_bound += 1;
        } else {
            self.stats.refused_shape += 1;
        }
        None
    }

    /// Manifold edge, boundary rules, link condition, valence, no duplicate face.
    fn topology_ok(&self, keep: u32, gone: u32) -> bool {
        let (k, g) = (keep as usize, gone as usize);
        // Faces with both ends: 1 on a boundary edge, 2 inside; else non-manifold.
        let shared: Vec<u32> = self.vfaces[g]
            .iter()
            .copied()
            .filter(|&f| self.faces[f as usize].contains(&keep))
            .collect();
        let boundary_edge = match shared.len() {
            1 => true,
            2 => false,
            _ => return false,
        };
        if self.boundary[k] && self.boundary[g] && !boundary_edge {
            return false;
        }
        if boundary_edge && !(self.boundary[k] && self.boundary[g]) {
            return false;
        }
        // Link condition: the common neighbours are the opposite corners.
        let (nk, ng) = (self.neighbours(keep), self.neighbours(gone));
        let mut opposite: Vec<u32> = shared
            .iter()
            .flat_map(|&f| self.faces[f as usize])
            .filter(|&w| w != keep && w != gone)
            .collect();
        opposite.sort_unstable();
        let common: Vec<u32> = nk.iter().copied().filter(|w| ng.binary_search(w).is_ok()).collect();
        if common != opposite {
            return false;
        }
        // Valence left to the kept vertex.
        if nk.len() + ng.len() - common.len() - 2 < 3 {
            return false;
        }
        !self.duplicates_a_face(keep, gone)
    }

    /// A face of `gone` (without `keep`) would become one `keep` has already.
    fn duplicates_a_face(&self, keep: u32, gone: u32) -> bool {
        let sorted = |mut f: [u32; 3]| {
            f.sort_unstable();
            f
        };
        let have: Vec<[u32; 3]> =
            self.vfaces[keep as usize].iter().map(|&f| sorted(self.faces[f as usize])).collect();
        self.vfaces[gone as usize].iter().any(|&f| {
            let f = self.faces[f as usize];
            !f.contains(&keep)
                && have.contains(&sorted(f.map(|v| if v == gone { keep } else { v })))
        })
    }

    fn ring(&self, keep: u32, gone: u32, p: V) -> Ring {
        let mut ring = Ring::default();
        let mut ids: Vec<u32> =
            self.vfaces[gone as usize].iter().chain(&self.vfaces[keep as usize]).copied().collect();
        ids.sort_unstable();
        ids.dedup();
        for f in ids {
            let face = self.faces[f as usize];
            if face.contains(&keep) && face.contains(&gone) {
                ring.removed.push(f);
            } else {
                let corners =
                    face.map(|v| if v == keep || v == gone { p } else { self.pos[v as usize] });
                ring.kept.push((f, corners));
            }
        }
        ring
    }

    /// Normals, areas and angles of the changed faces.
    fn shapes_ok(&self, ring: &Ring, keep: u32, gone: u32, p: V) -> bool {
        let cos_turn = self.opts.max_normal_turn_deg.to_radians().cos();
        let moved = p != self.pos[keep as usize];
        let corners = |f: u32| self.faces[f as usize].map(|v| self.pos[v as usize]);
        // The worst angle around before: a collapse may keep a sliver, not make a new one.
        let worst = ring
            .removed
            .iter()
            .chain(ring.kept.iter().map(|(f, _)| f))
            .map(|&f| min_sine(corners(f)))
            .fold(self.opts.min_angle_deg.to_radians().sin(), f64::min);
        ring.kept.iter().all(|(f, new)| {
            if !moved && !self.faces[*f as usize].contains(&gone) {
                return true;
            }
            let (n0, n1) = (normal(corners(*f)), normal(*new));
            let (l0, l1) = (dot(n0, n0), dot(n1, n1));
            if l1 <= TINY_AREA2 {
                return false;
            }
            if l0 > TINY_AREA2 && dot(n0, n1) < cos_turn * (l0 * l1).sqrt() {
                return false;
            }
            min_sine(*new) >= worst
        })
    }

    /// Both sides of the bound (module docs).
    fn within(&self, ring: &Ring, bound: f64) -> bool {
        let b2 = bound * bound;
        let all = || ring.removed.iter().chain(ring.kept.iter().map(|(f, _)| f));
        // Original vertices: their own face first, then any face around.
        for &f in all() {
            let own = ring.kept.iter().find(|(g, _)| *g == f).map(|(_, c)| c);
            for &q in &self.pts[f as usize] {
                let x = self.orig[q as usize];
                let near = |c: &[V; 3]| dist2_point_triangle(x, c[0], c[1], c[2]) <= b2;
                if own.is_some_and(near) {
                    continue;
                }
                if !ring.kept.iter().any(|(_, c)| near(c)) {
                    return false;
                }
            }
        }
        // Samples of the changed faces: the original triangle the last one was near first,
        // then those whose boxes come within the bound.
        let mut last = None;
        for (f, c) in &ring.kept {
            if self.faces[*f as usize].map(|v| self.pos[v as usize]) == *c {
                continue;
            }
            for w in BARY {
                let s = [0, 1, 2].map(|k| w[0] * c[0][k] + w[1] * c[1][k] + w[2] * c[2][k]);
                let near = |t: &OrigTri| {
                    let o = &self.orig_tris[t.0 as usize];
                    dist2_point_triangle(s, o[0], o[1], o[2]) <= b2
                };
                if last.is_some_and(near) {
                    continue;
                }
                let reach = AABB::from_corners(s.map(|x| x - bound), s.map(|x| x + bound));
                match self.index.locate_in_envelope_intersecting(&reach).find(|t| near(t)) {
                    Some(t) => last = Some(t),
                    None => return false,
                }
            }
        }
        true
    }

    fn commit(&mut self, keep: u32, gone: u32, p: V, ring: &Ring) {
        self.recount(ring);
        let (k, g) = (keep as usize, gone as usize);
        let mut pts = Vec::new();
        for &f in ring.removed.iter().chain(ring.kept.iter().map(|(f, _)| f)) {
            pts.append(&mut self.pts[f as usize]);
        }
        for &f in &ring.removed {
            self.alive_f[f as usize] = false;
            self.live -= 1;
            for v in self.faces[f as usize] {
                self.vfaces[v as usize].retain(|&x| x != f);
            }
        }
        for &f in &self.vfaces[g].clone() {
            for v in &mut self.faces[f as usize] {
                if *v == gone {
                    *v = keep;
                }
            }
            self.vfaces[k].push(f);
        }
        self.vfaces[g].clear();
        self.alive_v[g] = false;
        let q = self.quad[g];
        self.quad[k].add(&q);
        self.pos[k] = p;
        self.version[k] = self.version[k].wrapping_add(1);
        // Each original vertex to the nearest face around.
        let nearest = |x: V| {
            ring.kept
                .iter()
                .map(|(f, c)| (dist2_point_triangle(x, c[0], c[1], c[2]), *f))
                .min_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)))
                .map(|(_, f)| f as usize)
        };
        for q in pts {
            if let Some(f) = nearest(self.orig[q as usize]) {
                self.pts[f].push(q);
            }
        }
    }
}

/// Simplifies `tris` (welded on bit-identical corners) within `bound_mm`.
pub fn simplify(tris: &[Triangle], bound_mm: f64, opts: Options) -> Vec<Triangle> {
    let (points, indices) = weld(tris);
    let mut s = Simplifier::new(&points, &indices, opts);
    s.run(bound_mm);
    s.triangles()
}

/// The distinct corners of `tris` (first seen first) and three indices per triangle.
pub fn weld(tris: &[Triangle]) -> (Vec<Point3>, Vec<u32>) {
    let mut map = std::collections::HashMap::new();
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
    (points, indices)
}

/// The slicing planes' heights (um) of a mesh over `points` sliced at `layers`: those strictly
/// below its top, as `SliceConfig::plane_z_um` places them.
pub fn planes_um(points: &[Point3], layers: Layers) -> Vec<i64> {
    let top = points.iter().map(|p| p.z).max().unwrap_or(0);
    let mut settings = PrintSettings::default();
    settings.first_layer_height_um = layers.first_um;
    settings.layer_height_um = layers.height_um;
    match SliceConfig::new(&settings, top.max(0)) {
        Ok(c) => (0..c.layer_count()).map(|k| c.plane_z_um(k)).collect(),
        Err(_) => Vec::new(),
    }
}

fn bbox(pos: &[V]) -> (V, V) {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in pos {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    if pos.is_empty() {
        ([0.0; 3], [0.0; 3])
    } else {
        (lo, hi)
    }
}

fn sub(a: V, b: V) -> V {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: V, b: V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: V, b: V) -> V {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn lerp(o: V, d: V, t: f64) -> V {
    [o[0] + d[0] * t, o[1] + d[1] * t, o[2] + d[2] * t]
}
fn normal(c: [V; 3]) -> V {
    cross(sub(c[1], c[0]), sub(c[2], c[0]))
}
/// `p` in mm.
pub(crate) fn mm(p: Point3) -> V {
    [p.x as f64 / 1e3, p.y as f64 / 1e3, p.z as f64 / 1e3]
}
fn um(x: V) -> Point3 {
    let c = |v: f64| (v * 1e3).round() as i32;
    Point3::new(c(x[0]), c(x[1]), c(x[2]))
}

/// Sine of a triangle's smallest angle (0 for a degenerate one).
///
/// The smallest angle is opposite the shortest edge: `|n| = b c sin(angle)` with `b`, `c` the
/// two longer edges.
fn min_sine(c: [V; 3]) -> f64 {
    let n = normal(c);
    let mut l = [0, 1, 2].map(|k| {
        let e = sub(c[(k + 1) % 3], c[k]);
        dot(e, e)
    });
    l.sort_by(f64::total_cmp);
    let den = (l[1] * l[2]).sqrt();
    if den > 0.0 {
        dot(n, n).sqrt() / den
    } else {
        0.0
    }
}

/// Squared distance from `p` to the segment `a b`.
fn dist2_point_segment(p: V, a: V, b: V) -> f64 {
    let e = sub(b, a);
    let ee = dot(e, e);
    let t = if ee > 0.0 { (dot(sub(p, a), e) / ee).clamp(0.0, 1.0) } else { 0.0 };
    let d = sub(p, lerp(a, e, t));
    dot(d, d)
}

/// Squared distance from `p` to triangle `abc` (Voronoi regions of the corners and edges,
/// else the plane; a triangle without area by its edges).
pub(crate) fn dist2_point_triangle(p: V, a: V, b: V, c: V) -> f64 {
    let (ab, ac, ap) = (sub(b, a), sub(c, a), sub(p, a));
    let (d1, d2) = (dot(ab, ap), dot(ac, ap));
    let at = |q: V| {
        let d = sub(p, q);
        dot(d, d)
    };
    if d1 <= 0.0 && d2 <= 0.0 {
        return at(a);
    }
    let bp = sub(p, b);
    let (d3, d4) = (dot(ab, bp), dot(ac, bp));
    if d3 >= 0.0 && d4 <= d3 {
        return at(b);
    }
    let cp = sub(p, c);
    let (d5, d6) = (dot(ab, cp), dot(ac, cp));
    if d6 >= 0.0 && d5 <= d6 {
        return at(c);
    }
    let (vc, vb, va) = (d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4);
    let sum = va + vb + vc;
    let edges = || {
        dist2_point_segment(p, a, b)
            .min(dist2_point_segment(p, b, c))
            .min(dist2_point_segment(p, c, a))
    };
    if sum.is_nan() || sum <= 0.0 || vc <= 0.0 || vb <= 0.0 || va <= 0.0 {
        return edges();
    }
    let (v, w) = (vb / sum, vc / sum);
    at([a[0] + ab[0] * v + ac[0] * w, a[1] + ab[1] * v + ac[1] * w, a[2] + ab[2] * v + ac[2] * w])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn three_planes_meet_at_the_quadric_optimum() {
        let mut q = Quadric::default();
        // x = 1, y = 2, z = 3.
        for (n, d) in [([1.0, 0.0, 0.0], -1.0), ([0.0, 1.0, 0.0], -2.0), ([0.0, 0.0, 1.0], -3.0)] {
            q.add(&Quadric::plane(n, d, 1.0));
        }
        let x = q.optimum().unwrap();
        assert!(x.iter().zip([1.0, 2.0, 3.0]).all(|(a, b)| (a - b).abs() < 1e-12), "{x:?}");
        assert!(q.eval(x) < 1e-12);
        assert!((q.eval([2.0, 2.0, 3.0]) - 1.0).abs() < 1e-12);
        // Two planes: a line of minima, no single optimum; along a segment across it.
        let mut crease = Quadric::plane([1.0, 0.0, 0.0], -1.0, 1.0);
        crease.add(&Quadric::plane([0.0, 1.0, 0.0], 0.0, 1.0));
        assert!(crease.optimum().is_none());
        let m = crease.on_segment([0.0, 0.0, 5.0], [2.0, 0.0, 5.0]);
        assert!((m[0] - 1.0).abs() < 1e-12 && m[2] == 5.0, "{m:?}");
    }

    #[test]
    fn distances_to_degenerate_triangles_are_their_edges() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]);
        assert!((dist2_point_triangle([1.5, 1.0, 0.0], a, b, c) - 1.0).abs() < 1e-12);
        assert!((dist2_point_triangle([3.0, 0.0, 0.0], a, a, a) - 9.0).abs() < 1e-12);
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        assert!((dist2_point_triangle([0.2, 0.2, 0.5], a, b, c) - 0.25).abs() < 1e-12);
        assert!((dist2_point_triangle([1.0, 1.0, 0.0], a, b, c) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn the_smallest_angle_of_a_right_isosceles_triangle_is_45_degrees() {
        let s = min_sine([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
        assert!((s - 45f64.to_radians().sin()).abs() < 1e-12);
        assert_eq!(min_sine([[0.0; 3]; 3]), 0.0);
    }

    #[test]
    fn a_bent_sheet_keeps_its_crease_within_the_bound() {
        // Two 10 x 10 mm squares of 1 mm cells meeting at a right angle along x = 10 (um).
        let mut tris = Vec::new();
        let p = |x: i32, y: i32, z: i32| Point3::new(x * 1000, y * 1000, z * 1000);
        for i in 0..10 {
            for j in 0..10 {
                let (a, b, c, d) = (p(i, j, 0), p(i + 1, j, 0), p(i + 1, j + 1, 0), p(i, j + 1, 0));
                tris.push(Triangle { v: [a, b, c] });
                tris.push(Triangle { v: [a, c, d] });
                let (a, b, c, d) =
                    (p(10, j, i), p(10, j + 1, i), p(10, j + 1, i + 1), p(10, j, i + 1));
                // Wound the other way: the crease edge runs once each way.
                tris.push(Triangle { v: [a, c, b] });
                tris.push(Triangle { v: [a, d, c] });
            }
        }
        let out = simplify(&tris, 0.01, Options::default());
        assert!(out.len() <= 8, "{} triangles", out.len());
        // Every corner stays on one of the two planes, inside the squares.
        for t in &out {
            for q in t.v {
                assert!(q.z == 0 || q.x == 10_000, "{q:?}");
                assert!((0..=10_000).contains(&q.x) && (0..=10_000).contains(&q.z), "{q:?}");
            }
        }
    }
}

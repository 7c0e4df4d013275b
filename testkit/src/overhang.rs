//! Extrusion over air: how much of a print's extrusion has nothing under it.
//!
//! An independent instrument for bridges and supports: plain `f64` geometry that reads only the
//! extrusion segments of a print (start, end, line width, feature), grouped by layer, whoever
//! produced them (the core's toolpath stage, or another slicer's G-code through
//! [`layers_from_gcode`]). Coordinates are um.
//!
//! ## Model
//!
//! A point of a layer's extrusion is *supported* when it lies within `w / 2 + h tan 50°` of some
//! extrusion centre line of the layer below (`w`: the extrusion's own line width, `h`: the
//! layer's height above the layer below, [`SUPPORT_ANGLE_DEG`]); otherwise it is *over air*.
//! The first layer sits on the bed and is never over air. Support extrusions ([`is_support`])
//! hold across the air gap a support leaves under the part ([`CONTACT_GAP_UM`]): those of the
//! layers up to that far under the layer below count as the layer below's. The layer below of
//! a part extrusion is the highest lower layer with part extrusions, that of a support
//! extrusion the highest with support extrusions (other slicers' supports may have heights
//! of their own); the layers between count too.
//!
//! ## Exact lengths
//!
//! The points of a segment within distance `r` of another segment are the segment cut by a
//! capsule, a convex set: one interval of the segment's parameter (the hull of its cuts by the
//! capsule's two discs and its slab). A segment's supported length is the measure of the union
//! of these intervals over the segments of the layer below that a uniform grid
//! ([`GRID_CELL_UM`]) puts near it; its over-air length is the rest.
//!
//! ## Anchored bridges and true air
//!
//! A *run* is a maximal chain of consecutive bridge segments ([`BRIDGE`], or
//! [`OVERHANG_PERIMETER`]: PrusaSlicer's perimeters printed as bridges) of one path (each
//! starts where the one before ends, [`JOIN_UM`]) that stays straight (within
//! [`RUN_TURN_DEG`] of its first segment's direction); any other segment is a run by itself.
//! The over-air length of a bridge run between its first and its last supported point is an
//! *anchored bridge* (all of it when both ends are supported); the stretches beyond them
//! hang from one side only.
//!
//! Sparse infill ([`SPARSE`]) and supports ([`is_support`]) cross the lines of the layer
//! below and span the gaps between them by design: their over-air length is counted apart. All
//! other over-air length is *true air*.

use std::fmt::Write as _;

/// The `;TYPE:` name of bridge extrusions (PrusaSlicer's role name).
pub const BRIDGE: &str = "Bridge infill";

/// The `;TYPE:` name of perimeters printed with bridge settings (PrusaSlicer's role name).
pub const OVERHANG_PERIMETER: &str = "Overhang perimeter";

/// The `;TYPE:` name of sparse infill (PrusaSlicer's role name).
pub const SPARSE: &str = "Internal infill";

/// Steepest overhang printed without support, degrees from vertical: a layer may reach
/// `h tan 50°` (1.19 h) beyond the edge of the line below it.
pub const SUPPORT_ANGLE_DEG: f64 = 50.0;

/// How far under a layer's layer below a support's top may be and still hold the layer, um.
///
/// PrusaSlicer's default contact distance, 0.2 mm, under a first layer printed as a bridge
/// 0.4 mm thick (its nozzle's diameter): 0.2 mm more than under a 0.2 mm layer.
pub const CONTACT_GAP_UM: f64 = 400.0;

/// Heights closer than this are the same, um.
const Z_TOLERANCE_UM: f64 = 1.0;

/// Largest turn from a run's first direction that keeps a bridge run going, degrees.
pub const RUN_TURN_DEG: f64 = 15.0;

/// Largest gap between one segment's end and the next one's start within a path, um.
pub const JOIN_UM: f64 = 1.0;

/// Side of the grid cells that index the layer below, um (about twice the support distance
/// of a 0.45 mm line at 0.2 mm layers, 0.46 mm).
pub const GRID_CELL_UM: f64 = 1000.0;

/// One extrusion segment a-b (um).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extrusion {
    /// Start, um.
    pub a: (f64, f64),
    /// End, um.
    pub b: (f64, f64),
    /// Line width, um.
    pub width_um: f64,
    /// Feature name (PrusaSlicer's `;TYPE:` names).
    pub feature: &'static str,
    /// A bridge line (feature [`BRIDGE`] or [`OVERHANG_PERIMETER`] for [`Extrusion::new`]).
    pub bridge: bool,
}

impl Extrusion {
    /// The segment a-b of `feature`, a bridge when the feature is [`BRIDGE`] or
    /// [`OVERHANG_PERIMETER`].
    pub fn new(a: (f64, f64), b: (f64, f64), width_um: f64, feature: &'static str) -> Self {
        let bridge = feature == BRIDGE || feature == OVERHANG_PERIMETER;
        Self { a, b, width_um, feature, bridge }
    }

    /// Length, um.
    pub fn length(&self) -> f64 {
        (self.b.0 - self.a.0).hypot(self.b.1 - self.a.1)
    }
}

/// One layer's extrusions in print order, at height `z_um` (um).
#[derive(Debug, Clone, Default)]
pub struct Layer {
    /// Height of the layer (its top), um.
    pub z_um: f64,
    /// The extrusions, in print order.
    pub extrusions: Vec<Extrusion>,
}

/// Head of the markdown table of [`OverAir::row`]s (two lines).
pub const TABLE_HEAD: &str =
    "| part | extruded mm | anchored bridge % | sparse/support % | true air % |\n\
                              |---|---:|---:|---:|---:|";

/// The segment of a layer with the most true air.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Offender {
    /// The segment.
    pub extrusion: Extrusion,
    /// Its true-air length, mm.
    pub air_mm: f64,
}

/// One layer's figures.
#[derive(Debug, Clone)]
pub struct LayerAir {
    /// Index in the input.
    pub index: usize,
    /// Height, um.
    pub z_um: f64,
    /// Extruded length, mm.
    pub extruded_mm: f64,
    /// Over-air length in anchored bridge runs, mm.
    pub anchored_bridge_mm: f64,
    /// Over-air length of sparse infill and supports, mm.
    pub sparse_support_mm: f64,
    /// Other over-air length, mm.
    pub true_air_mm: f64,
    /// The segment with the most true air, if any.
    pub worst: Option<Offender>,
}

/// What [`over_air`] measured.
#[derive(Debug, Clone, Default)]
pub struct OverAir {
    /// Extruded length, mm.
    pub extruded_mm: f64,
    /// Over-air length in anchored bridge runs, mm.
    pub anchored_bridge_mm: f64,
    /// Over-air length of sparse infill and supports, mm.
    pub sparse_support_mm: f64,
    /// Other over-air length, mm.
    pub true_air_mm: f64,
    /// True air per feature, mm, in order of first appearance.
    pub true_air_by_feature: Vec<(&'static str, f64)>,
    /// Per layer, in input order.
    pub layers: Vec<LayerAir>,
}

impl OverAir {
    /// Anchored bridge length, percent of the extruded length.
    pub fn anchored_bridge_percent(&self) -> f64 {
        percent(self.anchored_bridge_mm, self.extruded_mm)
    }

    /// A markdown row under [`TABLE_HEAD`]: `name`, extruded mm, then anchored bridge, sparse
    /// infill and supports, and true air in percent of it.
    pub fn row(&self, name: &str) -> String {
        format!(
            "| {name} | {:.1} | {:.2} | {:.2} | {:.2} |",
            self.extruded_mm,
            self.anchored_bridge_percent(),
            self.sparse_support_percent(),
            self.true_air_percent()
        )
    }

    /// Sparse infill and supports over air, percent of the extruded length.
    pub fn sparse_support_percent(&self) -> f64 {
        percent(self.sparse_support_mm, self.extruded_mm)
    }

    /// True air, percent of the extruded length.
    pub fn true_air_percent(&self) -> f64 {
        percent(self.true_air_mm, self.extruded_mm)
    }

    /// True air of `feature`, mm.
    pub fn true_air_of(&self, feature: &str) -> f64 {
        self.true_air_by_feature.iter().filter(|(f, _)| *f == feature).map(|(_, mm)| mm).sum()
    }

    /// The `n` layers with the most true air, most first, in words (one line each) with the
    /// true air per feature, for assertion messages.
    pub fn describe_worst(&self, n: usize) -> String {
        let mut layers: Vec<&LayerAir> =
            self.layers.iter().filter(|l| l.true_air_mm > 0.0).collect();
        layers.sort_by(|x, y| y.true_air_mm.total_cmp(&x.true_air_mm));
        let mut out = String::new();
        for (f, mm) in &self.true_air_by_feature {
            let _ = write!(out, "{f}: {mm:.1} mm; ");
        }
        for l in layers.into_iter().take(n) {
            let _ = write!(
                out,
                "\n  layer {} z {:.0} um: {:.1} mm true air, {:.1} mm anchored",
                l.index, l.z_um, l.true_air_mm, l.anchored_bridge_mm
            );
            if let Some(w) = l.worst {
                let e = w.extrusion;
                let _ = write!(
                    out,
                    "; worst {} ({:.0}, {:.0})-({:.0}, {:.0}) {:.2} mm",
                    e.feature, e.a.0, e.a.1, e.b.0, e.b.1, w.air_mm
                );
            }
        }
        out
    }
}

fn percent(part: f64, whole: f64) -> f64 {
    if whole > 0.0 {
        100.0 * part / whole
    } else {
        0.0
    }
}

/// Measures the extrusion over air of a print, layers bottom first (the first on the bed).
pub fn over_air(layers: &[Layer]) -> OverAir {
    let segs: Vec<Vec<Extrusion>> = layers
        .iter()
        .map(|l| l.extrusions.iter().copied().filter(|e| e.length() > 0.0).collect())
        .collect();
    let mut out = OverAir::default();
    for (index, layer) in layers.iter().enumerate() {
        let holds = [false, true].map(|support| holding(layers, &segs, index, support));
        let la =
            measure_layer(index, layer.z_um, &segs[index], &holds, &mut out.true_air_by_feature);
        out.extruded_mm += la.extruded_mm;
        out.anchored_bridge_mm += la.anchored_bridge_mm;
        out.sparse_support_mm += la.sparse_support_mm;
        out.true_air_mm += la.true_air_mm;
        out.layers.push(la);
    }
    out
}

/// What holds layer `index`'s part extrusions (or its support extrusions, `support`): a grid
/// of the extrusions of the layers from the layer below up, with the support extrusions down
/// to [`CONTACT_GAP_UM`] under it, and the reach `h tan 50°` (um); `None` on the bed.
///
/// The layer below is the highest lower layer with extrusions of the same kind (another
/// slicer's supports may have heights of their own), else the next lower layer.
fn holding(
    layers: &[Layer],
    segs: &[Vec<Extrusion>],
    index: usize,
    support: bool,
) -> Option<(Grid, f64)> {
    let kind = |k: usize| segs[k].iter().any(|e| is_support(e.feature) == support);
    if !kind(index) {
        return None;
    }
    let below = (0..index).rev().find(|&k| kind(k)).or(index.checked_sub(1))?;
    let z_below = layers[below].z_um;
    let lowest = z_below - CONTACT_GAP_UM - Z_TOLERANCE_UM;
    let mut held = Vec::new();
    for k in (0..index).rev().take_while(|&k| layers[k].z_um >= lowest) {
        let all = layers[k].z_um >= z_below - Z_TOLERANCE_UM;
        held.extend(segs[k].iter().filter(|e| all || is_support(e.feature)));
    }
    let h = (layers[index].z_um - z_below).max(0.0);
    Some((Grid::new(&held), h * SUPPORT_ANGLE_DEG.to_radians().tan()))
}

/// A support feature: its name starts with `support` in any case (PrusaSlicer's `Support
/// material` and `Support material interface`, Cura's `SUPPORT`, `SUPPORT-INTERFACE`).
pub fn is_support(feature: &str) -> bool {
    feature.get(..7).is_some_and(|s| s.eq_ignore_ascii_case("support"))
}

/// The parts of a segment (parameter intervals in [0, 1], sorted, disjoint) within reach of
/// what holds it; all of it on the bed.
type Held = Vec<(f64, f64)>;

/// One layer's figures; `holds`: what holds its part and its support extrusions
/// ([`holding`]).
fn measure_layer(
    index: usize,
    z_um: f64,
    segs: &[Extrusion],
    holds: &[Option<(Grid, f64)>; 2],
    by_feature: &mut Vec<(&'static str, f64)>,
) -> LayerAir {
    let mut stamps =
        holds.each_ref().map(|h| vec![usize::MAX; h.as_ref().map_or(0, |(g, _)| g.segs.len())]);
    let held: Vec<Held> = segs
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let kind = usize::from(is_support(e.feature));
            match &holds[kind] {
                None => vec![(0.0, 1.0)],
                Some((grid, reach)) => grid.held(e, e.width_um / 2.0 + reach, i, &mut stamps[kind]),
            }
        })
        .collect();
    let mut la = LayerAir {
        index,
        z_um,
        extruded_mm: segs.iter().map(Extrusion::length).sum::<f64>() / 1000.0,
        anchored_bridge_mm: 0.0,
        sparse_support_mm: 0.0,
        true_air_mm: 0.0,
        worst: None,
    };
    let mut start = 0;
    while start < segs.len() {
        let end = run_end(segs, start);
        for (e, [anchored, air]) in
            segs[start..end].iter().zip(run_air(&segs[start..end], &held[start..end]))
        {
            let (anchored, air) = (anchored / 1000.0, air / 1000.0);
            la.anchored_bridge_mm += anchored;
            if e.feature == SPARSE || is_support(e.feature) {
                la.sparse_support_mm += air;
            } else if air > 0.0 {
                la.true_air_mm += air;
                match by_feature.iter_mut().find(|(f, _)| *f == e.feature) {
                    Some((_, total)) => *total += air,
                    None => by_feature.push((e.feature, air)),
                }
                if la.worst.map_or(true, |w| w.air_mm < air) {
                    la.worst = Some(Offender { extrusion: *e, air_mm: air });
                }
            }
        }
        start = end;
    }
    la
}

/// Per segment of a run: its over air (um) between the run's first and last held points
/// when the run is a bridge (anchored), and the rest of its over air.
fn run_air(run: &[Extrusion], held: &[Held]) -> Vec<[f64; 2]> {
    let mut at = 0.0;
    let starts: Vec<f64> = run
        .iter()
        .map(|e| {
            at += e.length();
            at - e.length()
        })
        .collect();
    let arc = |k: usize, t: f64| starts[k] + t * run[k].length();
    let first = held.iter().enumerate().find_map(|(k, h)| Some(arc(k, h.first()?.0)));
    let last = held.iter().enumerate().rev().find_map(|(k, h)| Some(arc(k, h.last()?.1)));
    let anchor = match (run[0].bridge, first, last) {
        (true, Some(first), Some(last)) => (first, last),
        _ => (0.0, 0.0),
    };
    (0..run.len())
        .map(|k| {
            let (mut anchored, mut air) = (0.0, 0.0);
            let mut from = 0.0;
            for &(lo, hi) in held[k].iter().chain([&(1.0, 1.0)]) {
                let (p, q) = (arc(k, from), arc(k, lo));
                if q > p {
                    let inside = (q.min(anchor.1) - p.max(anchor.0)).max(0.0);
                    anchored += inside;
                    air += q - p - inside;
                }
                from = hi;
            }
            [anchored, air]
        })
        .collect()
}

/// One past the last segment of the run that starts at `start`.
fn run_end(segs: &[Extrusion], start: usize) -> usize {
    let first = &segs[start];
    if !first.bridge {
        return start + 1;
    }
    let cos_turn = RUN_TURN_DEG.to_radians().cos();
    let dir = unit(first);
    let mut end = start + 1;
    while let Some(next) = segs.get(end) {
        let prev = &segs[end - 1];
        let joined = (next.a.0 - prev.b.0).hypot(next.a.1 - prev.b.1) <= JOIN_UM;
        let d = unit(next);
        if !(next.bridge && joined && d.0 * dir.0 + d.1 * dir.1 >= cos_turn) {
            break;
        }
        end += 1;
    }
    end
}

fn unit(e: &Extrusion) -> (f64, f64) {
    let l = e.length();
    ((e.b.0 - e.a.0) / l, (e.b.1 - e.a.1) / l)
}

/// The segments of a layer in a uniform grid of [`GRID_CELL_UM`] cells over their bounding box.
struct Grid {
    segs: Vec<((f64, f64), (f64, f64))>,
    lo: (f64, f64),
    nx: usize,
    ny: usize,
    cells: Vec<Vec<u32>>,
}

impl Grid {
    fn new(extrusions: &[Extrusion]) -> Self {
        let segs: Vec<_> = extrusions.iter().map(|e| (e.a, e.b)).collect();
        let pts = segs.iter().flat_map(|&(a, b)| [a, b]);
        let lo = pts.clone().fold((f64::MAX, f64::MAX), |m, p| (m.0.min(p.0), m.1.min(p.1)));
        let hi = pts.fold((f64::MIN, f64::MIN), |m, p| (m.0.max(p.0), m.1.max(p.1)));
        let (nx, ny) =
            if segs.is_empty() { (0, 0) } else { (cell_count(lo.0, hi.0), cell_count(lo.1, hi.1)) };
        let mut grid = Self { segs, lo, nx, ny, cells: vec![Vec::new(); nx * ny] };
        let mut touched = Vec::new();
        for id in 0..grid.segs.len() {
            let (a, b) = grid.segs[id];
            touched.clear();
            grid.cells_along(a, b, 0.0, |cell| touched.push(cell));
            for &cell in &touched {
                let cell = &mut grid.cells[cell];
                if cell.last() != Some(&(id as u32)) {
                    cell.push(id as u32);
                }
            }
        }
        grid
    }

    /// Calls `f` with the index of every cell within `margin` of a piece of a-b no longer
    /// than a cell (some cells more than once).
    fn cells_along(&self, a: (f64, f64), b: (f64, f64), margin: f64, mut f: impl FnMut(usize)) {
        if self.nx == 0 {
            return;
        }
        let pieces = ((b.0 - a.0).hypot(b.1 - a.1) / GRID_CELL_UM).ceil().max(1.0) as usize;
        let at = |t: f64| (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        let cell = |v: f64, lo: f64, n: usize| {
            ((v - lo) / GRID_CELL_UM).floor().clamp(-1.0, n as f64) as isize
        };
        for k in 0..pieces {
            let (p, q) = (at(k as f64 / pieces as f64), at((k + 1) as f64 / pieces as f64));
            let i0 = cell(p.0.min(q.0) - margin, self.lo.0, self.nx).max(0);
            let i1 = cell(p.0.max(q.0) + margin, self.lo.0, self.nx).min(self.nx as isize - 1);
            let j0 = cell(p.1.min(q.1) - margin, self.lo.1, self.ny).max(0);
            let j1 = cell(p.1.max(q.1) + margin, self.lo.1, self.ny).min(self.ny as isize - 1);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    f(j as usize * self.nx + i as usize);
                }
            }
        }
    }

    /// The parts of `e` (the `query`-th of its layer) within `r` of these segments;
    /// `stamp` (one per segment here) keeps each candidate to one test per query.
    fn held(&self, e: &Extrusion, r: f64, query: usize, stamp: &mut [usize]) -> Held {
        let mut candidates = Vec::new();
        self.cells_along(e.a, e.b, r, |cell| {
            for &id in &self.cells[cell] {
                if stamp[id as usize] != query {
                    stamp[id as usize] = query;
                    candidates.push(id as usize);
                }
            }
        });
        let mut spans: Vec<(f64, f64)> = candidates
            .into_iter()
            .filter_map(|id| capsule_span(e.a, e.b, self.segs[id].0, self.segs[id].1, r))
            .collect();
        spans.sort_by(|x, y| x.0.total_cmp(&y.0));
        let mut held: Held = Vec::new();
        for (lo, hi) in spans {
            match held.last_mut() {
                Some(last) if lo <= last.1 => last.1 = last.1.max(hi),
                _ => held.push((lo, hi)),
            }
        }
        held
    }
}

/// Cells of [`GRID_CELL_UM`] covering `lo..=hi`.
fn cell_count(lo: f64, hi: f64) -> usize {
    ((hi - lo) / GRID_CELL_UM).floor() as usize + 1
}

/// The parameters `t` in [0, 1] of the points `a + t (b - a)` within `r` of the segment c-d:
/// the hull of the line's cuts by the capsule's discs and slab (the capsule is convex), or
/// `None`.
fn capsule_span(
    a: (f64, f64),
    b: (f64, f64),
    c: (f64, f64),
    d: (f64, f64),
    r: f64,
) -> Option<(f64, f64)> {
    let dir = (b.0 - a.0, b.1 - a.1);
    let mut span: Option<(f64, f64)> = None;
    let mut add = |s: Option<(f64, f64)>| {
        if let Some((lo, hi)) = s {
            span = Some(span.map_or((lo, hi), |(l, h)| (l.min(lo), h.max(hi))));
        }
    };
    add(disc_span(a, dir, c, r));
    add(disc_span(a, dir, d, r));
    let len = (d.0 - c.0).hypot(d.1 - c.1);
    if len > 0.0 {
        let u = ((d.0 - c.0) / len, (d.1 - c.1) / len);
        let ac = (a.0 - c.0, a.1 - c.1);
        // Along c-d within [0, len], across within [-r, r]: each linear in t.
        let along = slab(ac.0 * u.0 + ac.1 * u.1, dir.0 * u.0 + dir.1 * u.1, 0.0, len);
        let across = slab(ac.0 * u.1 - ac.1 * u.0, dir.0 * u.1 - dir.1 * u.0, -r, r);
        if let (Some(p), Some(q)) = (along, across) {
            let (lo, hi) = (p.0.max(q.0), p.1.min(q.1));
            add((lo <= hi).then_some((lo, hi)));
        }
    }
    let (lo, hi) = span?;
    let (lo, hi) = (lo.max(0.0), hi.min(1.0));
    (lo <= hi).then_some((lo, hi))
}

/// The `t` with `|a + t dir - p| <= r`.
fn disc_span(a: (f64, f64), dir: (f64, f64), p: (f64, f64), r: f64) -> Option<(f64, f64)> {
    let ap = (a.0 - p.0, a.1 - p.1);
    let qa = dir.0 * dir.0 + dir.1 * dir.1;
    let qb = dir.0 * ap.0 + dir.1 * ap.1;
    let qc = ap.0 * ap.0 + ap.1 * ap.1 - r * r;
    let disc = qb * qb - qa * qc;
    if qa == 0.0 || disc < 0.0 {
        return None;
    }
    let root = disc.sqrt();
    Some(((-qb - root) / qa, (-qb + root) / qa))
}

/// The `t` (all reals clipped to a wide range) with `lo <= v0 + t dv <= hi`.
fn slab(v0: f64, dv: f64, lo: f64, hi: f64) -> Option<(f64, f64)> {
    if dv == 0.0 {
        return (lo..=hi).contains(&v0).then_some((-1e300, 1e300));
    }
    let (t0, t1) = ((lo - v0) / dv, (hi - v0) / dv);
    Some((t0.min(t1), t0.max(t1)))
}

/// The extrusions of a G-code text, grouped into layers by their height.
///
/// A layer starts where an extrusion's z differs from the current layer's. Reads `G0`/`G1`
/// moves (`G2`/`G3` as straight lines to their end), `G90`/`G91`, `M82`/`M83`, `G92`, and the
/// comments `;TYPE:name` (the feature, `Custom` before any) and `;WIDTH:mm` (the line width,
/// `default_width_um` before any). A move extrudes when E grows and X or Y changes.
pub fn layers_from_gcode(text: &str, default_width_um: f64) -> Vec<Layer> {
    let mut names: Vec<&'static str> = Vec::new();
    let mut intern = |name: &str| match names.iter().find(|n| **n == name) {
        Some(n) => *n,
        None => {
            let n: &'static str = Box::leak(name.to_string().into_boxed_str());
            names.push(n);
            n
        }
    };
    let (mut abs_xyz, mut abs_e) = (true, true);
    let (mut pos, mut e) = ([0.0f64; 3], 0.0f64);
    let (mut feature, mut width) = (intern("Custom"), default_width_um);
    let mut layers: Vec<Layer> = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if let Some(t) = line.strip_prefix(";TYPE:") {
            feature = intern(t.trim());
        } else if let Some(w) = line.strip_prefix(";WIDTH:") {
            width = w.trim().parse::<f64>().map_or(width, |mm| mm * 1000.0);
        }
        let code = line.split(';').next().unwrap_or("");
        let mut words = code.split_whitespace();
        let Some(cmd) = words.next() else { continue };
        let arg = |letter: char| {
            code.split_whitespace()
                .skip(1)
                .find(|w| w.starts_with(letter) || w.starts_with(letter.to_ascii_lowercase()))
                .and_then(|w| w[1..].parse::<f64>().ok())
        };
        match cmd.to_ascii_uppercase().as_str() {
            "G90" => (abs_xyz, abs_e) = (true, true),
            "G91" => (abs_xyz, abs_e) = (false, false),
            "M82" => abs_e = true,
            "M83" => abs_e = false,
            "G92" => {
                for (k, c) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                    if let Some(v) = arg(c) {
                        pos[k] = v;
                    }
                }
                if let Some(v) = arg('E') {
                    e = v;
                }
            }
            "G0" | "G1" | "G2" | "G3" => {
                let mut to = pos;
                for (k, c) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                    if let Some(v) = arg(c) {
                        to[k] = if abs_xyz { v } else { pos[k] + v };
                    }
                }
                let de = match arg('E') {
                    Some(v) if abs_e => v - e,
                    Some(v) => v,
                    None => 0.0,
                };
                e += de;
                if de > 0.0 && (to[0], to[1]) != (pos[0], pos[1]) {
                    let z_um = to[2] * 1000.0;
                    if layers.last().map_or(true, |l| (l.z_um - z_um).abs() > Z_TOLERANCE_UM / 2.0)
                    {
                        layers.push(Layer { z_um, extrusions: Vec::new() });
                    }
                    let (a, b) =
                        ((pos[0] * 1000.0, pos[1] * 1000.0), (to[0] * 1000.0, to[1] * 1000.0));
                    layers
                        .last_mut()
                        .unwrap()
                        .extrusions
                        .push(Extrusion::new(a, b, width, feature));
                }
                pos = to;
            }
            _ => {}
        }
    }
    layers
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::point_seg_dist;
    use crate::rng::Rng;

    /// Line width, um.
    const W: f64 = 450.0;
    /// Layer height, um.
    const H: f64 = 200.0;

    /// How far past a supported line's centre a line may reach, um: w/2 + h tan 50°.
    fn reach() -> f64 {
        W / 2.0 + H * 50f64.to_radians().tan()
    }

    fn line(a: (f64, f64), b: (f64, f64), feature: &'static str) -> Extrusion {
        Extrusion::new(a, b, W, feature)
    }

    fn layer(index: usize, extrusions: Vec<Extrusion>) -> Layer {
        Layer { z_um: H * (index + 1) as f64, extrusions }
    }

    /// A closed path through `pts`.
    fn path(pts: &[(f64, f64)], feature: &'static str) -> Vec<Extrusion> {
        (0..pts.len()).map(|k| line(pts[k], pts[(k + 1) % pts.len()], feature)).collect()
    }

    fn close(x: f64, want: f64, rel: f64) -> bool {
        (x - want).abs() <= rel * want.abs()
    }

    #[test]
    fn a_stack_of_identical_squares_has_nothing_over_air() {
        let square = |d: f64| {
            path(
                &[(d, d), (20_000.0 - d, d), (20_000.0 - d, 20_000.0 - d), (d, 20_000.0 - d)],
                "Perimeter",
            )
        };
        let layers: Vec<Layer> =
            (0..10).map(|i| layer(i, [square(225.0), square(675.0)].concat())).collect();
        let air = over_air(&layers);
        assert_eq!(air.true_air_mm, 0.0);
        assert_eq!(air.anchored_bridge_mm, 0.0);
        // Per layer: two loops, 4 x 19.55 mm and 4 x 18.65 mm.
        assert!(close(air.extruded_mm, 10.0 * 4.0 * (19.55 + 18.65), 1e-12), "{}", air.extruded_mm);
    }

    #[test]
    fn a_cantilever_is_over_air_beyond_the_reach_of_the_line_below() {
        let layers = vec![
            layer(0, vec![line((0.0, 0.0), (10_000.0, 0.0), "Perimeter")]),
            layer(1, vec![line((0.0, 0.0), (20_000.0, 0.0), "Perimeter")]),
        ];
        let air = over_air(&layers);
        let want_mm = (10_000.0 - reach()) / 1000.0;
        assert!(close(air.true_air_mm, want_mm, 0.01), "{} vs {want_mm}", air.true_air_mm);
        assert_eq!(air.anchored_bridge_mm, 0.0);
        assert_eq!(air.extruded_mm, 30.0);
        assert_eq!(air.layers[1].worst.map(|w| w.extrusion.b), Some((20_000.0, 0.0)));
        assert!(air.describe_worst(1).contains("layer 1"), "{}", air.describe_worst(1));
    }

    /// Two pads (5 mm long lines at y 0, 450 and 900) 20 mm apart, and over them a zigzag of
    /// three lines of `feature` across the gap, joined on the pads.
    fn bridge(feature: &'static str) -> Vec<Layer> {
        let ys = [0.0, 450.0, 900.0];
        let pads = ys
            .iter()
            .flat_map(|&y| {
                [
                    line((0.0, y), (5_000.0, y), "Solid infill"),
                    line((25_000.0, y), (30_000.0, y), "Solid infill"),
                ]
            })
            .collect();
        let zigzag = vec![
            line((1_000.0, 0.0), (29_000.0, 0.0), feature),
            line((29_000.0, 0.0), (29_000.0, 450.0), feature),
            line((29_000.0, 450.0), (1_000.0, 450.0), feature),
            line((1_000.0, 450.0), (1_000.0, 900.0), feature),
            line((1_000.0, 900.0), (29_000.0, 900.0), feature),
        ];
        vec![layer(0, pads), layer(1, zigzag)]
    }

    /// Over air of the three bridge lines: the 20 mm gap less the reach from each pad, mm.
    fn bridge_gap_air_mm() -> f64 {
        3.0 * (20_000.0 - 2.0 * reach()) / 1000.0
    }

    #[test]
    fn a_bridge_between_two_pads_is_anchored_not_true_air() {
        assert_eq!(over_air(&bridge(OVERHANG_PERIMETER)).true_air_mm, 0.0);
        let air = over_air(&bridge(BRIDGE));
        assert!(
            close(air.anchored_bridge_mm, bridge_gap_air_mm(), 1e-9),
            "{}",
            air.anchored_bridge_mm
        );
        assert_eq!(air.true_air_mm, 0.0);
    }

    #[test]
    fn the_same_lines_untagged_are_true_air() {
        let air = over_air(&bridge("Solid infill"));
        assert!(close(air.true_air_mm, bridge_gap_air_mm(), 1e-9), "{}", air.true_air_mm);
        assert_eq!(air.anchored_bridge_mm, 0.0);
        assert!(close(air.true_air_of("Solid infill"), air.true_air_mm, 1e-12));
    }

    #[test]
    fn a_bridge_with_one_end_in_the_air_is_true_air() {
        let layers = vec![
            layer(0, vec![line((0.0, 0.0), (5_000.0, 0.0), "Solid infill")]),
            layer(1, vec![line((0.0, 0.0), (15_000.0, 0.0), BRIDGE)]),
        ];
        let air = over_air(&layers);
        let want_mm = (10_000.0 - reach()) / 1000.0;
        assert!(close(air.true_air_mm, want_mm, 1e-9), "{} vs {want_mm}", air.true_air_mm);
        assert_eq!(air.anchored_bridge_mm, 0.0);
    }

    #[test]
    fn a_bridge_past_its_pads_hangs_beyond_them() {
        // Pads 0..5 and 25..30 mm; the bridge from -2 to 32 mm, its tails over air.
        let layers = vec![
            layer(
                0,
                vec![
                    line((0.0, 0.0), (5_000.0, 0.0), "Solid infill"),
                    line((25_000.0, 0.0), (30_000.0, 0.0), "Solid infill"),
                ],
            ),
            layer(1, vec![line((-2_000.0, 0.0), (32_000.0, 0.0), BRIDGE)]),
        ];
        let air = over_air(&layers);
        let gap_mm = (20_000.0 - 2.0 * reach()) / 1000.0;
        let tails_mm = 2.0 * (2_000.0 - reach()) / 1000.0;
        assert!(close(air.anchored_bridge_mm, gap_mm, 1e-9), "{}", air.anchored_bridge_mm);
        assert!(close(air.true_air_mm, tails_mm, 1e-9), "{}", air.true_air_mm);
    }

    #[test]
    fn a_bridge_run_breaks_at_a_corner() {
        // An L of two bridge lines, held at its two ends only: its corner is in the air.
        let layers = vec![
            layer(
                0,
                vec![
                    line((0.0, 0.0), (2_000.0, 0.0), "Solid infill"),
                    line((10_000.0, 9_000.0), (10_000.0, 12_000.0), "Solid infill"),
                ],
            ),
            layer(
                1,
                vec![
                    line((0.0, 0.0), (10_000.0, 0.0), BRIDGE),
                    line((10_000.0, 0.0), (10_000.0, 10_000.0), BRIDGE),
                ],
            ),
        ];
        let air = over_air(&layers);
        // Each leg is held at one end only (its far end over the line below on the second):
        // true air, each short of its held end by the reach.
        let want_mm = (8_000.0 - reach() + 9_000.0 - reach()) / 1000.0;
        assert!(close(air.true_air_mm, want_mm, 1e-9), "{} vs {want_mm}", air.true_air_mm);
        assert_eq!(air.anchored_bridge_mm, 0.0);
    }

    #[test]
    fn sparse_infill_and_support_over_air_is_counted_apart() {
        let layers = vec![
            layer(0, vec![line((0.0, 0.0), (10_000.0, 0.0), SPARSE)]),
            layer(1, vec![line((5_000.0, -5_000.0), (5_000.0, 5_000.0), SPARSE)]),
        ];
        let air = over_air(&layers);
        // Crossing the line below, the line is held for the reach on each side.
        let want_mm = (10_000.0 - 2.0 * reach()) / 1000.0;
        assert!(
            close(air.sparse_support_mm, want_mm, 1e-9),
            "{} vs {want_mm}",
            air.sparse_support_mm
        );
        assert_eq!((air.true_air_mm, air.anchored_bridge_mm), (0.0, 0.0));
        let support = |e: Extrusion| Extrusion { feature: "Support material interface", ..e };
        let on_support: Vec<Layer> = layers
            .iter()
            .map(|l| Layer {
                extrusions: l.extrusions.iter().copied().map(support).collect(),
                ..*l
            })
            .collect();
        let air = over_air(&on_support);
        assert!(close(air.sparse_support_mm, want_mm, 1e-9), "{}", air.sparse_support_mm);
        assert_eq!((air.true_air_mm, air.anchored_bridge_mm), (0.0, 0.0));
    }

    /// A support interface line `gap_layers` layers under a part's line; beside them a wall
    /// in every layer.
    fn over_support(gap_layers: usize) -> OverAir {
        let wall = line((0.0, 5_000.0), (10_000.0, 5_000.0), "Perimeter");
        let interface = line((0.0, 0.0), (10_000.0, 0.0), "Support material interface");
        let mut layers = vec![layer(0, vec![interface, wall])];
        for i in 1..gap_layers {
            layers.push(layer(i, vec![wall]));
        }
        layers.push(layer(gap_layers, vec![line((0.0, 0.0), (10_000.0, 0.0), BRIDGE), wall]));
        over_air(&layers)
    }

    #[test]
    fn supports_hold_across_the_contact_gap() {
        // Right below, and with one or two 0.2 mm layers of air between.
        for gap_layers in [1, 2, 3] {
            let air = over_support(gap_layers);
            assert_eq!((air.true_air_mm, air.anchored_bridge_mm), (0.0, 0.0), "{gap_layers}");
        }
        // Three layers of air: 10 mm of line over air, held at neither end.
        assert!(close(over_support(4).true_air_mm, 10.0, 1e-12));
        assert!(is_support("SUPPORT-INTERFACE") && !is_support("Supp"));
    }

    #[test]
    fn supports_at_heights_of_their_own_hold_and_are_held() {
        let wall = line((0.0, 5_000.0), (10_000.0, 5_000.0), "Perimeter");
        let support = line((0.0, 0.0), (10_000.0, 0.0), "Support material");
        let at = |z_um: f64, extrusions: Vec<Extrusion>| Layer { z_um, extrusions };
        let bridge = line((0.0, 0.0), (10_000.0, 0.0), BRIDGE);
        let mut layers = vec![
            at(200.0, vec![wall, support]),
            at(400.0, vec![wall]),
            // 0.3 mm over the support below it, 0.3 mm under the bridge's layer below.
            at(500.0, vec![support]),
            at(600.0, vec![wall]),
            at(800.0, vec![wall]),
            at(1000.0, vec![wall, bridge]),
        ];
        let air = over_air(&layers);
        let (true_air, anchored) = (air.true_air_mm, air.anchored_bridge_mm);
        assert_eq!((true_air, anchored), (0.0, 0.0), "{}", air.describe_worst(3));
        // The bridge a layer higher: the support is out of the contact gap's reach.
        layers[5].extrusions.pop();
        layers.push(at(1200.0, vec![wall, bridge]));
        assert!(close(over_air(&layers).true_air_mm, 10.0, 1e-12));
    }

    #[test]
    fn the_first_layer_sits_on_the_bed() {
        let air = over_air(&[layer(0, vec![line((0.0, 0.0), (50_000.0, 0.0), "Perimeter")])]);
        assert_eq!((air.extruded_mm, air.true_air_mm), (50.0, 0.0));
    }

    /// The capsule cut against 20,000 points along the segment, for random segments.
    #[test]
    fn capsule_spans_match_sampled_distances() {
        let mut rng = Rng::new(50);
        let mut p = || (rng.signed_unit() * 3_000.0, rng.signed_unit() * 3_000.0);
        for _ in 0..300 {
            let (a, b, c, d) = (p(), p(), p(), p());
            let r = 463.0;
            let span = capsule_span(a, b, c, d, r);
            let n = 20_000;
            let held: Vec<f64> = (0..=n)
                .map(|k| k as f64 / n as f64)
                .filter(|t| {
                    point_seg_dist((a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1)), c, d) <= r
                })
                .collect();
            match span {
                None => assert!(held.is_empty(), "{a:?}-{b:?} vs {c:?}-{d:?}: {held:?}"),
                Some((lo, hi)) => {
                    let step = 1.0 / n as f64;
                    let (first, last) = (held[0], held[held.len() - 1]);
                    assert!(
                        (first - lo).abs() <= step && (last - hi).abs() <= step,
                        "{lo} {hi} vs {first} {last}"
                    );
                    assert_eq!(
                        held.len() as f64,
                        ((last - first) / step).round() + 1.0,
                        "one interval"
                    );
                }
            }
        }
    }

    #[test]
    fn gcode_extrusions_group_into_layers_with_their_type_and_width() {
        let text =
            "G90\nM83\nG1 Z0.2\n;TYPE:Perimeter\n;WIDTH:0.5\nG1 X10 Y0 E0.5\nG1 X20 Y0 E0.5 ; c\n\
                    G1 E-0.8\nG1 X0 Y0\nG1 E0.8\n;LAYER_CHANGE\nG1 Z0.4\n;TYPE:Bridge infill\n\
                    G1 X0 Y5 F1200 E0.3\nG92 E0\nG1 X5 Y5\n";
        let layers = layers_from_gcode(text, 450.0);
        assert_eq!(layers.len(), 2);
        assert_eq!(layers[0].z_um, 200.0);
        let first: Vec<_> =
            layers[0].extrusions.iter().map(|e| (e.b, e.width_um, e.feature)).collect();
        assert_eq!(
            first,
            [((10_000.0, 0.0), 500.0, "Perimeter"), ((20_000.0, 0.0), 500.0, "Perimeter")]
        );
        assert_eq!(layers[1].extrusions.len(), 1);
        assert!(layers[1].extrusions[0].bridge);
        assert_eq!(layers[1].extrusions[0].a, (0.0, 0.0));
    }
}

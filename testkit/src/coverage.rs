//! Top and bottom surface coverage: how much of a print's exposed surfaces its lines cover.
//!
//! An independent instrument for skins and gap fill: plain `f64` geometry on a raster of
//! [`CELL_UM`] cells that reads each layer's cross-section (the model's own, cut from the mesh
//! by [`mesh_sections`]) and the layer's extrusion segments, whoever produced them (the core's
//! toolpath stage, or another slicer's G-code through
//! [`layers_from_gcode`](crate::overhang::layers_from_gcode)). Coordinates are um.
//!
//! ## Model
//!
//! A cell is in a section when its centre is (non-zero winding of the section's directed
//! edges, the rule of [`inside`](crate::check::inside)). The *exposed top* of layer L is its
//! section minus the section of layer L + 1 (all of it on the last layer), its *exposed bottom*
//! its section minus that of layer L - 1 (all of it on the first layer). A cell is *covered*
//! when its centre lies within `w / 2` of the centre line of one of layer L's covering
//! extrusions ([`covers`]: all but sparse infill, skirt, brim and supports; `w` the
//! extrusion's own width). Sums run over the whole model, top and bottom apart, so a layer
//! weighs by its exposed area.
//!
//! ## Slivers
//!
//! Where a wall leans, a layer's outline moves by `h / tan(slope)` from one layer to the next:
//! a 0.2 mm layer on an 80° wall exposes a band 35 um wide along the outline, on a 45° wall
//! 200 um. Such bands are surfaces too (every slicer finds them the same way), but the
//! perimeters that run along them are placed from the slicer's own, simplified outline and
//! graze them by a few um either way, so they would score by chance. Each exposed surface is
//! therefore *eroded* by [`EROSION_UM`] before its cells are counted: a cell counts only when
//! every cell centre within that distance of its own is exposed too. Bands narrower than about
//! twice the erosion vanish, and wide surfaces lose a rim of that width (their area is
//! reported both ways: [`Cells::exposed`] and [`Cells::counted`]). The price: an open strip
//! along a surface's edge, narrower than the erosion, goes unseen.
//!
//! ## Speed
//!
//! Every section is filled into rows of bits by scanlines (each edge's crossings with the cell
//! centres' rows, sorted, the winding summed along the row); differences, erosion and counts are
//! word operations over the rows with exposed cells; only layers with exposed cells rasterise
//! their lines, each clipped to those rows and filled as one interval per row
//! (`tests/toolpath_coverage.rs` prints the checker's time per model).

use strata::geom::{Point2, Triangle};

use crate::check::{pt, section_segments_f64};
use crate::overhang::{Extrusion, SPARSE};

/// Side of the raster's square cells, um (the [`check`](crate::check) raster's).
pub const CELL_UM: f64 = crate::check::CELL_UM;

/// How far each exposed surface is eroded before its cells are counted, um: a quarter of a
/// 0.45 mm line.
///
/// Calibrated on PrusaSlicer 2.5's G-code of the shared models (`scripts/coverage_prusa.sh`,
/// which prints PrusaSlicer's figures at any erosion). Without erosion, one-cell slivers
/// along leaning walls, just beyond the reach of PrusaSlicer's outer perimeter, dominate the
/// open area of the curved models; one cell (50 um) removes most of them; a quarter line puts
/// PrusaSlicer's lowest top and bottom figures close to those the issue reports (LM8UU's top
/// aside, whose gaps inside the spiral walls are real); larger erosions change little more.
/// On this raster the erosion acts in steps of the distances between cell centres (50, 70.7,
/// 100, 111.8 um, ...).
pub const EROSION_UM: f64 = 112.5;

/// A directed edge of a section, from one point (um) to the next; the solid winds around them.
pub type Edge = [(f64, f64); 2];

/// One extrusion segment a-b (um), `width_um` wide.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Line {
    /// Start, um.
    pub a: (f64, f64),
    /// End, um.
    pub b: (f64, f64),
    /// Line width, um.
    pub width_um: f64,
}

/// One layer as the checker takes it: its section and its covering lines.
#[derive(Debug, Clone, Default)]
pub struct SurfaceLayer {
    /// The layer's cross-section as directed edges (any order, loops need not be chained).
    pub section: Vec<Edge>,
    /// The layer's covering extrusions.
    pub lines: Vec<Line>,
}

/// Whether extrusions of `feature` (PrusaSlicer's `;TYPE:` names) close a surface.
///
/// Everything but sparse infill (it leaves gaps by design), the skirt and brim (outside the
/// part) and supports (not part of the model).
pub fn covers(feature: &str) -> bool {
    feature != SPARSE
        && !feature.starts_with("Skirt")
        && !feature.starts_with("Support")
        && feature != "Wipe tower"
}

/// The covering extrusions ([`covers`]) as [`Line`]s.
pub fn lines_of(extrusions: &[Extrusion]) -> Vec<Line> {
    extrusions
        .iter()
        .filter(|e| covers(e.feature))
        .map(|e| Line { a: e.a, b: e.b, width_um: e.width_um })
        .collect()
}

/// The edges of a slicer's loops (points, hole flag; holes wind clockwise).
pub fn loop_edges(loops: &[(Vec<Point2>, bool)]) -> Vec<Edge> {
    let mut out = Vec::new();
    for (l, _) in loops {
        for k in 0..l.len() {
            out.push([pt(l[k]), pt(l[(k + 1) % l.len()])]);
        }
    }
    out
}

/// The sections of `tris` by the planes at heights `planes_um` (um, ascending), one per plane:
/// [`section_segments_f64`] of the triangles that reach the plane.
pub fn mesh_sections(tris: &[Triangle], planes_um: &[f64]) -> Vec<Vec<Edge>> {
    let mut out = vec![Vec::new(); planes_um.len()];
    for t in tris {
        let (lo, hi) = (f64::from(t.z_min()), f64::from(t.z_max()));
        let first = planes_um.partition_point(|&p| p < lo);
        for (k, &z) in planes_um.iter().enumerate().skip(first).take_while(|&(_, &z)| z <= hi) {
            for [a, b] in section_segments_f64(std::slice::from_ref(t), z) {
                out[k].push([(a[0], a[1]), (b[0], b[1])]);
            }
        }
    }
    out
}

/// Cell counts of one exposed surface (or of a sum of them).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Cells {
    /// Exposed cells.
    pub exposed: u64,
    /// Exposed cells left by the erosion: the cells that count.
    pub counted: u64,
    /// Counted cells that a line covers.
    pub covered: u64,
}

impl Cells {
    fn add(&mut self, o: Cells) {
        self.exposed += o.exposed;
        self.counted += o.counted;
        self.covered += o.covered;
    }

    /// Covered share of the counted cells (1 when none count).
    pub fn fraction(&self) -> f64 {
        if self.counted == 0 {
            1.0
        } else {
            self.covered as f64 / self.counted as f64
        }
    }

    /// Area of the counted cells, mm^2.
    pub fn area_mm2(&self) -> f64 {
        cells_mm2(self.counted)
    }

    /// Area of the exposed cells before the erosion, mm^2.
    pub fn exposed_mm2(&self) -> f64 {
        cells_mm2(self.exposed)
    }

    /// Area of the counted cells no line covers, mm^2.
    pub fn uncovered_mm2(&self) -> f64 {
        cells_mm2(self.counted - self.covered)
    }
}

fn cells_mm2(n: u64) -> f64 {
    n as f64 * CELL_UM * CELL_UM / 1e6
}

/// One layer's figures.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LayerCoverage {
    /// Layer index (in the checker's input).
    pub index: usize,
    /// Its exposed top.
    pub top: Cells,
    /// Its exposed bottom.
    pub bottom: Cells,
}

/// What [`surface_coverage`] measured.
#[derive(Debug, Clone, Default)]
pub struct Coverage {
    /// The exposed tops of all layers.
    pub top: Cells,
    /// The exposed bottoms of all layers.
    pub bottom: Cells,
    /// The layers with exposed cells, ascending.
    pub layers: Vec<LayerCoverage>,
    /// The erosion used, um.
    pub erosion_um: f64,
}

/// Head of the markdown table of [`Coverage::row`]s (two lines).
pub const TABLE_HEAD: &str = "| model | top mm^2 | top covered % | bottom mm^2 | bottom covered % \
                              | worst layer |\n|---|---:|---:|---:|---:|---|";

impl Coverage {
    /// The layer surface with the most uncovered area: layer, "top" or "bottom", its cells.
    pub fn worst(&self) -> Option<(usize, &'static str, Cells)> {
        let sides = self
            .layers
            .iter()
            .flat_map(|l| [(l.index, "top", l.top), (l.index, "bottom", l.bottom)]);
        sides.filter(|s| s.2.covered < s.2.counted).max_by_key(|s| s.2.counted - s.2.covered)
    }

    /// A markdown table row (see [`TABLE_HEAD`]): counted areas, covered shares, the worst
    /// layer surface.
    pub fn row(&self, name: &str) -> String {
        let worst = match self.worst() {
            Some((l, side, c)) => format!(
                "{l} {side}: {:.2} mm^2 open ({:.1} % of {:.1})",
                c.uncovered_mm2(),
                c.fraction() * 100.0,
                c.area_mm2()
            ),
            None => "-".to_string(),
        };
        format!(
            "| {name} | {:.1} | {:.2} | {:.1} | {:.2} | {worst} |",
            self.top.area_mm2(),
            self.top.fraction() * 100.0,
            self.bottom.area_mm2(),
            self.bottom.fraction() * 100.0
        )
    }
}

/// Coverage of the exposed top and bottom surfaces of `layers` (bottom first), eroded by
/// [`EROSION_UM`].
pub fn surface_coverage(layers: &[SurfaceLayer]) -> Coverage {
    surface_coverage_eroded(layers, EROSION_UM)
}

/// [`surface_coverage`] with the exposed surfaces eroded by `erosion_um` (0: none).
pub fn surface_coverage_eroded(layers: &[SurfaceLayer], erosion_um: f64) -> Coverage {
    let mut out = Coverage { erosion_um, ..Coverage::default() };
    let Some(grid) = Grid::around(layers) else { return out };
    let offsets = disc_offsets(erosion_um);
    let mut crossings = Vec::new();
    let mut prev = grid.bits();
    let mut cur = grid.bits();
    let mut next = grid.bits();
    let (mut exposed_top, mut exposed_bottom) = (grid.bits(), grid.bits());
    let (mut eroded, mut lines) = (grid.bits(), grid.bits());
    if let Some(l) = layers.first() {
        grid.fill(&l.section, &mut cur, &mut crossings);
    }
    for (i, layer) in layers.iter().enumerate() {
        match layers.get(i + 1) {
            Some(n) => grid.fill(&n.section, &mut next, &mut crossings),
            None => next.fill(0),
        }
        let mut lc = LayerCoverage { index: i, ..LayerCoverage::default() };
        let top_rows = grid.difference(&cur, &next, &mut exposed_top);
        let bottom_rows = grid.difference(&cur, &prev, &mut exposed_bottom);
        let rows = match (&top_rows, &bottom_rows) {
            (Some(t), Some(b)) => t.start.min(b.start)..t.end.max(b.end),
            (Some(r), None) | (None, Some(r)) => r.clone(),
            (None, None) => 0..0,
        };
        lines[rows.start * grid.words..rows.end * grid.words].fill(0);
        grid.draw(&layer.lines, &mut lines, rows);
        for (side, exposed, rows) in
            [(&mut lc.top, &exposed_top, top_rows), (&mut lc.bottom, &exposed_bottom, bottom_rows)]
        {
            let Some(rows) = rows else { continue };
            grid.erode(exposed, &mut eroded, rows.clone(), &offsets);
            *side = grid.count(exposed, &eroded, &lines, rows);
        }
        if lc.top.exposed > 0 || lc.bottom.exposed > 0 {
            out.top.add(lc.top);
            out.bottom.add(lc.bottom);
            out.layers.push(lc);
        }
        std::mem::swap(&mut prev, &mut cur);
        std::mem::swap(&mut cur, &mut next);
    }
    out
}

/// A picture of the exposed top (`top`) or bottom of layer `index`, as a plain PGM.
///
/// Top row first; 0 counted and open, 1 counted and covered, 2 exposed but eroded away, 3 a
/// line outside the surface, 4 the rest of the section, 5 outside it.
pub fn layer_pgm(layers: &[SurfaceLayer], index: usize, top: bool, erosion_um: f64) -> String {
    let Some(grid) = Grid::around(layers) else { return String::new() };
    let mut crossings = Vec::new();
    let section = |k: Option<usize>, crossings: &mut Vec<(usize, f64, i32)>| {
        let mut bits = grid.bits();
        if let Some(l) = k.and_then(|k| layers.get(k)) {
            grid.fill(&l.section, &mut bits, crossings);
        }
        bits
    };
    let cur = section(Some(index), &mut crossings);
    let other = section(if top { Some(index + 1) } else { index.checked_sub(1) }, &mut crossings);
    let (mut exposed, mut eroded, mut lines) = (grid.bits(), grid.bits(), grid.bits());
    let rows = grid.difference(&cur, &other, &mut exposed).unwrap_or(0..0);
    grid.erode(&exposed, &mut eroded, rows, &disc_offsets(erosion_um));
    grid.draw(&layers[index].lines, &mut lines, 0..grid.ny);
    let get = |bits: &[u64], i: usize, j: usize| bits[j * grid.words + i / 64] >> (i % 64) & 1 == 1;
    let mut img = format!("P2\n{} {}\n5\n", grid.nx, grid.ny);
    for j in (0..grid.ny).rev() {
        for i in 0..grid.nx {
            let v = match (get(&eroded, i, j), get(&exposed, i, j), get(&lines, i, j)) {
                (true, _, false) => 0,
                (true, _, true) => 1,
                (false, true, _) => 2,
                (false, false, true) => 3,
                _ if get(&cur, i, j) => 4,
                _ => 5,
            };
            img.push_str(if i + 1 == grid.nx { "\n" } else { " " });
            img.insert(img.len() - 1, char::from(b'0' + v));
        }
    }
    img
}

/// Offsets (columns, rows) of the cells whose centres lie within `r` um of a cell's centre.
fn disc_offsets(r: f64) -> Vec<(isize, isize)> {
    let reach = (r / CELL_UM).floor() as isize;
    let r2 = (r / CELL_UM).powi(2) + 1e-9;
    let mut out = Vec::new();
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            if (dx, dy) != (0, 0) && (dx * dx + dy * dy) as f64 <= r2 {
                out.push((dx, dy));
            }
        }
    }
    out
}

/// The raster: `nx` x `ny` cells from `lo`, each row `words` 64-bit words of one bit per cell.
#[derive(Debug, Clone)]
struct Grid {
    lo: (f64, f64),
    nx: usize,
    ny: usize,
    words: usize,
}

impl Grid {
    /// Around every section's points, a cell of margin on each side; `None` without points.
    fn around(layers: &[SurfaceLayer]) -> Option<Self> {
        let pts = layers.iter().flat_map(|l| l.section.iter().flatten());
        let (lo, hi) = pts.fold(((f64::MAX, f64::MAX), (f64::MIN, f64::MIN)), |(lo, hi), p| {
            ((lo.0.min(p.0), lo.1.min(p.1)), (hi.0.max(p.0), hi.1.max(p.1)))
        });
        if lo.0 > hi.0 {
            return None;
        }
        let lo = (lo.0 - CELL_UM, lo.1 - CELL_UM);
        let nx = ((hi.0 - lo.0) / CELL_UM).ceil() as usize + 2;
        let ny = ((hi.1 - lo.1) / CELL_UM).ceil() as usize + 2;
        Some(Self { lo, nx, ny, words: nx.div_ceil(64) })
    }

    fn bits(&self) -> Vec<u64> {
        vec![0; self.words * self.ny]
    }

    fn centre_y(&self, j: usize) -> f64 {
        self.lo.1 + (j as f64 + 0.5) * CELL_UM
    }

    /// First column whose centre is at or right of `x` (0..=nx).
    fn column_at(&self, x: f64) -> usize {
        ((x - self.lo.0) / CELL_UM - 0.5).ceil().clamp(0.0, self.nx as f64) as usize
    }

    /// First row whose centre is at or above `y` (0..=ny).
    fn row_at(&self, y: f64) -> usize {
        ((y - self.lo.1) / CELL_UM - 0.5).ceil().clamp(0.0, self.ny as f64) as usize
    }

    /// Sets the cells `i0..i1` of row `j`.
    fn set(&self, bits: &mut [u64], j: usize, i0: usize, i1: usize) {
        let row = &mut bits[j * self.words..(j + 1) * self.words];
        let mut i = i0;
        while i < i1 {
            let (w, b) = (i / 64, i % 64);
            let n = (64 - b).min(i1 - i);
            let mask = if n == 64 { !0 } else { ((1u64 << n) - 1) << b };
            row[w] |= mask;
            i += n;
        }
    }

    /// Fills `bits` with the cells inside `section` (non-zero winding of the edges; an edge
    /// crosses a row when `min y <= centre < max y`, as in [`crate::check::inside`]).
    fn fill(&self, section: &[Edge], bits: &mut [u64], crossings: &mut Vec<(usize, f64, i32)>) {
        bits.fill(0);
        crossings.clear();
        for &[a, b] in section {
            if a.1 == b.1 {
                continue;
            }
            let (ylo, yhi) = (a.1.min(b.1), a.1.max(b.1));
            let dir = if b.1 > a.1 { 1 } else { -1 };
            for j in self.row_at(ylo)..self.ny {
                let y = self.centre_y(j);
                if y >= yhi {
                    break;
                }
                if y >= ylo {
                    crossings.push((j, a.0 + (y - a.1) / (b.1 - a.1) * (b.0 - a.0), dir));
                }
            }
        }
        crossings.sort_unstable_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)));
        let mut winding = 0;
        for k in 0..crossings.len() {
            let (j, x, dir) = crossings[k];
            winding += dir;
            match crossings.get(k + 1) {
                Some(&(j2, x2, _)) if j2 == j => {
                    if winding != 0 {
                        self.set(bits, j, self.column_at(x), self.column_at(x2));
                    }
                }
                _ => winding = 0,
            }
        }
    }

    /// `out = a & !b`; the rows with a cell set, or `None`.
    fn difference(&self, a: &[u64], b: &[u64], out: &mut [u64]) -> Option<std::ops::Range<usize>> {
        let (mut first, mut last) = (usize::MAX, 0);
        for j in 0..self.ny {
            let r = j * self.words..(j + 1) * self.words;
            let mut any = 0;
            for ((o, &x), &y) in out[r.clone()].iter_mut().zip(&a[r.clone()]).zip(&b[r]) {
                *o = x & !y;
                any |= *o;
            }
            if any != 0 {
                first = first.min(j);
                last = j;
            }
        }
        (first != usize::MAX).then_some(first..last + 1)
    }

    /// Word `k` of row `j` shifted by `dx` columns: bit `b` is cell `64 k + b + dx` (unset
    /// outside the raster).
    fn shifted(&self, bits: &[u64], j: isize, k: usize, dx: isize) -> u64 {
        if j < 0 || j as usize >= self.ny {
            return 0;
        }
        let row = &bits[j as usize * self.words..(j as usize + 1) * self.words];
        let word = |q: isize| if q < 0 || q as usize >= self.words { 0 } else { row[q as usize] };
        let base = 64 * k as isize + dx;
        let (q, s) = (base.div_euclid(64), base.rem_euclid(64) as u32);
        if s == 0 {
            word(q)
        } else {
            (word(q) >> s) | (word(q + 1) << (64 - s))
        }
    }

    /// `out` = the cells of `bits` whose every `offsets` neighbour is set too, over `rows`.
    fn erode(
        &self,
        bits: &[u64],
        out: &mut [u64],
        rows: std::ops::Range<usize>,
        offsets: &[(isize, isize)],
    ) {
        for j in rows {
            for k in 0..self.words {
                let mut acc = bits[j * self.words + k];
                for &(dx, dy) in offsets {
                    if acc == 0 {
                        break;
                    }
                    acc &= self.shifted(bits, j as isize + dy, k, dx);
                }
                out[j * self.words + k] = acc;
            }
        }
    }

    /// Sets the cells whose centre lies within `w / 2` of a line, over `rows`.
    fn draw(&self, lines: &[Line], bits: &mut [u64], rows: std::ops::Range<usize>) {
        for l in lines {
            let r = l.width_um / 2.0;
            let j0 = self.row_at(l.a.1.min(l.b.1) - r).max(rows.start);
            let j1 = self.row_at(l.a.1.max(l.b.1) + r + 1e-9).min(rows.end);
            for j in j0..j1 {
                if let Some((x0, x1)) = capsule_span(l.a, l.b, r, self.centre_y(j)) {
                    let i1 = ((x1 - self.lo.0) / CELL_UM - 0.5).floor() + 1.0;
                    let i1 = i1.clamp(0.0, self.nx as f64) as usize;
                    self.set(bits, j, self.column_at(x0), i1);
                }
            }
        }
    }

    /// The counts of one surface over `rows`: `exposed` cells, `eroded` ones, those `lines`
    /// cover.
    fn count(
        &self,
        exposed: &[u64],
        eroded: &[u64],
        lines: &[u64],
        rows: std::ops::Range<usize>,
    ) -> Cells {
        let r = rows.start * self.words..rows.end * self.words;
        let ones = |w: &[u64]| w.iter().map(|x| u64::from(x.count_ones())).sum::<u64>();
        let covered = eroded[r.clone()]
            .iter()
            .zip(&lines[r.clone()])
            .map(|(e, l)| u64::from((e & l).count_ones()))
            .sum();
        Cells { exposed: ones(&exposed[r.clone()]), counted: ones(&eroded[r]), covered }
    }
}

/// The x interval of the points at height `y` within `r` of the segment a-b (the capsule's
/// chord), or `None`.
///
/// The capsule is convex, so its chord is the hull of the chords of its parts: the discs at
/// a and b and the rectangle between them.
pub fn capsule_span(a: (f64, f64), b: (f64, f64), r: f64, y: f64) -> Option<(f64, f64)> {
    let mut span: Option<(f64, f64)> = None;
    let mut hull = |lo: f64, hi: f64| {
        if lo <= hi {
            span = Some(span.map_or((lo, hi), |(l, h)| (l.min(lo), h.max(hi))));
        }
    };
    for c in [a, b] {
        let dy = y - c.1;
        if dy.abs() <= r {
            let h = (r * r - dy * dy).sqrt();
            hull(c.0 - h, c.0 + h);
        }
    }
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let len = dx.hypot(dy);
    if len > 0.0 {
        let (ux, uy) = (dx / len, dy / len);
        // Along: (x - a.x) ux + (y - a.y) uy in [0, len]; across: (x - a.x) uy - (y - a.y) ux
        // in [-r, r]. Each is c x + d.
        let mut lo = f64::MIN;
        let mut hi = f64::MAX;
        for (c, d, min, max) in
            [(ux, -a.0 * ux + (y - a.1) * uy, 0.0, len), (uy, -a.0 * uy - (y - a.1) * ux, -r, r)]
        {
            if c == 0.0 {
                if d < min || d > max {
                    return span;
                }
            } else {
                let (p, q) = ((min - d) / c, (max - d) / c);
                lo = lo.max(p.min(q));
                hi = hi.min(p.max(q));
            }
        }
        hull(lo, hi);
    }
    span
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::check::{inside, point_seg_dist};
    use crate::mesh::{cuboid, loft, square, to_um, TriMm};
    use crate::rng::Rng;

    fn grid_of(edges: &[Edge]) -> Grid {
        Grid::around(&[SurfaceLayer { section: edges.to_vec(), lines: Vec::new() }]).unwrap()
    }

    fn get(g: &Grid, bits: &[u64], i: usize, j: usize) -> bool {
        bits[j * g.words + i / 64] >> (i % 64) & 1 == 1
    }

    fn sq(lo: i32, hi: i32) -> Vec<Point2> {
        [(lo, lo), (hi, lo), (hi, hi), (lo, hi)].map(|(x, y)| Point2::new(x, y)).to_vec()
    }

    #[test]
    fn the_scanline_fill_agrees_with_the_winding_test() {
        // A holed square and an overlapping star-like polygon: every cell centre against
        // check::inside.
        let mut hole = sq(3000, 6000);
        hole.reverse();
        let star: Vec<Point2> = (0..14)
            .map(|k| {
                let a = k as f64 * std::f64::consts::TAU / 14.0;
                let r = if k % 2 == 0 { 4000.0 } else { 1700.0 };
                Point2::new(8000 + (r * a.cos()) as i32, 7000 + (r * a.sin()) as i32)
            })
            .collect();
        let loops = vec![(sq(0, 10_000), false), (hole, true), (star, false)];
        let edges = loop_edges(&loops);
        let g = grid_of(&edges);
        let mut bits = g.bits();
        g.fill(&edges, &mut bits, &mut Vec::new());
        let mut set = 0;
        for j in 0..g.ny {
            for i in 0..g.nx {
                let c = (g.lo.0 + (i as f64 + 0.5) * CELL_UM, g.centre_y(j));
                assert_eq!(get(&g, &bits, i, j), inside(&loops, c), "cell {i} {j} at {c:?}");
                set += usize::from(get(&g, &bits, i, j));
            }
        }
        assert!(set > 30_000, "{set}");
    }

    #[test]
    fn capsule_spans_are_the_cells_within_half_a_width() {
        let mut rng = Rng::new(7);
        for _ in 0..100 {
            let p = |rng: &mut Rng| (rng.signed_unit() * 2000.0, rng.signed_unit() * 2000.0);
            let a = p(&mut rng);
            let b = if rng.per_mille(100) { a } else { p(&mut rng) };
            let b = if rng.per_mille(100) { (b.0, a.1) } else { b };
            let r = 50.0 + rng.f64() * 400.0;
            for k in 0..80 {
                let y = -2500.0 + 62.5 * k as f64 + 0.3;
                let span = capsule_span(a, b, r, y);
                for i in 0..400 {
                    let x = -2500.0 + 12.5 * i as f64 + 0.1;
                    let d = point_seg_dist((x, y), a, b);
                    let within = span.is_some_and(|(lo, hi)| lo <= x && x <= hi);
                    if (d - r).abs() > 1e-6 {
                        assert_eq!(within, d < r, "{a:?}-{b:?} r {r} at ({x}, {y}): {d}");
                    }
                }
            }
        }
    }

    #[test]
    fn erosion_keeps_the_cells_whose_disc_is_set() {
        let edges = loop_edges(&[(sq(0, 2000), false)]);
        let g = grid_of(&edges);
        let (mut bits, mut out) = (g.bits(), g.bits());
        g.fill(&edges, &mut bits, &mut Vec::new());
        let offsets = disc_offsets(112.5);
        // Cells within 112.5 um: the 3 x 3 block, 4 at two cells, 8 at (2, 1): 20 neighbours.
        assert_eq!(offsets.len(), 20);
        g.erode(&bits, &mut out, 0..g.ny, &offsets);
        for j in 0..g.ny {
            for i in 0..g.nx {
                let all = get(&g, &bits, i, j)
                    && offsets.iter().all(|&(dx, dy)| {
                        let (x, y) = (i as isize + dx, j as isize + dy);
                        x >= 0 && y >= 0 && get(&g, &bits, x as usize, y as usize)
                    });
                assert_eq!(get(&g, &out, i, j), all, "cell {i} {j}");
            }
        }
        // 40 x 40 cells less a rim two cells wide.
        let n: u32 = out.iter().map(|w| w.count_ones()).sum();
        assert_eq!(n, 36 * 36);
    }

    /// Layers of `mesh` (mm) at 0.2 mm, planes at mid-layer, with `lines(z)` per layer.
    fn layers_of(mesh: &[TriMm], lines: impl Fn(usize) -> Vec<Line>) -> Vec<SurfaceLayer> {
        let tris = to_um(mesh);
        let top = tris.iter().map(|t| t.z_max()).max().unwrap();
        let planes: Vec<f64> =
            (0..).map(|k| 100.0 + 200.0 * k as f64).take_while(|&z| z < f64::from(top)).collect();
        mesh_sections(&tris, &planes)
            .into_iter()
            .enumerate()
            .map(|(k, section)| SurfaceLayer { section, lines: lines(k) })
            .collect()
    }

    /// Lines along x every `step` um over `[x0, x1] x [y0, y1]` (um), `w` wide.
    fn hatch(x0: f64, x1: f64, y0: f64, y1: f64, step: f64, w: f64) -> Vec<Line> {
        (0..)
            .map(|k| y0 + step / 2.0 + step * k as f64)
            .take_while(|&y| y < y1)
            .map(|y| Line { a: (x0, y), b: (x1, y), width_um: w })
            .collect()
    }

    #[test]
    fn a_hatched_box_is_covered_top_and_bottom() {
        // 10 x 10 x 1 mm: 5 layers; lines 400 um wide every 400 um cover the square.
        let mesh = cuboid([0.0, 0.0, 0.0], [10.0, 10.0, 1.0]);
        let layers = layers_of(&mesh, |_| hatch(0.0, 10_000.0, 0.0, 10_000.0, 400.0, 400.0));
        let c = surface_coverage_eroded(&layers, 0.0);
        // The top of layer 4 and the bottom of layer 0, each 100 mm^2 (200 x 200 cells).
        assert_eq!((c.top.exposed, c.bottom.exposed), (200 * 200, 200 * 200));
        assert_eq!((c.top.fraction(), c.bottom.fraction()), (1.0, 1.0));
        assert_eq!(c.layers.iter().map(|l| l.index).collect::<Vec<_>>(), [0, 4]);
        assert!(c.worst().is_none());
        // Eroded by 112.5 um: two cells off each side.
        let e = surface_coverage(&layers);
        assert_eq!((e.top.counted, e.top.exposed), (196 * 196, 200 * 200));
        // A line every 800 um: 12 lines over 8 rows of cells each, of 200 rows.
        let half = layers_of(&mesh, |_| hatch(0.0, 10_000.0, 0.0, 10_000.0, 800.0, 400.0));
        let h = surface_coverage_eroded(&half, 0.0);
        assert_eq!((h.top.covered, h.bottom.covered), (12 * 8 * 200, 12 * 8 * 200));
        let (_, _, worst) = h.worst().unwrap();
        assert_eq!(worst.counted - worst.covered, (200 - 12 * 8) * 200);
        // No lines at all.
        let bare = surface_coverage(&layers_of(&mesh, |_| Vec::new()));
        assert_eq!((bare.top.covered, bare.bottom.covered), (0, 0));
        assert_eq!(bare.top.fraction(), 0.0);
    }

    #[test]
    fn a_stepped_block_exposes_the_step_and_the_tops() {
        // A 20 mm square 1 mm tall under a 10 mm square from 1 to 2 mm: the step's ring
        // (400 - 100 mm^2) is the top of layer 4, the small square's top that of layer 9;
        // the bottom is layer 0's 400 mm^2 only.
        let mut mesh = cuboid([0.0, 0.0, 0.0], [20.0, 20.0, 1.0]);
        mesh.extend(cuboid([5.0, 5.0, 1.0], [15.0, 15.0, 2.0]));
        let c = surface_coverage_eroded(&layers_of(&mesh, |_| Vec::new()), 0.0);
        let by_layer: Vec<_> = c
            .layers
            .iter()
            .map(|l| (l.index, l.top.exposed_mm2(), l.bottom.exposed_mm2()))
            .collect();
        assert_eq!(by_layer, [(0, 0.0, 400.0), (4, 300.0, 0.0), (9, 100.0, 0.0)]);
    }

    #[test]
    fn slivers_of_a_steep_wall_do_not_count() {
        // A square frustum 10 mm tall whose sides move in 0.1 mm per mm (84° walls): bands
        // 20 um wide exposed on every layer's top, narrower than the erosion.
        let rings: Vec<(f64, Vec<[f64; 2]>)> = (0..=10)
            .map(|k| {
                let d = 0.1 * k as f64;
                (k as f64, square(d, 20.0 - d))
            })
            .collect();
        let layers = layers_of(&loft(&rings), |_| Vec::new());
        let raw = surface_coverage_eroded(&layers, 0.0);
        let eroded = surface_coverage(&layers);
        let last = layers.len() - 1;
        let slivers: u64 =
            raw.layers.iter().filter(|l| l.index != last).map(|l| l.top.exposed).sum();
        assert!(slivers > 1000, "{slivers}");
        for l in &eroded.layers {
            let top = if l.index == last { 0 } else { l.top.counted };
            let bottom = if l.index == 0 { 0 } else { l.bottom.counted };
            assert_eq!((top, bottom), (0, 0), "layer {}", l.index);
        }
        // The top face at the last plane (9.9 mm), 18.02 mm square, less the erosion's rim of
        // two cells; the bottom, 19.98 mm square, the same.
        let (top, bottom) = (eroded.top.area_mm2(), eroded.bottom.area_mm2());
        assert!((top - 17.82f64.powi(2)).abs() < 2.0, "{top}");
        assert!((bottom - 19.78f64.powi(2)).abs() < 2.0, "{bottom}");
    }
}

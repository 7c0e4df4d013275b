//! Infill and skins along scanlines, linked into long runs.
//!
//! For a layer `L` and its angle, the infill domain (the island shrunk past its perimeters)
//! is cut by lines one line width apart. Along each line, the 1D region is split exactly by
//! the skin window (the raw regions of the layers above and below, cut by the same line when
//! it is reached: [`line_spans`]):
//!
//! - *top solid* where layer `L + 1` has no material (or `L` is the last layer);
//! - *solid* where some layer within `top` above or `bottom` below has no material (a top or
//!   bottom surface is near), or where those layers do not exist (the first and last layers);
//! - *sparse* elsewhere, on every `k`-th line only (`k = 100 / density`).
//!
//! Printed stretches of a line form segments; a segment's ends on the domain boundary are
//! crossings. Segments are linked into runs (the zigzag): from a segment's end, the boundary
//! of the domain is walked (in both directions) to the next crossing that ends another
//! segment; if that segment is free and the walk is short, the run continues along the
//! boundary into it. Because a walk between consecutive crossings never crosses a line, the
//! connector stays inside the domain. Solid segments always link; sparse ones link for the
//! zigzag and grid patterns.

use crate::geom::Point2;

use super::paths::{PathBuf, PathKind};
use super::poly::{dist, segment_touches_rings, Ring};
use super::scan::{crossings, intervals, line_spans, sort_by_line, Angle, Crossing, Interval};
use super::window::StoredRings;
use super::{Buffer, Feature};

/// No crossing / no segment.
pub const NONE: u32 = u32::MAX;
/// Most crossings walked along the boundary looking for a link.
const MAX_WALK: usize = 64;
/// Most boundary vertices in one connector.
const MAX_CONNECTOR_VERTICES: usize = 64;
/// Most stretches of one interval that skin growth handles at once.
const MAX_STRETCHES: usize = 48;

pub use super::scan::Span;

/// What a stretch of a line gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Default)]
#[repr(u8)]
pub enum Kind {
    /// Nothing (sparse zone, not a sparse line).
    #[default]
    None = 0,
    /// Sparse infill.
    Sparse = 1,
    /// Solid infill.
    Solid = 2,
    /// Solid infill under no material (the top surface).
    Top = 3,
}

impl Kind {
    fn feature(self) -> Feature {
        match self {
            Kind::Sparse | Kind::None => Feature::InternalInfill,
            Kind::Solid => Feature::SolidInfill,
            Kind::Top => Feature::TopSolidInfill,
        }
    }
}

/// A printed stretch of one line: pieces `piece0 .. piece0 + npieces` give its kinds.
#[derive(Debug, Clone, Copy, Default)]
pub struct LineSeg {
    line: i32,
    u0: i32,
    u1: i32,
    c0: u32,
    c1: u32,
    piece0: u32,
    npieces: u32,
    island: u16,
    used: bool,
    /// Solid or top (otherwise sparse).
    solid: bool,
    linkable: bool,
}

/// A piece of a segment: up to `u1`, of `kind`.
#[derive(Debug, Clone, Copy, Default)]
pub struct LinePiece {
    u1: i32,
    kind: Kind,
}

impl LinePiece {
    /// An empty piece (buffer filler).
    pub const EMPTY: Self = Self { u1: 0, kind: Kind::None };
}

impl LineSeg {
    /// An empty segment (buffer filler).
    pub const EMPTY: Self = Self {
        line: 0,
        u0: 0,
        u1: 0,
        c0: 0,
        c1: 0,
        piece0: 0,
        npieces: 0,
        island: 0,
        used: false,
        solid: false,
        linkable: false,
    };
}

/// The skin window as seen from one layer: the stored contours ([`StoredRings`]) of the
/// layers around it.
#[derive(Debug, Clone, Copy)]
pub struct SkinView<'a> {
    /// Layers `L + 1 ..= L + top` (those that exist).
    pub above: [&'a [Point2]; 16],
    /// Number of entries in `above`.
    pub n_above: usize,
    /// All `top` layers above exist (otherwise nothing is covered from above).
    pub above_complete: bool,
    /// Layers `L - 1 ..= L - bottom` (those that exist).
    pub below: [&'a [Point2]; 16],
    /// Number of entries in `below`.
    pub n_below: usize,
    /// All `bottom` layers below exist.
    pub below_complete: bool,
    /// Whether layer `L + 1` exists (it is `above[0]`).
    pub has_next: bool,
}

/// Parameters of one infill pass.
#[derive(Debug, Clone, Copy)]
pub struct FillParams {
    /// Line direction.
    pub angle: Angle,
    /// Line step in `t` units.
    pub step: i64,
    /// Line spacing in um.
    pub spacing_um: i32,
    /// Sparse lines are those with `line % sparse_every == 0` (0: no sparse infill).
    pub sparse_every: i32,
    /// Print solid and top skins in this pass.
    pub solid: bool,
    /// Link sparse segments into runs (zigzag, grid).
    pub link_sparse: bool,
    /// Segments shorter than this (in `u` units) are dropped.
    pub min_len_u: i32,
    /// Line width in um (connector length allowance).
    pub width_um: i32,
    /// Skins shrink this far (in `u` units) first: the regions of the window layers count
    /// as grown by it, so skin slivers narrower than twice this vanish (perimeters cover
    /// them).
    pub erode_u: i32,
    /// Solid skins then grow this far (in `u` units) into the sparse zone along each line.
    pub margin_u: i32,
    /// Run ends on the domain boundary are pushed this far (in `u` units) further out.
    pub end_ext_u: i32,
}

/// The scratch buffers of the infill stage (`CROSS` entries each).
pub struct FillWork<'a> {
    /// Crossings.
    pub cross: &'a mut [Crossing],
    /// Crossing order by line.
    pub order: &'a mut [u32],
    /// Segment end at each crossing (`2 x seg + end`), or [`NONE`].
    pub cend: &'a mut [u32],
    /// Segments.
    pub segs: &'a mut [LineSeg],
    /// Their pieces.
    pub pieces: &'a mut [LinePiece],
    /// The window's spans on the current line, all its layers (`SPANS`).
    pub spans: &'a mut [Span],
}

/// What one pass used (largest counts).
#[derive(Debug, Clone, Copy, Default)]
pub struct FillUse {
    /// Crossings.
    pub crossings: usize,
    /// Segments.
    pub segments: usize,
    /// Pieces.
    pub pieces: usize,
    /// Window crossings on one line.
    pub spans: usize,
}

/// Cursor over one window layer's spans on the current line, `spans[idx..end]` left; every
/// span counts as grown by `grow` at both ends.
#[derive(Clone, Copy, Default)]
struct Cursor {
    start: usize,
    idx: usize,
    end: usize,
}

impl Cursor {
    /// Whether `pos` is covered, and the next boundary after `pos` (if any); `pos` never
    /// decreases between [`Skin::set_line`]s.
    fn probe(&mut self, spans: &[Span], grow: i32, pos: i32) -> (bool, Option<i32>) {
        let left = spans.get(self.idx..self.end).unwrap_or(&[]);
        let skip = left.iter().take_while(|s| s.u1 + grow <= pos).count();
        self.idx += skip;
        match left.get(skip) {
            Some(s) if s.u0 - grow <= pos => (true, Some(s.u1 + grow)),
            Some(s) => (false, Some(s.u0 - grow)),
            None => (false, None),
        }
    }
}

struct Builder<'a> {
    segs: &'a mut [LineSeg],
    pieces: &'a mut [LinePiece],
    nseg: usize,
    npieces: usize,
    /// The segment being built: (start u, start crossing, first piece).
    open: Option<(i32, u32, usize)>,
    params: FillParams,
}

impl Builder<'_> {
    fn add_stretch(&mut self, iv: &Interval, u0: i32, u1: i32, kind: Kind) -> Result<(), Buffer> {
        if kind == Kind::None {
            return self.close(iv, u0, NONE);
        }
        // Solid and sparse never share a segment: each class is linked on its own.
        if let Some((_, _, first)) = self.open {
            if self.npieces > first
                && (self.pieces[self.npieces - 1].kind >= Kind::Solid) != (kind >= Kind::Solid)
            {
                self.close(iv, u0, NONE)?;
            }
        }
        if self.open.is_none() {
            let c0 = if u0 == iv.u0 { iv.c0 } else { NONE };
            self.open = Some((u0, c0, self.npieces));
        }
        let first = self.open.map_or(0, |o| o.2);
        if self.npieces > first && self.pieces[self.npieces - 1].kind == kind {
            self.pieces[self.npieces - 1].u1 = u1;
            return Ok(());
        }
        let slot = self.pieces.get_mut(self.npieces).ok_or(Buffer::LineSegments)?;
        *slot = LinePiece { u1, kind };
        self.npieces += 1;
        Ok(())
    }

    /// Ends the open segment at `u1` (crossing `c1`).
    fn close(&mut self, iv: &Interval, u1: i32, c1: u32) -> Result<(), Buffer> {
        let Some((u0, c0, piece0)) = self.open.take() else { return Ok(()) };
        if u1 - u0 < self.params.min_len_u {
            self.npieces = piece0;
            return Ok(());
        }
        let pieces = &self.pieces[piece0..self.npieces];
        let solid = pieces.iter().any(|p| p.kind >= Kind::Solid);
        let slot = self.segs.get_mut(self.nseg).ok_or(Buffer::LineSegments)?;
        *slot = LineSeg {
            line: iv.line,
            u0,
            u1,
            c0,
            c1,
            piece0: piece0 as u32,
            npieces: (self.npieces - piece0) as u32,
            island: iv.island,
            used: false,
            solid,
            linkable: solid || self.params.link_sparse,
        };
        self.nseg += 1;
        Ok(())
    }

    fn interval(&mut self, iv: Interval, skin: &mut Skin<'_>) -> Result<(), Buffer> {
        skin.set_line(iv.line)?;
        let p = self.params;
        let sparse_line = p.sparse_every > 0 && iv.line.rem_euclid(p.sparse_every) == 0;
        // Stretches of this interval, then the solid ones grown by `margin_u` into their
        // non-solid neighbours (skins overlap the sparse zone instead of ending exactly on
        // the surface's edge).
        let mut st = [(0i32, 0i32, Kind::None); MAX_STRETCHES];
        let mut ns = 0;
        let mut pos = iv.u0;
        while pos < iv.u1 {
            let (covered, in_next, next) = skin.probe(pos, iv.u1);
            let kind = if !covered {
                if !p.solid {
                    Kind::None
                } else if in_next {
                    Kind::Solid
                } else {
                    Kind::Top
                }
            } else if sparse_line {
                Kind::Sparse
            } else {
                Kind::None
            };
            if ns > 0 && st[ns - 1].2 == kind {
                st[ns - 1].1 = next;
            } else if ns < MAX_STRETCHES {
                st[ns] = (pos, next, kind);
                ns += 1;
            } else {
                // Too fragmented to grow: emit what we have as it is.
                for &(a, b, k) in &st[..ns] {
                    self.add_stretch(&iv, a, b, k)?;
                }
                st[0] = (pos, next, kind);
                ns = 1;
            }
            pos = next;
        }
        let m = p.margin_u;
        if m > 0 && p.solid {
            for i in 0..ns {
                if st[i].2 < Kind::Solid {
                    continue;
                }
                if i + 1 < ns && st[i + 1].2 < Kind::Solid {
                    let take = m.min(st[i + 1].1 - st[i + 1].0);
                    st[i].1 += take;
                    st[i + 1].0 += take;
                }
                if i > 0 && st[i - 1].2 < Kind::Solid {
                    let take = m.min(st[i - 1].1 - st[i - 1].0);
                    st[i].0 -= take;
                    st[i - 1].1 -= take;
                }
            }
        }
        for &(a, b, k) in &st[..ns] {
            if b > a {
                self.add_stretch(&iv, a, b, k)?;
            }
        }
        self.close(&iv, iv.u1, iv.c1)
    }
}

/// Cursors over the skin window for one pass.
struct Skin<'a> {
    above: [Cursor; 16],
    below: [Cursor; 16],
    view: SkinView<'a>,
    top: usize,
    bottom: usize,
    /// Spans of every window layer on `line` (the layers' runs one after the other).
    spans: &'a mut [Span],
    line: Option<i32>,
    angle: Angle,
    step: i64,
    grow: i32,
    /// Most entries of `spans` used.
    peak: usize,
}

impl<'a> Skin<'a> {
    fn new(
        view: SkinView<'a>,
        top: usize,
        bottom: usize,
        p: &FillParams,
        spans: &'a mut [Span],
    ) -> Self {
        let c = Cursor::default();
        Self {
            above: [c; 16],
            below: [c; 16],
            view,
            top,
            bottom,
            spans,
            line: None,
            angle: p.angle,
            step: p.step,
            grow: p.erode_u,
            peak: 0,
        }
    }

    /// Moves to `line`: cuts every window layer with it (once per line) and rewinds.
    fn set_line(&mut self, line: i32) -> Result<(), Buffer> {
        let v = &self.view;
        let layers = (self.above.iter_mut().zip(&v.above).take(v.n_above))
            .chain(self.below.iter_mut().zip(&v.below).take(v.n_below));
        if self.line == Some(line) {
            for (c, _) in layers {
                c.idx = c.start;
            }
            return Ok(());
        }
        self.line = None;
        let mut at = 0;
        for (c, data) in layers {
            let out = self.spans.get_mut(at..).unwrap_or(&mut []);
            let rings = StoredRings::new(data).map(|(_, pts)| pts);
            let (n, used) = line_spans(rings, self.angle, line, self.step, out)?;
            self.peak = self.peak.max(at + used);
            *c = Cursor { start: at, idx: at, end: at + n };
            at += n;
        }
        self.line = Some(line);
        Ok(())
    }

    /// At `pos`: covered by every layer of the window (no surface near), covered by layer
    /// L + 1, and where that next changes (at most `end`).
    fn probe(&mut self, pos: i32, end: i32) -> (bool, bool, i32) {
        let mut next = end;
        let mut all_above = self.top == 0 || self.view.above_complete;
        let mut all_below = self.bottom == 0 || self.view.below_complete;
        let mut in_next = false;
        let (spans, g) = (&*self.spans, self.grow);
        for (k, c) in self.above.iter_mut().take(self.view.n_above).enumerate() {
            let (cov, b) = c.probe(spans, g, pos);
            if let Some(b) = b {
                next = next.min(b);
            }
            if k == 0 && self.view.has_next {
                in_next = cov;
            }
            if k < self.top {
                all_above &= cov;
            }
        }
        for (k, c) in self.below.iter_mut().take(self.view.n_below).enumerate() {
            let (cov, b) = c.probe(spans, g, pos);
            if let Some(b) = b {
                next = next.min(b);
            }
            if k < self.bottom {
                all_below &= cov;
            }
        }
        (all_above && all_below, in_next, next.max(pos + 1))
    }
}

fn seg_point(p: &FillParams, line: i32, u: i32) -> Point2 {
    p.angle.point(i64::from(line) * p.step, i64::from(u))
}

fn crossing_point(p: &FillParams, c: &Crossing) -> Point2 {
    seg_point(p, c.line, c.u)
}

/// Boundary vertices passed walking from crossing `i` to crossing `k` (`fwd`: along the
/// loop's direction). Returns false if more than [`MAX_CONNECTOR_VERTICES`].
fn for_each_vertex(
    cross: &[Crossing],
    rings: &[Ring],
    points: &[Point2],
    i: usize,
    k: usize,
    fwd: bool,
    mut f: impl FnMut(Point2),
) -> bool {
    let (ci, ck) = (&cross[i], &cross[k]);
    let Some(r) = rings.get(ci.ring as usize) else { return false };
    let (start, len) = (r.start as usize, r.len as usize);
    if len == 0 {
        return false;
    }
    let (e1, e2) = (ci.edge as usize - start, ck.edge as usize - start);
    let wrapped = if fwd { k <= i } else { k >= i };
    let count = if fwd {
        if e1 == e2 && !wrapped {
            0
        } else {
            (e2 + len - e1 - 1) % len + 1
        }
    } else if e1 == e2 && !wrapped {
        0
    } else {
        (e1 + len - e2 - 1) % len + 1
    };
    if e1 == e2 && wrapped {
        return false;
    }
    if count > MAX_CONNECTOR_VERTICES {
        return false;
    }
    for s in 0..count {
        let v = if fwd { (e1 + 1 + s) % len } else { (e1 + len - s) % len };
        f(points[start + v]);
    }
    true
}

/// Builds the infill of one layer at one angle into `paths`.
#[allow(clippy::too_many_arguments)]
pub fn fill<const N: usize, const R: usize>(
    points: &[Point2],
    rings: &[Ring],
    params: FillParams,
    view: SkinView<'_>,
    top: usize,
    bottom: usize,
    work: &mut FillWork<'_>,
    paths: &mut PathBuf<N, R>,
    usage: &mut FillUse,
) -> Result<(), Buffer> {
    let mut n = 0;
    crossings(points, rings, params.angle, params.step, work.cross, &mut n)?;
    if n > work.order.len() || n > work.cend.len() {
        return Err(Buffer::Crossings);
    }
    sort_by_line(&work.cross[..n], &mut work.order[..n]);
    usage.crossings = usage.crossings.max(n);
    for c in work.cend[..n].iter_mut() {
        *c = NONE;
    }
    let mut skin = Skin::new(view, top, bottom, &params, &mut *work.spans);
    let (nseg, npieces) = {
        let (cross, order) = (&work.cross[..n], &work.order[..n]);
        let mut b = Builder {
            segs: &mut *work.segs,
            pieces: &mut *work.pieces,
            nseg: 0,
            npieces: 0,
            open: None,
            params,
        };
        let r = intervals(cross, order, |iv| b.interval(iv, &mut skin));
        usage.spans = usage.spans.max(skin.peak);
        r?;
        (b.nseg, b.npieces)
    };
    usage.segments = usage.segments.max(nseg);
    usage.pieces = usage.pieces.max(npieces);
    for s in 0..nseg {
        let sg = work.segs[s];
        if sg.c0 != NONE {
            work.cend[sg.c0 as usize] = 2 * s as u32;
        }
        if sg.c1 != NONE {
            work.cend[sg.c1 as usize] = 2 * s as u32 + 1;
        }
    }
    link(points, rings, &params, work, n, nseg, paths)
}

/// Emits segment `s` (forward: from `u0`) into the open path.
fn emit_seg<const N: usize, const R: usize>(
    p: &FillParams,
    work: &FillWork<'_>,
    s: usize,
    forward: bool,
    paths: &mut PathBuf<N, R>,
) -> Result<(), Buffer> {
    let sg = work.segs[s];
    let pieces = &work.pieces[sg.piece0 as usize..(sg.piece0 + sg.npieces) as usize];
    let first_kind = if forward { pieces[0].kind } else { pieces[pieces.len() - 1].kind };
    if forward {
        paths.push(seg_point(p, sg.line, sg.u0), first_kind.feature())?;
        for pc in pieces {
            paths.push(seg_point(p, sg.line, pc.u1), pc.kind.feature())?;
        }
    } else {
        paths.push(seg_point(p, sg.line, sg.u1), first_kind.feature())?;
        for (i, pc) in pieces.iter().enumerate().rev() {
            let u = if i == 0 { sg.u0 } else { pieces[i - 1].u1 };
            paths.push(seg_point(p, sg.line, u), pc.kind.feature())?;
        }
    }
    Ok(())
}

/// Where a run stands: at segment `seg`'s `u1` end (`at_u1`) or its `u0` end.
#[derive(Clone, Copy)]
struct End {
    seg: usize,
    at_u1: bool,
}

impl End {
    fn crossing(self, segs: &[LineSeg]) -> u32 {
        let s = &segs[self.seg];
        if self.at_u1 {
            s.c1
        } else {
            s.c0
        }
    }

    fn u(self, segs: &[LineSeg]) -> i32 {
        let s = &segs[self.seg];
        if self.at_u1 {
            s.u1
        } else {
            s.u0
        }
    }

    fn point(self, p: &FillParams, segs: &[LineSeg]) -> Point2 {
        seg_point(p, segs[self.seg].line, self.u(segs))
    }

    /// The end pushed `ext` further out along the line.
    fn extended(self, p: &FillParams, segs: &[LineSeg], ext: i32) -> Point2 {
        let u = if self.at_u1 { self.u(segs) + ext } else { self.u(segs) - ext };
        seg_point(p, segs[self.seg].line, u)
    }
}

/// The next segment reachable along the boundary from crossing `from`: (crossing, walk
/// direction), if its segment is free, linkable and the walk short enough.
#[allow(clippy::too_many_arguments)]
fn boundary_link(
    points: &[Point2],
    rings: &[Ring],
    p: &FillParams,
    work: &FillWork<'_>,
    cross: &[Crossing],
    from: usize,
    at: End,
    pref: i32,
) -> Option<(usize, bool)> {
    let here = &work.segs[at.seg];
    let mut best: Option<((i32, bool, i64), usize, bool)> = None;
    for fwd in [true, false] {
        let mut k = from;
        let mut found = None;
        for _ in 0..MAX_WALK {
            let c = &cross[k];
            k = if fwd { c.next(k) } else { c.prev(k) };
            if k == from {
                break;
            }
            if work.cend[k] != NONE {
                found = Some(k);
                break;
            }
        }
        let Some(k) = found else { continue };
        let sg = &work.segs[(work.cend[k] / 2) as usize];
        if sg.used || !sg.linkable || sg.solid != here.solid {
            continue;
        }
        let step = sg.line - here.line;
        let mut length = 0i64;
        let mut prev = crossing_point(p, &cross[from]);
        let ok = for_each_vertex(cross, rings, points, from, k, fwd, |v| {
            length += dist(prev, v);
            prev = v;
        });
        if !ok {
            continue;
        }
        length += dist(prev, crossing_point(p, &cross[k]));
        let allowed = i64::from(step.abs()) * i64::from(p.spacing_um) * 4 + i64::from(p.width_um);
        let score = (step.abs(), step.signum() != pref && pref != 0, length);
        if length <= allowed && best.map_or(true, |b| score < b.0) {
            best = Some((score, k, fwd));
        }
    }
    best.map(|b| (b.1, b.2))
}

/// The nearest free interior segment end of the same class on the next lines (1 or 2 away
/// for solid, one sparse step for sparse) that a straight connector from `at` reaches
/// without leaving the domain.
fn interior_link(
    points: &[Point2],
    rings: &[Ring],
    p: &FillParams,
    segs: &[LineSeg],
    at: End,
    pref: i32,
) -> Option<End> {
    let here = at.point(p, segs);
    let cur = &segs[at.seg];
    let k = p.sparse_every.max(1);
    let steps: &[i32] = if cur.solid { &[1, -1, 2, -2] } else { &[1, -1] };
    let mut best: Option<((i32, bool, i64), End)> = None;
    for &dl in steps {
        let dl = if cur.solid { dl } else { dl * k };
        let target = cur.line + dl;
        let lo = segs.partition_point(|s| s.line < target);
        let allowed = 3 * i64::from(dl.abs()) * i64::from(p.spacing_um);
        for (i, s) in segs[lo..].iter().enumerate().take_while(|(_, s)| s.line == target) {
            if s.used || !s.linkable || s.solid != cur.solid {
                continue;
            }
            for at_u1 in [false, true] {
                let e = End { seg: lo + i, at_u1 };
                if e.crossing(segs) != NONE {
                    continue;
                }
                let d = dist(here, e.point(p, segs));
                let score = (dl.abs(), dl.signum() != pref && pref != 0, d);
                if d <= allowed && best.map_or(true, |b| score < b.0) {
                    best = Some((score, e));
                }
            }
        }
    }
    let (_, e) = best?;
    (!segment_touches_rings(points, rings, here, e.point(p, segs))).then_some(e)
}

/// Links segments into runs and emits them as paths.
fn link<const N: usize, const R: usize>(
    points: &[Point2],
    rings: &[Ring],
    p: &FillParams,
    work: &mut FillWork<'_>,
    n: usize,
    nseg: usize,
    paths: &mut PathBuf<N, R>,
) -> Result<(), Buffer> {
    let cross = &work.cross[..n];
    for s0 in 0..nseg {
        if work.segs[s0].used {
            continue;
        }
        work.segs[s0].used = true;
        let island = work.segs[s0].island;
        let reversible = work.segs[s0].linkable;
        emit_seg(p, work, s0, true, paths)?;
        // Unlinked ends on the boundary reach a little into the perimeter.
        let start = End { seg: s0, at_u1: false };
        if start.crossing(work.segs) != NONE && p.end_ext_u > 0 {
            paths.set_open_point(0, true, start.extended(p, work.segs, p.end_ext_u));
        }
        let mut at = End { seg: s0, at_u1: true };
        let mut pref = 0;
        while work.segs[s0].linkable {
            let end_c = at.crossing(work.segs);
            let line = work.segs[at.seg].line;
            let next = if end_c != NONE {
                boundary_link(points, rings, p, work, cross, end_c as usize, at, pref).map(
                    |(k, fwd)| {
                        let e =
                            End { seg: (work.cend[k] / 2) as usize, at_u1: work.cend[k] % 2 == 1 };
                        (e, Some((end_c as usize, k, fwd)))
                    },
                )
            } else {
                interior_link(points, rings, p, &work.segs[..nseg], at, pref).map(|e| (e, None))
            };
            let Some((e, walk)) = next else { break };
            let feat = {
                let sg = work.segs[e.seg];
                let pieces = &work.pieces[sg.piece0 as usize..(sg.piece0 + sg.npieces) as usize];
                if e.at_u1 {
                    pieces[pieces.len() - 1].kind.feature()
                } else {
                    pieces[0].kind.feature()
                }
            };
            if let Some((from, k, fwd)) = walk {
                let mut err = Ok(());
                for_each_vertex(cross, rings, points, from, k, fwd, |v| {
                    if err.is_ok() {
                        err = paths.push(v, feat);
                    }
                });
                err?;
            }
            work.segs[e.seg].used = true;
            emit_seg(p, work, e.seg, !e.at_u1, paths)?;
            // Entered at one end: now at the other.
            pref = (work.segs[e.seg].line - line).signum();
            at = End { seg: e.seg, at_u1: !e.at_u1 };
        }
        if at.crossing(work.segs) != NONE && p.end_ext_u > 0 {
            paths.set_open_point(0, false, at.extended(p, work.segs, p.end_ext_u));
        }
        paths.end(island, PathKind::Infill, false, reversible)?;
    }
    Ok(())
}

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
use crate::math::isqrt_u64;

use super::paths::{PathBuf, PathKind};
use super::poly::{dist, segment_touches_rings, Ring};
use super::scan::{
    crossings, intervals, line_spans, loop_range, next_in, prev_in, sort_by_line, Angle, Crossing,
    Interval, Loops,
};
use super::window::{self, StoredRings};
use super::{Buffer, Feature, SparseLines};

/// No crossing / no segment end (a `u16` index).
pub const NONE: u16 = u16::MAX;
/// Words of [`FillWork::pool`] per `CROSS`: a crossing's share of segments and pieces.
pub const POOL_WORDS: usize = 3;
/// Words per segment in the pool (see [`Segs`]).
const SEG_WORDS: usize = 5;
/// Most segments of one pass: `2 x seg + end` fits a `u16` below [`NONE`].
const MAX_SEGS: usize = (NONE as usize - 1) / 2;
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
    /// Solid infill over sparse infill (the lowest layer of a top skin, far from any bottom
    /// surface): an internal bridge across the sparse lines below (with bridges on).
    OverSparse = 4,
    /// Over no material of the layer below, left to the bridge pass
    /// ([`OverAir::Leave`]): nothing in this pass, and no skin grows into it (never stored in
    /// a piece).
    Air = 5,
}

impl Kind {
    /// The feature of a stretch of this kind in a pass of `p` (all of a bridge pass's are
    /// bridges).
    fn feature(self, p: &FillParams) -> Feature {
        match self {
            _ if p.over_air == OverAir::Bridge => Feature::BridgeInfill,
            Kind::Sparse | Kind::None | Kind::Air => Feature::InternalInfill,
            Kind::Solid => Feature::SolidInfill,
            Kind::Top => Feature::TopSolidInfill,
            Kind::OverSparse => Feature::BridgeInfill,
        }
    }
}

/// What a pass makes of the stretches over no material of the layer below (a bottom surface
/// over air, not within half a line of that layer's region).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverAir {
    /// Solid skin like any bottom surface (no bridges, or the first layer).
    Solid,
    /// Nothing: a later [`OverAir::Bridge`] pass prints them; counted in [`BridgeTally`].
    Leave,
    /// Only them, as bridges ([`Feature::BridgeInfill`]), each grown by the skin margin onto
    /// the material around it (its anchors).
    Bridge,
    /// Like `Bridge`, but only counted ([`BridgeTally`]): nothing is printed.
    Measure,
    /// Over the layer's own region (its contour, not the infill domain): the perimeters'
    /// moves whose middle lies over air on both lines around it become
    /// [`Feature::OverhangPerimeter`]; nothing is printed.
    Locate,
}

/// The stretches over air one pass met ([`OverAir`]), in its along-line units (saturating:
/// a bed-wide layer's lines are far fewer than `2^32` units).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BridgeTally {
    /// All of them.
    pub over_air_u: u32,
    /// Those with material of the layer below at both ends along their line (anchored).
    pub anchored_u: u32,
}

impl BridgeTally {
    /// Nothing met.
    pub const NONE: Self = Self { over_air_u: 0, anchored_u: 0 };
}

/// A printed stretch of one line: pieces `piece0 .. piece0 + npieces` give its kinds.
#[derive(Debug, Clone, Copy, Default)]
pub struct LineSeg {
    line: i32,
    u0: i32,
    u1: i32,
    c0: u16,
    c1: u16,
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
    /// An empty piece.
    pub const EMPTY: Self = Self { u1: 0, kind: Kind::None };
}

impl LineSeg {
    /// An empty segment.
    pub const EMPTY: Self = Self {
        line: 0,
        u0: 0,
        u1: 0,
        c0: NONE,
        c1: NONE,
        piece0: 0,
        npieces: 0,
        island: 0,
        used: false,
        solid: false,
        linkable: false,
    };
}

/// The segments and pieces of one pass in one word pool.
///
/// Segment `s` in the 5 words from `5 s` (`line x 8 + flags`, `u0`, `c0 + c1 x 2^16`, `piece0`,
/// `npieces + island x 2^16`; its `u1` is its last piece's), piece `k` in the word `len - 1 - k`
/// from the back (`u1 x 8 + kind`). A line beyond `2^28`, a `u1` beyond `2^28` or a segment of more
/// than 65535 pieces is [`Buffer::LineSegments`], like a full pool.
pub struct Segs<'a> {
    w: &'a mut [u32],
    /// Segments.
    pub nseg: usize,
    /// Pieces.
    pub npieces: usize,
}

impl<'a> Segs<'a> {
    /// Empty, in `w`.
    pub fn new(w: &'a mut [u32]) -> Self {
        Self { w, nseg: 0, npieces: 0 }
    }

    /// Words in use.
    pub fn used_words(&self) -> usize {
        SEG_WORDS * self.nseg + self.npieces
    }

    fn free_words(&self) -> usize {
        self.w.len().saturating_sub(self.used_words())
    }

    fn push_seg(&mut self, s: &LineSeg) -> Result<(), Buffer> {
        let fits = self.free_words() >= SEG_WORDS
            && (-(1 << 28)..1 << 28).contains(&s.line)
            && (1..=u32::from(u16::MAX)).contains(&s.npieces);
        debug_assert!(!fits || s.u1 == self.piece((s.piece0 + s.npieces) as usize - 1).u1);
        let at = SEG_WORDS * self.nseg;
        let slot = self.w.get_mut(at..at + SEG_WORDS).filter(|_| fits);
        let slot = slot.ok_or(Buffer::LineSegments)?;
        let flags = u32::from(s.used) | u32::from(s.solid) << 1 | u32::from(s.linkable) << 2;
        slot.copy_from_slice(&[
            (s.line as u32) << 3 | flags,
            s.u0 as u32,
            u32::from(s.c0) | u32::from(s.c1) << 16,
            s.piece0,
            s.npieces | u32::from(s.island) << 16,
        ]);
        self.nseg += 1;
        Ok(())
    }

    /// Segment `s` (an empty one past the end).
    pub fn get(&self, s: usize) -> LineSeg {
        let Some(w) = self.w.get(SEG_WORDS * s..SEG_WORDS * s + SEG_WORDS) else {
            return LineSeg::EMPTY;
        };
        let (piece0, npieces) = (w[3], w[4] & 0xFFFF);
        LineSeg {
            line: (w[0] as i32) >> 3,
            used: w[0] & 1 != 0,
            solid: w[0] & 2 != 0,
            linkable: w[0] & 4 != 0,
            u0: w[1] as i32,
            u1: (piece0 + npieces)
                .checked_sub(1)
                .map_or(w[1] as i32, |k| self.piece(k as usize).u1),
            c0: w[2] as u16,
            c1: (w[2] >> 16) as u16,
            piece0,
            npieces,
            island: (w[4] >> 16) as u16,
        }
    }

    fn set_used(&mut self, s: usize) {
        if let Some(w) = self.w.get_mut(SEG_WORDS * s) {
            *w |= 1;
        }
    }

    fn piece_slot(&self, k: usize) -> Option<usize> {
        (k < self.npieces).then(|| self.w.len() - 1 - k)
    }

    /// Piece `k` (an empty one past the end).
    pub fn piece(&self, k: usize) -> LinePiece {
        let Some(&w) = self.piece_slot(k).and_then(|i| self.w.get(i)) else {
            return LinePiece::EMPTY;
        };
        let kind = match w & 7 {
            0 => Kind::None,
            1 => Kind::Sparse,
            2 => Kind::Solid,
            3 => Kind::Top,
            _ => Kind::OverSparse,
        };
        LinePiece { u1: (w as i32) >> 3, kind }
    }

    fn set_piece(&mut self, k: usize, p: LinePiece) -> Result<(), Buffer> {
        let i = self.piece_slot(k).filter(|_| (-(1 << 28)..1 << 28).contains(&p.u1));
        let slot = i.and_then(|i| self.w.get_mut(i)).ok_or(Buffer::LineSegments)?;
        *slot = (p.u1 as u32) << 3 | p.kind as u32;
        Ok(())
    }

    fn push_piece(&mut self, p: LinePiece) -> Result<(), Buffer> {
        if self.free_words() == 0 {
            return Err(Buffer::LineSegments);
        }
        self.npieces += 1;
        self.set_piece(self.npieces - 1, p).inspect_err(|_| self.npieces -= 1)
    }
}

/// The skin window as seen from one layer: the stored contours ([`StoredRings`]) of the
/// layers around it, as `(start, len)` blocks of the window's storage ([`window::parts`]).
#[derive(Debug, Clone, Copy)]
pub struct SkinView<'a> {
    /// The window's storage.
    pub ring: &'a [u32],
    /// Layers `L + 1 ..= L + top` (those that exist).
    pub above: [(u32, u32); 16],
    /// Number of entries in `above`.
    pub n_above: usize,
    /// All `top` layers above exist (otherwise nothing is covered from above).
    pub above_complete: bool,
    /// Layers `L - 1 ..= L - bottom` (those that exist).
    pub below: [(u32, u32); 16],
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
    /// Which lines are sparse infill lines.
    pub sparse: SparseLines,
    /// Print solid and top skins in this pass.
    pub solid: bool,
    /// What the pass makes of stretches over air.
    pub over_air: OverAir,
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

/// The scratch buffers of the infill stage.
pub struct FillWork<'a> {
    /// Crossings (`CROSS`).
    pub cross: &'a mut [Crossing],
    /// The crossings' order by line, then (once the segments are built) the segment end at
    /// each crossing (`2 x seg + end`, or [`NONE`]) (`CROSS`).
    pub idx: &'a mut [u16],
    /// Segments and their pieces ([`Segs`], [`POOL_WORDS`] x `CROSS` words).
    pub pool: &'a mut [u32],
    /// The window's spans on the current line, all its layers (`SPANS`).
    pub spans: &'a mut [Span],
}

/// What one pass used (largest counts).
#[derive(Debug, Clone, Copy, Default)]
pub struct FillUse {
    /// Crossings.
    pub crossings: usize,
    /// Pool words of segments and pieces, in [`POOL_WORDS`] units.
    pub segments: usize,
    /// Window crossings on one line.
    pub spans: usize,
    /// The stretches over air the last pass met (kept here, not on the stack).
    pub bridge: BridgeTally,
    /// Segments and pieces an [`OverAir::Locate`] pass left in the pool, for
    /// [`tag_overhangs`].
    pub located: (usize, usize),
}

/// Cursor over one window layer's spans on the current line, `spans[idx..end]` left (its
/// spans start where the previous layer's `end` is); every span counts as grown by `grow` at
/// both ends.
#[derive(Clone, Copy, Default)]
struct Cursor {
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
    segs: Segs<'a>,
    cross: &'a [Crossing],
    rings: &'a [Ring],
    /// The segment being built: (start u, start crossing, first piece).
    open: Option<(i32, u16, usize)>,
    params: &'a FillParams,
    /// Stretches over air met.
    tally: &'a mut BridgeTally,
}

impl Builder<'_> {
    fn last_kind(&self) -> Kind {
        self.segs.piece(self.segs.npieces.wrapping_sub(1)).kind
    }

    fn add_stretch(&mut self, iv: &Interval, u0: i32, u1: i32, kind: Kind) -> Result<(), Buffer> {
        if kind == Kind::Air {
            self.close(iv, u0, NONE)?;
            return self.block(iv, u0, u1);
        }
        if kind == Kind::None {
            return self.close(iv, u0, NONE);
        }
        // Solid and sparse never share a segment: each class is linked on its own.
        if let Some((_, _, first)) = self.open {
            if self.segs.npieces > first
                && (self.last_kind() >= Kind::Solid) != (kind >= Kind::Solid)
            {
                self.close(iv, u0, NONE)?;
            }
        }
        if self.open.is_none() {
            let c0 = if u0 == iv.u0 { iv.c0 } else { NONE };
            self.open = Some((u0, c0, self.segs.npieces));
        }
        let first = self.open.map_or(0, |o| o.2);
        if self.segs.npieces > first && self.last_kind() == kind {
            return self.segs.set_piece(self.segs.npieces - 1, LinePiece { u1, kind });
        }
        self.segs.push_piece(LinePiece { u1, kind })
    }

    /// A stretch left for the bridge pass that reaches the boundary: a used segment there, so
    /// that boundary links stop at its crossing instead of walking over the air.
    fn block(&mut self, iv: &Interval, u0: i32, u1: i32) -> Result<(), Buffer> {
        let c0 = if u0 == iv.u0 { iv.c0 } else { NONE };
        let c1 = if u1 == iv.u1 { iv.c1 } else { NONE };
        if c0 == NONE && c1 == NONE {
            return Ok(());
        }
        let piece0 = self.segs.npieces as u32;
        self.segs.push_piece(LinePiece { u1, kind: Kind::None })?;
        self.segs.push_seg(&LineSeg {
            line: iv.line,
            u0,
            u1,
            c0,
            c1,
            piece0,
            npieces: 1,
            island: 0,
            used: true,
            solid: false,
            linkable: false,
        })
    }

    /// Ends the open segment at `u1` (crossing `c1`).
    fn close(&mut self, iv: &Interval, u1: i32, c1: u16) -> Result<(), Buffer> {
        let Some((u0, c0, piece0)) = self.open.take() else { return Ok(()) };
        if u1 - u0 < self.params.min_len_u {
            self.segs.npieces = piece0;
            return Ok(());
        }
        let solid = (piece0..self.segs.npieces).any(|k| self.segs.piece(k).kind >= Kind::Solid);
        // The island of the interval's starting crossing.
        let ring = self.cross.get(usize::from(iv.c0)).map(Crossing::ring);
        let island = ring.and_then(|r| self.rings.get(r)).map_or(0, |r| r.island);
        self.segs.push_seg(&LineSeg {
            line: iv.line,
            u0,
            u1,
            c0,
            c1,
            piece0: piece0 as u32,
            npieces: (self.segs.npieces - piece0) as u32,
            island,
            used: false,
            solid,
            linkable: solid || self.params.link_sparse,
        })
    }

    fn interval(&mut self, iv: Interval, skin: &mut Skin<'_>) -> Result<(), Buffer> {
        skin.set_line(iv.line)?;
        let p = *self.params;
        let sparse_line = p.sparse.is_sparse(iv.line);
        // Stretches of this interval, then the solid ones grown by `margin_u` into their
        // non-solid neighbours (skins overlap the sparse zone instead of ending exactly on
        // the surface's edge).
        // Stretch `k` is `at[k]..at[k + 1]` of `kinds[k]`: stretches are contiguous, so they
        // share their ends (5 B a stretch on the stack, not 12).
        let mut at = [0i32; MAX_STRETCHES + 1];
        let mut kinds = [Kind::None; MAX_STRETCHES];
        let mut ns = 0;
        let mut pos = iv.u0;
        let air = if p.over_air == OverAir::Leave { Kind::Air } else { Kind::Solid };
        while pos < iv.u1 {
            let at_pos = skin.probe(pos, iv.u1);
            let next = at_pos.next;
            let kind = if p.over_air != OverAir::Solid && !at_pos.in_prev {
                air
            } else if matches!(p.over_air, OverAir::Bridge | OverAir::Measure | OverAir::Locate) {
                Kind::None
            } else if !at_pos.covered {
                if !p.solid {
                    Kind::None
                } else if !at_pos.in_next {
                    Kind::Top
                } else if p.over_air == OverAir::Leave && at_pos.over_sparse {
                    Kind::OverSparse
                } else {
                    Kind::Solid
                }
            } else if sparse_line {
                Kind::Sparse
            } else {
                Kind::None
            };
            if ns > 0 && kinds[ns - 1] == kind {
                at[ns] = next;
            } else if ns < MAX_STRETCHES {
                (at[ns], at[ns + 1], kinds[ns]) = (pos, next, kind);
                ns += 1;
            } else {
                // Too fragmented to grow: emit what we have as it is.
                for k in 0..ns {
                    self.add_stretch(&iv, at[k], at[k + 1], kinds[k])?;
                }
                (at[0], at[1], kinds[0]) = (pos, next, kind);
                ns = 1;
            }
            pos = next;
        }
        if p.over_air != OverAir::Solid {
            self.tally_air(&at[..=ns], &kinds[..ns], air);
            if p.over_air == OverAir::Measure {
                return Ok(());
            }
        }
        let m = p.margin_u;
        if m > 0 && p.solid {
            for i in 0..ns {
                if kinds[i] < Kind::Solid || kinds[i] == Kind::Air {
                    continue;
                }
                if i + 1 < ns && kinds[i + 1] < Kind::Solid {
                    at[i + 1] += m.min(at[i + 2] - at[i + 1]);
                }
                if i > 0 && kinds[i - 1] < Kind::Solid {
                    at[i] -= m.min(at[i] - at[i - 1]);
                }
            }
        }
        for k in 0..ns {
            if at[k + 1] > at[k] {
                self.add_stretch(&iv, at[k], at[k + 1], kinds[k])?;
            }
        }
        self.close(&iv, iv.u1, iv.c1)
    }

    /// Counts the stretches of kind `air` of one interval (stretch `k` is `at[k]..at[k + 1]`):
    /// anchored when stretches with material below lie on both sides within the interval.
    fn tally_air(&mut self, at: &[i32], kinds: &[Kind], air: Kind) {
        for (k, &kind) in kinds.iter().enumerate() {
            if kind != air {
                continue;
            }
            let len = at[k + 1].abs_diff(at[k]);
            self.tally.over_air_u = self.tally.over_air_u.saturating_add(len);
            if k > 0 && k + 1 < kinds.len() {
                self.tally.anchored_u = self.tally.anchored_u.saturating_add(len);
            }
        }
    }
}

/// Cursors over the skin window for one pass.
struct Skin<'a> {
    above: [Cursor; 16],
    below: [Cursor; 16],
    view: &'a SkinView<'a>,
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
        view: &'a SkinView<'a>,
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
        let v = self.view;
        let layers = (self.above.iter_mut().zip(&v.above).take(v.n_above))
            .chain(self.below.iter_mut().zip(&v.below).take(v.n_below));
        if self.line == Some(line) {
            let mut start = 0;
            for (c, _) in layers {
                (c.idx, start) = (start, c.end);
            }
            return Ok(());
        }
        self.line = None;
        let mut at = 0;
        for (c, data) in layers {
            let out = self.spans.get_mut(at..).unwrap_or(&mut []);
            // Only the loops whose range holds the line are decoded.
            let data = window::parts(v.ring, data.0, data.1);
            let rings = StoredRings::new(data).near_line(self.angle, i64::from(line) * self.step);
            let (n, used) = line_spans(rings, self.angle, line, self.step, out)?;
            self.peak = self.peak.max(at + used);
            *c = Cursor { idx: at, end: at + n };
            at += n;
        }
        self.line = Some(line);
        Ok(())
    }

    /// What the window says at `pos` ([`Probe`]).
    fn probe(&mut self, pos: i32, end: i32) -> Probe {
        let mut next = end;
        let mut all_above = self.top == 0 || self.view.above_complete;
        let mut all_below = self.bottom == 0 || self.view.below_complete;
        let (mut in_next, mut in_prev) = (false, false);
        // Layers L + 1 .. L + top - 1 cover `pos` (there are that many), L + top does not.
        let mut upper = self.top >= 2 && self.view.n_above + 1 >= self.top;
        let mut deepest = false;
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
            if k + 1 < self.top {
                upper &= cov;
            } else if k + 1 == self.top {
                deepest = cov;
            }
        }
        for (k, c) in self.below.iter_mut().take(self.view.n_below).enumerate() {
            let (cov, b) = c.probe(spans, g, pos);
            if let Some(b) = b {
                next = next.min(b);
            }
            if k == 0 {
                in_prev = cov;
            }
            if k < self.bottom {
                all_below &= cov;
            }
        }
        let covered = all_above && all_below;
        let over_sparse = upper && !deepest && all_below;
        Probe { covered, in_next, in_prev, over_sparse, next: next.max(pos + 1) }
    }
}

/// What the skin window says at a point of a line ([`Skin::probe`]).
struct Probe {
    /// Every layer of the window covers it: no surface near.
    covered: bool,
    /// Layer L + 1 covers it.
    in_next: bool,
    /// Layer L - 1 covers it.
    in_prev: bool,
    /// Layer L is the lowest of a top skin there and no bottom surface is near: the layer
    /// below was sparse infill.
    over_sparse: bool,
    /// Where this next changes (at most the line's end).
    next: i32,
}

fn seg_point(p: &FillParams, line: i32, u: i32) -> Point2 {
    p.angle.point(i64::from(line) * p.step, i64::from(u))
}

fn crossing_point(p: &FillParams, loops: &Loops<'_>, c: &Crossing) -> Point2 {
    seg_point(p, c.line, loops.u(c))
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
    let Some(r) = rings.get(ci.ring()) else { return false };
    let (start, len) = (r.start as usize, r.len as usize);
    if len == 0 {
        return false;
    }
    let (e1, e2) = (usize::from(ci.edge) - start, usize::from(ck.edge) - start);
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

/// Intervals between two calls of `fill`'s progress hook (each costs a few thousand
/// instructions on the Cortex-M3, most of it the skin window's crossings with its line).
const PROGRESS_EVERY: u32 = 8;

/// Builds the infill of one layer at one angle into `paths`.
#[allow(clippy::too_many_arguments)]
pub fn fill<const N: usize>(
    points: &[Point2],
    rings: &[Ring],
    params: FillParams,
    view: &SkinView<'_>,
    top: usize,
    bottom: usize,
    work: &mut FillWork<'_>,
    paths: &mut PathBuf<N>,
    usage: &mut FillUse,
    progress: &mut dyn FnMut(),
) -> Result<(), Buffer> {
    let mut n = 0;
    crossings(points, rings, params.angle, params.step, work.cross, &mut n)?;
    if n > work.idx.len() {
        return Err(Buffer::Crossings);
    }
    let cross = &work.cross[..n];
    let loops = Loops { points, rings, angle: params.angle, step: params.step };
    sort_by_line(cross, &loops, &mut work.idx[..n]);
    usage.crossings = usage.crossings.max(n);
    let mut skin = Skin::new(view, top, bottom, &params, &mut *work.spans);
    usage.bridge = BridgeTally::NONE;
    let tally = &mut usage.bridge;
    let mut b = Builder {
        segs: Segs::new(&mut *work.pool),
        cross,
        rings,
        open: None,
        params: &params,
        tally,
    };
    let mut count = 0u32;
    let r = intervals(cross, &loops, &work.idx[..n], |iv| {
        count += 1;
        if count % PROGRESS_EVERY == 0 {
            progress();
        }
        b.interval(iv, &mut skin)
    });
    usage.spans = usage.spans.max(skin.peak);
    r?;
    let mut segs = b.segs;
    usage.segments = usage.segments.max(segs.used_words().div_ceil(POOL_WORDS));
    if segs.nseg > MAX_SEGS {
        return Err(Buffer::LineSegments);
    }
    if params.over_air == OverAir::Locate {
        usage.located = (segs.nseg, segs.npieces);
        return Ok(());
    }
    // The order is done with: segment ends at crossings instead.
    let cend = &mut work.idx[..n];
    cend.fill(NONE);
    for s in 0..segs.nseg {
        let sg = segs.get(s);
        for (c, end) in [(sg.c0, 0), (sg.c1, 1)] {
            if c != NONE {
                if let Some(slot) = cend.get_mut(usize::from(c)) {
                    *slot = (2 * s + end) as u16;
                }
            }
        }
    }
    link(points, rings, &params, cross, cend, &mut segs, paths)
}

/// Marks the perimeters' moves over air.
///
/// `pool` holds the stretches of the layer's region over air, line by line, that an
/// [`OverAir::Locate`] pass at `angle` (lines `step` apart) left ([`FillUse::located`]).
/// Called by the layer's builder after that pass, not inside it: the stack stays as deep as
/// the infill's.
pub fn tag_overhangs<const N: usize>(
    pool: &mut [u32],
    (nseg, npieces): (usize, usize),
    angle: Angle,
    step: i64,
    width_um: i32,
    paths: &mut PathBuf<N>,
) {
    let segs = Segs { w: pool, nseg, npieces };
    if segs.nseg == 0 {
        return;
    }
    // Whether position `u` of line `line` lies in a stretch over air.
    let air = |line: i64, u: i64| {
        let (mut lo, mut hi) = (0, segs.nseg);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if i64::from(segs.get(mid).line) < line {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        (lo..segs.nseg)
            .map(|s| segs.get(s))
            .take_while(|s| i64::from(s.line) == line)
            .any(|s| i64::from(s.u0) <= u && u <= i64::from(s.u1))
    };
    for i in 0..paths.len() {
        let r = paths.rec(i);
        if !matches!(r.kind, PathKind::Perimeter(_)) {
            continue;
        }
        let n = r.len as usize;
        for k in 0..n {
            // The move reaching point k (a loop's first from its last point).
            let pts = paths.points(&r);
            let (a, b) = (pts.at((k + n - 1) % n), pts.at(k));
            // Its middle, moved a line width into the material (on the loops' left, a width
            // and a half from the edge): the lines either side (two widths apart) then cross
            // the layer there unless the edge runs along them; over air on both.
            let (dx, dy) = (i64::from(b.x - a.x), i64::from(b.y - a.y));
            let len = isqrt_u64((dx * dx + dy * dy) as u64).max(1) as i64;
            let w = i64::from(width_um);
            let mid = Point2::new(
                (i64::from(a.x) + dx / 2 - dy * w / len) as i32,
                (i64::from(a.y) + dy / 2 + dx * w / len) as i32,
            );
            let (t, u) = angle.key(mid);
            let line = t.div_euclid(step);
            if air(line, u) && air(line + 1, u) {
                paths.set_feature(i, k, Feature::OverhangPerimeter);
            }
        }
    }
}

/// Emits segment `s` (forward: from `u0`) into the open path.
fn emit_seg<const N: usize>(
    p: &FillParams,
    segs: &Segs<'_>,
    s: usize,
    forward: bool,
    paths: &mut PathBuf<N>,
) -> Result<(), Buffer> {
    let sg = segs.get(s);
    let pieces = sg.piece0 as usize..(sg.piece0 + sg.npieces) as usize;
    let last = pieces.end.saturating_sub(1);
    let first_kind = segs.piece(if forward { pieces.start } else { last }).kind;
    if forward {
        paths.push(seg_point(p, sg.line, sg.u0), first_kind.feature(p))?;
        for k in pieces {
            let pc = segs.piece(k);
            paths.push(seg_point(p, sg.line, pc.u1), pc.kind.feature(p))?;
        }
    } else {
        paths.push(seg_point(p, sg.line, sg.u1), first_kind.feature(p))?;
        for k in pieces.clone().rev() {
            let u = if k == pieces.start { sg.u0 } else { segs.piece(k - 1).u1 };
            paths.push(seg_point(p, sg.line, u), segs.piece(k).kind.feature(p))?;
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
    fn crossing(self, segs: &Segs<'_>) -> u16 {
        let s = segs.get(self.seg);
        if self.at_u1 {
            s.c1
        } else {
            s.c0
        }
    }

    fn u(self, segs: &Segs<'_>) -> i32 {
        let s = segs.get(self.seg);
        if self.at_u1 {
            s.u1
        } else {
            s.u0
        }
    }

    fn point(self, p: &FillParams, segs: &Segs<'_>) -> Point2 {
        seg_point(p, segs.get(self.seg).line, self.u(segs))
    }

    /// The end pushed `ext` further out along the line.
    fn extended(self, p: &FillParams, segs: &Segs<'_>, ext: i32) -> Point2 {
        let u = if self.at_u1 { self.u(segs) + ext } else { self.u(segs) - ext };
        seg_point(p, segs.get(self.seg).line, u)
    }

    /// The segment end recorded at a crossing (`2 x seg + end`).
    fn from_cend(e: u16) -> Self {
        Self { seg: usize::from(e / 2), at_u1: e % 2 == 1 }
    }
}

/// The next segment reachable along the boundary from crossing `from`: (crossing, walk
/// direction), if its segment is free, linkable and the walk short enough.
#[allow(clippy::too_many_arguments)]
fn boundary_link(
    points: &[Point2],
    rings: &[Ring],
    p: &FillParams,
    segs: &Segs<'_>,
    cend: &[u16],
    cross: &[Crossing],
    from: usize,
    at: End,
    pref: i32,
) -> Option<(usize, bool)> {
    let here = segs.get(at.seg);
    let range = loop_range(cross, from);
    let mut best: Option<((i32, bool, i64), usize, bool)> = None;
    for fwd in [true, false] {
        let mut k = from;
        let mut found = None;
        for _ in 0..MAX_WALK {
            k = if fwd { next_in(&range, k) } else { prev_in(&range, k) };
            if k == from {
                break;
            }
            if cend.get(k).is_some_and(|&e| e != NONE) {
                found = Some(k);
                break;
            }
        }
        let Some(k) = found else { continue };
        let sg = segs.get(End::from_cend(cend[k]).seg);
        if sg.used || !sg.linkable || sg.solid != here.solid {
            continue;
        }
        let step = sg.line - here.line;
        let mut length = 0i64;
        let loops = Loops { points, rings, angle: p.angle, step: p.step };
        let mut prev = crossing_point(p, &loops, &cross[from]);
        let ok = for_each_vertex(cross, rings, points, from, k, fwd, |v| {
            length += dist(prev, v);
            prev = v;
        });
        if !ok {
            continue;
        }
        length += dist(prev, crossing_point(p, &loops, &cross[k]));
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
    segs: &Segs<'_>,
    at: End,
    pref: i32,
) -> Option<End> {
    let here = at.point(p, segs);
    let cur = segs.get(at.seg);
    let steps: &[i32] = if cur.solid { &[1, -1, 2, -2] } else { &[1, -1] };
    let mut best: Option<((i32, bool, i64), End)> = None;
    for &dl in steps {
        // A sparse segment links to the next sparse line either way.
        let target = if cur.solid {
            cur.line + dl
        } else {
            match p.sparse.next(cur.line, dl > 0) {
                Some(t) => t,
                None => continue,
            }
        };
        let dl = target - cur.line;
        // Segments come line by line: the first on `target`.
        let (mut lo, mut hi) = (0, segs.nseg);
        while lo < hi {
            let mid = (lo + hi) / 2;
            if segs.get(mid).line < target {
                lo = mid + 1;
            } else {
                hi = mid;
            }
        }
        let allowed = 3 * i64::from(dl.abs()) * i64::from(p.spacing_um);
        for i in lo..segs.nseg {
            let s = segs.get(i);
            if s.line != target {
                break;
            }
            if s.used || !s.linkable || s.solid != cur.solid {
                continue;
            }
            for at_u1 in [false, true] {
                let e = End { seg: i, at_u1 };
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
#[allow(clippy::too_many_arguments)]
fn link<const N: usize>(
    points: &[Point2],
    rings: &[Ring],
    p: &FillParams,
    cross: &[Crossing],
    cend: &[u16],
    segs: &mut Segs<'_>,
    paths: &mut PathBuf<N>,
) -> Result<(), Buffer> {
    for s0 in 0..segs.nseg {
        let seg0 = segs.get(s0);
        if seg0.used {
            continue;
        }
        segs.set_used(s0);
        emit_seg(p, segs, s0, true, paths)?;
        // Unlinked ends on the boundary reach a little into the perimeter.
        let start = End { seg: s0, at_u1: false };
        if start.crossing(segs) != NONE && p.end_ext_u > 0 {
            paths.set_open_point(0, true, start.extended(p, segs, p.end_ext_u));
        }
        let mut at = End { seg: s0, at_u1: true };
        let mut pref = 0;
        while segs.get(s0).linkable {
            let end_c = at.crossing(segs);
            let line = segs.get(at.seg).line;
            let next = if end_c != NONE {
                let from = usize::from(end_c);
                boundary_link(points, rings, p, segs, cend, cross, from, at, pref)
                    .map(|(k, fwd)| (End::from_cend(cend[k]), Some((from, k, fwd))))
            } else {
                interior_link(points, rings, p, segs, at, pref).map(|e| (e, None))
            };
            let Some((e, walk)) = next else { break };
            let feat = {
                let sg = segs.get(e.seg);
                let k =
                    if e.at_u1 { (sg.piece0 + sg.npieces).saturating_sub(1) } else { sg.piece0 };
                segs.piece(k as usize).kind.feature(p)
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
            segs.set_used(e.seg);
            emit_seg(p, segs, e.seg, !e.at_u1, paths)?;
            // Entered at one end: now at the other.
            pref = (segs.get(e.seg).line - line).signum();
            at = End { seg: e.seg, at_u1: !e.at_u1 };
        }
        if at.crossing(segs) != NONE && p.end_ext_u > 0 {
            paths.set_open_point(0, false, at.extended(p, segs, p.end_ext_u));
        }
        paths.end(seg0.island, PathKind::Infill, false, seg0.linkable)?;
    }
    Ok(())
}

//! Chaining a layer's segments into closed loops through an endpoint hash.
//!
//! Every segment's start point goes into an open-addressing table (linear probing over
//! `2 n` slots for `n` segments, so clearing and filling cost O(n), not O(capacity)); each
//! segment is then linked to a not-yet-claimed segment starting where it ends. On a closed,
//! consistently wound mesh every cut point has as many segments ending as starting there, so
//! the links form cycles only, whatever is chosen at points where loops touch. Segments left
//! without predecessor start open chains, which `repair` joins or drops.

use crate::geom::{doubled_signed_area, Point2};

use super::intersect::Segment;
use super::{LayerRepairs, LoopInfo, Resource};

/// "No segment" in the link and hash arrays.
pub(super) const NONE: u32 = u32::MAX;
/// Flag: some segment links to this one.
const HAS_PRED: u8 = 1;
/// Flag: already part of an open chain or an emitted loop.
const DONE: u8 = 2;

/// State of an open chain during repair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) enum ChainState {
    /// Still open.
    #[default]
    Open,
    /// Closed into a loop by repair.
    Closed,
    /// Appended to another chain.
    Merged,
}

/// An open chain: a path of linked segments from `head` to `tail`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct Chain {
    /// First segment.
    pub head: u32,
    /// Last segment (its `next` is `NONE` while open).
    pub tail: u32,
    /// Segments in the chain.
    pub segments: u32,
    /// A lower bound of the chain's length in um (sum of max(|dx|, |dy|) per segment).
    pub length_um: i64,
    /// Repair state.
    pub state: ChainState,
}

/// What building one layer's loops reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(super) struct LayerOutcome {
    /// Repairs of open chains.
    pub repairs: LayerRepairs,
    /// Loops below the minimum area (or of zero area), dropped.
    pub dropped_small_loops: u32,
}

/// A layer's segments, links, loops and loop points. Memory per unit of capacity: 37 bytes
/// per segment (16 segment + 4 link + 1 flags + 8 hash slots + 8 output point) and
/// `size_of::<LoopInfo>() + size_of::<Chain>()` per loop.
pub(super) struct Contours<const S: usize, const L: usize> {
    pub segs: [Segment; S],
    pub next: [u32; S],
    flags: [u8; S],
    table: [[u32; 2]; S],
    pub points: [Point2; S],
    pub loops: [LoopInfo; L],
    pub chains: [Chain; L],
    pub seg_len: usize,
    pub points_len: usize,
    pub loops_len: usize,
    pub chains_len: usize,
}

/// Slot of `p` in a table of `slots` entries: multiplicative hash, then a multiply-shift
/// range reduction (no division, any table size).
fn slot_of(p: Point2, slots: usize) -> usize {
    let key = u64::from(p.x as u32) << 32 | u64::from(p.y as u32);
    let h = key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32;
    ((h * slots as u64) >> 32) as usize
}

impl<const S: usize, const L: usize> Contours<S, L> {
    /// Empty buffers.
    pub const EMPTY: Self = Self {
        segs: [Segment { start: Point2::new(0, 0), end: Point2::new(0, 0) }; S],
        next: [NONE; S],
        flags: [0; S],
        table: [[NONE; 2]; S],
        points: [Point2::new(0, 0); S],
        loops: [LoopInfo::EMPTY; L],
        chains: [Chain { head: 0, tail: 0, segments: 0, length_um: 0, state: ChainState::Open }; L],
        seg_len: 0,
        points_len: 0,
        loops_len: 0,
        chains_len: 0,
    };

    /// Forgets the previous layer.
    pub fn clear(&mut self) {
        self.seg_len = 0;
        self.points_len = 0;
        self.loops_len = 0;
        self.chains_len = 0;
    }

    /// Adds a segment; `Err` when the segment buffer is full.
    pub fn push_segment(&mut self, s: Segment) -> Result<(), Resource> {
        let slot = self.segs.get_mut(self.seg_len).ok_or(Resource::Segments)?;
        *slot = s;
        self.seg_len += 1;
        Ok(())
    }

    /// Chains, repairs, filters, orients and nests the layer's loops.
    pub fn build(
        &mut self,
        min_loop_area_um2: i64,
        join_tolerance_um: i32,
        max_gap_um: i32,
    ) -> Result<LayerOutcome, Resource> {
        self.link();
        self.collect_open_chains()?;
        let repairs = self.repair(join_tolerance_um, max_gap_um);
        let mut outcome = LayerOutcome { repairs, dropped_small_loops: 0 };
        let min_doubled = min_loop_area_um2.saturating_mul(2);
        for c in 0..self.chains_len {
            if self.chains[c].state == ChainState::Closed {
                let head = self.chains[c].head as usize;
                if !self.emit(head, min_doubled)? {
                    outcome.dropped_small_loops += 1;
                }
            }
        }
        for i in 0..self.seg_len {
            if self.flags[i] & DONE == 0 && !self.emit(i, min_doubled)? {
                outcome.dropped_small_loops += 1;
            }
        }
        super::nest::orient_and_nest(
            &mut self.points[..self.points_len],
            &mut self.loops[..self.loops_len],
        );
        Ok(outcome)
    }

    /// Links each segment to an unclaimed segment starting at its end point.
    fn link(&mut self) {
        let n = self.seg_len;
        let Self { segs, next, flags, table, .. } = self;
        let slots = 2 * n;
        let table = &mut table.as_flattened_mut()[..slots];
        table.fill(NONE);
        for (i, seg) in segs[..n].iter().enumerate() {
            let mut s = slot_of(seg.start, slots);
            while table[s] != NONE {
                s = if s + 1 == slots { 0 } else { s + 1 };
            }
            table[s] = i as u32;
        }
        next[..n].fill(NONE);
        flags[..n].fill(0);
        for i in 0..n {
            let end = segs[i].end;
            let mut s = slot_of(end, slots);
            loop {
                let j = table[s] as usize;
                if j == NONE as usize {
                    break;
                }
                if segs[j].start == end && flags[j] & HAS_PRED == 0 {
                    next[i] = j as u32;
                    flags[j] |= HAS_PRED;
                    break;
                }
                s = if s + 1 == slots { 0 } else { s + 1 };
            }
        }
    }

    /// Records every maximal path starting at a segment without predecessor.
    fn collect_open_chains(&mut self) -> Result<(), Resource> {
        for head in 0..self.seg_len {
            if self.flags[head] & HAS_PRED != 0 {
                continue;
            }
            let (mut cur, mut segments, mut length_um) = (head, 0u32, 0i64);
            loop {
                self.flags[cur] |= DONE;
                segments += 1;
                let s = self.segs[cur];
                let (dx, dy) = (i64::from(s.end.x - s.start.x), i64::from(s.end.y - s.start.y));
                length_um += dx.abs().max(dy.abs());
                match self.next[cur] {
                    NONE => break,
                    n => cur = n as usize,
                }
            }
            let chain = self.chains.get_mut(self.chains_len).ok_or(Resource::OpenChains)?;
            *chain = Chain {
                head: head as u32,
                tail: cur as u32,
                segments,
                length_um,
                state: ChainState::Open,
            };
            self.chains_len += 1;
        }
        Ok(())
    }

    fn push_point(&mut self, p: Point2) -> Result<(), Resource> {
        let slot = self.points.get_mut(self.points_len).ok_or(Resource::ContourPoints)?;
        *slot = p;
        self.points_len += 1;
        Ok(())
    }

    /// Writes the cycle through segment `head` as a loop; `Ok(false)` when it is dropped
    /// for its area (below `min_doubled / 2` or zero).
    fn emit(&mut self, head: usize, min_doubled: i64) -> Result<bool, Resource> {
        let start = self.points_len;
        let mut cur = head;
        // A cycle visits each segment once: the bound only guards against a broken link.
        for _ in 0..self.seg_len {
            self.flags[cur] |= DONE;
            let seg = self.segs[cur];
            self.push_point(seg.start)?;
            let nxt = self.next[cur] as usize;
            let Some(following) = self.segs[..self.seg_len].get(nxt) else { break };
            if seg.end != following.start {
                // A repaired gap: keep the segment's own end, then bridge straight across.
                self.push_point(seg.end)?;
            }
            cur = nxt;
            if cur == head {
                break;
            }
        }
        let points = &self.points[start..self.points_len];
        let doubled = doubled_signed_area(points);
        if doubled == 0 || doubled.abs() < min_doubled {
            self.points_len = start;
            return Ok(false);
        }
        let (mut min, mut max) = (points[0], points[0]);
        for p in points {
            min = Point2::new(min.x.min(p.x), min.y.min(p.y));
            max = Point2::new(max.x.max(p.x), max.y.max(p.y));
        }
        let info = LoopInfo {
            start: start as u32,
            len: points.len() as u32,
            hole: false,
            parent: None,
            // Half the doubled area, rounded away from zero (never 0 for a kept loop).
            area_um2: (doubled + doubled.signum()) / 2,
            min,
            max,
        };
        let slot = self.loops.get_mut(self.loops_len).ok_or(Resource::Loops)?;
        *slot = info;
        self.loops_len += 1;
        Ok(true)
    }
}

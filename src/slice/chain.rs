//! Chaining a layer's segments into closed loops through an endpoint hash.
//!
//! Every segment's start point goes into an open-addressing table (linear probing over
//! `2 n` slots for `n` segments, so clearing and filling cost O(n), not O(capacity)); each
//! segment is then linked to a not-yet-claimed segment starting where it ends. On a closed,
//! consistently wound mesh every cut point has as many segments ending as starting there, so
//! the links form cycles only, whatever is chosen at points where loops touch. Segments left
//! without predecessor start open chains, which `repair` joins or drops.
//!
//! The table is dead once every segment is linked (repair and emission follow links only),
//! so it shares its place with the layer's output points: [`CutScratch::slots`] holds one
//! [`Point2`] (8 bytes) per segment, read as two `u32` hash slots while linking and written
//! with the loops' points afterwards.

use core::mem::size_of;

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

/// A layer's cut.
///
/// Its segments, their links and flags, the endpoint hash table and then, in the table's place, the
/// layer's loop points (the slicer's output, read through [`SlicedLayer`](super::SlicedLayer)). It
/// lives in the working memory the slicer is lent ([`CutSpace`](super::CutSpace)) and is dead once
/// the next stage has copied the layer: [`BYTES_PER_SEGMENT`](Self::BYTES_PER_SEGMENT) per segment
/// (16 segment + 4 link + 1 flags + 8 hash slots or a point).
pub struct CutScratch<const S: usize> {
    pub(super) segs: [Segment; S],
    pub(super) next: [u32; S],
    flags: [u8; S],
    /// While linking: the endpoint hash, two `u32` slots per entry ([`hash_slot`]); then the
    /// layer's loop points, `slots[..points_len]`.
    slots: [Point2; S],
    len: usize,
    points_len: usize,
}

/// Hash slot `k` of the table kept in `slots` while linking: slot `2 i` is `slots[i].x`,
/// slot `2 i + 1` is `slots[i].y`, a segment index (or [`NONE`]) stored as the bit pattern of
/// the `i32` field (`as` casts both ways: no value is lost). The same layout as a flat
/// `[u32; 2 S]`, so probing visits the same slots in the same order.
fn hash_slot(slots: &[Point2], k: usize) -> u32 {
    let entry = slots[k / 2];
    (if k % 2 == 0 { entry.x } else { entry.y }) as u32
}

/// Writes hash slot `k` (see [`hash_slot`]).
fn set_hash_slot(slots: &mut [Point2], k: usize, segment: u32) {
    let entry = &mut slots[k / 2];
    if k % 2 == 0 {
        entry.x = segment as i32;
    } else {
        entry.y = segment as i32;
    }
}

/// A layer's loops (read through [`Layer`](super::Layer), their points are in the
/// [`CutScratch`]) and the open chains of its repair. Memory per unit of capacity:
/// `size_of::<LoopInfo>() + size_of::<Chain>()` per loop.
pub(super) struct Contours<const L: usize> {
    pub loops: [LoopInfo; L],
    pub chains: [Chain; L],
    pub loops_len: usize,
    pub chains_len: usize,
}

/// The chaining of one layer: reads and links the cut, writes the loop points into the cut
/// (over its dead hash table) and the loops into `out`.
pub(super) struct Chaining<'a, const S: usize, const L: usize> {
    pub cut: &'a mut CutScratch<S>,
    pub out: &'a mut Contours<L>,
}

/// Slot of `p` in a table of `slots` entries: multiplicative hash, then a multiply-shift
/// range reduction (no division, any table size).
fn slot_of(p: Point2, slots: usize) -> usize {
    let key = u64::from(p.x as u32) << 32 | u64::from(p.y as u32);
    let h = key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 32;
    ((h * slots as u64) >> 32) as usize
}

impl<const S: usize> Default for CutScratch<S> {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl<const S: usize> CutScratch<S> {
    /// Bytes per segment: the segment, its link, its flags and two hash slots (or a point).
    pub const BYTES_PER_SEGMENT: usize =
        size_of::<Segment>() + size_of::<u32>() + size_of::<u8>() + size_of::<Point2>();

    /// No segments. All zero: written in place by a memset (no constant in flash).
    pub const EMPTY: Self = Self {
        segs: [Segment { start: Point2::new(0, 0), end: Point2::new(0, 0) }; S],
        next: [0; S],
        flags: [0; S],
        slots: [Point2::new(0, 0); S],
        len: 0,
        points_len: 0,
    };

    /// An empty cut (see [`EMPTY`](Self::EMPTY)).
    pub const fn new() -> Self {
        Self::EMPTY
    }

    /// Forgets the previous layer's segments and points.
    pub(crate) fn clear(&mut self) {
        self.len = 0;
        self.points_len = 0;
    }

    /// The loop points of the layer linked last (until the next cut).
    pub fn points(&self) -> &[Point2] {
        &self.slots[..self.points_len]
    }

    /// Segments of the layer.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// Adds a segment; `Err` when the segment buffer is full.
    pub(crate) fn push(&mut self, s: Segment) -> Result<(), Resource> {
        let slot = self.segs.get_mut(self.len).ok_or(Resource::Segments)?;
        *slot = s;
        self.len += 1;
        Ok(())
    }
}

impl<const L: usize> Contours<L> {
    /// Empty buffers.
    pub const EMPTY: Self = Self {
        loops: [LoopInfo::EMPTY; L],
        chains: [Chain { head: 0, tail: 0, segments: 0, length_um: 0, state: ChainState::Open }; L],
        loops_len: 0,
        chains_len: 0,
    };

    /// Forgets the previous layer.
    pub fn clear(&mut self) {
        self.loops_len = 0;
        self.chains_len = 0;
    }
}

impl<const S: usize, const L: usize> Chaining<'_, S, L> {
    /// Chains, repairs, filters, orients and nests the layer's loops.
    pub fn build(
        &mut self,
        min_loop_area_um2: i64,
        join_tolerance_um: i32,
        max_gap_um: i32,
    ) -> Result<LayerOutcome, Resource> {
        self.out.clear();
        self.cut.points_len = 0;
        // The hash table is used here only: repair and emission follow the links, and the
        // points emitted below overwrite the table.
        self.link();
        self.collect_open_chains()?;
        let repairs = self.repair(join_tolerance_um, max_gap_um);
        let mut outcome = LayerOutcome { repairs, dropped_small_loops: 0 };
        let min_doubled = min_loop_area_um2.saturating_mul(2);
        for c in 0..self.out.chains_len {
            if self.out.chains[c].state == ChainState::Closed {
                let head = self.out.chains[c].head as usize;
                if !self.emit(head, min_doubled)? {
                    outcome.dropped_small_loops += 1;
                }
            }
        }
        for i in 0..self.cut.len {
            if self.cut.flags[i] & DONE == 0 && !self.emit(i, min_doubled)? {
                outcome.dropped_small_loops += 1;
            }
        }
        let (cut, out) = (&mut *self.cut, &mut *self.out);
        super::nest::orient_and_nest(
            &mut cut.slots[..cut.points_len],
            &mut out.loops[..out.loops_len],
        );
        Ok(outcome)
    }

    /// Links each segment to an unclaimed segment starting at its end point, through the
    /// endpoint hash in `slots` (`2 n` slots for `n` segments: [`hash_slot`]).
    fn link(&mut self) {
        let CutScratch { segs, next, flags, slots, len, .. } = &mut *self.cut;
        let n = *len;
        let table_len = 2 * n;
        let table = &mut slots[..n];
        table.fill(Point2::new(NONE as i32, NONE as i32));
        for (i, seg) in segs[..n].iter().enumerate() {
            let mut s = slot_of(seg.start, table_len);
            while hash_slot(table, s) != NONE {
                s = if s + 1 == table_len { 0 } else { s + 1 };
            }
            set_hash_slot(table, s, i as u32);
        }
        next[..n].fill(NONE);
        flags[..n].fill(0);
        for i in 0..n {
            let end = segs[i].end;
            let mut s = slot_of(end, table_len);
            loop {
                let j = hash_slot(table, s) as usize;
                if j == NONE as usize {
                    break;
                }
                if segs[j].start == end && flags[j] & HAS_PRED == 0 {
                    next[i] = j as u32;
                    flags[j] |= HAS_PRED;
                    break;
                }
                s = if s + 1 == table_len { 0 } else { s + 1 };
            }
        }
    }

    /// Records every maximal path starting at a segment without predecessor.
    fn collect_open_chains(&mut self) -> Result<(), Resource> {
        let (cut, out) = (&mut *self.cut, &mut *self.out);
        for head in 0..cut.len {
            if cut.flags[head] & HAS_PRED != 0 {
                continue;
            }
            let (mut cur, mut segments, mut length_um) = (head, 0u32, 0i64);
            loop {
                cut.flags[cur] |= DONE;
                segments += 1;
                let s = cut.segs[cur];
                let (dx, dy) = (i64::from(s.end.x - s.start.x), i64::from(s.end.y - s.start.y));
                length_um += dx.abs().max(dy.abs());
                match cut.next[cur] {
                    NONE => break,
                    n => cur = n as usize,
                }
            }
            let chain = out.chains.get_mut(out.chains_len).ok_or(Resource::OpenChains)?;
            *chain = Chain {
                head: head as u32,
                tail: cur as u32,
                segments,
                length_um,
                state: ChainState::Open,
            };
            out.chains_len += 1;
        }
        Ok(())
    }

    /// Appends a loop point in the table's place (dead since `link`). A repaired gap adds a
    /// point, so a layer may have more points than segments: the capacity is still `S`.
    fn push_point(&mut self, p: Point2) -> Result<(), Resource> {
        let cut = &mut *self.cut;
        let slot = cut.slots.get_mut(cut.points_len).ok_or(Resource::ContourPoints)?;
        *slot = p;
        cut.points_len += 1;
        Ok(())
    }

    /// Writes the cycle through segment `head` as a loop; `Ok(false)` when it is dropped
    /// for its area (below `min_doubled / 2` or zero).
    fn emit(&mut self, head: usize, min_doubled: i64) -> Result<bool, Resource> {
        let start = self.cut.points_len;
        let mut cur = head;
        // A cycle visits each segment once: the bound only guards against a broken link.
        for _ in 0..self.cut.len {
            self.cut.flags[cur] |= DONE;
            let seg = self.cut.segs[cur];
            self.push_point(seg.start)?;
            let nxt = self.cut.next[cur] as usize;
            let Some(following) = self.cut.segs[..self.cut.len].get(nxt) else { break };
            if seg.end != following.start {
                // A repaired gap: keep the segment's own end, then bridge straight across.
                self.push_point(seg.end)?;
            }
            cur = nxt;
            if cur == head {
                break;
            }
        }
        let (cut, out) = (&mut *self.cut, &mut *self.out);
        let points = &cut.slots[start..cut.points_len];
        let doubled = doubled_signed_area(points);
        if doubled == 0 || doubled.abs() < min_doubled {
            cut.points_len = start;
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
        let slot = out.loops.get_mut(out.loops_len).ok_or(Resource::Loops)?;
        *slot = info;
        out.loops_len += 1;
        Ok(true)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hash_slots_keep_every_u32_in_the_point_fields() {
        let mut slots = [Point2::new(0, 0); 3];
        let values = [NONE, 0, 1, i32::MAX as u32, i32::MAX as u32 + 1, 0xDEAD_BEEF];
        for (k, &v) in values.iter().enumerate() {
            set_hash_slot(&mut slots, k, v);
        }
        for (k, &v) in values.iter().enumerate() {
            assert_eq!(hash_slot(&slots, k), v, "slot {k}");
        }
        // Slots 2 i and 2 i + 1 share entry i, as in a flat `[u32; 2 n]`.
        assert_eq!(slots[0], Point2::new(-1, 0));
        assert_eq!(slots[2].y, 0xDEAD_BEEF_u32 as i32);
    }
}

//! Repair of open chains left by broken meshes (holes, non-manifold edges, flipped faces).
//!
//! Three passes, each over every open chain, each extending a chain at its end (then, after
//! reversing it, at its former start) with the nearest candidate within the pass's reach:
//! 1. exact: an endpoint equal to this chain's end. An end meeting another chain's end (or a
//!    start meeting a start) means one of them runs backwards: it is reversed first;
//! 2. near: within `join_tolerance_um` (rounding differences of duplicated vertices);
//! 3. gap: within `max_gap_um`, bridged by a straight edge; a chain is only closed onto
//!    itself when it is longer than the gap (so no sliver closes over its own opening).
//!
//! Candidates are the chain's own start (closing it) and the starts and ends of the other
//! open chains; the nearest wins, ties go to the earliest (closing first), so results are
//! deterministic. Chains still open afterwards are dropped and counted. The cost is O(k^2) in
//! the number of open chains k, which is zero for a closed mesh.

use crate::geom::Point2;

use super::chain::{ChainState, Chaining, NONE};
use super::LayerRepairs;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Pass {
    Exact,
    Near,
    Gap,
}

/// How a chain's end gets extended.
#[derive(Clone, Copy)]
enum Join {
    Close,
    Append(usize),
    AppendReversed(usize),
}

fn dist2(a: Point2, b: Point2) -> i64 {
    let (dx, dy) = (i64::from(a.x) - i64::from(b.x), i64::from(a.y) - i64::from(b.y));
    dx * dx + dy * dy
}

impl<const S: usize, const L: usize> Chaining<'_, S, L> {
    fn chain_start(&self, c: usize) -> Point2 {
        self.cut.segs[self.out.chains[c].head as usize].start
    }

    fn chain_end(&self, c: usize) -> Point2 {
        self.cut.segs[self.out.chains[c].tail as usize].end
    }

    /// Reverses chain `c` in place: link order and every segment's direction.
    fn reverse(&mut self, c: usize) {
        let chain = self.out.chains[c];
        let (mut prev, mut cur) = (NONE, chain.head as usize);
        for _ in 0..chain.segments {
            let nxt = self.cut.next[cur];
            self.cut.next[cur] = prev;
            let s = &mut self.cut.segs[cur];
            core::mem::swap(&mut s.start, &mut s.end);
            prev = cur as u32;
            if nxt == NONE {
                break;
            }
            cur = nxt as usize;
        }
        let chain = &mut self.out.chains[c];
        core::mem::swap(&mut chain.head, &mut chain.tail);
    }

    /// Joins the nearest candidate within `reach` (um) to chain `c`'s end. Returns true when
    /// the chain grew and is still open (so it may grow again).
    fn extend(&mut self, c: usize, pass: Pass, reach: i64, repairs: &mut LayerRepairs) -> bool {
        let end = self.chain_end(c);
        let limit = reach * reach;
        let mut best: Option<(i64, Join)> = None;
        let mut consider = |d2: i64, join: Join| {
            if d2 <= limit && best.map_or(true, |(b, _)| d2 < b) {
                best = Some((d2, join));
            }
        };
        let own = dist2(end, self.chain_start(c));
        // Closing across a gap needs a chain longer than the gap.
        let long_enough = pass != Pass::Gap || {
            let len = self.out.chains[c].length_um;
            len >= reach || len.saturating_mul(len) > own
        };
        if long_enough {
            consider(own, Join::Close);
        }
        for d in 0..self.out.chains_len {
            if d == c || self.out.chains[d].state != ChainState::Open {
                continue;
            }
            consider(dist2(end, self.chain_start(d)), Join::Append(d));
            consider(dist2(end, self.chain_end(d)), Join::AppendReversed(d));
        }
        let Some((_, join)) = best else { return false };
        match pass {
            Pass::Exact => repairs.exact_joins += 1,
            Pass::Near => repairs.tolerance_joins += 1,
            Pass::Gap => repairs.gaps_closed += 1,
        }
        let tail = self.out.chains[c].tail as usize;
        let d = match join {
            Join::Close => {
                self.cut.next[tail] = self.out.chains[c].head;
                self.out.chains[c].state = ChainState::Closed;
                return false;
            }
            Join::Append(d) => d,
            Join::AppendReversed(d) => {
                self.reverse(d);
                d
            }
        };
        let other = self.out.chains[d];
        self.cut.next[tail] = other.head;
        self.out.chains[d].state = ChainState::Merged;
        let chain = &mut self.out.chains[c];
        chain.tail = other.tail;
        chain.segments += other.segments;
        chain.length_um += other.length_um;
        true
    }

    /// Runs the three passes over the open chains; counts what was joined and dropped.
    pub(super) fn repair(&mut self, join_tolerance_um: i32, max_gap_um: i32) -> LayerRepairs {
        let mut repairs = LayerRepairs::default();
        if self.out.chains_len == 0 {
            return repairs;
        }
        let passes = [
            (Pass::Exact, 0),
            (Pass::Near, i64::from(join_tolerance_um)),
            (Pass::Gap, i64::from(max_gap_um)),
        ];
        for (pass, reach) in passes {
            for c in 0..self.out.chains_len {
                for _side in 0..2 {
                    if self.out.chains[c].state != ChainState::Open {
                        break;
                    }
                    while self.extend(c, pass, reach, &mut repairs) {}
                    if self.out.chains[c].state == ChainState::Open {
                        self.reverse(c);
                    }
                }
            }
        }
        for chain in &self.out.chains[..self.out.chains_len] {
            if chain.state == ChainState::Open {
                repairs.dropped_chains += 1;
                repairs.dropped_segments += chain.segments;
            }
        }
        repairs
    }
}

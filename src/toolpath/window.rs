//! The layer window: per-layer blocks in bounded FIFO storage.
//!
//! Skins need to know, for layer `L`, the regions of the `bottom` layers below and the `top`
//! layers above. The slicer emits layers in order, so the toolpath of layer `L` is built when
//! layer `L + top` arrives; until then `L`'s simplified contours wait here (a [`Fifo`] of
//! words, one block per layer in the [`StoredRings`] layout: about one word a point), and
//! they stay for `bottom`
//! more layers: the skin detection cuts them with each scanline when it needs them
//! ([`scan::line_spans`](super::scan::line_spans)), so no per-line data of the window is
//! stored.
//!
//! A [`Fifo`] keeps blocks contiguous (a block that does not fit before the end of the array
//! starts again at 0 when the oldest blocks have left room there), so each layer's data is a
//! plain slice.

use crate::geom::Point2;

use super::Buffer;

/// Blocks a window can hold: one per layer, `bottom + top + 2` layers at most (the layers
/// below, the one being built, those above and the one being stored); top and bottom layers
/// are limited to 16 each.
pub const MAX_BLOCKS: usize = 34;

/// One block: `start..start + len` of the storage, and the layer it belongs to.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Block {
    /// Layer index.
    pub layer: u32,
    /// First element.
    pub start: u32,
    /// Elements.
    pub len: u32,
}

/// FIFO of contiguous blocks in `N` elements of `T`.
pub struct Fifo<T: Copy, const N: usize> {
    data: [T; N],
    blocks: [Block; MAX_BLOCKS],
    /// Index of the oldest block and number of blocks.
    head: usize,
    count: usize,
    /// Where the block being written starts and its reserved length.
    open: Option<(usize, usize)>,
    /// Most elements in use at once, a reserved block counted whole.
    pub peak: usize,
    what: Buffer,
}

impl<T: Copy, const N: usize> Fifo<T, N> {
    /// Empty storage filled with `fill`; `what` names it in errors.
    pub const fn new(fill: T, what: Buffer) -> Self {
        Self {
            data: [fill; N],
            blocks: [Block { layer: 0, start: 0, len: 0 }; MAX_BLOCKS],
            head: 0,
            count: 0,
            open: None,
            peak: 0,
            what,
        }
    }

    /// Drops everything.
    pub fn clear(&mut self) {
        self.head = 0;
        self.count = 0;
        self.open = None;
    }

    /// Number of blocks.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True without blocks.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// The `k`-th oldest block.
    pub fn block(&self, k: usize) -> Option<Block> {
        (k < self.count).then(|| self.blocks[(self.head + k) % MAX_BLOCKS])
    }

    /// The block of `layer`, if held.
    pub fn find(&self, layer: u32) -> Option<Block> {
        (0..self.count)
            .map(|k| self.blocks[(self.head + k) % MAX_BLOCKS])
            .find(|b| b.layer == layer)
    }

    /// The elements of a block.
    pub fn data(&self, b: &Block) -> &[T] {
        self.data.get(b.start as usize..(b.start + b.len) as usize).unwrap_or(&[])
    }

    /// Drops the oldest block.
    pub fn pop(&mut self) {
        if self.count > 0 {
            self.head = (self.head + 1) % MAX_BLOCKS;
            self.count -= 1;
        }
    }

    fn in_use(&self) -> usize {
        (0..self.count).map(|k| self.blocks[(self.head + k) % MAX_BLOCKS].len as usize).sum()
    }

    /// Reserves room for a block of up to `max` elements and returns it to be written; the
    /// block is added by [`commit`](Self::commit).
    pub fn reserve(&mut self, max: usize) -> Result<&mut [T], Buffer> {
        if self.count >= MAX_BLOCKS {
            return Err(Buffer::WindowLayers);
        }
        let start = if self.count == 0 {
            0
        } else {
            let first = self.blocks[self.head].start as usize;
            let last = self.blocks[(self.head + self.count - 1) % MAX_BLOCKS];
            let end = (last.start + last.len) as usize;
            if end >= first {
                // Not wrapped: after the newest block, or from 0 up to the oldest.
                if end + max <= N {
                    end
                } else if max <= first {
                    0
                } else {
                    return Err(self.what);
                }
            } else if end + max <= first {
                end
            } else {
                return Err(self.what);
            }
        };
        if start + max > N {
            return Err(self.what);
        }
        self.open = Some((start, max));
        self.peak = self.peak.max(self.in_use() + max);
        Ok(&mut self.data[start..start + max])
    }

    /// Adds the reserved block with its first `len` elements.
    pub fn commit(&mut self, layer: u32, len: usize) {
        let Some((start, max)) = self.open.take() else { return };
        let len = len.min(max);
        self.blocks[(self.head + self.count) % MAX_BLOCKS] =
            Block { layer, start: start as u32, len: len as u32 };
        self.count += 1;
        self.peak = self.peak.max(self.in_use());
    }
}

/// Escape word of [`StoredRings`]: an absolute point follows in two words.
const FAR: u32 = 0x8000_8000;

/// Words a point takes after `prev` in a stored loop: 1 for an offset of `i16`s (not
/// `i16::MIN`), 3 otherwise.
fn point_words(prev: Point2, p: Point2) -> usize {
    if delta(prev, p).is_some() {
        1
    } else {
        3
    }
}

/// `p - prev` packed in one word, if both components fit.
fn delta(prev: Point2, p: Point2) -> Option<u32> {
    let d =
        |a: i32, b: i32| i16::try_from(i64::from(b) - i64::from(a)).ok().filter(|&v| v != i16::MIN);
    Some(u32::from(d(prev.x, p.x)? as u16) | u32::from(d(prev.y, p.y)? as u16) << 16)
}

/// Writes one stored layer in the [`StoredRings`] layout into a word slice.
pub struct Encoder<'a> {
    out: &'a mut [u32],
    at: usize,
    /// Start of the loop being written, its points and the last one.
    ring: usize,
    n: u32,
    last: Point2,
}

impl<'a> Encoder<'a> {
    /// A layer in `out` (its header first).
    pub fn new(out: &'a mut [u32]) -> Self {
        Self { out, at: 2, ring: 2, n: 0, last: Point2::new(0, 0) }
    }

    fn word(&mut self, w: u32) -> Result<(), Buffer> {
        *self.out.get_mut(self.at).ok_or(Buffer::RingPoints)? = w;
        self.at += 1;
        Ok(())
    }

    /// Starts a loop of `island`.
    pub fn begin(&mut self, island: u16) -> Result<(), Buffer> {
        (self.ring, self.n) = (self.at, 0);
        self.word(0)?;
        self.word(u32::from(island))
    }

    /// Appends a point to the loop.
    pub fn push(&mut self, p: Point2) -> Result<(), Buffer> {
        match delta(self.last, p).filter(|_| self.n > 0) {
            Some(w) => self.word(w)?,
            None => {
                if self.n > 0 {
                    self.word(FAR)?;
                }
                self.word(p.x as u32)?;
                self.word(p.y as u32)?;
            }
        }
        self.last = p;
        self.n += 1;
        Ok(())
    }

    /// Ends the loop: kept with its points if `keep`, else removed.
    pub fn end(&mut self, keep: bool) {
        if keep {
            if let Some(h) = self.out.get_mut(self.ring) {
                *h = self.n;
            }
        } else {
            self.at = self.ring;
        }
    }

    /// Writes the layer header (`loops` kept, `islands`) and returns the words used.
    pub fn finish(self, loops: u32, islands: u16) -> usize {
        if let Some(h) = self.out.get_mut(..2) {
            h.copy_from_slice(&[loops, u32::from(islands)]);
        }
        self.at
    }
}

/// Counts the words a loop takes in the [`StoredRings`] layout, point by point: its header,
/// its first point in two and every later one in one (an offset) or three (escaped).
pub struct LoopWords {
    prev: Option<Point2>,
    /// Words so far.
    pub words: usize,
}

impl Default for LoopWords {
    /// A loop without points: its header.
    fn default() -> Self {
        Self { prev: None, words: 2 }
    }
}

impl LoopWords {
    /// Adds the loop's next point.
    pub fn add(&mut self, p: Point2) {
        self.words += self.prev.map_or(2, |q| point_words(q, p));
        self.prev = Some(p);
    }
}

/// The loops of one stored layer, in words: `(loops, islands)`, then every loop is a
/// header `(points, island)`, its first point (x, y) and every later point as its offset
/// from the previous one (`dx + dy x 2^16`, both `i16`) or, when an offset does not fit,
/// the escape word `0x8000_8000` and the point (x, y): one word a point on a typical loop
/// (simplified points are under 33 mm apart). Yields `(island, points)` for the loops of
/// at least three points.
pub struct StoredRings<'a> {
    data: &'a [u32],
    at: usize,
    left: u32,
}

impl<'a> StoredRings<'a> {
    /// The loops of `data` (a block written by an [`Encoder`]).
    pub fn new(data: &'a [u32]) -> Self {
        Self { data, at: 2, left: data.first().copied().unwrap_or(0) }
    }

    /// The layer's islands.
    pub fn islands(data: &[u32]) -> u16 {
        data.get(1).map_or(0, |&w| w as u16)
    }
}

impl<'a> Iterator for StoredRings<'a> {
    type Item = (u16, LoopPoints<'a>);

    fn next(&mut self) -> Option<Self::Item> {
        while self.left > 0 {
            self.left -= 1;
            let (&n, &island) = (self.data.get(self.at)?, self.data.get(self.at + 1)?);
            let pts = LoopPoints { data: self.data, at: self.at + 2, left: n, last: None };
            // Skip the points: one word each, three after an escape, two for the first.
            let mut at = self.at + 2;
            for k in 0..n {
                at += match (k, self.data.get(at)) {
                    (0, _) => 2,
                    (_, Some(&FAR)) => 3,
                    _ => 1,
                };
            }
            self.at = at;
            if n >= 3 {
                return Some((island as u16, pts));
            }
        }
        None
    }
}

/// The points of one stored loop.
#[derive(Clone)]
pub struct LoopPoints<'a> {
    data: &'a [u32],
    at: usize,
    left: u32,
    last: Option<Point2>,
}

impl Iterator for LoopPoints<'_> {
    type Item = Point2;

    fn next(&mut self) -> Option<Point2> {
        if self.left == 0 {
            return None;
        }
        self.left -= 1;
        let w = *self.data.get(self.at)?;
        let p = match self.last {
            Some(q) if w != FAR => {
                self.at += 1;
                let (dx, dy) = (i32::from(w as u16 as i16), i32::from((w >> 16) as u16 as i16));
                Point2::new(q.x.wrapping_add(dx), q.y.wrapping_add(dy))
            }
            _ => {
                let skip = usize::from(self.last.is_some());
                let xy = self.data.get(self.at + skip..self.at + skip + 2)?;
                self.at += skip + 2;
                Point2::new(xy[0] as i32, xy[1] as i32)
            }
        };
        self.last = Some(p);
        Some(p)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_loops_round_trip() {
        let a = [Point2::new(100_000, 5), Point2::new(100_010, -7), Point2::new(40_000, 9)];
        let b = [Point2::new(-3, 4), Point2::new(i32::MAX, i32::MIN), Point2::new(0, 0)];
        let mut out = [0u32; 64];
        let mut e = Encoder::new(&mut out);
        for (island, pts, keep) in [(0, &a[..], true), (5, &a[..2], false), (1, &b[..], true)] {
            e.begin(island).unwrap();
            pts.iter().for_each(|&p| e.push(p).unwrap());
            e.end(keep);
        }
        let words = e.finish(2, 2);
        let count = |pts: &[Point2]| {
            let mut w = LoopWords::default();
            pts.iter().for_each(|&p| w.add(p));
            w.words
        };
        assert_eq!(words, 2 + count(&a) + count(&b));
        // a: 2 + 2 + 3 (60 mm jump) + 1; b: 2 + 2 + 3 + 3.
        assert_eq!(words, 2 + 8 + 10);
        let data = &out[..words];
        assert_eq!(StoredRings::islands(data), 2);
        let got: std::vec::Vec<(u16, std::vec::Vec<Point2>)> =
            StoredRings::new(data).map(|(i, p)| (i, p.collect())).collect();
        assert_eq!(got, [(0, a.to_vec()), (1, b.to_vec())]);
        assert_eq!(Encoder::new(&mut out[..3]).begin(0), Err(Buffer::RingPoints));
    }

    #[test]
    fn blocks_wrap_and_stay_contiguous() {
        let mut f = Fifo::<u8, 10>::new(0, Buffer::RingPoints);
        for (layer, n) in [(0u32, 4usize), (1, 4)] {
            let s = f.reserve(n).unwrap();
            s.fill(layer as u8 + 1);
            f.commit(layer, n);
        }
        assert_eq!(f.reserve(3), Err(Buffer::RingPoints));
        f.pop();
        // 2 free at the end, 4 at the start: a block of 3 wraps to 0.
        let s = f.reserve(3).unwrap();
        s.fill(9);
        f.commit(2, 3);
        let b = f.find(2).unwrap();
        assert_eq!((b.start, b.len), (0, 3));
        assert_eq!(f.data(&f.find(1).unwrap()), &[2, 2, 2, 2]);
        assert_eq!(f.data(&b), &[9, 9, 9]);
        assert_eq!(f.len(), 2);
        assert_eq!(f.peak, 8);
        // 1 free before the oldest block (3..4) and 2 at the end are not contiguous for 3.
        assert_eq!(f.reserve(3), Err(Buffer::RingPoints));
        assert!(f.reserve(1).is_ok());
        // A reservation counts whole, even when committed shorter.
        f.commit(3, 0);
        f.pop();
        assert!(f.reserve(6).is_ok());
        f.commit(4, 1);
        assert_eq!(f.peak, 3 + 6);
    }
}

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
//! A [`Fifo`] is circular: a block that reaches the end of the array goes on at 0, so it
//! holds whatever fits in its free room (no fragmentation: the largest use is the capacity
//! needed) and a block is read as two slices ([`Parts`]).

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

/// A block's elements: `a`, then `b` when it wraps past the end of the storage.
#[derive(Debug, Clone, Copy)]
pub struct Parts<'a, T> {
    /// The elements up to the end of the storage.
    pub a: &'a [T],
    /// The rest, from the start of the storage.
    pub b: &'a [T],
}

impl<'a, T> Parts<'a, T> {
    /// No elements.
    pub const EMPTY: Self = Self { a: &[], b: &[] };

    /// Element `i`.
    pub fn get(&self, i: usize) -> Option<&'a T> {
        match i.checked_sub(self.a.len()) {
            None => self.a.get(i),
            Some(j) => self.b.get(j),
        }
    }
}

/// A reserved block being written: `a`, then `b` (see [`Parts`]).
pub struct PartsMut<'a, T> {
    a: &'a mut [T],
    b: &'a mut [T],
}

impl<T> PartsMut<'_, T> {
    /// Element `i`.
    pub fn get_mut(&mut self, i: usize) -> Option<&mut T> {
        match i.checked_sub(self.a.len()) {
            None => self.a.get_mut(i),
            Some(j) => self.b.get_mut(j),
        }
    }
}

/// Circular FIFO of blocks in `N` elements of `T`.
pub struct Fifo<T: Copy, const N: usize> {
    data: [T; N],
    blocks: [Block; MAX_BLOCKS],
    /// Index of the oldest block and number of blocks.
    head: usize,
    count: usize,
    /// Where the block being written starts and its reserved length.
    open: Option<(usize, usize)>,
    /// Most elements in use at once, a reserved block counted whole: the capacity needed.
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

    /// `len` elements from `start`, wrapping: (up to the end, from 0).
    fn span(start: usize, len: usize) -> (core::ops::Range<usize>, core::ops::Range<usize>) {
        let start = start.min(N);
        let first = len.min(N - start);
        (start..start + first, 0..(len - first).min(start))
    }

    /// The elements of a block.
    pub fn data(&self, b: &Block) -> Parts<'_, T> {
        let (a, w) = Self::span(b.start as usize, b.len as usize);
        Parts { a: &self.data[a], b: &self.data[w] }
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

    /// Reserves room for a block of up to `max` elements (right after the newest block,
    /// wrapping) and returns it to be written; the block is added by
    /// [`commit`](Self::commit).
    pub fn reserve(&mut self, max: usize) -> Result<PartsMut<'_, T>, Buffer> {
        if self.count >= MAX_BLOCKS {
            return Err(Buffer::WindowLayers);
        }
        let used = self.in_use();
        if used + max > N {
            return Err(self.what);
        }
        let start = match self.block(self.count.wrapping_sub(1)) {
            Some(last) => (last.start as usize + last.len as usize).checked_rem(N).unwrap_or(0),
            None => 0,
        };
        self.open = Some((start, max));
        self.peak = self.peak.max(used + max);
        let (a, w) = Self::span(start, max);
        let (lo, hi) = self.data.split_at_mut(start.min(N));
        Ok(PartsMut { a: &mut hi[..a.len()], b: &mut lo[w] })
    }

    /// Adds the reserved block with its first `len` elements.
    pub fn commit(&mut self, layer: u32, len: usize) {
        let Some((start, max)) = self.open.take() else { return };
        let len = len.min(max);
        self.blocks[(self.head + self.count) % MAX_BLOCKS] =
            Block { layer, start: start as u32, len: len as u32 };
        self.count += 1;
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

/// Writes one stored layer in the [`StoredRings`] layout into a reserved block.
pub struct Encoder<'a> {
    out: PartsMut<'a, u32>,
    at: usize,
    /// Start of the loop being written, its points and the last one.
    ring: usize,
    n: u32,
    last: Point2,
}

impl<'a> Encoder<'a> {
    /// A layer in `out` (its header first).
    pub fn new(out: PartsMut<'a, u32>) -> Self {
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
    pub fn finish(mut self, loops: u32, islands: u16) -> usize {
        for (i, w) in [loops, u32::from(islands)].into_iter().enumerate() {
            if let Some(h) = self.out.get_mut(i) {
                *h = w;
            }
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
    data: Parts<'a, u32>,
    at: usize,
    left: u32,
}

impl<'a> StoredRings<'a> {
    /// The loops of `data` (a block written by an [`Encoder`]).
    pub fn new(data: Parts<'a, u32>) -> Self {
        Self { data, at: 2, left: data.get(0).copied().unwrap_or(0) }
    }

    /// The layer's islands.
    pub fn islands(data: Parts<'_, u32>) -> u16 {
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
    data: Parts<'a, u32>,
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
                let (x, y) = (self.data.get(self.at + skip)?, self.data.get(self.at + skip + 1)?);
                self.at += skip + 2;
                Point2::new(*x as i32, *y as i32)
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
        // A block wrapping past the end of the storage.
        let mut f = Fifo::<u32, 30>::new(0, Buffer::RingPoints);
        f.reserve(10).unwrap();
        f.commit(0, 10);
        f.pop();
        let mut e = Encoder::new(f.reserve(20).unwrap());
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
        f.commit(1, words);
        let data = f.data(&f.find(1).unwrap());
        assert_eq!((data.a.len(), data.b.len()), (20, 0));
        assert_eq!(StoredRings::islands(data), 2);
        let got: std::vec::Vec<(u16, std::vec::Vec<Point2>)> =
            StoredRings::new(data).map(|(i, p)| (i, p.collect())).collect();
        assert_eq!(got, [(0, a.to_vec()), (1, b.to_vec())]);
        let mut small = Fifo::<u32, 3>::new(0, Buffer::RingPoints);
        assert_eq!(Encoder::new(small.reserve(3).unwrap()).begin(0), Err(Buffer::RingPoints));
    }

    #[test]
    fn blocks_wrap_around_the_end() {
        let mut f = Fifo::<u8, 10>::new(0, Buffer::RingPoints);
        let fill = |f: &mut Fifo<u8, 10>, layer: u32, n: usize| {
            let mut w = f.reserve(n).unwrap();
            for i in 0..n {
                *w.get_mut(i).unwrap() = layer as u8 + 1;
            }
            assert!(w.get_mut(n).is_none());
            f.commit(layer, n);
        };
        fill(&mut f, 0, 4);
        fill(&mut f, 1, 4);
        assert!(f.reserve(3).is_err());
        f.pop();
        // 2 free at the end and 4 at the start: a block of 5 goes on at 0.
        fill(&mut f, 2, 5);
        let b = f.find(2).unwrap();
        let d = f.data(&b);
        assert_eq!((b.start, b.len, d.a, d.b), (8, 5, &[3, 3][..], &[3, 3, 3][..]));
        assert_eq!(f.data(&f.find(1).unwrap()).a, &[2, 2, 2, 2]);
        assert_eq!((f.len(), f.peak), (2, 9));
        // 1 free: a reservation counts whole, even when committed shorter.
        assert_eq!(f.reserve(2).err(), Some(Buffer::RingPoints));
        assert!(f.reserve(1).is_ok());
        f.commit(3, 0);
        f.pop();
        assert!(f.reserve(5).is_ok());
        f.commit(4, 1);
        assert_eq!(f.peak, 10);
    }
}

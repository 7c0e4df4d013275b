//! The layer window: per-layer blocks in bounded FIFO storage.
//!
//! Skins need to know, for layer `L`, the regions of the `bottom` layers below and the `top`
//! layers above. The slicer emits layers in order, so the toolpath of layer `L` is built when
//! layer `L + top` arrives; until then `L`'s simplified contours wait here (a [`Fifo`] of
//! words, one block per layer in the [`StoredRings`] layout: mostly 3 or 4 bytes a point and
//! four words a loop), and they stay for `bottom` more layers: the skin detection cuts them with each
//! scanline when it needs them ([`scan::line_spans`](super::scan::line_spans)), so no
//! per-line data of the window is stored. A loop's header holds the range of its points'
//! line keys `t` for both line directions and its length in words, so a scanline skips the
//! loops it cannot cross without decoding them ([`StoredRings::near_line`]).
//!
//! A [`Fifo`] is circular: a block that reaches the end of the array goes on at 0, so it
//! holds whatever fits in its free room (no fragmentation: the largest use is the capacity
//! needed) and a block is read as two slices ([`Parts`]).

use crate::geom::Point2;

use super::scan::{Angle, CrossingWalk, ScanLoop};
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

    /// Elements `start..start + len` (those that exist).
    pub fn sub(&self, start: usize, len: usize) -> Self {
        let end = start.saturating_add(len);
        let (a, b) = (self.a.len(), self.b.len());
        let part = |s: &'a [T], lo: usize, hi: usize| s.get(lo.min(hi)..hi).unwrap_or(&[]);
        Self {
            a: part(self.a, start.min(a), end.min(a)),
            b: part(self.b, start.saturating_sub(a).min(b), end.saturating_sub(a).min(b)),
        }
    }
}

/// `len` elements from `start` in a circular storage of `n`: (up to the end, from 0).
fn span(n: usize, start: usize, len: usize) -> (core::ops::Range<usize>, core::ops::Range<usize>) {
    let start = start.min(n);
    let first = len.min(n - start);
    (start..start + first, 0..(len - first).min(start))
}

/// The `len` elements from `start` of a [`Fifo`]'s `storage` (a block kept as two `u32`s,
/// 8 bytes, instead of its [`Parts`]' two slices, 16 bytes on the Cortex-M3).
pub fn parts<T>(storage: &[T], start: u32, len: u32) -> Parts<'_, T> {
    let (a, w) = span(storage.len(), start as usize, len as usize);
    Parts { a: &storage[a], b: &storage[w] }
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

/// Circular FIFO of blocks in `N` elements of `T` (the skin window's ring: a full one is
/// [`Buffer::RingPoints`]).
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
}

impl<T: Copy, const N: usize> Fifo<T, N> {
    /// Empty storage filled with `fill`.
    pub const fn new(fill: T) -> Self {
        Self {
            data: [fill; N],
            blocks: [Block { layer: 0, start: 0, len: 0 }; MAX_BLOCKS],
            head: 0,
            count: 0,
            open: None,
            peak: 0,
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
        span(N, start, len)
    }

    /// The elements of a block.
    pub fn data(&self, b: &Block) -> Parts<'_, T> {
        parts(&self.data, b.start, b.len)
    }

    /// The whole storage, where [`parts`] finds a block from its start and length.
    pub fn storage(&self) -> &[T] {
        &self.data
    }

    /// The block of `layer` to be rewritten in place (none while a block is reserved): its
    /// storage, to be ended by [`shrink`](Self::shrink).
    pub fn rewrite(&mut self, layer: u32) -> Option<(usize, PartsMut<'_, T>)> {
        if self.open.is_some() {
            return None;
        }
        let k =
            (0..self.count).find(|&k| self.blocks[(self.head + k) % MAX_BLOCKS].layer == layer)?;
        let b = self.blocks[(self.head + k) % MAX_BLOCKS];
        let (a, w) = Self::span(b.start as usize, b.len as usize);
        let (lo, hi) = self.data.split_at_mut((b.start as usize).min(N));
        Some((k, PartsMut { a: &mut hi[..a.len()], b: &mut lo[w] }))
    }

    /// Keeps the first `len` elements of the `k`-th oldest block and moves the newer blocks
    /// down onto the room it gave up (one pass over their elements, wrapping).
    pub fn shrink(&mut self, k: usize, len: usize) {
        if k >= self.count || N == 0 {
            return;
        }
        let i = (self.head + k) % MAX_BLOCKS;
        let b = self.blocks[i];
        let d = (b.len as usize).saturating_sub(len);
        if d == 0 {
            return;
        }
        self.blocks[i].len = len as u32;
        let newer = (k + 1..self.count).map(|j| self.blocks[(self.head + j) % MAX_BLOCKS].len);
        let moved: usize = newer.map(|l| l as usize).sum();
        let src = (b.start as usize + b.len as usize) % N;
        let dst = (b.start as usize + len) % N;
        for j in 0..moved {
            self.data[(dst + j) % N] = self.data[(src + j) % N];
        }
        for j in k + 1..self.count {
            let nb = &mut self.blocks[(self.head + j) % MAX_BLOCKS];
            nb.start = ((nb.start as usize + N - d) % N) as u32;
        }
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
            return Err(Buffer::RingPoints);
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

/// A stored loop's point as bytes (little-endian, tag in the low bits of the first byte),
/// after the previous point: `Short` (bit 0 clear) 3 bytes, `dx` and `dy` as 11-bit two's
/// complement in bits 1..12 and 12..23; `Mid` (bits 0..2 = `01`) 4 bytes, 15-bit `dx`, `dy` in
/// bits 2..17 and 17..32; `Far` (tag byte `0x03`) 9 bytes, then `x`, `y`. A loop's first point
/// is `Abs`: `x`, `y` in 8 bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Code {
    Abs(Point2),
    Short(u32),
    Mid(u32),
    Far(Point2),
}

impl Code {
    /// The code of `p` after `prev` (`None`: the loop's first point). The one coding function
    /// of the layout: [`Encoder`] writes it and [`LoopWords`] counts it.
    fn of(prev: Option<Point2>, p: Point2) -> Self {
        let Some(prev) = prev else { return Self::Abs(p) };
        let (dx, dy) = (i64::from(p.x) - i64::from(prev.x), i64::from(p.y) - i64::from(prev.y));
        let fits = |bits: u32| {
            let m = 1i64 << (bits - 1);
            (-m..m).contains(&dx) && (-m..m).contains(&dy)
        };
        let field = |d: i64, bits: u32| (d as u32) & ((1 << bits) - 1);
        if fits(11) {
            Self::Short(field(dx, 11) << 1 | field(dy, 11) << 12)
        } else if fits(15) {
            Self::Mid(1 | field(dx, 15) << 2 | field(dy, 15) << 17)
        } else {
            Self::Far(p)
        }
    }

    /// Bytes of the code.
    fn bytes(self) -> usize {
        match self {
            Self::Abs(_) => 8,
            Self::Short(_) => 3,
            Self::Mid(_) => 4,
            Self::Far(_) => 9,
        }
    }
}

/// `v`'s low `bits` bits as two's complement.
#[inline]
fn sext(v: u32, bits: u32) -> i32 {
    ((v << (32 - bits)) as i32) >> (32 - bits)
}

/// Words of a stored loop's header.
///
/// Its points and island, words of its points and the packed `t` range of its points for
/// [`Angle::D45`] and [`Angle::D135`] (in 32 `t` units, see [`LoopPoints::t_range`]).
pub const LOOP_HEADER: usize = 4;

/// The header words of the [`Angle::D45`] and [`Angle::D135`] ranges.
const DIAGONAL_WORDS: [usize; 2] = [2, 3];

/// Largest count of points, or words of points, of a stored loop (24 bits of a header word).
const LOOP_MAX: usize = (1 << 24) - 1;

/// `t` ranges in loop headers are in units of `2^T_SHIFT` `t` (32 `t`, 23 um), rounded
/// outwards.
const T_SHIFT: u32 = 5;

/// Header word of a loop whose points' `t` lie in `lo..=hi`: `lo` rounded down and `hi`
/// rounded up to [`T_SHIFT`] units, as `i16`s (`lo + hi x 2^16`); a bound beyond `i16`
/// saturates to `i16::MIN` (no lower bound) or `i16::MAX` (no upper bound).
fn pack_range(lo: i64, hi: i64) -> u32 {
    let sat = |v: i64| v.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16 as u16;
    let hi_up = (hi >> T_SHIFT) + i64::from(hi & ((1 << T_SHIFT) - 1) != 0);
    u32::from(sat(lo >> T_SHIFT)) | u32::from(sat(hi_up)) << 16
}

/// Bounds `(lo, hi)` in `t` of a [`pack_range`] word: every point has `lo <= t <= hi`.
fn unpack_range(w: u32) -> (i64, i64) {
    let (lo, hi) = (w as u16 as i16, (w >> 16) as u16 as i16);
    let lo = if lo == i16::MIN { i64::MIN } else { i64::from(lo) << T_SHIFT };
    let hi = if hi == i16::MAX { i64::MAX } else { i64::from(hi) << T_SHIFT };
    (lo, hi)
}

/// Index of `angle`'s range word in a loop header (stored for the diagonals only).
fn range_word(angle: Angle) -> Option<usize> {
    match angle {
        Angle::D45 => Some(2),
        Angle::D135 => Some(3),
        Angle::D0 | Angle::D90 => None,
    }
}

/// Bounds `(lo, hi)` of the points' `t` for `angle` from their packed diagonal ranges
/// `[D45, D135]`: the axes' `t` are half sums of the diagonals' (`y = (t45 + t135) / 2`,
/// `x = (t135 - t45) / 2`), rounded outwards; unbounded when a diagonal is.
fn t_range_of(range: [u32; 2], angle: Angle) -> (i64, i64) {
    let (d45, d135) = (unpack_range(range[0]), unpack_range(range[1]));
    let bounded = |(lo, hi): (i64, i64)| lo != i64::MIN && hi != i64::MAX;
    match angle {
        Angle::D45 => d45,
        Angle::D135 => d135,
        _ if !bounded(d45) || !bounded(d135) => (i64::MIN, i64::MAX),
        Angle::D0 => ((d45.0 + d135.0).div_euclid(2), (d45.1 + d135.1 + 1).div_euclid(2)),
        Angle::D90 => ((d135.0 - d45.1).div_euclid(2), (d135.1 - d45.0 + 1).div_euclid(2)),
    }
}

/// A loop header's first two words: `(points, island, words of its points)`.
fn unpack_head(w0: u32, w1: u32) -> (u32, u16, usize) {
    let island = (w0 >> 24 | (w1 >> 24) << 8) as u16;
    (w0 & LOOP_MAX as u32, island, (w1 & LOOP_MAX as u32) as usize)
}

/// Writes one stored layer in the [`StoredRings`] layout into a reserved block.
pub struct Encoder<'a> {
    out: PartsMut<'a, u32>,
    at: usize,
    /// Start of the loop being written, its island, its points and the last one.
    ring: usize,
    island: u16,
    n: u32,
    last: Point2,
    /// Bytes not yet in a whole word: `bits` bits of `acc` (also written to word `at`).
    acc: u64,
    bits: u32,
    /// Smallest and largest `t` of the loop's points, [`Angle::D45`] then [`Angle::D135`].
    t: [(i64, i64); 2],
}

impl<'a> Encoder<'a> {
    /// A layer in `out` (its header first).
    pub fn new(out: PartsMut<'a, u32>) -> Self {
        Self {
            out,
            at: 2,
            ring: 2,
            island: 0,
            n: 0,
            last: Point2::new(0, 0),
            acc: 0,
            bits: 0,
            t: [(0, 0); 2],
        }
    }

    fn word(&mut self, w: u32) -> Result<(), Buffer> {
        *self.out.get_mut(self.at).ok_or(Buffer::RingPoints)? = w;
        self.at += 1;
        Ok(())
    }

    /// Appends the low `bytes` (1..=4) bytes of `v` to the loop's bytes.
    fn put(&mut self, v: u32, bytes: u32) -> Result<(), Buffer> {
        self.acc |= u64::from(v) << self.bits;
        self.bits += 8 * bytes;
        if self.bits >= 32 {
            self.word(self.acc as u32)?;
            (self.acc, self.bits) = (self.acc >> 32, self.bits - 32);
        }
        if self.bits > 0 {
            // The partial word, so that `end` cannot run out of room.
            *self.out.get_mut(self.at).ok_or(Buffer::RingPoints)? = self.acc as u32;
        }
        Ok(())
    }

    /// Starts a loop of `island`.
    pub fn begin(&mut self, island: u16) -> Result<(), Buffer> {
        (self.ring, self.island, self.n, self.acc, self.bits) = (self.at, island, 0, 0, 0);
        self.t = [(i64::MAX, i64::MIN); 2];
        // Written by `end`.
        for _ in 0..LOOP_HEADER {
            self.word(0)?;
        }
        Ok(())
    }

    /// Appends a point to the loop.
    pub fn push(&mut self, p: Point2) -> Result<(), Buffer> {
        if self.n as usize >= LOOP_MAX || self.at - self.ring >= LOOP_MAX {
            return Err(Buffer::RingPoints);
        }
        match Code::of((self.n > 0).then_some(self.last), p) {
            Code::Short(v) => self.put(v, 3)?,
            Code::Mid(v) => self.put(v, 4)?,
            c @ (Code::Abs(q) | Code::Far(q)) => {
                if matches!(c, Code::Far(_)) {
                    self.put(3, 1)?;
                }
                self.put(q.x as u32, 4)?;
                self.put(q.y as u32, 4)?;
            }
        }
        for (r, a) in self.t.iter_mut().zip([Angle::D45, Angle::D135]) {
            let t = a.key(p).0;
            *r = (r.0.min(t), r.1.max(t));
        }
        self.last = p;
        self.n += 1;
        Ok(())
    }

    /// Ends the loop: kept with its points if `keep`, else removed.
    pub fn end(&mut self, keep: bool) {
        if keep {
            // The partial word, already written by `put`.
            self.at += usize::from(self.bits > 0);
            let words = (self.at - self.ring - LOOP_HEADER) as u32;
            let [(l45, h45), (l135, h135)] = self.t;
            let island = u32::from(self.island);
            let head = [
                self.n | (island & 0xFF) << 24,
                words | (island >> 8) << 24,
                pack_range(l45, h45),
                pack_range(l135, h135),
            ];
            for (i, w) in head.into_iter().enumerate() {
                if let Some(h) = self.out.get_mut(self.ring + i) {
                    *h = w;
                }
            }
        } else {
            self.at = self.ring;
        }
        (self.acc, self.bits) = (0, 0);
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

/// Counts the words a loop takes in the [`StoredRings`] layout, point by point: its header
/// and its points' bytes rounded up to whole words.
pub struct LoopWords {
    prev: Option<Point2>,
    bytes: usize,
    /// Words so far.
    pub words: usize,
}

impl Default for LoopWords {
    /// A loop without points: its header.
    fn default() -> Self {
        Self { prev: None, bytes: 0, words: LOOP_HEADER }
    }
}

impl LoopWords {
    /// Adds the loop's next point.
    pub fn add(&mut self, p: Point2) {
        self.bytes += Code::of(self.prev, p).bytes();
        self.words = LOOP_HEADER + self.bytes.div_ceil(4);
        self.prev = Some(p);
    }
}

/// The loops of one stored layer, in words.
///
/// `(loops, islands)`, then every loop is a [`LOOP_HEADER`] (`points + (island & 0xFF) x 2^24`,
/// `words of its points + (island >> 8) x 2^24`, t range at 45 degrees, t range at 135 degrees) and
/// its points' bytes in little-endian words, the last one padded with zeros: the first point's x, y
/// in 8, then each point after the previous one in 3 (11-bit offsets), 4 (15-bit offsets) or 9
/// bytes (tag byte, x, y), the tag in the low bits of the first byte (on a typical loop most
/// simplified points are under 1 mm apart). Yields `(island, points)` for the loops of at least
/// three points; the next loop is found from the words, without walking the points.
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

    /// The loops that may cross line `t` of `angle` (their header's range holds `t`), for
    /// [`line_spans`](super::scan::line_spans); the others are skipped undecoded.
    pub fn near_line(self, angle: Angle, t: i64) -> NearLine<'a> {
        // `t` in range units, rounded down: `lo x 32 <= t` is `lo <= tq` and `t < hi x 32` is
        // `tq < hi`; clamped to `i16` (the saturated bounds compare as unbounded).
        let tq = (t >> T_SHIFT).clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16;
        NearLine { rings: self, word: range_word(angle), angle, t, tq }
    }
}

/// The loops of a stored layer that may cross one line ([`StoredRings::near_line`]).
pub struct NearLine<'a> {
    rings: StoredRings<'a>,
    /// The line direction's range word in a loop header (`None`: from both diagonals'), and
    /// the line's `t` in its units.
    word: Option<usize>,
    angle: Angle,
    t: i64,
    tq: i16,
}

impl<'a> Iterator for NearLine<'a> {
    type Item = LoopCut<'a>;

    fn next(&mut self) -> Option<LoopCut<'a>> {
        let r = &mut self.rings;
        while r.left > 0 {
            r.left -= 1;
            let head = r.at;
            let h = |i: usize| r.data.get(head + i).copied();
            let (n, _, words) = unpack_head(h(0)?, h(1)?);
            let ranges = [h(DIAGONAL_WORDS[0])?, h(DIAGONAL_WORDS[1])?];
            r.at = head.checked_add(LOOP_HEADER + words)?;
            // An edge crosses `t` when `min <= t < max` of its ends' `t`.
            let near = match self.word {
                Some(w) => {
                    let range = h(w)?;
                    let (lo, hi) = (range as u16 as i16, (range >> 16) as u16 as i16);
                    lo <= self.tq && (self.tq < hi || hi == i16::MAX)
                }
                None => {
                    let (lo, hi) = t_range_of(ranges, self.angle);
                    lo <= self.t && self.t <= hi
                }
            };
            if n >= 3 && near {
                let range = ranges;
                let words = r.data.sub(head + LOOP_HEADER, words);
                return Some(LoopCut(LoopPoints::new(words, range, n)));
            }
        }
        None
    }
}

impl<'a> Iterator for StoredRings<'a> {
    type Item = (u16, LoopPoints<'a>);

    fn next(&mut self) -> Option<Self::Item> {
        while self.left > 0 {
            self.left -= 1;
            let head = self.at;
            let h = |i: usize| self.data.get(head + i).copied();
            let (n, island, words) = unpack_head(h(0)?, h(1)?);
            let range = [h(DIAGONAL_WORDS[0])?, h(DIAGONAL_WORDS[1])?];
            self.at = head.checked_add(LOOP_HEADER + words)?;
            if n >= 3 {
                let words = self.data.sub(head + LOOP_HEADER, words);
                return Some((island, LoopPoints::new(words, range, n)));
            }
        }
        None
    }
}

/// A stored loop that may cross a line ([`NearLine`]): cut by
/// [`line_spans`](super::scan::line_spans) straight from its words.
pub struct LoopCut<'a>(pub LoopPoints<'a>);

impl LoopCut<'_> {
    /// [`ScanLoop::crossing_edges`] with `t` of a point `y - x` (`A` 0: `D45`), `y + x` (1),
    /// `y` (2) or `x` (3). Not inlined: its loop keeps its state in registers (inlined into
    /// the infill pass, it spilled to the stack).
    #[inline(never)]
    fn walk<const A: u8>(
        self,
        t: i64,
        mut f: impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        let key = |p: Point2| {
            let (x, y) = (i64::from(p.x), i64::from(p.y));
            match A {
                0 => y - x,
                1 => y + x,
                2 => y,
                _ => x,
            }
        };
        let mut pts = self.0;
        let Some(first) = pts.next() else { return Ok(()) };
        let mut walk = CrossingWalk::new(first, key(first) <= t);
        // The later points, as `LoopPoints::next` reads them (a truncated loop ends early).
        while pts.left > 0 {
            pts.left -= 1;
            let Some(q) = pts.bits.point(walk.last()) else { break };
            walk.to(q, key(q) <= t, &mut f)?;
        }
        walk.close(&mut f)
    }
}

impl ScanLoop for LoopCut<'_> {
    fn crossing_edges(
        self,
        angle: Angle,
        t: i64,
        f: impl FnMut(Point2, Point2) -> Result<(), Buffer>,
    ) -> Result<(), Buffer> {
        match angle {
            Angle::D45 => self.walk::<0>(t, f),
            Angle::D135 => self.walk::<1>(t, f),
            Angle::D0 => self.walk::<2>(t, f),
            Angle::D90 => self.walk::<3>(t, f),
        }
    }
}

/// Reads the bytes of a stored loop's points ([`Code`]).
#[derive(Clone)]
struct Bits<'a> {
    /// The words not yet read (`a`, then `b` after the end of the storage).
    words: Parts<'a, u32>,
    /// Bytes read ahead: the low `bits` bits of `buf`.
    buf: u64,
    bits: u32,
}

impl Bits<'_> {
    /// Reads ahead a word if 32 bits or fewer are, and one is left.
    #[inline]
    fn fill(&mut self) {
        if self.bits <= 32 {
            if self.words.a.is_empty() {
                self.words.a = core::mem::take(&mut self.words.b);
            }
            if let Some((&w, rest)) = self.words.a.split_first() {
                self.words.a = rest;
                self.buf |= u64::from(w) << self.bits;
                self.bits += 32;
            }
        }
    }

    /// The next `n` (1..=32) bits, if there are.
    #[inline]
    fn take(&mut self, n: u32) -> Option<u32> {
        self.fill();
        if self.bits < n {
            return None;
        }
        let v = (self.buf & ((1u64 << n) - 1)) as u32;
        (self.buf, self.bits) = (self.buf >> n, self.bits - n);
        Some(v)
    }

    /// The next point after `prev` (a [`Code`] other than `Abs`), if the bytes hold one.
    #[inline]
    fn point(&mut self, prev: Point2) -> Option<Point2> {
        self.fill();
        let (dx, dy) = if self.buf & 1 == 0 {
            let v = self.take(24)?;
            (sext(v >> 1, 11), sext(v >> 12, 11))
        } else if self.buf & 2 == 0 {
            let v = self.take(32)?;
            (sext(v >> 2, 15), sext(v >> 17, 15))
        } else {
            self.take(8)?;
            let (x, y) = (self.take(32)?, self.take(32)?);
            return Some(Point2::new(x as i32, y as i32));
        };
        Some(Point2::new(prev.x.wrapping_add(dx), prev.y.wrapping_add(dy)))
    }
}

/// The points of one stored loop.
#[derive(Clone)]
pub struct LoopPoints<'a> {
    /// The bytes not yet read.
    bits: Bits<'a>,
    /// The header's packed `t` ranges.
    range: [u32; 2],
    /// Points not yet read, whether none was, and the last one read.
    left: u32,
    first: bool,
    last: Point2,
}

impl<'a> LoopPoints<'a> {
    /// The `n` points coded in `words`, with the header's `range` words.
    fn new(words: Parts<'a, u32>, range: [u32; 2], n: u32) -> Self {
        let bits = Bits { words, buf: 0, bits: 0 };
        Self { bits, range, left: n, first: true, last: Point2::new(0, 0) }
    }

    /// Bounds `(lo, hi)` of the loop's points' `t` for `angle` (from its header): every
    /// point has `lo <= t <= hi`.
    pub fn t_range(&self, angle: Angle) -> (i64, i64) {
        t_range_of(self.range, angle)
    }
}

impl Iterator for LoopPoints<'_> {
    type Item = Point2;

    #[inline]
    fn next(&mut self) -> Option<Point2> {
        self.left = self.left.checked_sub(1)?;
        let p = if self.first {
            let x = self.bits.take(32)?;
            Point2::new(x as i32, self.bits.take(32)? as i32)
        } else {
            self.bits.point(self.last)?
        };
        (self.first, self.last) = (false, p);
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
        let mut f = Fifo::<u32, 40>::new(0);
        f.reserve(14).unwrap();
        f.commit(0, 14);
        f.pop();
        let mut e = Encoder::new(f.reserve(26).unwrap());
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
        // a: 4 + (8 + 3 + 9 (60 mm jump) bytes: 5 words); b: 4 + (8 + 9 + 9 bytes: 7 words).
        assert_eq!(words, 2 + 9 + 11);
        f.commit(1, words);
        let data = f.data(&f.find(1).unwrap());
        assert_eq!((data.a.len(), data.b.len()), (22, 0));
        assert_eq!(StoredRings::islands(data), 2);
        let got: std::vec::Vec<(u16, std::vec::Vec<Point2>)> =
            StoredRings::new(data).map(|(i, p)| (i, p.collect())).collect();
        assert_eq!(got, [(0, a.to_vec()), (1, b.to_vec())]);
        let mut small = Fifo::<u32, 3>::new(0);
        assert_eq!(Encoder::new(small.reserve(3).unwrap()).begin(0), Err(Buffer::RingPoints));
    }

    /// Seeded xorshift: `0..n`.
    fn rand(state: &mut u64, n: u64) -> u64 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        *state % n
    }

    #[test]
    fn loop_headers_bound_their_points_and_skip_to_the_next_loop() {
        let mut seed = 0x5eed_1234_abcd_0001u64;
        let lim = i64::from(i16::MAX) << T_SHIFT;
        for case in 0..300 {
            // Loops of 0..12 points: clustered (offsets), far apart (escapes) or beyond the
            // packed range (saturated bounds); some dropped, some too short to be yielded.
            let mut loops = std::vec::Vec::new();
            for _ in 0..rand(&mut seed, 6) {
                let spread = [2_000, 80_000, 3_000_000][rand(&mut seed, 3) as usize];
                let c = |s: &mut u64| rand(s, 2 * spread + 1) as i32 - spread as i32;
                let (cx, cy) = (c(&mut seed), c(&mut seed));
                let pts: std::vec::Vec<Point2> = (0..rand(&mut seed, 12))
                    .map(|_| Point2::new(cx + c(&mut seed) / 8, cy + c(&mut seed) / 8))
                    .collect();
                loops.push((rand(&mut seed, 5) as u16, pts, rand(&mut seed, 4) != 0));
            }
            let mut f = Fifo::<u32, 512>::new(0);
            // Start anywhere: blocks wrap.
            let skip = rand(&mut seed, 512) as usize;
            f.reserve(skip).unwrap();
            f.commit(0, skip);
            f.pop();
            let mut e = Encoder::new(f.reserve(400).unwrap());
            let mut kept = 0;
            for (island, pts, keep) in &loops {
                e.begin(*island).unwrap();
                pts.iter().for_each(|&p| e.push(p).unwrap());
                e.end(*keep);
                kept += u32::from(*keep);
            }
            let words = e.finish(kept, 5);
            let want_words: usize = 2
                + (loops.iter().filter(|l| l.2))
                    .map(|(_, pts, _)| {
                        let mut w = LoopWords::default();
                        pts.iter().for_each(|&p| w.add(p));
                        w.words
                    })
                    .sum::<usize>();
            assert_eq!(words, want_words, "case {case}");
            f.commit(1, words);
            let data = f.data(&f.find(1).unwrap());
            let want: std::vec::Vec<_> =
                loops.iter().filter(|l| l.2 && l.1.len() >= 3).map(|l| (l.0, &l.1)).collect();
            let got: std::vec::Vec<_> = StoredRings::new(data).collect();
            assert_eq!(got.len(), want.len(), "case {case}");
            for ((island, pts), (w_island, w_pts)) in got.into_iter().zip(want) {
                assert_eq!(island, w_island, "case {case}");
                for angle in Angle::ALL {
                    let (lo, hi) = pts.t_range(angle);
                    let ts = w_pts.iter().map(|&p| angle.key(p).0);
                    let (min, max) = (ts.clone().min().unwrap(), ts.max().unwrap());
                    assert!(lo <= min && max <= hi, "case {case}: {lo}..{hi} {min}..{max}");
                    if matches!(angle, Angle::D0 | Angle::D90) {
                        // The axes' bounds come from the diagonals': only containing.
                        continue;
                    }
                    // Within a unit of the points unless saturated.
                    let (lo_sat, hi_sat) =
                        (lo == i64::MIN || lo == lim, hi == i64::MAX || hi == -lim - 32);
                    assert!(lo_sat || lo > min - (1 << T_SHIFT), "case {case}");
                    assert!(hi_sat || hi < max + (1 << T_SHIFT), "case {case}");
                }
                // The loop's points, and the next loop found from its header's words.
                assert_eq!(&pts.collect::<std::vec::Vec<_>>(), w_pts, "case {case}");
            }
        }
        // The packed bounds: rounded outwards, saturated beyond `i16` units.
        assert_eq!(unpack_range(pack_range(-33, 33)), (-64, 64));
        assert_eq!(unpack_range(pack_range(-32, 32)), (-32, 32));
        assert_eq!(unpack_range(pack_range(-lim - 100, lim + 100)), (i64::MIN, i64::MAX));
        assert_eq!(unpack_range(pack_range(lim + 100, lim + 200)), (lim, i64::MAX));
        assert_eq!(unpack_range(pack_range(-lim - 200, -lim - 100)).0, i64::MIN);
    }

    /// Stores `pts` as one loop at `skip` words into a ring of 256 (wrapping) and checks the
    /// words against [`LoopWords`]; returns the ring and the block.
    fn store_loop(pts: &[Point2], skip: usize) -> (Fifo<u32, 256>, Block) {
        let mut f = Fifo::<u32, 256>::new(0);
        f.reserve(skip).unwrap();
        f.commit(0, skip);
        f.pop();
        let mut w = LoopWords::default();
        pts.iter().for_each(|&p| w.add(p));
        let mut e = Encoder::new(f.reserve(2 + w.words).unwrap());
        e.begin(0x1234).unwrap();
        pts.iter().for_each(|&p| e.push(p).unwrap());
        e.end(true);
        assert_eq!(e.finish(1, 1), 2 + w.words);
        f.commit(1, 2 + w.words);
        let b = f.find(1).unwrap();
        (f, b)
    }

    #[test]
    fn point_codes_round_trip_at_every_tag_boundary() {
        let o = Point2::new(0, 0);
        let size = |x, y| Code::of(Some(o), Point2::new(x, y)).bytes();
        assert_eq!((size(1023, -1024), size(-1024, 1023), size(0, 0)), (3, 3, 3));
        assert_eq!((size(1024, 0), size(0, -1025), size(16383, -16384)), (4, 4, 4));
        assert_eq!((size(16384, 0), size(0, -16385), size(i32::MAX, i32::MIN)), (9, 9, 9));
        assert_eq!(Code::of(None, o).bytes(), 8);
        let ds: std::vec::Vec<i64> = [0, 1, 1022, 1023, 1024, 1025, 16382, 16383, 16384, 16385]
            .into_iter()
            .flat_map(|d| [d, -d, -d - 1])
            .chain([i64::from(i32::MAX), i64::from(i32::MIN), 1 << 31, -(1 << 32) + 1])
            .collect();
        let starts = [o, Point2::new(i32::MAX, i32::MIN), Point2::new(i32::MIN, i32::MAX)];
        let mut seed = 0x0dd_c0de_u64;
        for (k, &start) in starts.iter().enumerate() {
            for &dx in &ds {
                // Each `dx` with every `dy`, from `start` (wrapping as `i32`).
                let mut pts = std::vec![start];
                for &dy in &ds {
                    let p = *pts.last().unwrap();
                    pts.push(Point2::new(
                        (i64::from(p.x) + dx) as i32,
                        (i64::from(p.y) + dy) as i32,
                    ));
                }
                let (f, b) = store_loop(&pts, rand(&mut seed, 256) as usize);
                let got: std::vec::Vec<_> = StoredRings::new(f.data(&b)).collect();
                assert_eq!(got.len(), 1);
                assert_eq!(got[0].0, 0x1234);
                assert_eq!(got[0].1.clone().collect::<std::vec::Vec<_>>(), pts, "{k} {dx}");
            }
        }
        // Random points and deltas of every size, checked against the cut's edges too.
        for case in 0..500 {
            let n = 3 + rand(&mut seed, 10) as usize;
            let mut pts = std::vec![Point2::new(rand(&mut seed, 1 << 32) as i32, 7)];
            for _ in 1..n {
                let bits = [11, 15, 16, 32][rand(&mut seed, 4) as usize];
                let mut d = || (rand(&mut seed, 1 << bits) as i64 - (1 << (bits - 1))) as i32;
                let p = *pts.last().unwrap();
                pts.push(Point2::new(p.x.wrapping_add(d()), p.y.wrapping_add(d())));
            }
            let (f, b) = store_loop(&pts, rand(&mut seed, 256) as usize);
            let (_, got) = StoredRings::new(f.data(&b)).next().unwrap();
            assert_eq!(got.collect::<std::vec::Vec<_>>(), pts, "case {case}");
        }
    }

    #[test]
    fn malformed_or_truncated_blocks_do_not_panic() {
        let mut seed = 0xbad_da7a_u64;
        let pts: std::vec::Vec<Point2> =
            (0..12).map(|i| Point2::new(i * 5_000 - 20_000, (i * i * 900) % 70_000)).collect();
        let (f, b) = store_loop(&pts, 250);
        let good = f.data(&b);
        let walk = |data: Parts<'_, u32>| {
            let mut n = 0usize;
            for (_, p) in StoredRings::new(data).take(100) {
                n += p.take(1000).count();
            }
            for angle in Angle::ALL {
                for t in [i64::MIN, -70_000, 0, 70_000, i64::MAX] {
                    for cut in StoredRings::new(data).near_line(angle, t).take(100) {
                        let _ = cut.crossing_edges(angle, t, |_, _| {
                            n += 1;
                            Ok(())
                        });
                    }
                }
            }
            n
        };
        assert!(walk(good) > 0);
        // Every truncation, and every word of the block replaced by a random or extreme one.
        for len in 0..b.len as usize {
            walk(good.sub(0, len));
        }
        for i in 0..b.len as usize {
            for _ in 0..20 {
                let mut words: std::vec::Vec<u32> = good.a.iter().chain(good.b).copied().collect();
                words[i] = [0, u32::MAX, 0x00FF_FFFF, rand(&mut seed, 1 << 32) as u32]
                    [rand(&mut seed, 4) as usize];
                walk(Parts { a: &words, b: &[] });
            }
        }
        for _ in 0..200 {
            let words: std::vec::Vec<u32> =
                (0..rand(&mut seed, 40)).map(|_| rand(&mut seed, 1 << 32) as u32).collect();
            walk(Parts { a: &words, b: &[] });
        }
    }

    #[test]
    fn blocks_wrap_around_the_end() {
        let mut f = Fifo::<u8, 10>::new(0);
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

    #[test]
    fn a_block_shrunk_in_place_gives_its_room_to_the_newer_ones() {
        let mut f = Fifo::<u8, 10>::new(0);
        let fill = |f: &mut Fifo<u8, 10>, layer: u32, n: usize| {
            let mut w = f.reserve(n).unwrap();
            for i in 0..n {
                *w.get_mut(i).unwrap() = (10 * layer as usize + i) as u8;
            }
            f.commit(layer, n);
        };
        // Blocks 0 (at 0..3), 1 (3..7), 2 (7..10): full; after dropping 0, block 3 wraps.
        fill(&mut f, 0, 3);
        fill(&mut f, 1, 4);
        fill(&mut f, 2, 3);
        f.pop();
        fill(&mut f, 3, 2);
        assert_eq!(f.reserve(2).err(), Some(Buffer::RingPoints));
        // Layer 1 keeps its first element (rewritten) and gives up three.
        let (k, mut w) = f.rewrite(1).unwrap();
        *w.get_mut(0).unwrap() = 99;
        f.shrink(k, 1);
        let elements = |f: &Fifo<u8, 10>, layer: u32| {
            let d = f.data(&f.find(layer).unwrap());
            d.a.iter().chain(d.b).copied().collect::<std::vec::Vec<u8>>()
        };
        assert_eq!(elements(&f, 1), [99]);
        assert_eq!(elements(&f, 2), [20, 21, 22]);
        assert_eq!(elements(&f, 3), [30, 31]);
        assert_eq!(f.find(2).unwrap().start, 4);
        assert_eq!(f.find(3).unwrap().start, 7);
        // The room is free again, after the newest block.
        fill(&mut f, 4, 3);
        assert_eq!(elements(&f, 4), [40, 41, 42]);
        assert_eq!(f.find(4).unwrap().start, 9);
        // No rewrite while a block is reserved.
        f.pop();
        let _ = f.reserve(1).unwrap();
        assert!(f.rewrite(2).is_none());
    }
}

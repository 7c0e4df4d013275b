//! The layer window: per-layer blocks in bounded FIFO storage.
//!
//! Skins need to know, for layer `L`, the regions of the `bottom` layers below and the `top`
//! layers above. The slicer emits layers in order, so the toolpath of layer `L` is built when
//! layer `L + top` arrives; until then `L`'s simplified contours wait here (a [`Fifo`] of
//! points, one block per layer in the [`StoredRings`] layout), and they stay for `bottom`
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

/// The loops of one stored layer: `data[0]` is `(loops, islands)`, then every loop is a
/// header `(points, island)` followed by its points (the closing edge implied). Yields
/// `(island, points)` for the loops of at least three points.
pub struct StoredRings<'a> {
    data: &'a [Point2],
    at: usize,
    left: i32,
}

impl<'a> StoredRings<'a> {
    /// The loops of `data` (a block written in this layout).
    pub fn new(data: &'a [Point2]) -> Self {
        Self { data, at: 1, left: data.first().map_or(0, |h| h.x.max(0)) }
    }
}

impl<'a> Iterator for StoredRings<'a> {
    type Item = (u16, &'a [Point2]);

    fn next(&mut self) -> Option<Self::Item> {
        while self.left > 0 {
            self.left -= 1;
            let h = self.data.get(self.at)?;
            let n = h.x.max(0) as usize;
            let pts = self.data.get(self.at + 1..self.at + 1 + n).unwrap_or(&[]);
            self.at += 1 + n;
            if pts.len() >= 3 {
                return Some((h.y as u16, pts));
            }
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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

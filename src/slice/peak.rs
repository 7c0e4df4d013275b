//! Peak needs of a model: the capacities a device must have to slice it (admission control).
//!
//! Runs on the host over placed triangles. It uses the slicer's own rules (the planes a
//! triangle crosses, the cut of a triangle by a plane), so its figures are exactly the
//! slicer's peak active set and peak segment count (= contour points of a closed mesh).

use crate::geom::Triangle;

use super::intersect::cut;
use super::packed::is_packable;
use super::{SliceConfig, SliceError};

/// The largest per-layer needs of a model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct PeakNeeds {
    /// Layers of the model.
    pub layers: u32,
    /// Triangles that cross at least one plane (the rest are dropped on arrival).
    pub spanning_triangles: u32,
    /// Largest active set: the `ACTIVE` capacity the slicer needs.
    pub active_triangles: u32,
    /// The first layer with that active set.
    pub active_layer: u32,
    /// Largest number of cut segments in a layer: the `SEGMENTS` capacity the slicer needs,
    /// and the contour points of that layer when the mesh is closed.
    pub contour_points: u32,
    /// The first layer with that many segments.
    pub points_layer: u32,
}

/// Layers counted per pass over the triangles (stack counters, no allocation).
const BATCH: usize = 256;

/// The peak active set and peak segments per layer of `triangles` (placed, any order).
/// Costs one pass over the triangles per 256 layers plus one cut per crossing.
pub fn peak_needs(triangles: &[Triangle], config: &SliceConfig) -> Result<PeakNeeds, SliceError> {
    config.validate()?;
    let layers = config.layer_count();
    let mut needs = PeakNeeds { layers, ..PeakNeeds::default() };
    for (index, t) in triangles.iter().enumerate() {
        if !is_packable(t) {
            return Err(SliceError::OutOfRange { index: index as u32 });
        }
        if config.crossed_planes(t.z_min(), t.z_max()).is_some() {
            needs.spanning_triangles += 1;
        }
    }
    let mut batch_start = 0u32;
    while batch_start < layers {
        let batch_end = layers.min(batch_start + BATCH as u32);
        // `starts[k]` - `ends[k]`: running count of active triangles (difference array).
        let (mut starts, mut ends, mut segments) = ([0u32; BATCH], [0u32; BATCH], [0u32; BATCH]);
        for t in triangles {
            let Some((first, last)) = config.crossed_planes(t.z_min(), t.z_max()) else {
                continue;
            };
            let (lo, hi) = (first.max(batch_start), last.min(batch_end - 1));
            if lo > hi {
                continue;
            }
            starts[(lo - batch_start) as usize] += 1;
            ends[(hi - batch_start) as usize] += 1;
            for k in lo..=hi {
                if cut(&t.v, config.plane_z_um(k) as i32).is_some() {
                    segments[(k - batch_start) as usize] += 1;
                }
            }
        }
        let mut active = 0u32;
        for k in batch_start..batch_end {
            let i = (k - batch_start) as usize;
            active += starts[i];
            if active > needs.active_triangles {
                (needs.active_triangles, needs.active_layer) = (active, k);
            }
            if segments[i] > needs.contour_points {
                (needs.contour_points, needs.points_layer) = (segments[i], k);
            }
            active -= ends[i];
        }
        batch_start = batch_end;
    }
    Ok(needs)
}

/// The active set of a triangle stream sorted by lowest z, counted as it streams.
///
/// In words its caller lends ([`ActiveCount::push`]): on the device, where the whole model is
/// never in RAM (an STL sorted on the card). The largest count it gives is [`peak_needs`]'s
/// `active_triangles`.
///
/// `words[0]` is the count; `words[1..]` a min-heap of the last plane each active triangle
/// crosses, so that the triangles below a newcomer's first plane leave first.
pub struct ActiveCount<'a> {
    words: &'a mut [i32],
}

/// The lent words cannot hold one more active triangle.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WordsFull;

impl<'a> ActiveCount<'a> {
    /// Counts in `words` as they stand (a count begun earlier goes on).
    pub fn resume(words: &'a mut [i32]) -> Self {
        Self { words }
    }

    /// Starts a new count in `words`.
    pub fn start(words: &'a mut [i32]) -> Self {
        if let Some(len) = words.first_mut() {
            *len = 0;
        }
        Self { words }
    }

    /// `t`, the next triangle of the stream (no lower z_min than the one before), counted:
    /// the active set at its first plane (or the count unchanged, if it crosses no plane).
    pub fn push(&mut self, config: &SliceConfig, t: &Triangle) -> Result<u32, WordsFull> {
        let Some((len, heap)) = self.words.split_first_mut() else { return Err(WordsFull) };
        let mut n = (*len as usize).min(heap.len());
        let Some((first, last)) = config.crossed_planes(t.z_min(), t.z_max()) else {
            return Ok(n as u32);
        };
        // Triangles whose last plane is below this one's first left the active set.
        while n > 0 && (heap[0] as u32) < first {
            n -= 1;
            heap.swap(0, n);
            sift_down(&mut heap[..n], 0);
        }
        *len = n as i32;
        if n == heap.len() {
            return Err(WordsFull);
        }
        heap[n] = last as i32;
        let mut i = n;
        while i > 0 && heap[(i - 1) / 2] > heap[i] {
            heap.swap(i, (i - 1) / 2);
            i = (i - 1) / 2;
        }
        *len = (n + 1) as i32;
        Ok(n as u32 + 1)
    }
}

/// Moves `heap[i]` down the min-heap `heap`.
fn sift_down(heap: &mut [i32], mut i: usize) {
    loop {
        let mut least = i;
        for child in [2 * i + 1, 2 * i + 2] {
            if child < heap.len() && heap[child] < heap[least] {
                least = child;
            }
        }
        if least == i {
            return;
        }
        heap.swap(i, least);
        i = least;
    }
}

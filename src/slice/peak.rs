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

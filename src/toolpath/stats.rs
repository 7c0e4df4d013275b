//! What the toolpath stage counted, and the capacities a model needs.

use super::infill::{Span, POOL_WORDS};
use super::offset;
use super::poly::Ring;
use super::scan::Crossing;
#[cfg(doc)]
#[allow(unused_imports)]
use super::*;
use super::{Engine, Toolpath};
use crate::geom::Point2;

/// Counters of one layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LayerStats {
    /// Layer index.
    pub index: u32,
    /// Nozzle height, um.
    pub z_um: i32,
    /// Islands (outer loops with their holes).
    pub islands: u32,
    /// Islands too thin for one perimeter (nothing printed for them).
    pub thin_islands: u32,
    /// Area of the layer's cross-section that no line covers because it is thinner than a
    /// line width (thin walls, fins and whole thin islands; see the [module docs](super)), um^2.
    pub thin_area_um2: u64,
    /// Islands whose thin area was not measured: the measurement did not fit the offset
    /// buffers (`PTS`, see [`ToolpathStats::thin_pts`]); their toolpaths are complete.
    pub thin_unmeasured: u32,
    /// Extrusion paths (loops and runs) before ordering.
    pub paths: u32,
    /// Extruding moves.
    pub extrusion_moves: u32,
    /// Travel moves (including Z moves).
    pub travel_moves: u32,
    /// Retractions.
    pub retractions: u32,
    /// Continuous extrusion runs: extrusion stops once per run.
    pub stops: u32,
    /// Travel distance in XY, um.
    pub travel_um: u64,
    /// Filament fed by extruding moves, um.
    pub filament_um: i64,
    /// Moves of the layer's largest emission unit (a path with the travel, retraction and
    /// priming before it, see [`Toolpath::emit_next`]): the least room an owner's move
    /// buffer needs to take the layer path by path.
    pub max_unit_moves: u32,
}

impl LayerStats {
    /// All zero.
    pub const EMPTY: Self = Self {
        index: 0,
        z_um: 0,
        islands: 0,
        thin_islands: 0,
        thin_area_um2: 0,
        thin_unmeasured: 0,
        paths: 0,
        extrusion_moves: 0,
        travel_moves: 0,
        retractions: 0,
        stops: 0,
        travel_um: 0,
        filament_um: 0,
        max_unit_moves: 0,
    };
}

/// Largest use of every buffer (the capacities a model needs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ToolpathNeeds {
    /// Simplified contour points of one layer (and of one offset result): `PTS`.
    pub layer_points: u32,
    /// Loops of one layer: `LOOPS`.
    pub layer_loops: u32,
    /// Offset edges, splits or pieces of one island: `PTS`.
    pub offset_edges: u32,
    /// Scanline crossings of one infill pass, or its segments and pieces in 12-byte units
    /// (20 bytes a segment, 4 a piece): `CROSS`.
    pub crossings: u32,
    /// Path points of one layer, two per path for its record: `PATH`.
    pub path_points: u32,
    /// Paths of one layer (their records are in `path_points`).
    pub paths: u32,
    /// Words of the contours stored in the window (3 to 4 bytes a point packed into words,
    /// four words a loop): `RING`.
    pub ring_points: u32,
    /// Crossings of the window's layers with one scanline (their spans): `SPANS`.
    pub spans: u32,
}

impl ToolpathNeeds {
    /// Bytes per `PTS` in the stage: two loop buffers' points (the third's are in the
    /// working memory, beside the offset engine).
    pub const PTS_BYTES: usize = 2 * core::mem::size_of::<Point2>();
    /// Bytes per `PTS` of the offset engine and the stage's loop points kept beside it, in the
    /// working memory (where they take turns with the infill scratch, and with other stages'
    /// tenants in a shared one: the largest counts).
    pub const ENGINE_BYTES: usize = offset::BYTES_PER_EDGE + core::mem::size_of::<Point2>();
    /// Bytes per `LOOPS`: three loop buffers' loop records, island map and stage scratch.
    pub const LOOPS_BYTES: usize = 3 * core::mem::size_of::<Ring>() + 2 + 1;
    /// Bytes per `CROSS` of the infill scratch, in the working memory: a crossing, its order
    /// (then segment-end) entry and its share of the segment and piece pool.
    pub const CROSS_BYTES: usize =
        core::mem::size_of::<Crossing>() + core::mem::size_of::<u16>() + POOL_WORDS * 4;
    /// Bytes per `PATH`: a point, its feature packed in (a path record takes two).
    pub const PATH_BYTES: usize = core::mem::size_of::<super::paths::Slot>();
    /// Bytes per `RING` word (a stored point takes 3 to 9 bytes of them, see
    /// [`window::StoredRings`]).
    pub const RING_BYTES: usize = core::mem::size_of::<u32>();
    /// Bytes per `SPANS` entry (a crossing, then a span, of one scanline).
    pub const SPAN_BYTES: usize = core::mem::size_of::<Span>();

    /// What the stage needs for the model's largest layer (and its window) with working
    /// memory of its own, on this target: [`stage_bytes`](Self::stage_bytes) plus
    /// [`work_bytes`](Self::work_bytes).
    pub fn bytes(&self) -> usize {
        self.stage_bytes() + self.work_bytes()
    }

    /// The `PTS` these needs call for (loop points or offset edges, the larger).
    fn pts(&self) -> usize {
        self.layer_points.max(self.offset_edges) as usize
    }

    /// RAM of the stage's working memory for these needs (the offset engine or the infill
    /// scratch, the larger; [`ToolpathSpace`]), bytes; another stage's tenant may share the
    /// place.
    pub fn work_bytes(&self) -> usize {
        Self::work_bytes_of(self.pts(), self.crossings as usize)
    }

    /// RAM of the stage's working memory with `pts` offset edges and `crossings` infill
    /// crossings: its larger tenant, bytes.
    pub fn work_bytes_of(pts: usize, crossings: usize) -> usize {
        let engine = core::mem::size_of::<Engine<0>>() + pts * Self::ENGINE_BYTES;
        engine.max(crossings * Self::CROSS_BYTES)
    }

    /// RAM of a [`Toolpath`] whose capacities equal these needs, on this target, without
    /// its working memory.
    pub fn stage_bytes(&self) -> usize {
        core::mem::size_of::<Toolpath<0, 0, 0, 0, 0, 0>>()
            + self.pts() * Self::PTS_BYTES
            + self.layer_loops as usize * Self::LOOPS_BYTES
            + self.path_points as usize * Self::PATH_BYTES
            + self.ring_points as usize * Self::RING_BYTES
            + self.spans as usize * Self::SPAN_BYTES
    }

    /// RAM of the skin window alone (stored contours and one scanline's spans), bytes.
    pub fn window_bytes(&self) -> usize {
        self.ring_points as usize * Self::RING_BYTES + self.spans as usize * Self::SPAN_BYTES
    }
}

// The documented bytes per capacity unit hold on every target (the thumbv7m-none-eabi build
// checks them for the device).
const _: () = assert!(
    ToolpathNeeds::PTS_BYTES == 16
        && ToolpathNeeds::ENGINE_BYTES == 46
        && ToolpathNeeds::LOOPS_BYTES == 123
        && ToolpathNeeds::CROSS_BYTES == 22
        && ToolpathNeeds::PATH_BYTES == 6
        && ToolpathNeeds::RING_BYTES == 4
        && ToolpathNeeds::SPAN_BYTES == 8
);

/// Totals of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ToolpathStats {
    /// Layers emitted.
    pub layers: u32,
    /// Extruding moves.
    pub extrusion_moves: u64,
    /// Travel moves.
    pub travel_moves: u64,
    /// Retractions.
    pub retractions: u64,
    /// Extrusion runs (stops).
    pub stops: u64,
    /// Travel distance, um.
    pub travel_um: u64,
    /// Filament, um.
    pub filament_um: i64,
    /// Islands too thin for a perimeter, over all layers.
    pub thin_islands: u64,
    /// Cross-section area thinner than a line width, summed over all layers, um^2.
    pub thin_area_um2: u64,
    /// The largest [`LayerStats::thin_area_um2`] of one layer, um^2.
    pub max_thin_area_um2: u64,
    /// The layer with that area.
    pub max_thin_area_layer: u32,
    /// Islands whose thin area was not measured (offset buffers too small for it).
    pub thin_unmeasured: u64,
    /// `PTS` needed to print and to measure every island's thin area (at least the `PTS` of
    /// [`needs`](Self::needs), which leave the measurement out: a stage sized to the needs
    /// prints the same, but may leave some islands unmeasured).
    pub thin_pts: u32,
    /// Offset boundary chains that could not be closed (should be 0).
    pub open_chains: u32,
    /// The largest [`LayerStats::max_unit_moves`] of all layers.
    pub max_unit_moves: u32,
    /// Buffer use.
    pub needs: ToolpathNeeds,
}

impl ToolpathNeeds {
    /// All zero.
    pub const EMPTY: Self = Self {
        layer_points: 0,
        layer_loops: 0,
        offset_edges: 0,
        crossings: 0,
        path_points: 0,
        paths: 0,
        ring_points: 0,
        spans: 0,
    };
}

impl ToolpathStats {
    /// All zero.
    pub const EMPTY: Self = Self {
        layers: 0,
        extrusion_moves: 0,
        travel_moves: 0,
        retractions: 0,
        stops: 0,
        travel_um: 0,
        filament_um: 0,
        thin_islands: 0,
        thin_area_um2: 0,
        max_thin_area_um2: 0,
        max_thin_area_layer: 0,
        thin_unmeasured: 0,
        thin_pts: 0,
        open_chains: 0,
        max_unit_moves: 0,
        needs: ToolpathNeeds::EMPTY,
    };
}

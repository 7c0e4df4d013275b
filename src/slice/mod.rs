//! Sweep-plane slicer over a zmin-sorted triangle stream: closed contours, one layer at a time.
//!
//! Triangles (placed, in um) arrive sorted by their lowest z. A triangle whose lowest z is at
//! or above the next plane completes that plane: the plane is cut, its loops are handed to the
//! sink, and the sweep moves up. Only the *active set* is stored: triangles that cross a plane
//! not yet cut. A triangle crossing no plane is dropped on arrival; a triangle leaves the set
//! once the sweep has passed its highest z. Every layer goes through these stages:
//!
//! 1. `intersect`: each active triangle is cut exactly in integers (corners classified
//!    below `z < p` / above `z >= p`; crossings computed on canonically ordered edges, so
//!    shared edges give identical points);
//! 2. `chain`: segments are linked end-to-start through an open-addressing endpoint hash;
//! 3. `repair`: open chains (broken meshes only) are joined exactly, then within a small
//!    tolerance, then across gaps up to 2 mm; the rest are dropped and counted;
//! 4. `nest`: loops below the minimum area are dropped, the rest get their depth, parent
//!    and orientation (outer counter-clockwise, holes clockwise).
//!
//! No floats, no allocation, no panics on input: coordinates outside the packable range,
//! unsorted input and full buffers are typed [`SliceError`]s.
//!
//! # Memory
//!
//! A [`Slicer<ACTIVE, SEGMENTS, LOOPS>`](Slicer) holds its buffers inline:
//! - 24 bytes per `ACTIVE` (three corners packed as 21-bit fields in three `u64`);
//! - 72 bytes per `LOOPS` (a [`LoopInfo`] of 48 and an open-chain record of 24);
//! - about 200 bytes of state.
//!
//! The cut of a layer ([`CutScratch::BYTES_PER_SEGMENT`] per `SEGMENTS`: segment, link,
//! flags and two endpoint hash slots, then an output point) lives in working memory the
//! caller lends to every call that may cut ([`Slicer::push`], [`Slicer::cut_one`],
//! [`Slicer::finish`]): a [`SliceScratch`] when slicing alone, or memory the caller shares
//! with later stages ([`CutSpace`]). The hash table is dead once the segments are linked, so
//! the layer's loop points are written in its place: the layer is handed to the sink in that
//! memory, as a [`SlicedLayer`] (its [`layer`](SlicedLayer::layer) to read it, or the whole
//! to the next stage, which copies it before it uses the memory).
//!
//! For example a slicer of 1024 active triangles, 512 segments and 32 loops takes about
//! 26 KB and its cut about 15 KB (`memory_per_capacity_unit_is_as_documented`).
//! [`peak_needs`] tells the host which capacities a model needs.

mod chain;
mod intersect;
mod nest;
mod packed;
mod peak;
mod plane;
mod repair;

use core::fmt;

use crate::geom::{Point2, Triangle};
use crate::machine::PrintSettings;

use chain::{Chaining, Contours};
use packed::PackedTriangle;

pub use chain::CutScratch;

pub use packed::MAX_COORD_UM;
pub use peak::{peak_needs, ActiveCount, PeakNeeds, WordsFull};

/// Where a slicer cuts its layers.
///
/// Working memory that holds its [`CutScratch`] while the slicer works (and, once the cut is
/// linked, the layer's loop points in the place of its dead hash table). Its owner may lend the
/// place to others between layers (the printer's shared scratch); a slicer alone cuts in a
/// [`SliceScratch`].
pub trait CutSpace<const SEGMENTS: usize> {
    /// The cut (a cleared one if another tenant had the place).
    fn cut(&mut self) -> &mut CutScratch<SEGMENTS>;
    /// The loop points of the layer cut last, while the cut has the place (empty otherwise).
    fn contour_points(&self) -> &[Point2];
}

/// The working memory of a slicer used alone: its cut, nothing else.
pub type SliceScratch<const SEGMENTS: usize> = CutScratch<SEGMENTS>;

impl<const SEGMENTS: usize> CutSpace<SEGMENTS> for CutScratch<SEGMENTS> {
    fn cut(&mut self) -> &mut CutScratch<SEGMENTS> {
        self
    }
    fn contour_points(&self) -> &[Point2] {
        self.points()
    }
}

/// RAM of a [`Slicer`] with these capacities (`ACTIVE`, `LOOPS`), without the cut and the loop
/// points in its working memory ([`CutScratch::BYTES_PER_SEGMENT`] per `SEGMENTS`), bytes.
///
/// 24 per active triangle, 72 per loop and the fixed state.
pub fn slicer_bytes(active: usize, loops: usize) -> usize {
    core::mem::size_of::<Slicer<0, 0, 0>>()
        + active * core::mem::size_of::<PackedTriangle>()
        + loops * (core::mem::size_of::<LoopInfo>() + core::mem::size_of::<chain::Chain>())
}

/// A [`Slicer`] type with its capacities named at the point of use (the names of
/// [`Capacities`](crate::protocol::Capacities)):
///
/// ```
/// strata::slicer_type! {
///     /// A bench slicer.
///     pub type BenchSlicer = { active_triangles: 8192, contour_points: 8192, contour_loops: 256 };
/// }
/// ```
#[macro_export]
macro_rules! slicer_type {
    (
        $(#[$meta:meta])*
        $vis:vis type $name:ident = {
            active_triangles: $a:expr,
            contour_points: $s:expr,
            contour_loops: $l:expr $(,)?
        };
    ) => {
        $(#[$meta])*
        $vis type $name = $crate::slice::Slicer<{ $a }, { $s }, { $l }>;
    };
}

/// Default tolerance for joining open chain ends that nearly meet, in um.
pub const DEFAULT_JOIN_TOLERANCE_UM: i32 = 20;
/// Default largest gap closed by a straight bridge, in um.
pub const DEFAULT_MAX_GAP_UM: i32 = 2_000;

/// How a model is cut into layers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SliceConfig {
    /// First layer height in um (plane 0 at half of it).
    pub first_layer_height_um: i32,
    /// Height of every further layer in um.
    pub layer_height_um: i32,
    /// Top of the placed model in um: layers are the planes strictly below it.
    pub model_height_um: i32,
    /// Loops with a smaller area are dropped (counted per layer), in um^2.
    pub min_loop_area_um2: i64,
    /// Open chain ends closer than this are joined (repair pass 2), in um.
    pub join_tolerance_um: i32,
    /// Open chain ends closer than this are bridged (repair pass 3), in um.
    pub max_gap_um: i32,
}

impl SliceConfig {
    /// The slicing part of `settings` for a placed model whose top is at `model_height_um`.
    pub fn new(settings: &PrintSettings, model_height_um: i32) -> Result<Self, SliceError> {
        let config = Self {
            first_layer_height_um: settings.first_layer_height_um,
            layer_height_um: settings.layer_height_um,
            model_height_um,
            min_loop_area_um2: settings.min_loop_area_um2,
            join_tolerance_um: DEFAULT_JOIN_TOLERANCE_UM,
            max_gap_um: DEFAULT_MAX_GAP_UM,
        };
        config.validate()?;
        Ok(config)
    }

    /// Checks every field: heights positive and inside the packable range, distances and
    /// the minimum area not negative.
    pub fn validate(&self) -> Result<(), SliceError> {
        let checks = [
            ("first_layer_height_um", (1..=MAX_COORD_UM).contains(&self.first_layer_height_um)),
            ("layer_height_um", (1..=MAX_COORD_UM).contains(&self.layer_height_um)),
            ("model_height_um", (0..=MAX_COORD_UM).contains(&self.model_height_um)),
            ("min_loop_area_um2", (0..=1 << 50).contains(&self.min_loop_area_um2)),
            ("join_tolerance_um", (0..=MAX_COORD_UM).contains(&self.join_tolerance_um)),
            ("max_gap_um", (0..=MAX_COORD_UM).contains(&self.max_gap_um)),
        ];
        match checks.iter().find(|(_, ok)| !ok) {
            Some(&(field, _)) => Err(SliceError::InvalidConfig { field }),
            None => Ok(()),
        }
    }
}

/// A bounded buffer of the slicer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Resource {
    /// Triangles crossing a plane not yet cut (`ACTIVE`).
    ActiveTriangles,
    /// Cut segments of one layer (`SEGMENTS`).
    Segments,
    /// Points of one layer's loops (`SEGMENTS`; only repairs can add points).
    ContourPoints,
    /// Loops of one layer (`LOOPS`).
    Loops,
    /// Open chains of one layer awaiting repair (`LOOPS`).
    OpenChains,
}

impl fmt::Display for Resource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::ActiveTriangles => "active triangles",
            Self::Segments => "segments per layer",
            Self::ContourPoints => "contour points per layer",
            Self::Loops => "loops per layer",
            Self::OpenChains => "open chains per layer",
        })
    }
}

/// Why slicing stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SliceError {
    /// `push` or `finish` after `finish`, or on a [`Slicer::empty`] one never
    /// [`reset`](Slicer::reset) (call `reset` to slice again). First, so that it is the zero
    /// tag and an empty slicer's `Some(Finished)` is zero bytes.
    Finished,
    /// A [`SliceConfig`] field is out of range.
    InvalidConfig {
        /// The field.
        field: &'static str,
    },
    /// A triangle arrived with a lower z_min than the one before it.
    Unsorted {
        /// Index of the triangle in the stream (from 0).
        index: u32,
        /// Its lowest z in um.
        z_min: i32,
        /// The previous triangle's lowest z in um.
        previous: i32,
    },
    /// A triangle has a coordinate outside `0..=MAX_COORD_UM` (not placed on the bed?).
    OutOfRange {
        /// Index of the triangle in the stream (from 0).
        index: u32,
    },
    /// A buffer is full.
    Capacity {
        /// Which buffer.
        what: Resource,
        /// Its capacity.
        capacity: u32,
        /// The layer being filled.
        layer: u32,
    },
}

impl fmt::Display for SliceError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::InvalidConfig { field } => write!(f, "slice setting `{field}` is out of range"),
            Self::Unsorted { index, z_min, previous } => write!(
                f,
                "triangle {index} is out of order: lowest z {z_min} um after {previous} um \
                 (input must be sorted by lowest z)"
            ),
            Self::OutOfRange { index } => write!(
                f,
                "triangle {index} has a coordinate outside 0..={MAX_COORD_UM} um (not on the bed)"
            ),
            Self::Capacity { what, capacity, layer } => {
                write!(f, "too many {what} in layer {layer} (capacity {capacity})")
            }
            Self::Finished => f.write_str("the slicer has finished; reset it to slice again"),
        }
    }
}

/// One closed loop of a layer: `points[start..start + len]` of the [`Layer`], the closing
/// edge from the last point back to the first implied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LoopInfo {
    /// Index of the first point in [`Layer::points`].
    pub start: u32,
    /// Number of points.
    pub len: u32,
    /// True for a hole (odd nesting depth, clockwise); false for an outer boundary
    /// (even depth, counter-clockwise).
    pub hole: bool,
    /// Index in [`Layer::loops`] of the smallest loop containing this one.
    pub parent: Option<u32>,
    /// Signed area in um^2: positive for outer loops, negative for holes.
    pub area_um2: i64,
    /// Bounding box corner with the smallest x and y.
    pub min: Point2,
    /// Bounding box corner with the largest x and y.
    pub max: Point2,
}

impl LoopInfo {
    const EMPTY: Self = Self {
        start: 0,
        len: 0,
        hole: false,
        parent: None,
        area_um2: 0,
        min: Point2::new(0, 0),
        max: Point2::new(0, 0),
    };
}

/// What was repaired in a layer (or, summed, in a model). All zero for a closed mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LayerRepairs {
    /// Chains joined end to end exactly (one reversed when both ends or both starts met).
    pub exact_joins: u32,
    /// Chains joined (or closed) across at most `join_tolerance_um`.
    pub tolerance_joins: u32,
    /// Gaps of at most `max_gap_um` bridged by a straight edge.
    pub gaps_closed: u32,
    /// Chains that could not be closed, dropped.
    pub dropped_chains: u32,
    /// Segments in those dropped chains.
    pub dropped_segments: u32,
}

impl LayerRepairs {
    const EMPTY: Self = Self {
        exact_joins: 0,
        tolerance_joins: 0,
        gaps_closed: 0,
        dropped_chains: 0,
        dropped_segments: 0,
    };

    /// Joins plus bridges plus dropped chains.
    pub fn total(&self) -> u32 {
        [self.tolerance_joins, self.gaps_closed, self.dropped_chains]
            .iter()
            .fold(self.exact_joins, |sum, &n| sum.saturating_add(n))
    }

    fn add(&mut self, other: &Self) {
        // Totals over a whole model: saturate rather than wrap.
        self.exact_joins = self.exact_joins.saturating_add(other.exact_joins);
        self.tolerance_joins = self.tolerance_joins.saturating_add(other.tolerance_joins);
        self.gaps_closed = self.gaps_closed.saturating_add(other.gaps_closed);
        self.dropped_chains = self.dropped_chains.saturating_add(other.dropped_chains);
        self.dropped_segments = self.dropped_segments.saturating_add(other.dropped_segments);
    }
}

/// One sliced layer.
///
/// From the slicer, its points borrowed from the working memory it was cut in and its loops from
/// the slicer while the sink has the [`SlicedLayer`] (or a layer of the caller's own, for the next
/// stage).
#[derive(Debug, Clone, Copy)]
pub struct Layer<'a> {
    /// Layer index from 0 (the first layer).
    pub index: u32,
    /// Height of the cutting plane above the bed, in um (mid-layer).
    pub z_um: i32,
    /// Points of all loops, loop after loop.
    pub points: &'a [Point2],
    /// The loops.
    pub loops: &'a [LoopInfo],
    /// Repairs made in this layer.
    pub repairs: LayerRepairs,
    /// Loops dropped for an area below `min_loop_area_um2`.
    pub dropped_small_loops: u32,
    /// Triangles in the active set when the layer was cut.
    pub active_triangles: u32,
    /// Cut segments (non-zero length) of this layer.
    pub segments: u32,
}

impl<'a> Layer<'a> {
    /// The points of `l` (empty if `l` is not one of this layer's loops).
    pub fn loop_points(&self, l: &LoopInfo) -> &'a [Point2] {
        self.points.get(l.start as usize..l.start as usize + l.len as usize).unwrap_or(&[])
    }
}

/// The layer the slicer has just cut, lent to its sink together with the working memory `W` it was
/// cut in ([`CutSpace`]).
///
/// Its points are in that memory (in the place of the cut's dead hash table), its loops in the
/// slicer. Read it with [`layer`](Self::layer), or hand the whole to the next stage, which copies
/// the layer before it uses the memory.
pub struct SlicedLayer<'a, const SEGMENTS: usize, W: CutSpace<SEGMENTS>> {
    /// The layer but its points (`points` is empty: they are in `work`'s cut).
    head: Layer<'a>,
    work: &'a mut W,
}

impl<'a, const SEGMENTS: usize, W: CutSpace<SEGMENTS>> SlicedLayer<'a, SEGMENTS, W> {
    /// The layer (its points in the scratch).
    pub fn layer(&self) -> Layer<'_> {
        Layer { points: self.work.contour_points(), ..self.head }
    }

    /// The scratch, for what leaves the cut in place (the layer stays readable).
    pub(crate) fn scratch_keeping_layer(&mut self) -> &mut W {
        self.work
    }

    /// The scratch, the layer given up (copy it first).
    pub(crate) fn into_scratch(self) -> &'a mut W {
        self.work
    }
}

impl<const SEGMENTS: usize, W: CutSpace<SEGMENTS>> fmt::Debug for SlicedLayer<'_, SEGMENTS, W> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("SlicedLayer").field(&self.layer()).finish()
    }
}

/// Totals of a whole slicing run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SliceStats {
    /// Layers produced.
    pub layers: u32,
    /// Triangles pushed.
    pub triangles: u32,
    /// Triangles dropped on arrival (crossing no plane).
    pub dropped_triangles: u32,
    /// Largest active set.
    pub peak_active: u32,
    /// Largest number of segments in a layer.
    pub peak_segments: u32,
    /// Largest number of loop points in a layer.
    pub peak_points: u32,
    /// Largest number of loops in a layer.
    pub peak_loops: u32,
    /// Loops produced.
    pub loops: u32,
    /// Loops dropped for their area.
    pub dropped_small_loops: u32,
    /// Repairs over all layers.
    pub repairs: LayerRepairs,
}

impl SliceStats {
    const EMPTY: Self = Self {
        layers: 0,
        triangles: 0,
        dropped_triangles: 0,
        peak_active: 0,
        peak_segments: 0,
        peak_points: 0,
        peak_loops: 0,
        loops: 0,
        dropped_small_loops: 0,
        repairs: LayerRepairs::EMPTY,
    };
}

/// The streaming slicer.
///
/// Capacities: `ACTIVE` triangles in the active set, `SEGMENTS` cut segments (and loop points) per
/// layer, `LOOPS` loops (and open chains) per layer. It cuts each layer in working memory lent to
/// the calls that may cut ([`CutSpace`]), and leaves the layer's points there (see the [module
/// docs](self)).
///
/// Large capacities make a large value: on the host, build it where the stack is big enough
/// (or in a `static`/boxed slot and call [`Slicer::reset`]).
pub struct Slicer<const ACTIVE: usize, const SEGMENTS: usize, const LOOPS: usize> {
    config: SliceConfig,
    layers: u32,
    /// Next plane to cut and its height.
    next_layer: u32,
    next_plane: i32,
    active: [PackedTriangle; ACTIVE],
    active_len: usize,
    contours: Contours<LOOPS>,
    last_z_min: i32,
    stats: SliceStats,
    /// Set by `finish` or by an error: later calls fail.
    stopped: Option<SliceError>,
}

impl<const ACTIVE: usize, const SEGMENTS: usize, const LOOPS: usize>
    Slicer<ACTIVE, SEGMENTS, LOOPS>
{
    /// A slicer at the bottom of the model.
    pub fn new(config: SliceConfig) -> Result<Self, SliceError> {
        config.validate()?;
        let mut s = Self {
            config,
            layers: 0,
            next_layer: 0,
            next_plane: 0,
            active: [PackedTriangle::EMPTY; ACTIVE],
            active_len: 0,
            contours: Contours::EMPTY,
            last_z_min: 0,
            stats: SliceStats::default(),
            stopped: None,
        };
        s.reset(config)?;
        Ok(s)
    }

    /// An unconfigured slicer, every byte zero: no layers, and `push` and `finish` fail with
    /// [`SliceError::Finished`] until [`Slicer::reset`] configures it. Lets a large owner be
    /// built in a `static` in `.bss` without a stack temporary.
    pub const fn empty() -> Self {
        const UNCONFIGURED: SliceConfig = SliceConfig {
            first_layer_height_um: 0,
            layer_height_um: 0,
            model_height_um: 0,
            min_loop_area_um2: 0,
            join_tolerance_um: 0,
            max_gap_um: 0,
        };
        Self {
            config: UNCONFIGURED,
            layers: 0,
            next_layer: 0,
            next_plane: 0,
            active: [PackedTriangle::EMPTY; ACTIVE],
            active_len: 0,
            contours: Contours::EMPTY,
            // `reset` sets it to i32::MIN (no triangle yet).
            last_z_min: 0,
            stats: SliceStats::EMPTY,
            stopped: Some(SliceError::Finished),
        }
    }

    /// Starts over with `config`, keeping the buffers (no large value is moved).
    pub fn reset(&mut self, config: SliceConfig) -> Result<(), SliceError> {
        config.validate()?;
        self.config = config;
        self.layers = config.layer_count();
        self.next_layer = 0;
        self.next_plane = config.plane_z_um(0) as i32;
        self.active_len = 0;
        self.contours.clear();
        self.last_z_min = i32::MIN;
        self.stats = SliceStats::default();
        self.stopped = None;
        Ok(())
    }

    /// The configuration.
    pub fn config(&self) -> &SliceConfig {
        &self.config
    }

    /// Number of layers this model gets (sink calls in a complete run).
    pub fn layer_count(&self) -> u32 {
        self.layers
    }

    /// Statistics so far.
    pub fn stats(&self) -> &SliceStats {
        &self.stats
    }

    /// Takes the next triangle (sorted by lowest z). Cuts every plane at or below its lowest
    /// z first in `scratch`, calling `sink` once per layer in order with the layer, which
    /// lives in `scratch` until the sink returns or hands the scratch on ([`SlicedLayer`]).
    pub fn push<W: CutSpace<SEGMENTS>>(
        &mut self,
        tri: &Triangle,
        scratch: &mut W,
        sink: &mut impl FnMut(SlicedLayer<'_, SEGMENTS, W>),
    ) -> Result<(), SliceError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        let result = self.push_inner(tri, scratch, sink);
        if let Err(e) = result {
            self.stopped = Some(e);
        }
        result
    }

    /// A triangle with lowest point `z_min` would first complete the next plane: pushing it
    /// cuts at least one layer. A paced owner calls [`Slicer::cut_one`] until this is false
    /// (one layer at a time, as its downstream buffers allow), then pushes.
    pub fn would_cut(&self, z_min: i32) -> bool {
        self.stopped.is_none() && self.next_layer < self.layers && z_min >= self.next_plane
    }

    /// Cuts the next plane, if any is left, in `scratch` and hands its layer to `sink` (as
    /// [`Slicer::push`] does): true when a layer was cut. The triangles still to come must
    /// lie at or above that plane (the stream is sorted; use [`Slicer::would_cut`] for the
    /// next triangle, or call this at the end).
    pub fn cut_one<W: CutSpace<SEGMENTS>>(
        &mut self,
        scratch: &mut W,
        sink: &mut impl FnMut(SlicedLayer<'_, SEGMENTS, W>),
    ) -> Result<bool, SliceError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        if self.next_layer >= self.layers {
            return Ok(false);
        }
        match self.cut_next(scratch, sink) {
            Ok(()) => Ok(true),
            Err(e) => {
                self.stopped = Some(e);
                Err(e)
            }
        }
    }

    /// Ends the stream: cuts the remaining planes (as [`Slicer::push`] does) and returns the
    /// totals.
    pub fn finish<W: CutSpace<SEGMENTS>>(
        &mut self,
        scratch: &mut W,
        sink: &mut impl FnMut(SlicedLayer<'_, SEGMENTS, W>),
    ) -> Result<SliceStats, SliceError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        let mut result = Ok(());
        while result.is_ok() && self.next_layer < self.layers {
            result = self.cut_next(scratch, sink);
        }
        self.stopped = Some(result.err().unwrap_or(SliceError::Finished));
        result.map(|()| self.stats)
    }

    fn push_inner<W: CutSpace<SEGMENTS>>(
        &mut self,
        tri: &Triangle,
        scratch: &mut W,
        sink: &mut impl FnMut(SlicedLayer<'_, SEGMENTS, W>),
    ) -> Result<(), SliceError> {
        let index = self.stats.triangles;
        let (z_min, z_max) = (tri.z_min(), tri.z_max());
        if z_min < self.last_z_min {
            return Err(SliceError::Unsorted { index, z_min, previous: self.last_z_min });
        }
        let packed = PackedTriangle::pack(tri).ok_or(SliceError::OutOfRange { index })?;
        self.last_z_min = z_min;
        self.stats.triangles = self.stats.triangles.saturating_add(1);
        // Sorted input: no later triangle reaches below these planes, so they are complete.
        while self.next_layer < self.layers && z_min >= self.next_plane {
            self.cut_next(scratch, sink)?;
        }
        // The first plane it crosses can only be the next plane (all lower ones are cut).
        let spans = self
            .config
            .crossed_planes(z_min, z_max)
            .is_some_and(|(first, _)| first == self.next_layer);
        if !spans {
            self.stats.dropped_triangles = self.stats.dropped_triangles.saturating_add(1);
            return Ok(());
        }
        let slot = self.active.get_mut(self.active_len).ok_or(SliceError::Capacity {
            what: Resource::ActiveTriangles,
            capacity: ACTIVE as u32,
            layer: self.next_layer,
        })?;
        *slot = packed;
        self.active_len += 1;
        Ok(())
    }

    /// Cuts the next plane in `scratch`, expires triangles below the plane after it, emits
    /// the layer.
    fn cut_next<W: CutSpace<SEGMENTS>>(
        &mut self,
        scratch: &mut W,
        sink: &mut impl FnMut(SlicedLayer<'_, SEGMENTS, W>),
    ) -> Result<(), SliceError> {
        let layer = self.next_layer;
        let plane = self.next_plane;
        let after = self.config.plane_z_um(layer + 1);
        let capacity_error =
            |what, capacity: usize| SliceError::Capacity { what, capacity: capacity as u32, layer };
        let active_triangles = self.active_len as u32;
        let cut = scratch.cut();
        cut.clear();
        let mut i = 0;
        while i < self.active_len {
            let t = self.active[i];
            if let Some(seg) = intersect::cut(&t.corners(), plane) {
                cut.push(seg).map_err(|w| capacity_error(w, SEGMENTS))?;
            }
            if i64::from(t.z_max()) < after {
                // Crosses no later plane: swap-remove (order is irrelevant).
                self.active_len -= 1;
                self.active[i] = self.active[self.active_len];
            } else {
                i += 1;
            }
        }
        let segments = cut.len() as u32;
        let c = &mut self.contours;
        let outcome = Chaining { cut: &mut *cut, out: &mut *c }
            .build(
                self.config.min_loop_area_um2,
                self.config.join_tolerance_um,
                self.config.max_gap_um,
            )
            .map_err(|w| {
                capacity_error(
                    w,
                    if matches!(w, Resource::Loops | Resource::OpenChains) {
                        LOOPS
                    } else {
                        SEGMENTS
                    },
                )
            })?;
        let points = cut.points().len() as u32;
        let head = Layer {
            index: layer,
            z_um: plane,
            points: &[],
            loops: &c.loops[..c.loops_len],
            repairs: outcome.repairs,
            dropped_small_loops: outcome.dropped_small_loops,
            active_triangles,
            segments,
        };
        let st = &mut self.stats;
        st.layers += 1;
        st.peak_active = st.peak_active.max(active_triangles);
        st.peak_segments = st.peak_segments.max(head.segments);
        st.peak_points = st.peak_points.max(points);
        st.peak_loops = st.peak_loops.max(head.loops.len() as u32);
        st.loops = st.loops.saturating_add(head.loops.len() as u32);
        st.dropped_small_loops = st.dropped_small_loops.saturating_add(head.dropped_small_loops);
        st.repairs.add(&head.repairs);
        sink(SlicedLayer { head, work: scratch });
        self.next_layer += 1;
        self.next_plane = after as i32;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::size_of;

    #[test]
    fn memory_per_capacity_unit_is_as_documented() {
        assert_eq!(size_of::<PackedTriangle>(), 24);
        assert_eq!(size_of::<LoopInfo>() + size_of::<chain::Chain>(), 72);
        let fixed = size_of::<Slicer<0, 0, 0>>();
        assert!(fixed <= 200, "{fixed}");
        crate::slicer_type! {
            type Device = { active_triangles: 1024, contour_points: 512, contour_loops: 32 };
        }
        let device = size_of::<Device>();
        assert_eq!(device, fixed + 1024 * 24 + 32 * 72);
        assert_eq!(device, slicer_bytes(1024, 32));
        assert!(device < 27 * 1024, "{device}");
        // The cut and the loop points, in the scratch.
        assert_eq!(size_of::<intersect::Segment>() + 4 + 1 + size_of::<Point2>(), 29);
        assert_eq!(CutScratch::<0>::BYTES_PER_SEGMENT, 29);
    }
}

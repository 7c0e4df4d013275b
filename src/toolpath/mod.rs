//! Toolpaths: perimeters, infill, skins, skirt, ordering and retraction, as a stream of moves.
//!
//! [`Toolpath`] takes the slicer's layers in order ([`Toolpath::push_sliced`] from the
//! slicer's sink, [`Toolpath::push_layer`] for a layer held elsewhere) and emits, per layer,
//! a [`ToolEvent::LayerStart`], the [`ToolMove`]s (absolute XY and Z in um, an extrusion
//! delta in um of filament, a feed rate and the [`Feature`]) and a [`ToolEvent::LayerEnd`]
//! with the layer's counters. Everything is integer (um, `i64` products) or fixed point;
//! nothing allocates; every buffer has a capacity given as a const generic and overflowing
//! one is a [`ToolpathError::Capacity`] naming it and the layer.
//!
//! Per layer:
//! 1. contours are simplified ([`simplify`], 10 um) and grouped into islands (an outer loop
//!    and its holes);
//! 2. per island, the perimeters are exact integer offsets of the contours by
//!    `(k + 1/2) x width` and the infill domain an offset by `perimeters x width` (infill
//!    lines reach the innermost perimeter's inner edge) ([`offset`]: offsets of holes and
//!    outer loops merge, parts narrower than a line vanish instead of leaving a broken loop;
//!    an island with no room for even one perimeter is counted in
//!    [`LayerStats::thin_islands`]); what vanishes is reported: the external perimeter's
//!    centre lines (the island offset inwards by w/2) are grown back outwards by w/2 (miter
//!    joins, the same exact offsetting), which gives the island's opening by half a line
//!    width, the part any line can cover; the island's area minus the opening's is the area
//!    thinner than a line (fins and thin walls attached to thicker parts, whole thin islands,
//!    corners sharper than 60 degrees), [`LayerStats::thin_area_um2`], summed in
//!    [`ToolpathStats::thin_area_um2`] (0 for a rectangle: square corners come back whole;
//!    each pass rounds to the um grid, so the error is at most ~1 um x the outline length).
//!    It costs one more offset per island and layer and no memory of its own: it runs in the
//!    offset engine and the offset result buffer (`PTS`), outside the printing needs; where
//!    it does not fit (the grown curves of thin slivers can overlap a lot), the island is
//!    counted in [`LayerStats::thin_unmeasured`] and its toolpaths are unaffected
//!    ([`ToolpathStats::thin_pts`]: the `PTS` the measurement used);
//! 3. the infill domain is filled along scanlines ([`scan`], [`infill`]) at 45 degrees on even
//!    layers and 135 on odd ones: solid where a top or bottom surface is within
//!    `top_layers`/`bottom_layers` (found exactly along each line by cutting the window's
//!    stored contours with it, then opened: slivers under a line wide go, skins reach a line
//!    into the sparse zone), top solid under no material, sparse every `100 / density`-th
//!    line elsewhere; segments are
//!    linked into long runs along the domain boundary (zigzag) and straight between the
//!    inner ends of skin segments;
//! 4. the first layer gets a skirt: the convex hull offset 3 mm + width/2 with round joins
//!    (plus the brim's width); and a brim if asked ([`ToolpathConfig::brim_width_um`]):
//!    `floor(width / line width)` loops, the union of its outer loops (not its holes) offset
//!    by `(k + 1/2) x line width` with round joins, printed after the skirt, outermost first;
//! 5. paths are ordered and turned into moves ([`order`]): islands nearest first; in each,
//!    inner perimeters before the external one (each hole's loops together), then the infill
//!    runs, nearest first from either end; loops start at the rear-most vertex; the nearest
//!    path is found in a uniform grid of the paths' entry points ([`near`]) built in the
//!    infill's segment pool (free by then: half of it for cells, half for entries, two per
//!    path; a layer with more paths is scanned: same order), searched within the island's
//!    box once an island is chosen (its paths are grouped first); a travel that would cross
//!    a contour is combed along the island's external perimeter, and retracts only when no
//!    such route exists (another island) and it is at least 1.5 mm long.
//!
//! A built layer's moves go out unit by unit ([`Toolpath::emit_next`]): one path with the
//! retraction, travel and height change before it (or the layer's closing move to its
//! height), each generated once into the owner's [`Room`], whole or not at all: opened with
//! the unit's exact move count (a room counting moves, [`Moves`], decides there), its moves
//! sent as they are generated and then closed, when the room keeps or undoes it (the
//! printer's [`RingRoom`](crate::move_ring::RingRoom) codes the moves into its byte ring as
//! they come and undoes a unit that ran out of bytes; the stage then restores the nozzle
//! state from before the unit, which waits). The stage keeps the
//! layer (its paths, its contour for combing, the ordering state, the nearest-path grid in
//! the infill scratch of its working memory) until its last unit went out and builds no
//! other meanwhile ([`Toolpath::emitting`]), so an owner's move buffer needs room for the
//! largest unit ([`LayerStats::max_unit_moves`] moves), not for a layer.
//! [`Toolpath::push_layer`] (and [`push_sliced`](Toolpath::push_sliced)),
//! [`flush_one`](Toolpath::flush_one) and [`finish`](Toolpath::finish) emit whole layers at
//! once.
//!
//! The skin window costs the simplified contours of `bottom + top + 1` layers (the `top`
//! layers that wait for the layers above them and the `bottom` ones below the layer being
//! built) and the crossings of all of them with one scanline
//! ([`ToolpathNeeds::window_bytes`]: 9 KB for 3DBenchy, 1.7 KB for a 20 mm cube). A built
//! layer stays only for the bottom skins above it, its contours simplified again within
//! [`ToolpathConfig::below_tolerance_um`] in its own block, which gives the words it frees to
//! the newer blocks (the printer keeps them within half a line).
//!
//! # Memory
//!
//! [`Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>`](Toolpath) holds:
//! - 3 loop buffers of `PTS` points and `LOOPS` loops (the layer, one offset result, the
//!   infill domain): [`ToolpathNeeds::PTS_BYTES`] per `PTS` (the offset result's points are
//!   in the working memory, beside the engine), [`ToolpathNeeds::LOOPS_BYTES`] per `LOOPS`;
//! - the layer's paths: [`ToolpathNeeds::PATH_BYTES`] per `PATH` (a point and its feature
//!   in 48 bits; a path's record takes two);
//! - the window: [`ToolpathNeeds::RING_BYTES`] per `RING` word (the simplified contours of
//!   up to `bottom + top + 2` layers, 3 to 4 bytes a point (9 for a far jump) and four words a
//!   loop: [`window::StoredRings`]) and [`ToolpathNeeds::SPAN_BYTES`] per `SPANS` (the
//!   crossings, then spans, of those layers with the scanline being filled);
//! - about 1.5 KB of fixed state (settings, counters, the window's block table).
//!
//! It works in working memory lent to every call that computes layers ([`ToolpathSpace`]: a
//! [`ToolpathScratch`] when used alone; the slicer's sink hands on the memory the layer was
//! cut in, with the layer in it: [`Toolpath::push_sliced`]), where two tenants take turns per
//! layer (offsets, then infill and ordering), and in a shared one also with the slicer's cut
//! and output points, which the stage copies first ([`Toolpath::push_layer`]'s store), the
//! largest counting:
//! - the offset engine (`PTS` edges, splits and pieces) and the offset result's points:
//!   [`ToolpathNeeds::ENGINE_BYTES`] per `PTS`;
//! - the infill scratch: [`ToolpathNeeds::CROSS_BYTES`] per `CROSS` (a crossing, its order
//!   then segment-end index, and 12 bytes of the pool of segments and pieces); `CROSS` is the
//!   larger of the crossings of one pass and the pool's use in 12-byte units.
//!
//! [`ToolpathStats::needs`] reports the largest use of each, so a model's needs are known
//! after one host run, and [`ToolpathNeeds::stage_bytes`] and
//! [`ToolpathNeeds::work_bytes`] what a stage sized to them and its tenants take.

use crate::geom::Point2;
use crate::machine::{InfillPattern, Rate};
use crate::math;
use crate::slice::{CutSpace, Layer, SlicedLayer};

use infill::{BridgeTally, FillParams, FillUse, FillWork, OverAir, SkinView, Span, POOL_WORDS};
use offset::Join;
use order::{Ctx, Emission, Emitter, FEED_SCALE_ONE};
use paths::{PathBuf, PathKind};
use poly::{LoopBuf, LoopMeta, Loops, Ring};
use scan::{Angle, Crossing};
use window::{Encoder, Fifo, LoopWords, StoredRings};

mod config;
mod error;
mod events;
pub mod infill;
pub mod near;
pub mod offset;
pub mod order;
pub mod paths;
pub mod poly;
pub mod scan;
pub mod simplify;
pub mod sort;
mod space;
mod stats;
mod thin;
pub mod window;

use config::IDLE_CONFIG;
pub use config::{
    duty_of_percent, Cooling, Seam, SparseLines, ToolpathConfig, BRIDGE_SPEED_MM_S,
    MAX_BRIM_WIDTH_UM,
};
pub use error::{Buffer, ToolpathError};
pub use events::{Emitted, Feature, Moves, Room, ToolEvent, ToolMove};
pub use space::{Engine, ToolpathScratch, ToolpathSpace};
pub use stats::{LayerStats, ToolpathNeeds, ToolpathStats};

/// A [`Toolpath`] type with its capacities named at the point of use (the names of
/// [`Capacities`](crate::protocol::Capacities)):
///
/// ```
/// strata::toolpath_type! {
///     /// A bench stage.
///     pub type BenchToolpath = {
///         toolpath_points: 8192,
///         toolpath_loops: 256,
///         scan_crossings: 16384,
///         path_points: 32768,
///         window_ring_words: 16384,
///         window_spans: 16384,
///     };
/// }
/// ```
#[macro_export]
macro_rules! toolpath_type {
    (
        $(#[$meta:meta])*
        $vis:vis type $name:ident = {
            toolpath_points: $pts:expr,
            toolpath_loops: $loops:expr,
            scan_crossings: $cross:expr,
            path_points: $path:expr,
            window_ring_words: $ring:expr,
            window_spans: $spans:expr $(,)?
        };
    ) => {
        $(#[$meta])*
        $vis type $name = $crate::toolpath::Toolpath<
            { $pts }, { $loops }, { $cross }, { $path }, { $ring }, { $spans },
        >;
    };
}

/// Layers (0 and 1 for the ring) the window must hold beyond `top` and `bottom`.
const FIRST_LAYER: u32 = 0;

/// Overhang perimeters are located on lines this many line widths apart: fewer crossings of
/// the layer's outline than the infill's of its domain.
const LOCATE_SPACING: i32 = 2;

/// The infill scratch (`CROSS` entries each).
///
/// Crossings, their order then segment ends, and the pool of segments and pieces. It takes turns
/// with the offset engine (per layer: offsets, then infill and ordering) in the stage's working
/// memory ([`ToolpathSpace`]).
pub struct FillScratch<const C: usize> {
    cross: [Crossing; C],
    idx: [u16; C],
    pool: [[u32; POOL_WORDS]; C],
}

impl<const C: usize> FillScratch<C> {
    /// Cleared.
    pub const EMPTY: Self =
        Self { cross: [Crossing::EMPTY; C], idx: [0; C], pool: [[0; POOL_WORDS]; C] };
}

/// The streaming toolpath stage.
///
/// Capacities (see the [module docs](self) for their memory): `PTS` points of a layer or of one
/// island's offset, `LOOPS` loops of a layer, `CROSS` scanline crossings of one infill pass (and
/// its segments and pieces, in 12-byte units), `PATH` path points of a layer (2 a path record),
/// `RING` words of the window's stored contours, `SPANS` crossings of the window's layers with one
/// scanline.
pub struct Toolpath<
    const PTS: usize,
    const LOOPS: usize,
    const CROSS: usize,
    const PATH: usize,
    const RING: usize,
    const SPANS: usize,
> {
    cfg: ToolpathConfig,
    ring: Fifo<u32, RING>,

    contour: LoopBuf<PTS, LOOPS>,
    /// Loops between offsets (their points are in the offset engine's place of the scratch).
    tmp: LoopMeta<LOOPS>,
    fill: LoopBuf<PTS, LOOPS>,
    /// Engine peaks and open chains of the engines that had the scratch so far.
    offset_peaks: offset::OffsetPeaks,
    open_chains: u32,
    /// `PTS` less the edge slots and pieces an offset may use before it is done in bands
    /// (zero in a new stage: all of them).
    offset_shortfall: usize,
    /// `PATH` and `CROSS` less the path points and scanline crossings a layer with bridges
    /// may use before it is built again without them ([`Self::set_bridge_limits`]; zero in a
    /// new stage: all of them).
    bridge_shortfall: [u32; 2],
    /// The layer being built has bridges (within `bridge_shortfall`).
    bridging: bool,
    spans: [Span; SPANS],
    paths: PathBuf<PATH>,
    island_map: [u16; LOOPS],
    island_stage: [u8; LOOPS],
    em: Emitter,
    /// The built layer's extrusion feed scale for its minimum time, q16.
    feed_scale_q16: u32,
    /// The built layer's wait at its end for the rest of its minimum time, ms.
    cool_wait_ms: u32,
    /// The built layer's fan duty, and its bridges' ([`Ctx::fan`]).
    fan: [u8; 2],
    /// Where the built layer's emission stands.
    emission: Emission,
    next_in: u32,
    next_out: u32,
    fill_use: FillUse,
    stats: ToolpathStats,
    stopped: Option<ToolpathError>,
}

impl<
        const PTS: usize,
        const LOOPS: usize,
        const CROSS: usize,
        const PATH: usize,
        const RING: usize,
        const SPANS: usize,
    > Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>
{
    /// A stage ready for layer 0. The value is large: build it where the stack allows, or in
    /// a static slot with [`empty`](Self::empty) and call [`reset`](Self::reset).
    pub fn new(cfg: ToolpathConfig) -> Result<Self, ToolpathError> {
        let mut t = Self::empty();
        t.reset(cfg)?;
        Ok(t)
    }

    /// An idle stage for a `static` (no stack temporary): every buffer empty and a
    /// placeholder configuration. [`reset`](Self::reset) configures it; until then
    /// [`push_layer`](Self::push_layer) and [`finish`](Self::finish) return
    /// [`ToolpathError::Finished`] and [`config`](Self::config) is the placeholder.
    pub const fn empty() -> Self {
        Self {
            cfg: IDLE_CONFIG,
            ring: Fifo::new(0),
            contour: LoopBuf::new(),
            tmp: LoopMeta::new(),
            fill: LoopBuf::new(),
            offset_peaks: offset::OffsetPeaks {
                edges: 0,
                splits: 0,
                pieces: 0,
                darts: 0,
                bands: 0,
            },
            offset_shortfall: 0,
            bridge_shortfall: [0; 2],
            bridging: false,
            open_chains: 0,
            spans: [Span { u0: 0, u1: 0 }; SPANS],
            paths: PathBuf::new(),
            island_map: [0; LOOPS],
            island_stage: [0; LOOPS],
            em: Emitter::new(),
            // Set when a layer is built, before its first unit goes out; zero keeps an empty stage
            // all zero bytes (`.bss`).
            feed_scale_q16: 0,
            cool_wait_ms: 0,
            fan: [0; 2],
            emission: Emission::new(),
            next_in: 0,
            next_out: 0,
            fill_use: FillUse {
                crossings: 0,
                segments: 0,
                spans: 0,
                bridge: BridgeTally::NONE,
                located: (0, 0),
            },
            stats: ToolpathStats::EMPTY,
            stopped: Some(ToolpathError::Finished),
        }
    }

    /// Lets an offset use at most `edges` edge slots and pieces of the engine (`PTS` at
    /// most) before it is done in bands: a stage posing as a device with a smaller `PTS`
    /// offsets exactly as that device does. Kept across [`reset`](Self::reset).
    pub fn set_offset_limit(&mut self, edges: usize) {
        self.offset_shortfall = PTS - edges.min(PTS);
    }

    /// Lets a layer with bridges use at most `path_points` path points and `crossings`
    /// scanline crossings (`PATH` and `CROSS` at most); one that needs more is built again
    /// without bridges. A device does that at its own capacities: a stage posing as one with
    /// smaller capacities builds the layers it does. Kept across [`reset`](Self::reset).
    pub fn set_bridge_limits(&mut self, path_points: usize, crossings: usize) {
        // Within u32: a stage's capacities are far below 2^32 (the board's a few thousand).
        let short = |cap: usize, n: usize| (cap - n.min(cap)) as u32;
        self.bridge_shortfall = [short(PATH, path_points), short(CROSS, crossings)];
    }

    /// Path points (`which` 0) or crossings (1) the layer being built may not use.
    fn unused_for_bridges(&self, which: usize) -> usize {
        if self.bridging {
            self.bridge_shortfall[which] as usize
        } else {
            0
        }
    }

    /// Edge slots and pieces an offset may use before it is done in bands.
    fn offset_limit(&self) -> usize {
        PTS - self.offset_shortfall
    }

    /// Starts over with `cfg` (buffers kept). The nozzle is assumed at the bed origin.
    pub fn reset(&mut self, cfg: ToolpathConfig) -> Result<(), ToolpathError> {
        cfg.validate()?;
        self.cfg = cfg;
        self.ring.clear();
        self.em = Emitter::new();
        self.emission = Emission::new();
        self.next_in = 0;
        self.next_out = 0;
        self.stats = ToolpathStats::EMPTY;
        self.stopped = None;
        for m in [&mut self.contour.meta, &mut self.tmp, &mut self.fill.meta] {
            m.reset();
        }
        (self.offset_peaks, self.open_chains) = (offset::OffsetPeaks::default(), 0);
        self.paths.clear();
        self.paths.peak_points = 0;
        self.paths.peak_paths = 0;
        // Stale entries are read for holes listed before their parent (a fresh stage reads
        // zeros): start every run from the fresh state.
        self.island_map.fill(0);
        self.ring.peak = 0;
        self.fill_use = FillUse::default();
        Ok(())
    }

    /// Sets where the nozzle is before the first layer (after the start G-code).
    pub fn set_position(&mut self, p: Point2, z_um: i32) {
        self.em.pos = p;
        self.em.z = z_um;
    }

    /// The settings.
    pub fn config(&self) -> &ToolpathConfig {
        &self.cfg
    }

    /// Layers emitted so far ([`ToolpathStats::layers`] without computing the rest).
    pub fn layers_emitted(&self) -> u32 {
        self.stats.layers
    }

    /// Totals so far.
    pub fn stats(&self) -> ToolpathStats {
        let mut s = self.stats;
        let p = self.offset_peaks;
        s.open_chains = self.open_chains;
        let n = &mut s.needs;
        let (c, f) = (&self.contour.meta, &self.fill.meta);
        n.layer_points =
            [c.peak_points, self.tmp.peak_points, f.peak_points].into_iter().max().unwrap_or(0)
                as u32;
        n.layer_loops =
            [c.peak_rings, self.tmp.peak_rings, f.peak_rings].into_iter().max().unwrap_or(0) as u32;
        n.offset_edges = p.edges.max(p.splits).max(p.pieces) as u32;
        let f = self.fill_use;
        n.crossings = f.crossings.max(f.segments) as u32;
        n.path_points = self.paths.peak_points as u32;
        n.paths = self.paths.peak_paths as u32;
        n.ring_points = self.ring.peak as u32;
        n.spans = f.spans as u32;
        s.thin_pts = s.thin_pts.max(n.layer_points).max(n.offset_edges);
        s
    }

    /// Adds the engine's peaks and open chains to the stage's, if the engine has `work`, and
    /// zeroes them there (so the next turn, or another owner, starts from none).
    fn collect_engine_counters<W: ToolpathSpace<PTS, CROSS>>(&mut self, work: &mut W) {
        if let Some(e) = work.live_engine() {
            let p = &mut self.offset_peaks;
            p.edges = p.edges.max(e.peaks.edges);
            p.splits = p.splits.max(e.peaks.splits);
            p.pieces = p.pieces.max(e.peaks.pieces);
            self.open_chains += e.open_chains;
            (e.peaks, e.open_chains) = (offset::OffsetPeaks::default(), 0);
        }
    }

    /// Gives the engine's place to the infill scratch (the engine's counters are kept).
    fn park_engine<W: ToolpathSpace<PTS, CROSS>>(&mut self, work: &mut W) {
        self.collect_engine_counters(work);
        work.fill();
    }

    fn capacity(&self, what: Buffer, layer: u32) -> ToolpathError {
        let capacity = match what {
            Buffer::LayerPoints => PTS,
            Buffer::OffsetEdges | Buffer::OffsetSplits | Buffer::OffsetPieces => {
                self.offset_limit()
            }
            Buffer::LayerLoops => LOOPS,
            Buffer::Crossings | Buffer::LineSegments => CROSS,
            Buffer::LineIntervals => 64,
            Buffer::PathPoints | Buffer::Paths => PATH,
            Buffer::PathRange => 1 << 21,
            Buffer::RingPoints => RING,
            Buffer::WindowSpans => SPANS,
            Buffer::WindowLayers => window::MAX_BLOCKS,
        };
        ToolpathError::Capacity { what, capacity: capacity as u32, layer }
    }

    /// Takes the next layer; emits every layer whose `top_layers` layers above have now
    /// arrived, computing them in `work`, all its moves at once
    /// ([`accept_layer`](Self::accept_layer) and [`emit_next`](Self::emit_next) emit them as
    /// an owner's buffer allows). The layer is copied (simplified, into the skin window)
    /// before anything else. For the layer the slicer has just cut, in the scratch it hands
    /// its sink: [`push_sliced`](Self::push_sliced).
    pub fn push_layer<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        layer: &Layer<'_>,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), ToolpathError> {
        self.emit_all(work, sink)?;
        self.accept_layer(layer, work, sink)?;
        self.emit_all(work, sink)
    }

    /// [`push_layer`](Self::push_layer) of the layer the slicer has just cut in `layer`'s
    /// scratch (its points are there): the layer is copied before the scratch is used.
    pub fn push_sliced<const S: usize, W: CutSpace<S> + ToolpathSpace<PTS, CROSS>>(
        &mut self,
        mut layer: SlicedLayer<'_, S, W>,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), ToolpathError> {
        // Emitting leaves the cut in place (no infill scratch to find the paths in: scans).
        self.emit_all(layer.scratch_keeping_layer(), sink)?;
        let work = self.accept_sliced(layer, sink)?;
        self.emit_all(work, sink)
    }

    /// Takes the next layer like [`push_layer`](Self::push_layer), but only builds the
    /// layer that is now complete (its `top_layers` layers above have arrived; at most one)
    /// in `work`: its [`ToolEvent::Progress`] points and its [`ToolEvent::LayerStart`] go
    /// out, its moves wait for [`emit_next`](Self::emit_next).
    /// Refused with [`ToolpathError::Emitting`] while a layer is being emitted
    /// ([`emitting`](Self::emitting)): its paths, and the nearest-path grid in `work`'s
    /// infill scratch, are kept until its last move went out (an owner lends `work` to no
    /// one else meanwhile; if it does, the paths are found by scanning: the same order).
    /// For the layer the slicer has just cut: [`accept_sliced`](Self::accept_sliced).
    pub fn accept_layer<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        layer: &Layer<'_>,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), ToolpathError> {
        self.take(layer)?;
        self.complete(work, sink)
    }

    /// [`accept_layer`](Self::accept_layer) of the layer the slicer has just cut in
    /// `layer`'s scratch (its points are there): the layer is copied before the scratch is
    /// used. Gives the scratch back (the layer given up) for [`emit_next`](Self::emit_next).
    pub fn accept_sliced<'w, const S: usize, W: CutSpace<S> + ToolpathSpace<PTS, CROSS>>(
        &mut self,
        layer: SlicedLayer<'w, S, W>,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<&'w mut W, ToolpathError> {
        self.take(&layer.layer())?;
        // Copied: the scratch may go to the offset engine.
        let work = layer.into_scratch();
        self.complete(work, sink)?;
        Ok(work)
    }

    /// First half of [`accept_layer`](Self::accept_layer): checks and stores the layer (in
    /// the [`StoredRings`] layout; `layer` is not read afterwards).
    fn take(&mut self, layer: &Layer<'_>) -> Result<(), ToolpathError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        if self.emission.is_active() {
            return Err(ToolpathError::Emitting { layer: self.next_out });
        }
        let result = self.store_next(layer);
        if let Err(e) = result {
            self.stopped = Some(e);
        }
        result
    }

    /// Second half of [`accept_layer`](Self::accept_layer): builds the layer the one just
    /// taken completes (the one `top_layers` below it), if any, in `work`.
    fn complete<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), ToolpathError> {
        // Each layer taken completes at most one.
        let top = u32::from(self.cfg.top_layers);
        if self.next_out + top < self.next_in {
            let l = self.next_out;
            let result = self.process(l, work, sink).map_err(|w| self.capacity(w, l));
            if let Err(e) = result {
                self.stopped = Some(e);
            }
            return result;
        }
        Ok(())
    }

    /// A layer is built and its moves are not all emitted yet.
    pub fn emitting(&self) -> bool {
        self.emission.is_active()
    }

    /// Emits the built layer's moves into `room` unit by unit (a path with the travel,
    /// retraction and height change before it, or the layer's closing move to its height),
    /// each generated once, whole or not at all ([`Room`]: opened with its exact move count,
    /// kept or undone when closed), and the layer's [`ToolEvent::LayerEnd`] after its last
    /// unit. Every [`ToolEvent::Move`] of a layer is in one of its units. `work` is the
    /// scratch the layer was built in (its infill pool holds the nearest-path grid).
    /// [`Emitted::NeedsRoom`] names the moves of the unit `room` refused or undid: a later
    /// call offers it again first. [`Emitted::Complete`] when no layer is being emitted (any
    /// more).
    pub fn emit_next<W: ToolpathSpace<PTS, CROSS>, R: Room + ?Sized>(
        &mut self,
        work: &mut W,
        room: &mut R,
    ) -> Result<Emitted, ToolpathError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        if !self.emission.is_active() {
            return Ok(Emitted::Complete);
        }
        let l = self.next_out;
        let ctx = Ctx {
            cfg: &self.cfg,
            points: self.contour.points(),
            rings: self.contour.rings(),
            height_um: self.cfg.layer_height_of(l),
            first_layer: l == FIRST_LAYER,
            feed_scale_q16: self.feed_scale_q16,
            cool_wait_ms: self.cool_wait_ms,
            fan: self.fan,
        };
        // The infill pool is free since the layer was built: the nearest-path grid's cells
        // and entries, untouched until the layer is complete (without it: scans).
        let (grid_head, grid_next): (&mut [u32], &mut [u32]) = match work.live_fill() {
            Some(f) => f.pool.as_flattened_mut().split_at_mut(POOL_WORDS * CROSS / 2),
            None => (&mut [], &mut []),
        };
        let waiting = self.emission.emit(
            &mut self.em,
            &ctx,
            &mut self.paths,
            &mut self.island_stage,
            grid_head,
            grid_next,
            room,
        );
        if let Some(moves) = waiting {
            return Ok(Emitted::NeedsRoom { moves, layer: l });
        }
        self.end_layer(l, &mut |e: &ToolEvent<'_>| room.event(e));
        Ok(Emitted::Complete)
    }

    /// Emits the rest of the layer being emitted, if any, whatever its size.
    fn emit_all<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), ToolpathError> {
        self.emit_next(work, sink).map(|_| ())
    }

    /// After the model's last layer was pushed: processes the next layer still waiting in
    /// the window (in `work`); true when one was processed, false when none is left (then
    /// [`Toolpath::finish`] only returns the totals). Lets an owner release the last layers
    /// one at a time, as its move buffer allows.
    pub fn flush_one<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<bool, ToolpathError> {
        self.emit_all(work, sink)?;
        let built = self.build_next(work, sink)?;
        self.emit_all(work, sink)?;
        Ok(built)
    }

    /// After the model's last layer was accepted: builds the next layer still waiting in
    /// the window (in `work`), leaving its moves to [`emit_next`](Self::emit_next) (as
    /// [`accept_layer`](Self::accept_layer) does); true when one was built, false when none
    /// is left. Refused with [`ToolpathError::Emitting`] while a layer is being emitted.
    pub fn build_next<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<bool, ToolpathError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        if self.emission.is_active() {
            return Err(ToolpathError::Emitting { layer: self.next_out });
        }
        if self.next_out >= self.next_in {
            return Ok(false);
        }
        let l = self.next_out;
        match self.process(l, work, sink).map_err(|w| self.capacity(w, l)) {
            Ok(()) => Ok(true),
            Err(e) => {
                self.stopped = Some(e);
                Err(e)
            }
        }
    }

    /// Ends the stream: emits the remaining layers (the top ones, computed in `work`) and
    /// returns the totals.
    pub fn finish<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<ToolpathStats, ToolpathError> {
        if let Some(e) = self.stopped {
            return Err(e);
        }
        let mut result = self.emit_all(work, sink);
        while result.is_ok() {
            match self.build_next(work, sink) {
                Ok(true) => result = self.emit_all(work, sink),
                Ok(false) => break,
                Err(e) => result = Err(e),
            }
        }
        self.stopped = Some(result.err().unwrap_or(ToolpathError::Finished));
        result.map(|()| self.stats())
    }

    /// Stores `layer` if it is the next one.
    fn store_next(&mut self, layer: &Layer<'_>) -> Result<(), ToolpathError> {
        if layer.index != self.next_in {
            return Err(ToolpathError::OutOfOrder { expected: self.next_in, got: layer.index });
        }
        let index = layer.index;
        self.store(layer).map_err(|w| self.capacity(w, index))?;
        self.next_in += 1;
        Ok(())
    }

    /// Simplifies and stores the layer's contours (in the [`StoredRings`] layout).
    fn store(&mut self, layer: &Layer<'_>) -> Result<(), Buffer> {
        let index = layer.index;
        let tol = i64::from(self.cfg.simplify_tolerance_um);
        // Room for every loop simplified (a first pass counts its words) and the header.
        let words = |info| {
            let mut w = LoopWords::default();
            simplify::simplify_closed_each(layer.loop_points(info), tol, |p| w.add(p));
            w.words
        };
        let total = 2 + layer.loops.iter().map(words).sum::<usize>();
        let mut out = Encoder::new(self.ring.reserve(total)?);
        let mut rings = 0;
        let mut islands = 0u16;
        for (li, info) in layer.loops.iter().enumerate() {
            let island = if info.hole {
                match info.parent {
                    Some(p) if (p as usize) < li.max(self.island_map.len()) => {
                        match self.island_map.get(p as usize) {
                            Some(&i) if i != u16::MAX => i,
                            _ => continue,
                        }
                    }
                    _ => continue,
                }
            } else {
                islands += 1;
                islands - 1
            };
            out.begin(island)?;
            let mut written = Ok(());
            let n = simplify::simplify_closed_each(layer.loop_points(info), tol, |p| {
                written = written.and_then(|()| out.push(p));
            });
            written?;
            let keep = n >= 3;
            out.end(keep);
            if let Some(slot) = self.island_map.get_mut(li) {
                *slot = if keep || info.hole { island } else { u16::MAX };
            } else if !info.hole {
                return Err(Buffer::LayerLoops);
            }
            if !keep {
                if !info.hole {
                    // An outer loop that vanished takes its island (and holes) with it.
                    if let Some(slot) = self.island_map.get_mut(li) {
                        *slot = u16::MAX;
                    }
                }
                continue;
            }
            rings += 1;
        }
        let w = out.finish(rings, islands);
        self.ring.commit(index, w);
        Ok(())
    }

    /// Builds layer `l` in `work` and begins its emission ([`emit_next`](Self::emit_next));
    /// the engine's counters are collected whatever happens (the slicer may have `work`
    /// next).
    fn process<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        l: u32,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
    ) -> Result<(), Buffer> {
        let bridges = self.cfg.bridges && l > FIRST_LAYER;
        let mut built = self.build(l, work, sink, bridges);
        // Bridges are worth less than the layer: one they do not leave room for goes without.
        let full = matches!(
            built,
            Err(Buffer::Crossings | Buffer::LineSegments | Buffer::PathPoints | Buffer::Paths)
        );
        if bridges && full {
            built = self.build(l, work, sink, false);
        }
        self.collect_engine_counters(work);
        built
    }

    /// Builds layer `l`'s paths in `work` and begins their emission
    /// ([`emit_next`](Self::emit_next)).
    #[inline(never)]
    fn build<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        l: u32,
        work: &mut W,
        sink: &mut impl FnMut(&ToolEvent<'_>),
        bridges: bool,
    ) -> Result<(), Buffer> {
        // A layer with bridges within its limits ([`Self::set_bridge_limits`]).
        self.bridging = bridges;
        self.paths.set_limit(PATH - self.unused_for_bridges(0));
        let blk = self.ring.find(l).ok_or(Buffer::RingPoints)?;
        decode(self.ring.data(&blk), &mut self.contour)?;
        self.paths.clear();
        self.fill.clear();
        let mut layer = LayerStats { index: l, z_um: self.cfg.layer_z_um(l), ..LayerStats::EMPTY };
        let islands = StoredRings::islands(self.ring.data(&blk));
        layer.islands = u32::from(islands);
        let w = self.cfg.line_width_um;
        // Skirt around the first layer (and its brim), then the brim.
        if l == FIRST_LAYER && self.cfg.skirt_loops > 0 && !self.contour.rings().is_empty() {
            self.skirt(work)?;
        }
        if l == FIRST_LAYER && self.cfg.brim_loops() > 0 {
            self.brim(work, &mut || sink(&ToolEvent::Progress))?;
        }
        // Perimeters and the infill domain, island by island.
        let min_width = i64::from(w / 8);
        let limit = self.offset_limit();
        for island in 0..islands {
            // Doubled area of the island's opening by half a line (what lines can cover):
            // `Some(None)` when the measurement did not fit the offset buffers.
            let mut opened2: Option<Option<i64>> = None;
            for depth in 0..self.cfg.perimeters {
                let d = i32::from(depth) * w + w / 2;
                let (engine, points) = work.engine_and_points();
                let mut tmp = Loops::new(points, &mut self.tmp);
                tmp.clear();
                let curves = island_curves(&self.contour, island, d);
                engine.union_into(&mut tmp, island, depth, min_width, limit, curves)?;
                if tmp.rings().is_empty() {
                    if depth == 0 {
                        layer.thin_islands += 1;
                        opened2 = Some(Some(0));
                    }
                    break;
                }
                sink(&ToolEvent::Progress);
                let feature =
                    if depth == 0 { Feature::ExternalPerimeter } else { Feature::Perimeter };
                for r in tmp.rings() {
                    let pts = tmp.ring_points(r);
                    self.paths.add_loop(pts, feature, island, PathKind::Perimeter(depth))?;
                }
                if depth == 0 && self.cfg.measure_thin_area {
                    opened2 = Some(self.opening_of_tmp(work, island));
                }
            }
            if self.cfg.measure_thin_area {
                self.measure_thin_area(work, island, opened2, &mut layer);
            }
            let curves = island_curves(&self.contour, island, self.cfg.infill_inset_um());
            let out = &mut self.fill.loops();
            work.engine().union_into(out, island, 0, min_width, limit, curves)?;
            sink(&ToolEvent::Progress);
        }
        // Infill.
        if !self.fill.rings().is_empty() {
            let angle = if l % 2 == 0 { Angle::D45 } else { Angle::D135 };
            let grid = self.cfg.infill_pattern == InfillPattern::Grid;
            let mut progress = || sink(&ToolEvent::Progress);
            let over_air = if bridges { OverAir::Leave } else { OverAir::Solid };
            self.infill_pass(work, l, angle, true, over_air, &mut progress)?;
            let air = self.fill_use.bridge.over_air_u > 0;
            if grid && self.cfg.sparse_lines().any() {
                self.infill_pass(work, l, angle.other(), false, OverAir::Solid, &mut progress)?;
            }
            if air {
                let angle = self.bridge_angle(work, l, &mut progress)?;
                self.infill_pass(work, l, angle, true, OverAir::Bridge, &mut progress)?;
            }
        }
        // Perimeters over air.
        if bridges && !self.paths.is_empty() {
            let mut progress = || sink(&ToolEvent::Progress);
            self.infill_pass(work, l, Angle::D45, true, OverAir::Locate, &mut progress)?;
            let (step, w) = (Angle::D45.line_step(LOCATE_SPACING * w), self.cfg.line_width_um);
            // The pool as the pass had it (its pieces are stored from its end).
            let pool = work.fill().pool[..CROSS - self.unused_for_bridges(1)].as_flattened_mut();
            infill::tag_overhangs(
                pool,
                self.fill_use.located,
                Angle::D45,
                step,
                w,
                &mut self.paths,
            );
        }
        layer.paths = self.paths.len() as u32;
        // Emit.
        self.em.layer = layer;
        self.em.pending_z = Some(layer.z_um);
        sink(&ToolEvent::LayerStart {
            index: l,
            z_um: layer.z_um,
            height_um: self.cfg.layer_height_of(l),
        });
        // The infill scratch keeps the place (the nearest-path grid goes into its pool).
        self.park_engine(work);
        let fan;
        (self.feed_scale_q16, self.cool_wait_ms, fan) = self.min_time_plan(l);
        let fan_on = l >= u32::from(self.cfg.cooling.off_layers);
        self.fan = [fan, if fan_on { self.cfg.cooling.bridge_duty } else { 0 }];
        self.emission.begin(&self.cfg, &self.paths, &mut self.island_stage);
        Ok(())
    }

    /// The extrusion feed scale (q16) that makes the built layer's extrusions take at least the
    /// minimum layer time ([`ToolpathConfig::min_layer_time_ms`]), from their lengths (travels
    /// and acceleration left out: the layer takes at least that long), the wait (ms) at
    /// the layer's end for what the slowest print feed still leaves of that time (0 for a
    /// layer without extrusion: nothing to cool), and the layer's fan duty from its time at
    /// full speed ([`Cooling::layer_duty`]).
    fn min_time_plan(&self, l: u32) -> (u32, u32, u8) {
        let min_us = u64::from(self.cfg.min_layer_time_ms) * 1_000;
        let cooling = &self.cfg.cooling;
        let slow_us = u64::from(cooling.slow_below_s) * 1_000_000;
        let mut ctx = Ctx {
            cfg: &self.cfg,
            points: &[],
            rings: &[],
            height_um: 0,
            first_layer: l == FIRST_LAYER,
            feed_scale_q16: FEED_SCALE_ONE,
            cool_wait_ms: 0,
            fan: [0; 2],
        };
        // Most layers take longer than both: shown without a square root per segment, from
        // each segment's longer side (at most its length).
        let sides = self.extrusion_lengths(|dx, dy| dx.max(dy));
        let sides_us = time_us(&sides, |f| ctx.full_feed(f));
        if sides_us >= min_us.max(slow_us) {
            return (FEED_SCALE_ONE, 0, cooling.layer_duty(l, sides_us, min_us));
        }
        let lengths = self.extrusion_lengths(|dx, dy| math::isqrt_u64(dx * dx + dy * dy));
        let us = time_us(&lengths, |f| ctx.full_feed(f));
        let fan = cooling.layer_duty(l, us, min_us);
        if us >= min_us {
            return (FEED_SCALE_ONE, 0, fan);
        }
        ctx.feed_scale_q16 = ((us << 16) / min_us) as u32;
        if us == 0 {
            return (ctx.feed_scale_q16, 0, fan);
        }
        // Short of the minimum (by more than the sums' rounding, 1 us a feature) only where
        // the slowest print feed binds.
        let short_us = min_us.saturating_sub(time_us(&lengths, |f| ctx.feed(f)));
        if short_us <= lengths.len() as u64 {
            return (ctx.feed_scale_q16, 0, fan);
        }
        // Whole ms, rounded up: the layer takes at least its minimum.
        (ctx.feed_scale_q16, short_us.div_ceil(1_000).min(u64::from(u32::MAX)) as u32, fan)
    }

    /// The built layer's extrusion lengths per feature (index: the feature's code), um:
    /// `len(|dx|, |dy|)` summed over their segments (saturating: a bed-wide solid layer is
    /// about 100 m, far below 2^32 um; 32 bits keep the planning's frame small).
    fn extrusion_lengths(&self, len: impl Fn(u64, u64) -> u64) -> [u32; Feature::ALL.len()] {
        let mut per_feature = [0u32; Feature::ALL.len()];
        for i in 0..self.paths.len() {
            let r = self.paths.rec(i);
            let pts = self.paths.points(&r);
            let n = pts.len();
            let segs = if r.closed { n } else { n.saturating_sub(1) };
            if segs == 0 {
                continue;
            }
            let mut a = pts.at(0);
            for k in 1..=segs {
                let b = pts.at(k % n);
                let d = len(u64::from(a.x.abs_diff(b.x)), u64::from(a.y.abs_diff(b.y)));
                if let Some(sum) = per_feature.get_mut(pts.feature(k % n) as usize) {
                    *sum = sum.saturating_add(u32::try_from(d).unwrap_or(u32::MAX));
                }
                a = b;
            }
        }
        per_feature
    }

    /// Layer `l`'s last unit was emitted: its end event and counters.
    fn end_layer(&mut self, l: u32, sink: &mut impl FnMut(&ToolEvent<'_>)) {
        let ls = self.em.layer;
        sink(&ToolEvent::LayerEnd(&ls));
        let st = &mut self.stats;
        st.layers += 1;
        st.extrusion_moves += u64::from(ls.extrusion_moves);
        st.travel_moves += u64::from(ls.travel_moves);
        st.retractions += u64::from(ls.retractions);
        st.stops += u64::from(ls.stops);
        st.travel_um += ls.travel_um;
        st.filament_um += ls.filament_um;
        st.thin_islands += u64::from(ls.thin_islands);
        st.thin_area_um2 += ls.thin_area_um2;
        st.thin_unmeasured += u64::from(ls.thin_unmeasured);
        if ls.thin_area_um2 > st.max_thin_area_um2 {
            st.max_thin_area_um2 = ls.thin_area_um2;
            st.max_thin_area_layer = l;
        }
        st.max_unit_moves = st.max_unit_moves.max(ls.max_unit_moves);
        // Drop what no later layer needs (the next one looks `bottom` layers down, at least
        // one for its bridges).
        let bottom = u32::from(self.cfg.bottom_layers).max(u32::from(self.cfg.bridges));
        if bottom > 0 {
            self.coarsen_below(l);
        }
        while self.ring.block(0).is_some_and(|b| b.layer + bottom <= l) {
            self.ring.pop();
        }
        self.next_out = l + 1;
    }

    /// Layer `l` is built and its contours (still in `contour`) stay in the window only for
    /// the bottom skins above: stores them again within
    /// [`below_tolerance_um`](ToolpathConfig::below_tolerance_um) in their own block, which
    /// gives up the words it no longer needs (a loop that would vanish keeps its points).
    fn coarsen_below(&mut self, l: u32) {
        let tol = i64::from(self.cfg.below_tolerance_um);
        if tol <= i64::from(self.cfg.simplify_tolerance_um) {
            return;
        }
        let Some(blk) = self.ring.find(l) else { return };
        let (old, islands) = (blk.len as usize, StoredRings::islands(self.ring.data(&blk)));
        let contour = &self.contour;
        // A loop's points within `tol`, or all of them when fewer than three would remain.
        // One simplification per call: its first two points wait until a third shows.
        let each = |r: &Ring, f: &mut dyn FnMut(Point2)| {
            let pts = contour.ring_points(r);
            let (mut head, mut seen) = ([Point2::new(0, 0); 2], 0usize);
            simplify::simplify_closed_each(pts, tol, |p| {
                match seen {
                    0 | 1 => head[seen] = p,
                    2 => {
                        f(head[0]);
                        f(head[1]);
                        f(p);
                    }
                    _ => f(p),
                }
                seen += 1;
            });
            if seen < 3 {
                pts.iter().for_each(|&p| f(p));
            }
        };
        let words = 2 + contour
            .rings()
            .iter()
            .map(|r| {
                let mut w = LoopWords::default();
                each(r, &mut |p| w.add(p));
                w.words
            })
            .sum::<usize>();
        if words >= old {
            return;
        }
        let Some((k, out)) = self.ring.rewrite(l) else { return };
        let mut out = Encoder::new(out);
        let mut written = Ok(());
        for r in contour.rings() {
            written = written.and_then(|()| out.begin(r.island));
            each(r, &mut |p| written = written.and_then(|()| out.push(p)));
            out.end(true);
        }
        let w = out.finish(contour.rings().len() as u32, islands);
        // Counted first: the words fit the block.
        if written.is_ok() {
            self.ring.shrink(k, w);
        }
    }

    /// The skirt: convex hull of the first layer, offset outwards with round joins (past the
    /// brim: the skirt distance counts from the brim's outer edge).
    fn skirt<W: ToolpathSpace<PTS, CROSS>>(&mut self, work: &mut W) -> Result<(), Buffer> {
        let limit = self.offset_limit();
        // Line width, loops and the first loop's offset, um (no copy of the settings on the stack).
        let (w, loops) = (self.cfg.line_width_um, i32::from(self.cfg.skirt_loops));
        let first = self.cfg.skirt_distance_um + self.cfg.brim_extent_um() + w / 2;
        // Sort all points (in `tmp`), then Andrew's monotone chain into `fill`.
        let (engine, points) = work.engine_and_points();
        let mut tmp = Loops::new(points, &mut self.tmp);
        tmp.clear();
        for &p in self.contour.points() {
            tmp.push(p)?;
        }
        let sorted = tmp.open_points_mut();
        sort::sort_by_key(sorted, |p| (p.x, p.y));
        self.fill.clear();
        let hull = |buf: &mut LoopBuf<PTS, LOOPS>, p: Point2, floor: usize| -> Result<(), Buffer> {
            while buf.open_len() >= floor + 2 {
                let n = buf.open_len();
                let pts = buf.open_points_mut();
                if poly::orient(pts[n - 2], pts[n - 1], p) <= 0 {
                    buf.truncate_open(n - 1);
                } else {
                    break;
                }
            }
            buf.push(p)
        };
        let n = tmp.open_len();
        for i in 0..n {
            let p = tmp.open_points_mut()[i];
            hull(&mut self.fill, p, 0)?;
        }
        let lower = self.fill.open_len();
        for i in (0..n.saturating_sub(1)).rev() {
            let p = tmp.open_points_mut()[i];
            hull(&mut self.fill, p, lower - 1)?;
        }
        let h = self.fill.open_len();
        self.fill.truncate_open(h.saturating_sub(1));
        self.fill.close(u16::MAX, 0, Ring::NO_PARENT)?;
        tmp.clear();
        let Some(&hull_ring) = self.fill.rings().first() else { return Ok(()) };
        for k in 0..loops {
            let d = first + k * w;
            let hull = self.fill.ring_points(&hull_ring);
            tmp.clear();
            engine.union_into(&mut tmp, u16::MAX, 0, 1, limit, |engine| {
                engine.add_loop(hull, -d, Join::Round)
            })?;
            for r in tmp.rings() {
                if !r.is_hole() {
                    let pts = tmp.ring_points(r);
                    self.paths.add_loop(pts, Feature::Skirt, u16::MAX, PathKind::Skirt)?;
                }
            }
        }
        self.fill.clear();
        Ok(())
    }

    /// The direction of layer `l`'s bridges: the one whose lines have most of their length
    /// over air anchored on both sides (then the least over air in all; then the first of
    /// [`Angle::ALL`]), measured by a pass in each that prints nothing. Inlined: the passes
    /// stack no deeper than the layer's others.
    #[inline(always)]
    fn bridge_angle<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        l: u32,
        progress: &mut dyn FnMut(),
    ) -> Result<Angle, Buffer> {
        let mut best = (Angle::ALL[0], (i64::MIN, i64::MIN));
        for angle in Angle::ALL {
            self.infill_pass(work, l, angle, true, OverAir::Measure, progress)?;
            // In um: the diagonals' units are shorter.
            let t = self.fill_use.bridge;
            let um = |u: u32| i64::from(u) * 1000 / angle.scale_milli();
            let score = (um(t.anchored_u), -um(t.over_air_u));
            if score > best.1 {
                best = (angle, score);
            }
        }
        Ok(best.0)
    }

    /// The brim: loop `k` (of [`ToolpathConfig::brim_loops`]) is the union of the first
    /// layer's outer loops (holes left out: no brim inside them) offset outwards by
    /// `(k + 1/2) x width` with round joins, simplified like the contours; outermost first.
    /// Islands whose loops meet share them. `progress` after each loop.
    fn brim<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        progress: &mut dyn FnMut(),
    ) -> Result<(), Buffer> {
        let limit = self.offset_limit();
        let (w, loops) = (self.cfg.line_width_um, self.cfg.brim_loops());
        let tol = i64::from(self.cfg.simplify_tolerance_um);
        let (engine, points) = work.engine_and_points();
        let mut tmp = Loops::new(points, &mut self.tmp);
        let contour = &self.contour;
        for k in (0..loops).rev() {
            let d = w / 2 + k * w;
            tmp.clear();
            engine.union_into(&mut tmp, u16::MAX, 0, 1, limit, |engine| {
                for r in contour.rings().iter().filter(|r| !r.is_hole()) {
                    engine.add_loop(contour.ring_points(r), -d, Join::Round)?;
                }
                Ok(())
            })?;
            // Every loop of the union, its holes too (the gaps islands enclose).
            for r in tmp.rings() {
                let mut pushed = Ok(());
                simplify::simplify_closed_each(tmp.ring_points(r), tol, |p| {
                    pushed = pushed.and_then(|()| self.paths.push(p, Feature::Brim));
                });
                pushed?;
                self.paths.end(u16::MAX, PathKind::Brim, true, true)?;
            }
            progress();
        }
        tmp.clear();
        Ok(())
    }

    /// One infill pass of layer `l` at `angle` (`solid`: skins too, else sparse only), with
    /// what it makes of skin over air (what it met of it: [`FillUse::bridge`]).
    fn infill_pass<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        l: u32,
        angle: Angle,
        solid: bool,
        over_air: OverAir,
        progress: &mut dyn FnMut(),
    ) -> Result<(), Buffer> {
        self.park_engine(work);
        // Borrowed, not copied: the pass's frame is the deepest of the layer's.
        let cfg = &self.cfg;
        // A bridge pass sees only the layer below (fewer window spans a line).
        let bridging = matches!(over_air, OverAir::Bridge | OverAir::Measure | OverAir::Locate);
        let (top, bottom) = if bridging {
            (0, 0)
        } else {
            (usize::from(cfg.top_layers), usize::from(cfg.bottom_layers))
        };
        let ring = &self.ring;
        let mut view = SkinView {
            ring: ring.storage(),
            above: [(0, 0); 16],
            n_above: 0,
            above_complete: true,
            below: [(0, 0); 16],
            n_below: 0,
            below_complete: true,
            has_next: false,
        };
        let stored = |layer: u32| ring.find(layer).map(|b| (b.start, b.len));
        for k in 1..=top as u32 {
            match stored(l + k) {
                Some(d) => {
                    view.above[view.n_above] = d;
                    view.n_above += 1;
                    if k == 1 {
                        view.has_next = true;
                    }
                }
                None => {
                    view.above_complete = false;
                    break;
                }
            }
        }
        if top == 0 && !bridging {
            // No top skins, but the layer above still tells top surfaces apart.
            if let Some(d) = stored(l + 1) {
                view.above[0] = d;
                view.n_above = 1;
                view.has_next = true;
            }
        }
        // Bridges need the layer below even without bottom skins.
        let below = if over_air == OverAir::Solid { bottom } else { bottom.max(1) };
        for k in 1..=below as u32 {
            match l.checked_sub(k).and_then(stored) {
                Some(d) => {
                    view.below[view.n_below] = d;
                    view.n_below += 1;
                }
                None => {
                    view.below_complete = false;
                    break;
                }
            }
        }
        let spacing = cfg.line_width_um;
        let step = angle.line_step(if over_air == OverAir::Locate {
            LOCATE_SPACING * spacing
        } else {
            spacing
        });
        let params = FillParams {
            angle,
            step,
            spacing_um: spacing,
            sparse: cfg.sparse_lines(),
            solid,
            over_air,
            link_sparse: cfg.infill_pattern != InfillPattern::Lines,
            min_len_u: (i64::from(spacing) * angle.scale_milli() / 1000 / 3) as i32,
            width_um: cfg.line_width_um,
            erode_u: (step / 2) as i32,
            // Stretches over air are located as they are.
            margin_u: if over_air == OverAir::Locate { 0 } else { (3 * step / 2) as i32 },
            end_ext_u: if cfg.perimeters > 0 { (step / 2) as i32 } else { 0 },
        };
        let scratch = work.fill();
        // The crossings the layer may use, and the segments' pool in proportion.
        let cross = CROSS - self.unused_for_bridges(1);
        let mut fill_work = FillWork {
            cross: &mut scratch.cross[..cross],
            idx: &mut scratch.idx[..cross],
            pool: scratch.pool[..cross].as_flattened_mut(),
            spans: &mut self.spans,
        };
        // Overhangs are located over the layer's region, the infill over its domain.
        let loops = if over_air == OverAir::Locate { &self.contour } else { &self.fill };
        infill::fill(
            loops.points(),
            loops.rings(),
            params,
            &view,
            top,
            bottom,
            &mut fill_work,
            &mut self.paths,
            &mut self.fill_use,
            progress,
        )
    }
}

/// The source of an island's raw offset curves for [`Offsetter::union_into`]: every loop of
/// `island` in `contour`, shifted `d` um into the material (miter joins).
fn island_curves<'a, const P: usize, const L: usize>(
    contour: &'a LoopBuf<P, L>,
    island: u16,
    d: i32,
) -> impl FnMut(&mut offset::Offsetter<P>) -> Result<(), Buffer> + 'a {
    move |engine| {
        for r in contour.rings().iter().filter(|r| r.island == island) {
            engine.add_loop(contour.ring_points(r), d, Join::Miter)?;
        }
        Ok(())
    }
}

/// Decodes a stored layer ([`StoredRings`]) into `out`.
fn decode<const P: usize, const L: usize>(
    data: window::Parts<'_, u32>,
    out: &mut LoopBuf<P, L>,
) -> Result<(), Buffer> {
    out.clear();
    for (island, pts) in StoredRings::new(data) {
        for p in pts {
            out.push(p)?;
        }
        out.close(island, 0, Ring::NO_PARENT)?;
    }
    Ok(())
}

/// The time of `lengths` (um per feature, [`Toolpath::extrusion_lengths`]) at the feeds `feed`
/// gives, us, rounded down per feature.
fn time_us(lengths: &[u32; Feature::ALL.len()], feed: impl Fn(Feature) -> Rate) -> u64 {
    let mut us: u64 = 0;
    for (&f, &um) in Feature::ALL.iter().zip(lengths) {
        if um > 0 {
            // The feed's bits are mm/s x 2^32: us = um x 1000 / (mm/s).
            let bits = feed(f).to_bits().max(1);
            us = us
                .saturating_add(math::sat_u64(((u128::from(um) * 1_000) << 32) / u128::from(bits)));
        }
    }
    us
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::{MachineConfig, PrintSettings};
    use core::mem::size_of;

    crate::toolpath_type! {
        /// A stage for a few small squares.
        type Tiny = {
            toolpath_points: 16,
            toolpath_loops: 4,
            scan_crossings: 16,
            path_points: 16,
            window_ring_words: 16,
            window_spans: 16,
        };
    }

    crate::toolpath_type! {
        /// A stage for one layer of squares.
        type Squares = {
            toolpath_points: 256,
            toolpath_loops: 8,
            scan_crossings: 256,
            path_points: 1024,
            window_ring_words: 1024,
            window_spans: 64,
        };
    }

    /// Built at compile time (what a firmware `static` needs); idle until `reset`.
    static IDLE: Tiny = Toolpath::empty();

    #[test]
    fn empty_stage_waits_for_reset() {
        let mut t = Tiny::empty();
        assert_eq!(IDLE.stats(), ToolpathStats::EMPTY);
        let mut work = ToolpathScratch::new();
        let mut sink = |_: &ToolEvent<'_>| {};
        assert_eq!(t.finish(&mut work, &mut sink), Err(ToolpathError::Finished));
        let cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
        t.reset(cfg).unwrap();
        assert_eq!(t.config(), &cfg);
        assert_eq!(t.finish(&mut work, &mut sink).map(|s| s.layers), Ok(0));
    }

    /// Moves of a one-layer job: `squares` (x0, y0, size, hole) in this order, holes
    /// pointing at `parent`.
    fn job(t: &mut Squares, squares: &[(i32, i32, i32, bool)], parent: u32) -> Vec<ToolMove> {
        let cfg = ToolpathConfig::new(&MachineConfig::default(), &PrintSettings::default());
        t.reset(cfg).unwrap();
        let mut points = Vec::new();
        let mut loops = Vec::new();
        for &(x, y, d, hole) in squares {
            let mut sq = [(x, y), (x + d, y), (x + d, y + d), (x, y + d)];
            if hole {
                sq.reverse();
            }
            let start = points.len() as u32;
            points.extend(sq.iter().map(|&(x, y)| Point2::new(x, y)));
            let parent = hole.then_some(parent);
            loops.push(crate::slice::LoopInfo {
                start,
                len: 4,
                hole,
                parent,
                ..Default::default()
            });
        }
        let layer = Layer {
            index: 0,
            z_um: 200,
            points: &points,
            loops: &loops,
            repairs: Default::default(),
            dropped_small_loops: 0,
            active_triangles: 0,
            segments: 0,
        };
        let mut moves = Vec::new();
        let mut sink = |e: &ToolEvent<'_>| {
            if let ToolEvent::Move(m) = e {
                moves.push(*m);
            }
        };
        let mut work = Box::new(ToolpathScratch::new());
        t.push_layer(&layer, &mut *work, &mut sink).unwrap();
        t.finish(&mut *work, &mut sink).unwrap();
        moves
    }

    #[test]
    fn a_reused_stage_prints_like_a_fresh_one() {
        // A hole listed before its parent: its island comes from the island map.
        let holed = [(104_000, 104_000, 2_000, true), (100_000, 100_000, 10_000, false)];
        let mut fresh = Box::new(Toolpath::empty());
        let want = job(&mut fresh, &holed, 1);
        let mut reused = Box::new(Toolpath::empty());
        // Two islands first: the map's second entry is island 1.
        job(&mut reused, &[(0, 0, 5_000, false), (20_000, 0, 5_000, false)], 0);
        assert_eq!(job(&mut reused, &holed, 1), want);
    }

    #[test]
    fn memory_per_capacity_unit_is_as_documented() {
        assert_eq!(ToolpathNeeds::PTS_BYTES, 16);
        assert_eq!(ToolpathNeeds::ENGINE_BYTES, 46);
        assert_eq!(ToolpathNeeds::LOOPS_BYTES, 123);
        assert_eq!(ToolpathNeeds::CROSS_BYTES, 22);
        assert_eq!(ToolpathNeeds::PATH_BYTES, 6);
        assert_eq!((ToolpathNeeds::RING_BYTES, ToolpathNeeds::SPAN_BYTES), (4, 8));
        let fixed = size_of::<Toolpath<0, 0, 0, 0, 0, 0>>();
        assert!(fixed < 1640, "{fixed}");
        let needs = ToolpathNeeds {
            layer_points: 64,
            layer_loops: 8,
            offset_edges: 64,
            crossings: 128,
            path_points: 256,
            paths: 16,
            ring_points: 200,
            spans: 96,
        };
        // Alignment padding between arrays (and the scratch's tag) only.
        let close = |exact: usize, want: usize| exact >= want && exact <= want + 64;
        crate::toolpath_type! {
            type Sized = {
                toolpath_points: 64,
                toolpath_loops: 8,
                scan_crossings: 128,
                path_points: 256,
                window_ring_words: 200,
                window_spans: 96,
            };
        }
        let stage = size_of::<Sized>();
        assert!(close(stage, needs.stage_bytes()), "{stage} vs {}", needs.stage_bytes());
        let work = size_of::<ToolpathScratch<64, 128>>();
        assert!(close(work, needs.work_bytes()), "{work} vs {}", needs.work_bytes());
        assert_eq!(needs.bytes(), needs.stage_bytes() + needs.work_bytes());
        // The infill scratch larger than the engine it takes turns with.
        let needs = ToolpathNeeds { layer_points: 16, offset_edges: 16, crossings: 512, ..needs };
        let work = size_of::<ToolpathScratch<16, 512>>();
        assert!(close(work, needs.work_bytes()), "{work} vs {}", needs.work_bytes());
        assert_eq!(needs.work_bytes(), 512 * ToolpathNeeds::CROSS_BYTES);
    }
}

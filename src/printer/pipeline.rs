//! The computing half of the job runner: the slicer and the toolpath stage in their shared
//! scratch, and the toolpath stream that codes their moves into the move buffer.

use crate::card::fat::{File, Volume};
use crate::card::zsort::StlSort;
use crate::card::{OpenFile, WritingFile};
use crate::gcode::input::GcodeInput;
use crate::geom::{Point2, Triangle};
use crate::machine::MachineConfig;
use crate::move_ring::{MoveRing, MoveStream, PackedMove, RingFull, RoomMemory};
use crate::protocol::{Capacities, JobSpec};
use crate::scratch::Scratch;
use crate::slice::{SliceConfig, SliceError, SlicedLayer, Slicer};
use crate::toolpath::{Emitted, ToolEvent, Toolpath, ToolpathError};

use super::board::job_toolpath_config;
use super::failure::{Failure, Refusal};
/// What the pipeline does with the motion half while it computes a layer.
///
/// The moves its events carry go into the move buffer, and at each progress point
/// ([`ToolEvent::Progress`]) the job runner may lend the motion half its time.
pub trait Computing {
    /// Pushes a move into the move buffer; `Err` when it is full.
    fn push_move(&mut self, mv: &PackedMove) -> Result<(), RingFull>;
    /// A progress point of a long computation.
    fn progress(&mut self);
}

/// Where [`Stages::emit_moves`] left the built layer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Emit {
    /// No layer was being emitted.
    Idle,
    /// The layer's last unit went into the buffer.
    Complete,
    /// A unit waits for room in the buffer.
    Waiting,
}

/// What the job runner ([`Printer`](super::Printer)) needs of its computing half, whatever
/// its capacities: the [`Pipeline`]'s operations, each failing with the stage's own error.
pub trait Stages {
    /// Empty stages (all zero bytes).
    const EMPTY: Self;
    /// The stages' capacities (the motion half's are the printer's).
    const CAPACITIES: Capacities;
    /// The slicer.
    type Slicer;
    /// The toolpath stage.
    type Toolpath;

    /// The slicer (statistics: peak active set, peak points).
    fn slicer(&self) -> &Self::Slicer;
    /// The toolpath stage (statistics and needs).
    fn toolpath(&self) -> &Self::Toolpath;
    /// Layers the slicer has cut.
    fn layers_cut(&self) -> u32;
    /// Whether the next triangle, lowest at `z_min`, makes the slicer cut a plane.
    fn would_cut(&self, z_min: i32) -> bool;
    /// Whether the toolpath stage is emitting a built layer.
    fn emitting(&self) -> bool;
    /// Bytes of the largest unit that went into the move buffer in this job.
    fn largest_unit_bytes(&self) -> usize;
    /// Offsets with at most `edges` edges an island (in bands beyond).
    fn set_offset_limit(&mut self, edges: usize);
    /// Layers with bridges within `path_points` and `crossings` (built again without beyond).
    fn set_bridge_limits(&mut self, path_points: usize, crossings: usize);
    /// Sets the stages up for `job` on `machine`: its layers, or the stage that refused it.
    fn start(&mut self, machine: &MachineConfig, job: &JobSpec) -> Result<u32, Failure>;
    /// Starts a G-code job on `machine`: its input takes the scratch (nothing is sliced),
    /// with the card file it reads, if any.
    fn start_gcode(&mut self, machine: &MachineConfig, card: Option<OpenFile>);
    /// The card file the G-code job reads, while one runs from the card.
    fn card_file(&mut self) -> Option<&mut OpenFile>;
    /// A file being written to the card takes the scratch (no job runs).
    fn start_upload(&mut self, file: WritingFile);
    /// The file being written to the card, while it has the scratch.
    fn upload(&mut self) -> Option<&mut WritingFile>;
    /// An STL file on the card takes the scratch to be sorted (no job runs).
    fn start_stl(&mut self, volume: Volume, stl: File);
    /// The STL being sorted, while it has the scratch.
    fn stl(&mut self) -> Option<&mut StlSort>;
    /// The G-code job's input, while one runs.
    fn gcode(&mut self) -> Option<&mut GcodeInput>;
    /// The G-code job's input, while one runs.
    fn gcode_ref(&self) -> Option<&GcodeInput>;
    /// The triangle into the slicer; the layers it completes through the toolpath stage.
    fn push_triangle(&mut self, t: &Triangle, motion: &mut impl Computing) -> Result<(), Failure>;
    /// Cuts the slicer's next plane, its layer through the toolpath stage; whether a plane
    /// was left.
    fn cut_one(&mut self, motion: &mut impl Computing) -> Result<bool, Failure>;
    /// After the last plane: the toolpath stage builds its next waiting layer; whether one was
    /// left.
    fn flush_one(&mut self, motion: &mut impl Computing) -> Result<bool, Failure>;
    /// After the last triangle: every plane left is cut, each layer through the toolpath
    /// stage.
    fn finish_slicing(&mut self, motion: &mut impl Computing) -> Result<(), Failure>;
    /// After the last plane: the toolpath stage builds every layer it still holds.
    fn finish_toolpaths(&mut self, motion: &mut impl Computing) -> Result<(), Failure>;
    /// Emits the built layer into `moves` as far as it has room.
    fn emit_moves<const M: usize>(&mut self, moves: &mut MoveRing<M>) -> Result<Emit, Failure>;
}

/// The slicer and the toolpath stage taking turns in one [`Scratch`], and the toolpath stream
/// into the move buffer.
///
/// Capacities: the slicer's `A` active triangles, `S` segments and `L` loops, the toolpath
/// stage's `PTS`, `LOOPS`, `CROSS`, `PATH`, `RING` and `SPANS` (see [`Toolpath`]); name them
/// with [`printer_type!`](crate::printer_type).
pub struct Pipeline<
    const A: usize,
    const S: usize,
    const L: usize,
    const PTS: usize,
    const LOOPS: usize,
    const CROSS: usize,
    const PATH: usize,
    const RING: usize,
    const SPANS: usize,
> {
    slicer: Slicer<A, S, L>,
    tp: Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>,
    /// The slicer's cut, then the toolpath stage's offset engine and infill scratch.
    scratch: Scratch<S, PTS, CROSS>,
    /// The toolpath stream's layer, absolute E and position (moves for the buffer).
    stream: MoveStream,
    /// What the move buffer's rooms learnt about the toolpath stage's units (the waiting
    /// unit's bytes, the job's bytes per move, the largest unit).
    room_memory: RoomMemory,
}

impl<
        const A: usize,
        const S: usize,
        const L: usize,
        const PTS: usize,
        const LOOPS: usize,
        const CROSS: usize,
        const PATH: usize,
        const RING: usize,
        const SPANS: usize,
    > Stages for Pipeline<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS>
{
    const CAPACITIES: Capacities = Capacities {
        active_triangles: A as u32,
        contour_points: S as u32,
        contour_loops: L as u32,
        move_buffer_bytes: 0,
        layer_window: crate::toolpath::window::MAX_BLOCKS as u16,
        ram_bytes: core::mem::size_of::<Self>() as u32,
        toolpath_points: PTS as u32,
        toolpath_loops: LOOPS as u32,
        scan_crossings: CROSS as u32,
        path_points: PATH as u32,
        window_ring_words: RING as u32,
        window_spans: SPANS as u32,
    };
    type Slicer = Slicer<A, S, L>;
    type Toolpath = Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>;

    const EMPTY: Self = Self {
        slicer: Slicer::empty(),
        tp: Toolpath::empty(),
        scratch: Scratch::new(),
        stream: MoveStream::new(),
        room_memory: RoomMemory::EMPTY,
    };

    fn slicer(&self) -> &Self::Slicer {
        &self.slicer
    }

    fn toolpath(&self) -> &Self::Toolpath {
        &self.tp
    }

    fn layers_cut(&self) -> u32 {
        self.slicer.stats().layers
    }

    fn would_cut(&self, z_min: i32) -> bool {
        self.slicer.would_cut(z_min)
    }

    fn emitting(&self) -> bool {
        self.tp.emitting()
    }

    fn largest_unit_bytes(&self) -> usize {
        self.room_memory.largest()
    }

    fn set_offset_limit(&mut self, edges: usize) {
        self.tp.set_offset_limit(edges);
    }

    fn set_bridge_limits(&mut self, path_points: usize, crossings: usize) {
        self.tp.set_bridge_limits(path_points, crossings);
    }

    #[inline(never)]
    fn start_gcode(&mut self, machine: &MachineConfig, card: Option<OpenFile>) {
        self.scratch.start_gcode(machine, card);
    }

    fn card_file(&mut self) -> Option<&mut OpenFile> {
        self.scratch.card_file()
    }

    #[inline(never)]
    fn start_upload(&mut self, file: WritingFile) {
        self.scratch.start_upload(file);
    }

    fn upload(&mut self) -> Option<&mut WritingFile> {
        self.scratch.upload()
    }

    #[inline(never)]
    fn start_stl(&mut self, volume: Volume, stl: File) {
        self.scratch.start_stl(volume, stl);
    }

    fn stl(&mut self) -> Option<&mut StlSort> {
        self.scratch.stl()
    }

    fn gcode(&mut self) -> Option<&mut GcodeInput> {
        self.scratch.gcode()
    }

    fn gcode_ref(&self) -> Option<&GcodeInput> {
        self.scratch.gcode_ref()
    }

    /// Sets the stages up for `job` on `machine`: its layers, or the stage that refused it.
    #[inline(never)]
    fn start(&mut self, machine: &MachineConfig, job: &JobSpec) -> Result<u32, Failure> {
        let refused = |r| Failure::Refused(r);
        job.settings.validate(machine).map_err(|e| refused(Refusal::Settings(e)))?;
        let slice_cfg = SliceConfig::new(&job.settings, job.model_height_um)
            .map_err(|e| refused(Refusal::Slice(e)))?;
        let tp_cfg = job_toolpath_config(machine, job);
        self.slicer.reset(slice_cfg).map_err(|e| refused(Refusal::Slice(e)))?;
        self.tp.reset(tp_cfg).map_err(|e| refused(Refusal::Toolpath(e)))?;
        self.tp.set_position(Point2::new(0, 0), 0);
        self.stream = MoveStream::new();
        self.room_memory = RoomMemory::EMPTY;
        Ok(self.slicer.layer_count())
    }

    /// The triangle into the slicer; the layers it completes through the toolpath stage.
    #[inline(never)]
    fn push_triangle(&mut self, t: &Triangle, motion: &mut impl Computing) -> Result<(), Failure> {
        self.through_slicer(motion, |slicer, work, sink| slicer.push(t, work, &mut |l| sink(l)))
    }

    /// Cuts the slicer's next plane, its layer through the toolpath stage; whether a plane was
    /// left.
    fn cut_one(&mut self, motion: &mut impl Computing) -> Result<bool, Failure> {
        self.through_slicer(motion, |slicer, work, sink| slicer.cut_one(work, &mut |l| sink(l)))
    }

    /// After the last plane: the toolpath stage builds its next waiting layer; whether one was
    /// left.
    fn flush_one(&mut self, motion: &mut impl Computing) -> Result<bool, Failure> {
        self.through_toolpath(motion, |tp, work, events| tp.build_next(work, &mut |e| events(e)))
    }

    /// After the last triangle: every plane left is cut, each layer through the toolpath
    /// stage.
    #[inline(never)]
    fn finish_slicing(&mut self, motion: &mut impl Computing) -> Result<(), Failure> {
        self.through_slicer(motion, |slicer, work, sink| slicer.finish(work, &mut |l| sink(l)))
            .map(|_| ())
    }

    /// After the last plane: the toolpath stage builds every layer it still holds.
    fn finish_toolpaths(&mut self, motion: &mut impl Computing) -> Result<(), Failure> {
        self.through_toolpath(motion, |tp, work, events| tp.finish(work, &mut |e| events(e)))
            .map(|_| ())
    }

    /// Emits the toolpath stage's built layer into `moves`, unit by unit (a path with the
    /// travel before it), each coded into the buffer as it is generated and undone when its
    /// bytes do not fit the free ones ([`MoveRing::room`]). A unit whose bytes exceed the
    /// whole buffer could never go: [`Failure::Moves`].
    fn emit_moves<const M: usize>(&mut self, moves: &mut MoveRing<M>) -> Result<Emit, Failure> {
        if !self.tp.emitting() {
            return Ok(Emit::Idle);
        }
        // The unit refused last is offered first again, and its bytes stay what they were
        // (the coding state moves only when a unit goes in): no use offering it before the
        // buffer has that much free.
        if moves.free_bytes() < self.room_memory.waits_for() {
            return Ok(Emit::Waiting);
        }
        let mut room = moves.room(&mut self.stream, &mut self.room_memory);
        let emitted = self.tp.emit_next(&mut self.scratch, &mut room);
        let never_fits = room.never_fits();
        match emitted {
            Ok(Emitted::Complete) => Ok(Emit::Complete),
            Ok(Emitted::NeedsRoom { layer, .. }) if never_fits => Err(Failure::Moves { layer }),
            Ok(Emitted::NeedsRoom { .. }) => Ok(Emit::Waiting),
            Err(error) => Err(Failure::Toolpath(error)),
        }
    }
}

impl<
        const A: usize,
        const S: usize,
        const L: usize,
        const PTS: usize,
        const LOOPS: usize,
        const CROSS: usize,
        const PATH: usize,
        const RING: usize,
        const SPANS: usize,
    > Pipeline<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS>
{
    /// Runs `step` on the slicer with a sink that hands each layer to the toolpath stage,
    /// which builds the layer it completes (telling `motion` at its progress
    /// points; its moves wait for [`emit_moves`](Self::emit_moves)); the first failure of the
    /// slicer, the toolpath stage or the move buffer, in that order.
    fn through_slicer<R>(
        &mut self,
        motion: &mut impl Computing,
        step: impl FnOnce(
            &mut Slicer<A, S, L>,
            &mut Scratch<S, PTS, CROSS>,
            &mut dyn FnMut(SlicedLayer<'_, S, Scratch<S, PTS, CROSS>>),
        ) -> Result<R, SliceError>,
    ) -> Result<R, Failure> {
        let Self { slicer, tp, scratch, stream, .. } = self;
        let mut events = EventSink { motion, stream, failed: None };
        let mut tp_err = None;
        let r = {
            let mut sink = |l: SlicedLayer<'_, S, Scratch<S, PTS, CROSS>>| {
                if tp_err.is_none() {
                    tp_err = tp.accept_sliced(l, &mut |e: &ToolEvent<'_>| events.event(e)).err();
                }
            };
            step(slicer, scratch, &mut sink)
        };
        match (r, tp_err, events.failed) {
            (Err(error), _, _) => Err(Failure::Slice(error)),
            (Ok(_), Some(error), _) => Err(Failure::Toolpath(error)),
            (Ok(_), None, Some(layer)) => Err(Failure::Moves { layer }),
            (Ok(r), None, None) => Ok(r),
        }
    }

    /// The toolpath stage's step `step` (after the last plane); the first failure of the stage
    /// or the move buffer.
    fn through_toolpath<R>(
        &mut self,
        motion: &mut impl Computing,
        step: impl FnOnce(
            &mut Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>,
            &mut Scratch<S, PTS, CROSS>,
            &mut dyn FnMut(&ToolEvent<'_>),
        ) -> Result<R, ToolpathError>,
    ) -> Result<R, Failure> {
        let Self { tp, scratch, stream, .. } = self;
        let mut events = EventSink { motion, stream, failed: None };
        let r = step(tp, scratch, &mut |e: &ToolEvent<'_>| events.event(e));
        match (r, events.failed) {
            (Err(error), _) => Err(Failure::Toolpath(error)),
            (Ok(_), Some(layer)) => Err(Failure::Moves { layer }),
            (Ok(r), None) => Ok(r),
        }
    }
}

/// Where the toolpath stage's events go: planner moves (absolute E, [`MoveStream`]) into the
/// move buffer (the first layer whose moves do not fit is kept in `failed`), and progress
/// points to the job runner.
struct EventSink<'a, C: ?Sized> {
    motion: &'a mut C,
    stream: &'a mut MoveStream,
    failed: Option<u32>,
}

impl<C: Computing + ?Sized> EventSink<'_, C> {
    fn event(&mut self, e: &ToolEvent<'_>) {
        let stream = &mut *self.stream;
        match e {
            ToolEvent::Progress => self.motion.progress(),
            ToolEvent::LayerStart { index, .. } => stream.start_layer(*index),
            ToolEvent::Move(m) => {
                if self.motion.push_move(&stream.next(m)).is_err() {
                    self.failed.get_or_insert(stream.layer());
                }
            }
            ToolEvent::LayerEnd(_) => {}
        }
    }
}

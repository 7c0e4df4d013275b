//! The device-side job runner: protocol messages in, slicer, toolpaths, planner and step
//! generator driven incrementally, status reports and per-layer hashes out.
//!
//! [`Printer`] owns every pipeline stage with its capacities as const generics (a board picks
//! them once, see [`CREALITY_CAPACITIES`]); the step queue and the executor stay outside (the
//! executor runs in the timer interrupt on the board, on a virtual clock in the simulation).
//! [`Printer::service`] pumps the protocol [`Endpoint`]: it answers `Hello` with the
//! capacities, hands job messages to [`Printer::handle`] and sends status reports and
//! `LayerDone` hashes back. [`Printer::poll`] does a bounded amount of work: moves into the
//! planner (up to its queue), the toolpath stage's next paths into the move buffer (up to
//! its room), blocks into the step generator, steps into the queue. While a
//! message makes the toolpath stage compute a layer, `service` lends its caller the motion
//! half at the stage's progress points ([`MotionSlot`]), so steps keep being generated
//! during a long layer.
//!
//! Flow control reaches back to the host. The toolpath stage builds at most one layer per
//! cut and emits its moves into the move buffer (toolpath moves waiting for the planner,
//! delta-coded into `MOVE_BYTES` bytes, see [`crate::move_ring`]) unit by unit, a unit
//! being one path with the retraction, travel and height change before it (or a layer's
//! closing move to its height). The buffer's room ([`RingRoom`](crate::move_ring::RingRoom))
//! codes each unit's moves into the buffer as they are generated and undoes a unit whose
//! bytes do not fit the free bytes (it waits until its exact bytes are free); `poll` and
//! `service` emit more as the planner takes moves. The stage keeps
//! the layer (its paths, the contour combing follows, the ordering state, the nearest-path
//! grid in the shared scratch) until its last unit went in and builds no other meanwhile, so
//! the slicer cuts the next layer (which reuses the scratch) only once the stage has emitted
//! the whole layer before. A batch whose next triangle would need a cut that has to wait
//! stays in the endpoint's receive slot (and is resumed where it stopped), so the device
//! announces fewer credits and the host stops sending. The buffer thus holds the largest
//! unit's bytes, not a whole layer's: the paths, stored once in the stage, are not held
//! twice as moves. Cutting as soon as the stage is free (not when the buffer has drained to
//! some level) starts the next layer's computation with the most motion buffered: the
//! buffer is about full when a layer's last unit goes in, and those moves feed the motion
//! half, lent at the computation's progress points ([`MotionSlot`]), until the new layer's
//! first unit. A unit whose bytes exceed the whole buffer could never go in: a typed error
//! ([`ErrorCode::Moves`], detail: the layer), never a silent drop or a wait forever.
//!
//! Planner blocks are released only when the planner queue is full or the model has ended
//! (`pop_forced`), never earlier because data happened to be late: the blocks depend only on
//! the job, not on the link's timing, and the step generator's commands depend only on the
//! blocks. The step commands generated for each layer's blocks are hashed (FNV-1a over axis
//! and command, see [`StepProducer::take_hash`]) and reported with [`Message::LayerDone`]:
//! identical jobs give identical hashes on the host simulation and on the firmware.

use heapless::Deque;

use crate::geom::{Point2, Triangle};
use crate::machine::{MachineConfig, AXES};
use crate::move_ring::{MoveRing, MoveStream, RoomMemory};
use crate::plan::{PlanConfig, Planner};
use crate::protocol::{
    Capacities, DeviceState, Endpoint, ErrorCode, JobReport, JobSpec, Message, Status, MAX_PAYLOAD,
    VERSION,
};
use crate::scratch::Scratch;
use crate::slice::{SliceConfig, SliceError, SlicedLayer, Slicer};
use crate::slot::Slot;
use crate::step::{StepConfig, StepGenerator, StepProducer};
use crate::thermal::{ThermalFault, HEAT_WAIT_LIMIT_MS};
use crate::toolpath::{Emitted, Seam, ToolEvent, Toolpath, ToolpathConfig, ToolpathError};

/// Every capacity of the firmware build (the Creality 4.2.x boards and QEMU's lm3s6965evb,
/// 64 KB of RAM each) in one place: the firmware builds [`board::BoardPrinter`], which
/// announces [`BOARD_CAPACITIES`].
///
/// The capacities are the largest of what embodier_hotend_v2 needs at the default settings
/// (it prints unsimplified) and what embodier_LM8UU_8p2pi needs simplified for the slicer
/// (742 active triangles unsimplified; admission simplifies it to 388 with a measured
/// deviation of 0.0135 mm, under the default 0.02 mm) with its offsets done in bands;
/// embodier_asc and xyz_20mm_cube need far less of each. RAM on the board = the `Printer`
/// (slicer + toolpath + their scratch + move buffer + planner + generator) + the protocol
/// endpoint, the step queue, the executor and the UART buffers + the stack; the firmware
/// prints `.data + .bss` and the stack's high-water mark after every job, and
/// `scripts/build_firmware.sh` fails when the static part leaves less than the stack reserve
/// (see there).
/// Per-unit bytes: slicer 24 per active triangle, 72 per loop; the scratch the slicer and
/// the toolpath stage take turns in holds the largest of the cut (29 per segment: the
/// segment, its link and flags, and the endpoint hash whose place the layer's loop points
/// take once it is dead), the offset engine with its result's points (54 per `PTS`) and the
/// infill scratch (22 per `CROSS`) ([`crate::scratch`]); toolpath see `ToolpathNeeds`;
/// move buffer `MOVE_BYTES` + 60 (Cortex-M3), about 6 bytes per queued move (5.0 to 6.3 on
/// average over the sample models, at most 29), holding the largest path with its travel
/// (a unit) whole.
pub mod board {
    use super::Printer;

    /// Slicer: active triangles (embodier_hotend_v2: 388).
    pub const A: usize = 388;
    /// Slicer: segments and contour points per layer (hotend: 388).
    pub const S: usize = 388;
    /// Slicer: loops per layer.
    pub const L: usize = 8;
    /// Toolpath: loop points per layer and offset edges per island (embodier_LM8UU_8p2pi
    /// simplified for the slicer's capacities: 269 loop points; an island's offset that
    /// needs more edges, 710 there, is done in bands; hotend: 207 edges, whole).
    pub const PTS: usize = 271;
    /// Toolpath: loops per layer (LM8UU: 14; hotend: 6).
    pub const LOOPS: usize = 14;
    /// Toolpath: scanline crossings, infill segments and paths per layer (hotend: 512).
    pub const CROSS: usize = 512;
    /// Toolpath: path points per layer (hotend: 1,010).
    pub const PATH: usize = 1_010;
    /// Toolpath: words of the skin window's stored contours (hotend: 1,755).
    pub const RING: usize = 1_755;
    /// Toolpath: the skin window's crossings with one scanline (hotend 27; the banded
    /// cylinders of the HIL test more).
    pub const SPANS: usize = 48;
    /// Bytes of the move buffer (toolpath moves waiting for the planner, delta-coded). The
    /// toolpath stage fills it a unit (a path with the travel before it) at a time, each once
    /// its coded bytes fit, so the largest unit must fit whole: at the default settings
    /// embodier_asc 693 B, xyz_20mm_cube 1,051 B, embodier_hotend_v2 1,059 B,
    /// embodier_LM8UU_8p2pi 1,089 B, about 6 B a move. 2.25 KB is 2.1 times the largest. The
    /// rest keeps the motion fed while the next layer is computed: the stage refills the
    /// buffer as the planner takes moves, so it is about full when a layer's last unit goes
    /// in, and those ~370 moves (seconds of printing, still ~0.7 s of 2 ms segments) carry
    /// the motion through the next layer's cut and build (about 0.5 s for a large layer on
    /// the Cortex-M3), lent the motion half at its progress points.
    pub const MOVE_BYTES: usize = 2_304;
    /// Planner lookahead, moves (the host simulation plans with the same).
    pub const P: usize = 32;

    /// The job runner of the firmware build.
    pub type BoardPrinter = Printer<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS, MOVE_BYTES, P>;
}

/// The capacities the firmware build ([`board`]) announces.
pub const BOARD_CAPACITIES: Capacities = board::BoardPrinter::CAPACITIES;

/// What the host's simulated printer announces by default: the slicer capacities the protocol
/// was specified with (1024 active triangles, 768 contour points, 48 loops) and host-sized
/// toolpath capacities. The real 64 KB build holds far less: [`BOARD_CAPACITIES`].
pub const CREALITY_CAPACITIES: Capacities = Capacities {
    active_triangles: 1024,
    contour_points: 768,
    contour_loops: 48,
    move_buffer_bytes: 1 << 16,
    layer_window: 4,
    ram_bytes: 64 * 1024,
    toolpath_points: 1 << 15,
    toolpath_loops: 1 << 11,
    scan_crossings: 1 << 15,
    path_points: 1 << 17,
    window_ring_words: 1 << 17,
    window_spans: 1 << 16,
};

/// The toolpath settings the printer derives from `job` (the host's admission control sizes
/// the job with the same).
pub fn job_toolpath_config(machine: &MachineConfig, job: &JobSpec) -> ToolpathConfig {
    let mut cfg = ToolpathConfig::new(machine, &job.settings);
    cfg.outer_perimeter_last = job.options.outer_perimeter_last;
    cfg.seam = if job.options.seam == 1 { Seam::Nearest } else { Seam::Rear };
    cfg.skirt_loops = job.options.skirt_loops;
    cfg.skirt_distance_um = job.options.skirt_distance_um;
    // The thin-area figures are a host report (`strata slice`); the printer makes the same
    // toolpaths without them and saves an offset per island and layer.
    cfg.measure_thin_area = false;
    cfg
}

/// The motion half of the pipeline (move buffer, planner, step generator), lent by
/// [`Printer::service`] to its caller at the progress points of a long layer computation
/// ([`ToolEvent::Progress`]): the firmware generates steps there
/// ([`MotionSlot::run`]), so the step queue keeps being refilled while a layer's toolpaths
/// are computed in the same thread (on a Cortex-M3 a large layer takes about half a second,
/// far longer than a step queue covers).
///
/// The commands stay those of [`Printer::poll`]: moves go to the planner in the same order,
/// blocks leave it only when it is full (the model is not done while a layer is computed),
/// and the step generator's commands depend only on the blocks.
pub struct MotionSlot<'a, const MOVE_BYTES: usize, const P: usize> {
    moves: &'a mut MoveRing<MOVE_BYTES>,
    planner: &'a mut Planner<P>,
    tags: &'a mut Deque<u32, P>,
    gen: &'a mut StepGenerator,
    /// Blocks may go to the generator (printing and heated).
    allowed: bool,
}

/// What [`Printer::service`]'s caller does with a lent [`MotionSlot`] (`None`: nothing).
type MotionHook<'h, 'f, const MOVE_BYTES: usize, const P: usize> =
    Option<&'h mut (dyn FnMut(&mut MotionSlot<'_, MOVE_BYTES, P>) + 'f)>;

impl<const MOVE_BYTES: usize, const P: usize> MotionSlot<'_, MOVE_BYTES, P> {
    /// Moves into the planner, blocks into the generator, steps into `out`, as
    /// [`Printer::poll`] does; true when something happened. A planning error is left in
    /// place for the next `poll` to report.
    pub fn run<const Q: usize>(&mut self, out: &mut StepProducer<'_, Q>) -> bool {
        // Inside a layer's computation the toolpath stage is not done.
        self.feed(false, out).unwrap_or(true)
    }

    /// [`run`](Self::run); `toolpath_done`: the model's last moves are in the buffer, so
    /// the planner may release its blocks without being full. `Err(layer)`: the planner
    /// refused a move of that layer (it stays at the front of the buffer).
    fn feed<const Q: usize>(
        &mut self,
        toolpath_done: bool,
        out: &mut StepProducer<'_, Q>,
    ) -> Result<bool, u32> {
        let mut worked = false;
        // Each record is decoded once, when the planner has room for it (it is full most of
        // the time: peeking at the head first would decode it on every call).
        while !self.planner.is_full() {
            let Some(t) = self.moves.pop_front() else { break };
            let before = self.planner.position_um();
            let mv = t.unpack();
            // The planner had room: any refusal is the move's fault and fails the job.
            self.planner.push(mv).map_err(|_| u32::from(t.layer))?;
            worked = true;
            // A move that goes nowhere makes no block and has no tag.
            if mv.target_um != before {
                let _ = self.tags.push_back(u32::from(t.layer));
            }
        }
        let input_done = toolpath_done && self.moves.is_empty();
        if self.allowed {
            while self.gen.wants_block() && (input_done || self.planner.is_full()) {
                let Some(b) = self.planner.pop_forced() else { break };
                let layer = self.tags.pop_front().unwrap_or(0);
                // `wants_block` was true: the generator takes it.
                let _ = self.gen.load_tagged(b, layer);
                worked = true;
            }
        }
        let steps_before = self.gen.steps_generated();
        let _ = self.gen.run(out);
        Ok(worked || self.gen.steps_generated() != steps_before)
    }
}

/// Result of [`Printer::handle`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Accept {
    /// The message was consumed.
    Taken,
    /// Not now (the toolpath stage's layer is not all in the move buffer yet, so the next
    /// layer cannot be cut): offer it again later.
    Busy,
}

/// The job runner. Capacities: slicer `A` active triangles, `S` segments, `L` loops;
/// toolpath `PTS`, `LOOPS`, `CROSS`, `PATH`, `RING`, `SPANS` (see [`Toolpath`]); `MOVE_BYTES`
/// bytes of delta-coded toolpath moves waiting for the planner ([`MoveRing`]); `P` moves of
/// planner lookahead.
pub struct Printer<
    const A: usize,
    const S: usize,
    const L: usize,
    const PTS: usize,
    const LOOPS: usize,
    const CROSS: usize,
    const PATH: usize,
    const RING: usize,
    const SPANS: usize,
    const MOVE_BYTES: usize,
    const P: usize,
> {
    machine: MachineConfig,
    plan_cfg: PlanConfig,
    step_cfg: StepConfig,
    slicer: Slicer<A, S, L>,
    tp: Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>,
    /// The slicer's cut, then the toolpath stage's offset engine and infill scratch.
    scratch: Scratch<S, PTS, CROSS>,
    moves: MoveRing<MOVE_BYTES>,
    planner: Planner<P>,
    /// Layer of every move in the planner that makes a block.
    tags: Deque<u32, P>,
    gen: StepGenerator,
    state: DeviceState,
    error: ErrorCode,
    detail: u32,
    job: Slot<JobSpec>,
    /// The toolpath stream's layer, absolute E and position (moves for the buffer).
    stream: MoveStream,
    triangles: u32,
    /// Triangles of the batch being taken that are already in (it waits for room).
    batch_pos: u32,
    /// The message at the head of the link waits for room in the move buffer (it is not
    /// decoded again until the toolpath stage's layer is all in).
    waiting_for_room: bool,
    /// What the move buffer's rooms learnt about the toolpath stage's units (the waiting
    /// unit's bytes, the job's bytes per move, the largest unit).
    room_memory: RoomMemory,
    /// The job report went out (once the job is done).
    report_sent: bool,
    /// The board reports heaters ([`Printer::set_thermal`] was called): jobs wait for them.
    heaters: bool,
    /// The heaters reached the job's targets once (motion waits until then).
    heated: bool,
    /// When the job began waiting for its heaters, ms (the clock of [`Printer::service`]).
    heat_wait_since_ms: Option<u32>,
    /// Measured temperatures, 0.1 degC.
    temps_c_x10: (i16, i16),
    layers: u32,
    model_ended: bool,
    toolpath_done: bool,
    /// Step-command hashes of completed layers, waiting to be reported.
    done: Deque<(u32, u64), 8>,
    layers_planned: u32,
    status_due_ms: u32,
    /// The announced capacities when [`set_capacities`](Self::set_capacities) overrode them
    /// (`None`: [`Self::CAPACITIES`]).
    capacities: Option<Capacities>,
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
        const MOVE_BYTES: usize,
        const P: usize,
    > Printer<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS, MOVE_BYTES, P>
{
    /// A runner for `machine`, idle. (Large: on the host, build it in a `Box` on a thread
    /// with a big stack; on a board use [`Printer::empty`] in a `static` and
    /// [`Printer::configure`].)
    pub fn new(machine: &MachineConfig) -> Self {
        let mut p = Self::empty();
        p.configure(machine);
        p
    }

    /// An unconfigured runner with empty buffers, built at compile time: a board keeps it in
    /// a `static` (no stack temporary of the whole pipeline) and calls
    /// [`Printer::configure`] once at start-up, before anything else. Its configurations
    /// are [`MachineConfig::UNSET`] and the like: the whole value is zero bytes, so a
    /// `static` holding it is in `.bss` (no flash image).
    pub const fn empty() -> Self {
        Self {
            machine: MachineConfig::UNSET,
            plan_cfg: PlanConfig::UNSET,
            step_cfg: StepConfig::UNSET,
            slicer: Slicer::empty(),
            tp: Toolpath::empty(),
            scratch: Scratch::new(),
            moves: MoveRing::new(),
            planner: Planner::empty(),
            tags: Deque::new(),
            gen: StepGenerator::empty(),
            state: DeviceState::Idle,
            error: ErrorCode::None,
            detail: 0,
            job: Slot::Empty,
            stream: MoveStream::new(),
            triangles: 0,
            batch_pos: 0,
            waiting_for_room: false,
            room_memory: RoomMemory::NEW,
            report_sent: false,
            heaters: false,
            heated: false,
            heat_wait_since_ms: None,
            temps_c_x10: (0, 0),
            layers: 0,
            model_ended: false,
            toolpath_done: false,
            done: Deque::new(),
            layers_planned: 0,
            status_due_ms: 0,
            capacities: None,
        }
    }

    /// What a runner of these capacities holds, announced to the host.
    pub const CAPACITIES: Capacities = Capacities {
        active_triangles: A as u32,
        contour_points: S as u32,
        contour_loops: L as u32,
        move_buffer_bytes: MOVE_BYTES as u32,
        layer_window: crate::toolpath::window::MAX_BLOCKS as u16,
        ram_bytes: core::mem::size_of::<Self>() as u32,
        toolpath_points: PTS as u32,
        toolpath_loops: LOOPS as u32,
        scan_crossings: CROSS as u32,
        path_points: PATH as u32,
        window_ring_words: RING as u32,
        window_spans: SPANS as u32,
    };

    /// Sets the machine (limits, steps/mm) and goes idle at the origin; buffers stay where
    /// they are (no large value is moved).
    pub fn configure(&mut self, machine: &MachineConfig) {
        self.machine = *machine;
        self.plan_cfg = PlanConfig::from_machine(machine);
        self.step_cfg = StepConfig::from_machine(machine);
        self.planner.reset(&self.plan_cfg, [0; AXES]);
        self.gen.reset(&self.step_cfg, [0; AXES]);
        self.state = DeviceState::Idle;
        self.job = Slot::Empty;
    }

    /// What this runner holds (announced to the host).
    pub fn capacities(&self) -> Capacities {
        self.capacities.unwrap_or(Self::CAPACITIES)
    }

    /// Overrides the announced capacities (a simulated printer posing as a smaller board).
    pub fn set_capacities(&mut self, capacities: Capacities) {
        self.capacities = Some(capacities);
        // The device's offset engine holds `toolpath_points` edges: offset as it does.
        self.tp.set_offset_limit(capacities.toolpath_points as usize);
    }

    /// State.
    pub fn state(&self) -> DeviceState {
        self.state
    }

    /// Error and detail (when failed).
    pub fn error(&self) -> (ErrorCode, u32) {
        (self.error, self.detail)
    }

    /// The step generator (its statistics, motor positions).
    pub fn generator(&self) -> &StepGenerator {
        &self.gen
    }

    /// The step configuration the generator uses (the executor must use the same).
    pub fn step_config(&self) -> &StepConfig {
        &self.step_cfg
    }

    /// Layers of the job.
    pub fn layer_count(&self) -> u32 {
        self.layers
    }

    /// Print time of the blocks released so far, seconds.
    pub fn planned_s(&self) -> f64 {
        self.planner.released_ticks_q16() as f64 / 65536.0 / self.plan_cfg.timer_hz as f64
    }

    /// The slicer (statistics: peak active set, peak points).
    pub fn slicer(&self) -> &Slicer<A, S, L> {
        &self.slicer
    }

    /// The toolpath stage (statistics and needs).
    pub fn toolpath(&self) -> &Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS> {
        &self.tp
    }

    /// Bytes in use in the move buffer (coded moves waiting for the planner).
    pub fn move_buffer_used(&self) -> usize {
        self.moves.used_bytes()
    }

    /// Bytes of the largest toolpath unit (a path with the travel before it) that went into
    /// the move buffer in this job: the least buffer the job's units needed.
    pub fn largest_unit_bytes(&self) -> usize {
        self.room_memory.largest()
    }

    /// Uses at most `bytes` of the move buffer from now on (at most `MOVE_BYTES`): a printer
    /// posing as a board with a smaller one, flow control included (the host's tests). The
    /// announced capacities are [`set_capacities`](Self::set_capacities)'.
    pub fn limit_move_buffer(&mut self, bytes: usize) {
        self.moves.limit(bytes);
    }

    /// True when the job's last block went to the step generator and it sent every step.
    pub fn motion_finished(&self) -> bool {
        self.state == DeviceState::Done
    }

    /// True while steps may still come: printing or paused.
    pub fn is_active(&self) -> bool {
        matches!(self.state, DeviceState::Printing | DeviceState::Paused)
    }

    fn fail(&mut self, error: ErrorCode, detail: u32) {
        if self.is_active() || self.state == DeviceState::Idle {
            self.state = DeviceState::Failed;
            self.error = error;
            self.detail = detail;
        }
    }

    /// The heater targets the current job wants, degC (hotend, bed): the job's settings while
    /// it prints or is paused, 0 otherwise (idle, done, failed, aborted, stopped), so a board
    /// that applies them every update turns the heaters off when a job ends.
    pub fn heater_targets(&self) -> (i16, i16) {
        match (self.job.get(), self.is_active()) {
            (Some(j), true) => (j.settings.hotend_temp_c, j.settings.bed_temp_c),
            _ => (0, 0),
        }
    }

    /// The part-cooling fan's duty (0..=255) the job wants: full from the second layer on
    /// (the layer whose blocks are being turned into steps), off on the first layer (for bed
    /// adhesion, like slicers' defaults) and without an active job.
    pub fn fan_duty(&self) -> u8 {
        if self.state == DeviceState::Printing && self.gen.tag().is_some_and(|layer| layer >= 1) {
            255
        } else {
            0
        }
    }

    /// What the heaters measure (0.1 degC, for the status reports) and whether they are at
    /// their targets: motion waits until they have been once for the job (like M190/M109
    /// before the first layer; the slicer and the toolpath stage work meanwhile). A board that
    /// never calls this has no heaters (the host simulation): its jobs do not wait.
    pub fn set_thermal(&mut self, at_target: bool, hotend_c_x10: i16, bed_c_x10: i16) {
        self.heaters = true;
        self.temps_c_x10 = (hotend_c_x10, bed_c_x10);
        if at_target && self.is_active() {
            self.heated = true;
        }
    }

    /// A heater fault: the job fails at once with [`ErrorCode::Thermal`] (detail `code`),
    /// its moves are dropped; the board stops the steps and keeps the heaters off.
    pub fn thermal_fault(&mut self, code: u8) {
        self.fail(ErrorCode::Thermal, u32::from(code));
        self.moves.clear();
    }

    /// A job that waits longer than [`HEAT_WAIT_LIMIT_MS`] (printing, not paused) for its
    /// heaters fails with
    /// [`ThermalFault::HeatingTimeout`] (the last line of defence behind each heater's own
    /// checks, which also catch a heater that stalls short of its target).
    fn check_heat_wait(&mut self, now_ms: u32) {
        if !(self.state == DeviceState::Printing && self.heaters && !self.heated) {
            self.heat_wait_since_ms = None;
            return;
        }
        let since = *self.heat_wait_since_ms.get_or_insert(now_ms);
        if now_ms.wrapping_sub(since) > HEAT_WAIT_LIMIT_MS {
            self.thermal_fault(ThermalFault::HeatingTimeout.code());
        }
    }

    /// Ends the job on a dead link.
    pub fn link_lost(&mut self, silent_ms: u32) {
        self.fail(ErrorCode::LinkDead, silent_ms);
    }

    #[inline(never)]
    fn start(&mut self, job: &JobSpec) -> Result<(), ErrorCode> {
        job.settings.validate(&self.machine).map_err(|_| ErrorCode::BadJob)?;
        let slice_cfg =
            SliceConfig::new(&job.settings, job.model_height_um).map_err(|_| ErrorCode::BadJob)?;
        let tp_cfg = job_toolpath_config(&self.machine, job);
        self.slicer.reset(slice_cfg).map_err(|_| ErrorCode::BadJob)?;
        self.tp.reset(tp_cfg).map_err(|_| ErrorCode::BadJob)?;
        self.tp.set_position(Point2::new(0, 0), 0);
        self.moves.clear();
        self.planner.reset(&self.plan_cfg, [0; AXES]);
        self.tags.clear();
        self.gen.reset(&self.step_cfg, [0; AXES]);
        self.layers = self.slicer.layer_count();
        self.stream = MoveStream::new();
        self.triangles = 0;
        self.batch_pos = 0;
        self.room_memory = RoomMemory::NEW;
        self.report_sent = false;
        self.heated = false;
        self.heat_wait_since_ms = None;
        self.model_ended = false;
        self.toolpath_done = false;
        self.done.clear();
        self.layers_planned = 0;
        self.job = Slot::Full(*job);
        Ok(())
    }

    /// Takes a host message. Misplaced messages fail the job (never executed).
    pub fn handle(&mut self, msg: &Message<'_>) -> Accept {
        self.handle_with(msg, None)
    }

    /// [`handle`](Self::handle); `motion` is lent the motion half at the progress points of
    /// the layers this message makes the toolpath stage compute (see [`MotionSlot`]).
    fn handle_with(
        &mut self,
        msg: &Message<'_>,
        mut motion: MotionHook<'_, '_, MOVE_BYTES, P>,
    ) -> Accept {
        match (msg, self.state) {
            (Message::EmergencyStop, _) => {
                self.state = DeviceState::Stopped;
                self.moves.clear();
            }
            (Message::Abort, s) if s != DeviceState::Stopped => {
                self.state = DeviceState::Aborted;
                self.moves.clear();
            }
            (Message::JobStart(job), s)
                if !matches!(s, DeviceState::Printing | DeviceState::Paused) =>
            {
                self.error = ErrorCode::None;
                self.detail = 0;
                match self.start(job) {
                    Ok(()) => self.state = DeviceState::Printing,
                    Err(e) => {
                        self.state = DeviceState::Failed;
                        self.error = e;
                    }
                }
            }
            (Message::Pause, DeviceState::Printing) => self.state = DeviceState::Paused,
            (Message::Resume, DeviceState::Paused) => self.state = DeviceState::Printing,
            (Message::Triangles(batch), DeviceState::Printing | DeviceState::Paused)
                if !self.model_ended =>
            {
                // Layers are cut one at a time, each only once the toolpath stage has
                // emitted the layer before into the move buffer; a batch that has to wait is
                // offered again and resumes here.
                for (i, t) in batch.iter().enumerate().skip(self.batch_pos as usize) {
                    while self.slicer.would_cut(t.z_min()) {
                        if !self.emit_moves() {
                            if !self.is_active() {
                                break;
                            }
                            self.batch_pos = i as u32;
                            return Accept::Busy;
                        }
                        if !self.cut_one(motion.as_deref_mut()) {
                            break;
                        }
                    }
                    if !self.is_active() {
                        break;
                    }
                    self.push_triangle(&t, motion.as_deref_mut());
                }
                self.batch_pos = 0;
            }
            (Message::EndOfModel, DeviceState::Printing | DeviceState::Paused)
                if !self.model_ended =>
            {
                while self.is_active() {
                    if !self.emit_moves() {
                        if !self.is_active() {
                            break;
                        }
                        return Accept::Busy;
                    }
                    if !self.cut_one(motion.as_deref_mut())
                        && !self.flush_one(motion.as_deref_mut())
                    {
                        break;
                    }
                }
                self.model_ended = true;
                self.finish_model(motion);
            }
            (Message::Hello { .. }, _) => {}
            (m, _) => {
                let ty = match m {
                    Message::Triangles(_) => 0x11,
                    Message::EndOfModel => 0x12,
                    Message::Pause => 0x20,
                    Message::Resume => 0x21,
                    Message::JobStart(_) => 0x10,
                    _ => 0,
                };
                // A repeated pause/resume is harmless; everything else out of place fails.
                if !matches!(m, Message::Pause | Message::Resume) {
                    self.fail(ErrorCode::Unexpected, ty);
                }
            }
        }
        Accept::Taken
    }

    #[inline(never)]
    fn push_triangle(&mut self, t: &Triangle, motion: MotionHook<'_, '_, MOVE_BYTES, P>) {
        self.through_slicer(motion, |slicer, work, sink| slicer.push(t, work, &mut |l| sink(l)));
        self.triangles += 1;
    }

    /// Runs `step` on the slicer with a sink that hands each layer to the toolpath stage,
    /// which builds the layer it completes (lending `motion` the motion half at its
    /// progress points; its moves wait for [`emit_moves`](Self::emit_moves)), then
    /// records a slicer, toolpath or move-buffer error (the job fails); the step's result
    /// when it succeeded.
    fn through_slicer<R>(
        &mut self,
        motion: MotionHook<'_, '_, MOVE_BYTES, P>,
        step: impl FnOnce(
            &mut Slicer<A, S, L>,
            &mut Scratch<S, PTS, CROSS>,
            &mut dyn FnMut(SlicedLayer<'_, S, PTS, CROSS>),
        ) -> Result<R, SliceError>,
    ) -> Option<R> {
        let allowed = self.motion_allowed();
        let Self { slicer, tp, scratch, moves, stream, planner, tags, gen, .. } = self;
        let slot = MotionSlot { moves, planner, tags, gen, allowed };
        let mut events = EventSink { slot, stream, motion, failed: None };
        let mut tp_err = None;
        let r = {
            let mut sink = |l: SlicedLayer<'_, S, PTS, CROSS>| {
                if tp_err.is_none() {
                    tp_err = tp.accept_sliced(l, &mut |e: &ToolEvent<'_>| events.event(e)).err();
                }
            };
            step(slicer, scratch, &mut sink)
        };
        let failed = events.failed;
        self.check(r.is_err(), tp_err.is_some(), failed);
        r.ok()
    }

    /// The toolpath stage's step `step` (after the last plane) into the move buffer; records
    /// a toolpath or move-buffer error; the step's result when it succeeded.
    fn through_toolpath<R>(
        &mut self,
        motion: MotionHook<'_, '_, MOVE_BYTES, P>,
        step: impl FnOnce(
            &mut Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>,
            &mut Scratch<S, PTS, CROSS>,
            &mut dyn FnMut(&ToolEvent<'_>),
        ) -> Result<R, ToolpathError>,
    ) -> Option<R> {
        let allowed = self.motion_allowed();
        let Self { tp, scratch, moves, stream, planner, tags, gen, .. } = self;
        let slot = MotionSlot { moves, planner, tags, gen, allowed };
        let mut events = EventSink { slot, stream, motion, failed: None };
        let r = step(tp, scratch, &mut |e: &ToolEvent<'_>| events.event(e));
        let failed = events.failed;
        self.check(false, r.is_err(), failed);
        r.ok()
    }

    /// Blocks may go to the step generator: printing (not paused) and the heaters reached
    /// the job's targets once (or the board has none).
    fn motion_allowed(&self) -> bool {
        self.state == DeviceState::Printing && (self.heated || !self.heaters)
    }

    /// Emits the toolpath stage's built layer into the move buffer, unit by unit (a path
    /// with the travel before it), each coded into the buffer as it is generated and undone
    /// when its bytes do not fit the free ones ([`MoveRing::room`]); true when no layer is
    /// left to emit (the stage may build the next one). A unit whose bytes exceed the whole
    /// buffer could never go: the job fails ([`ErrorCode::Moves`], detail: the layer).
    fn emit_moves(&mut self) -> bool {
        if !self.tp.emitting() {
            return true;
        }
        // The unit refused last is offered first again, and its bytes stay what they were
        // (the coding state moves only when a unit goes in): no use offering it before the
        // buffer has that much free.
        if self.moves.free_bytes() < self.room_memory.waits_for() {
            return false;
        }
        let Self { tp, scratch, moves, stream, room_memory, .. } = self;
        let mut room = moves.room(stream, room_memory);
        let emitted = tp.emit_next(scratch, &mut room);
        let never_fits = room.never_fits();
        match emitted {
            Ok(Emitted::Complete) => self.is_active(),
            Ok(Emitted::NeedsRoom { layer, .. }) => {
                if never_fits {
                    self.fail(ErrorCode::Moves, layer);
                }
                false
            }
            Err(_) => {
                self.check(false, true, None);
                false
            }
        }
    }

    /// Cuts the slicer's next plane and hands its layer to the toolpath stage, then emits
    /// what the move buffer takes of the layer the stage built; false when no plane was
    /// left or on an error. Call only when [`emit_moves`](Self::emit_moves) is done.
    fn cut_one(&mut self, motion: MotionHook<'_, '_, MOVE_BYTES, P>) -> bool {
        let cut = self
            .through_slicer(motion, |slicer, work, sink| slicer.cut_one(work, &mut |l| sink(l)));
        self.emit_moves();
        cut == Some(true) && self.is_active()
    }

    /// After the last plane: the toolpath stage builds its next waiting layer, and what the
    /// move buffer takes of it is emitted; false when none was left or on an error. Call
    /// only when [`emit_moves`](Self::emit_moves) is done.
    fn flush_one(&mut self, motion: MotionHook<'_, '_, MOVE_BYTES, P>) -> bool {
        let built = self
            .through_toolpath(motion, |tp, work, events| tp.build_next(work, &mut |e| events(e)));
        self.emit_moves();
        built == Some(true) && self.is_active()
    }

    /// Ends the model: every plane is cut and every layer flushed and emitted (or the job
    /// failed).
    #[inline(never)]
    fn finish_model(&mut self, mut motion: MotionHook<'_, '_, MOVE_BYTES, P>) {
        let sliced = self.through_slicer(motion.as_deref_mut(), |slicer, work, sink| {
            slicer.finish(work, &mut |l| sink(l))
        });
        if sliced.is_some() && self.is_active() {
            self.through_toolpath(motion, |tp, work, events| tp.finish(work, &mut |e| events(e)));
        }
        self.toolpath_done = true;
    }

    fn check(&mut self, slice_err: bool, tp_err: bool, moves_full: Option<u32>) {
        let layer = self.slicer.stats().layers;
        if slice_err {
            self.fail(ErrorCode::Slice, layer);
        } else if tp_err {
            self.fail(ErrorCode::Toolpath, layer);
        } else if let Some(l) = moves_full {
            self.fail(ErrorCode::Moves, l);
        }
    }

    /// Layer hashes completed since the last call.
    pub fn take_layer_done(&mut self) -> Option<(u32, u64)> {
        self.done.pop_front()
    }

    /// Bounded work: moves into the planner, the toolpath stage's next paths into the move
    /// buffer, blocks into the generator, steps into `out`. Returns true when something
    /// happened (a move planned or emitted, a block or a step generated, a layer closed).
    pub fn poll<const Q: usize>(&mut self, out: &mut StepProducer<'_, Q>) -> bool {
        if !self.is_active() {
            return false;
        }
        let allowed = self.motion_allowed();
        let Self { moves, planner, tags, gen, .. } = self;
        let mut slot = MotionSlot { moves, planner, tags, gen, allowed };
        let mut worked = match slot.feed(self.toolpath_done, out) {
            Ok(w) => w,
            Err(layer) => {
                self.fail(ErrorCode::Plan, layer);
                return true;
            }
        };
        // The toolpath stage's next paths, as far as the room the planner made allows.
        if self.tp.emitting() {
            let before = self.moves.used_bytes();
            worked |= self.emit_moves() || self.moves.used_bytes() != before;
            if !self.is_active() {
                return true;
            }
        }
        let input_done = self.toolpath_done && self.moves.is_empty();
        // Completed layers' hashes; while the reports are full the generator holds at the
        // next layer (its marks fill up), so no hash is ever dropped.
        while !self.done.is_full() {
            let Some((layer, hash)) = self.gen.take_mark() else { break };
            let _ = self.done.push_back((layer, hash));
            self.layers_planned = layer + 1;
            worked = true;
        }
        if input_done && self.planner.is_empty() && self.gen.is_idle() && !self.done.is_full() {
            if let Some(layer) = self.gen.tag() {
                let _ = self.done.push_back((layer, out.take_hash()));
                self.layers_planned = layer + 1;
            }
            self.state = DeviceState::Done;
            worked = true;
        }
        worked
    }

    /// What the job did so far (complete once it is done): steps per axis, final motor
    /// positions and the planned motion's duration, from the step generator.
    pub fn job_report(&self) -> JobReport {
        JobReport {
            steps: self.gen.stats().steps,
            positions: self.gen.motor_steps(),
            print_ticks: self.gen.time_q16() >> 16,
        }
    }

    /// The status report; `done_ms` is the print time executed so far (the executor's).
    pub fn status(&self, done_ms: u32) -> Status {
        Status {
            state: self.state,
            layer: self.layers_planned,
            layers: self.layers,
            planned_ms: ((self.planner.released_ticks_q16() >> 16) * 1000
                / self.plan_cfg.timer_hz.max(1) as u64) as u32,
            done_ms,
            triangles: self.triangles,
            queue_fill_pct: (self.moves.used_bytes() * 100 / self.moves.capacity().max(1)) as u8,
            error: self.error,
            detail: self.detail,
            hotend_c_x10: self.temps_c_x10.0,
            bed_c_x10: self.temps_c_x10.1,
            heating: self.is_active() && self.heaters && !self.heated,
        }
    }

    /// Pumps the link: decodes delivered messages (a message that does not decode is
    /// reported and dropped, never executed), answers `Hello`, sends layer hashes and a
    /// status every `status_every_ms` and at once on a state change. A dead link fails the
    /// job.
    pub fn service<const TX: usize, const RX: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        now_ms: u32,
        done_ms: u32,
        status_every_ms: u32,
        motion: &mut dyn FnMut(&mut MotionSlot<'_, MOVE_BYTES, P>),
    ) {
        if let Err(crate::protocol::LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            self.link_lost(silent_ms);
        }
        self.check_heat_wait(now_ms);
        let before = self.state;
        while ep.tx_free() > 1 {
            let Some(p) = ep.peek() else { break };
            if self.waiting_for_room && self.is_active() && !self.emit_moves() {
                break;
            }
            self.waiting_for_room = false;
            match Message::decode(p) {
                Ok(Message::Hello { .. }) => {
                    let caps = self.capacities();
                    let m = Message::Capabilities { version: VERSION, capacities: caps };
                    send(ep, &m);
                }
                Ok(m) => {
                    if self.handle_with(&m, Some(&mut *motion)) == Accept::Busy {
                        self.waiting_for_room = true;
                        break;
                    }
                }
                Err(_) => self.fail(ErrorCode::BadMessage, p.first().copied().unwrap_or(0) as u32),
            }
            ep.pop();
        }
        while ep.tx_free() > 1 {
            let Some((layer, hash)) = self.take_layer_done() else { break };
            send(ep, &Message::LayerDone { layer, hash });
        }
        let finished = self.state == DeviceState::Done;
        if finished && !self.report_sent && self.done.is_empty() && ep.tx_free() > 1 {
            self.report_sent = send(ep, &Message::JobReport(self.job_report()));
        }
        let due = now_ms.wrapping_sub(self.status_due_ms) < 1 << 31;
        // Every layer report and the job report go out before a status (the host ends on
        // `Done`).
        let reported = self.done.is_empty() && (!finished || self.report_sent);
        let status_out = (due || self.state != before) && ep.tx_free() > 0 && reported;
        if status_out && send(ep, &Message::Status(self.status(done_ms))) {
            self.status_due_ms = now_ms.wrapping_add(status_every_ms);
        }
    }
}

/// Encodes `msg` and hands it to the link; false when it did not go out. The payload buffer
/// lives only while a message is sent (clearing it costs ~100 instructions on the
/// Cortex-M3, too much for every main-loop turn).
fn send<const TX: usize, const RX: usize>(ep: &mut Endpoint<TX, RX>, msg: &Message<'_>) -> bool {
    let mut buf = [0u8; MAX_PAYLOAD];
    match msg.encode(&mut buf) {
        Ok(n) => ep.send(&buf[..n]).is_ok(),
        Err(_) => false,
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
        const MOVE_BYTES: usize,
        const P: usize,
    > core::fmt::Debug for Printer<A, S, L, PTS, LOOPS, CROSS, PATH, RING, SPANS, MOVE_BYTES, P>
{
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Printer")
            .field("state", &self.state)
            .field("error", &self.error)
            .field("triangles", &self.triangles)
            .field("layers", &self.layers)
            .finish_non_exhaustive()
    }
}

/// Where the toolpath stage's events go inside [`Printer::service`]: planner moves (absolute
/// E, [`MoveStream`]) into the move buffer (the first layer whose moves do not fit is kept in
/// `failed`), and at a progress point the motion half lent to `motion` (nothing when there is
/// none).
struct EventSink<'a, 'h, 'f, const MOVE_BYTES: usize, const P: usize> {
    slot: MotionSlot<'a, MOVE_BYTES, P>,
    stream: &'a mut MoveStream,
    motion: MotionHook<'h, 'f, MOVE_BYTES, P>,
    failed: Option<u32>,
}

impl<const MOVE_BYTES: usize, const P: usize> EventSink<'_, '_, '_, MOVE_BYTES, P> {
    fn event(&mut self, e: &ToolEvent<'_>) {
        let stream = &mut *self.stream;
        match e {
            ToolEvent::Progress => {
                if let Some(lend) = self.motion.as_deref_mut() {
                    lend(&mut self.slot);
                }
            }
            ToolEvent::LayerStart { index, .. } => stream.start_layer(*index),
            ToolEvent::Move(m) => {
                if self.slot.moves.push(&stream.next(m)).is_err() {
                    self.failed.get_or_insert(stream.layer());
                }
            }
            ToolEvent::LayerEnd(_) => {}
        }
    }
}

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
//! half at the stage's progress points ([`MotionAccess`]), so steps keep being generated
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
//! half, lent at the computation's progress points ([`Computing`]), until the new layer's
//! first unit. A unit whose bytes exceed the whole buffer could never go in: a typed error
//! ([`ErrorCode::Moves`], detail: the layer), never a silent drop or a wait forever.
//!
//! Planner blocks are released when their plan is final, or with their current plan only when
//! the planner queue is full or the model has ended (`pop_forced`), never earlier because data
//! happened to be late: the blocks depend only on the job, not on the link's timing, and the
//! step generator's commands depend only on the blocks ([`Motion`]). The step commands
//! generated for each layer's blocks are hashed (FNV-1a over axis and command, see
//! [`StepProducer::take_hash`](crate::step::StepProducer::take_hash)) and reported with
//! [`Message::LayerDone`]: identical jobs give identical hashes on the host simulation and on
//! the firmware.

pub mod board;
mod card_job;
mod failure;
mod motion;
mod orphan;
mod pipeline;

use heapless::Deque;

use crate::gcode::input::{GcodeSink, Hold};
use crate::geom::Triangle;
use crate::machine::{MachineConfig, PrintSettings};
use crate::move_ring::{PackedMove, RingFull};
use crate::plan::PlanConfig;
use crate::protocol::{
    job_fingerprint, Capacities, DeviceState, Endpoint, ErrorCode, GcodeSpec, JobReport, JobSpec,
    Message, Status, MAX_PAYLOAD, VERSION,
};
use crate::slot::Slot;
use crate::step::StepConfig;
use crate::thermal::{ThermalFault, HEAT_WAIT_LIMIT_MS};

pub use board::{job_toolpath_config, BoardPrinter, BOARD_CAPACITIES, CREALITY_CAPACITIES};
pub use card_job::{file_kind, is_card_request, FileKind, CARD_CHUNK_BYTES, STL_JOB_NAME};
pub use failure::{Failure, Refusal};
pub use motion::{Motion, MotionAccess, MotionHalf};
use orphan::Orphan;
pub use orphan::{
    ResumePoint, DEFAULT_HEAT_HOLD_MS, GCODE_PARK_RETRACT_UM, PARK_LIFT_UM, PARK_TAG, PARK_XY_UM,
};
pub use pipeline::{Computing, Emit, Pipeline, Stages};

/// A [`Printer`] type with every capacity named at the point of use (the names of
/// [`Capacities`]; `lookahead_moves` is the planner's queue):
///
/// ```
/// strata::printer_type! {
///     /// A small printer.
///     pub type Small = {
///         active_triangles: 256,
///         contour_points: 256,
///         contour_loops: 16,
///         toolpath_points: 512,
///         toolpath_loops: 32,
///         scan_crossings: 1024,
///         path_points: 4096,
///         window_ring_words: 2048,
///         window_spans: 2048,
///         move_buffer_bytes: 16384,
///         lookahead_moves: 16,
///     };
/// }
/// assert_eq!(Small::CAPACITIES.contour_loops, 16);
/// ```
#[macro_export]
macro_rules! printer_type {
    (
        $(#[$meta:meta])*
        $vis:vis type $name:ident = {
            active_triangles: $a:expr,
            contour_points: $s:expr,
            contour_loops: $l:expr,
            toolpath_points: $pts:expr,
            toolpath_loops: $loops:expr,
            scan_crossings: $cross:expr,
            path_points: $path:expr,
            window_ring_words: $ring:expr,
            window_spans: $spans:expr,
            move_buffer_bytes: $moves:expr,
            lookahead_moves: $p:expr $(,)?
        };
    ) => {
        $(#[$meta])*
        $vis type $name = $crate::printer::Printer<
            $crate::printer::Pipeline<
                { $a }, { $s }, { $l }, { $pts }, { $loops }, { $cross }, { $path }, { $ring },
                { $spans },
            >,
            { $moves },
            { $p },
        >;
    };
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

/// The job runner: the job's state machine over a computing half and a motion half.
///
/// The computing half `Pl` is a [`Pipeline`] of the slicer and the toolpath stage
/// ([`Stages`]); the [`Motion`] half holds `MOVE_BYTES` bytes of delta-coded moves waiting for
/// the planner and `P` moves of planner lookahead. Name every capacity with
/// [`printer_type!`](crate::printer_type).
pub struct Printer<Pl, const MOVE_BYTES: usize, const P: usize> {
    machine: MachineConfig,
    plan_cfg: PlanConfig,
    step_cfg: StepConfig,
    pipeline: Pl,
    state: DeviceState,
    /// Why the job failed (once it did).
    failure: Slot<Failure>,
    /// The failure went to the host in words (`Message::Failure`).
    failure_sent: bool,
    /// The sliced job's settings (its heater targets and park moves; the rest of its start
    /// message is used up when it starts).
    job_settings: Slot<PrintSettings>,
    triangles: u32,
    /// Triangles of the batch being taken that are already in (it waits for room).
    batch_pos: u32,
    /// The message at the head of the link waits for room in the move buffer (it is not
    /// decoded again until the toolpath stage's layer is all in).
    waiting_for_room: bool,
    /// The job report went out (once the job is done).
    report_sent: bool,
    /// The board reports heaters ([`Printer::set_thermal`] was called): jobs wait for them.
    heaters: bool,
    /// The heaters reached the job's targets once (motion waits until then).
    heated: bool,
    /// A resumed job waits for its heaters to be back at their targets before it moves (a
    /// G-code job too: its own waits were read long ago).
    reheat: bool,
    /// When the job began waiting for its heaters, ms (the clock of [`Printer::service`]).
    heat_wait_since_ms: Option<u32>,
    /// Measured temperatures, 0.1 degC.
    temps_c_x10: (i16, i16),
    layers: u32,
    /// The job runs G-code (its input has the pipeline's scratch), not a sliced model.
    gcode_job: bool,
    /// The job's G-code comes from the card ([`card_job`]): it needs no host.
    card_job: bool,
    /// A model job from the card: where its file stands ([`card_job`]).
    card_records: Slot<card_job::CardRecords>,
    /// A file is being written to the card (its writer has the scratch).
    uploading: bool,
    /// An STL on the card is being sorted for a print (the sort has the scratch; the print
    /// request is answered once the job starts).
    preparing: bool,
    /// Every triangle, or the whole G-code text, was taken.
    model_ended: bool,
    /// The model's last moves are in the move buffer (a G-code job's: and its last settings
    /// are in effect): once the motion half is idle, the job is done.
    toolpath_done: bool,
    /// Step-command hashes of completed layers, waiting to be reported.
    done: Deque<LayerHash, 8>,
    layers_planned: u32,
    status_due_ms: u32,
    /// The host went silent during the job: where it stands since ([`orphan`]).
    orphan: Slot<Orphan>,
    /// For how long the host was silent when the job was orphaned, ms.
    orphan_silent_ms: u32,
    /// Where an orphaned job's input ended.
    resume: Slot<ResumePoint>,
    /// How long an orphaned job's heaters hold their targets once parked, ms, when the board
    /// set it (empty: [`DEFAULT_HEAT_HOLD_MS`]).
    heat_hold_ms: Slot<u32>,
    /// The job's fingerprint ([`crate::protocol::job_fingerprint`] of its start message).
    fingerprint: u32,
    /// A new host said hello while the job was orphaned: it hears of the parked job once
    /// the job has parked.
    parked_due: bool,
    /// The link session last seen (see [`crate::protocol::link`]): a new session means a
    /// new host, so a running job's own host is gone.
    session: u16,
}

impl<Pl: Stages, const MOVE_BYTES: usize, const P: usize> Printer<Pl, MOVE_BYTES, P> {
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
    /// are [`MachineConfig::EMPTY`] and the like: the whole value is zero bytes, so a
    /// `static` holding it is in `.bss` (no flash image).
    pub const fn empty() -> Self {
        Self {
            machine: MachineConfig::EMPTY,
            plan_cfg: PlanConfig::EMPTY,
            step_cfg: StepConfig::EMPTY,
            pipeline: Pl::EMPTY,
            state: DeviceState::Idle,
            failure: Slot::Empty,
            failure_sent: false,
            job_settings: Slot::Empty,
            triangles: 0,
            batch_pos: 0,
            waiting_for_room: false,
            report_sent: false,
            heaters: false,
            heated: false,
            reheat: false,
            heat_wait_since_ms: None,
            temps_c_x10: (0, 0),
            layers: 0,
            gcode_job: false,
            card_job: false,
            card_records: Slot::Empty,
            uploading: false,
            preparing: false,
            model_ended: false,
            toolpath_done: false,
            done: Deque::new(),
            layers_planned: 0,
            status_due_ms: 0,
            orphan: Slot::Empty,
            orphan_silent_ms: 0,
            resume: Slot::Empty,
            heat_hold_ms: Slot::Empty,
            fingerprint: 0,
            parked_due: false,
            session: 0,
        }
    }

    /// What a runner of these capacities holds, announced to the host (RAM: the runner and
    /// its motion half).
    pub const CAPACITIES: Capacities = Capacities {
        move_buffer_bytes: MOVE_BYTES as u32,
        ram_bytes: (core::mem::size_of::<Self>() + core::mem::size_of::<Motion<MOVE_BYTES, P>>())
            as u32,
        ..Pl::CAPACITIES
    };

    /// Sets the machine (limits, steps/mm) and goes idle at the origin; buffers stay where
    /// they are (no large value is moved).
    pub fn configure(&mut self, machine: &MachineConfig) {
        self.machine = *machine;
        self.plan_cfg = PlanConfig::from_machine(machine);
        self.step_cfg = StepConfig::from_machine(machine);
        self.state = DeviceState::Idle;
        self.job_settings = Slot::Empty;
    }

    /// What this runner holds (announced to the host): [`Self::CAPACITIES`].
    pub fn capacities(&self) -> Capacities {
        Self::CAPACITIES
    }

    /// Offsets with at most `edges` edges an island (in bands beyond), as a device whose
    /// offset engine holds that many does (a simulated printer posing as a smaller board:
    /// it announces that board's capacities itself).
    pub fn set_offset_limit(&mut self, edges: usize) {
        self.pipeline.set_offset_limit(edges);
    }

    /// Builds layers with bridges within `path_points` and `crossings`, and without bridges
    /// where they need more, as a device with those capacities does.
    pub fn set_bridge_limits(&mut self, path_points: usize, crossings: usize) {
        self.pipeline.set_bridge_limits(path_points, crossings);
    }

    /// State.
    pub fn state(&self) -> DeviceState {
        self.state
    }

    /// Why the job failed (once it did).
    pub fn failure(&self) -> Option<Failure> {
        self.failure.get().copied()
    }

    /// Error code and detail of the status report (`None, 0` unless failed; a job whose host
    /// went silent: `LinkDead` and the silence, ms, while it parks and waits).
    pub fn error(&self) -> (ErrorCode, u32) {
        let layers_cut = self.pipeline.layers_cut();
        match (self.failure(), self.orphan.get()) {
            (Some(f), _) => f.code(layers_cut),
            (None, Some(_)) => (ErrorCode::LinkDead, self.orphan_silent_ms),
            (None, None) => (ErrorCode::None, 0),
        }
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
    pub fn planned_s<const Q: usize>(
        &self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> f64 {
        let ticks_q16 = motion.with(|m, _| m.planner().released_ticks_q16());
        ticks_q16 as f64 / 65536.0 / self.plan_cfg.timer_hz as f64
    }

    /// The slicer (statistics: peak active set, peak points).
    pub fn slicer(&self) -> &Pl::Slicer {
        self.pipeline.slicer()
    }

    /// The toolpath stage (statistics and needs).
    pub fn toolpath(&self) -> &Pl::Toolpath {
        self.pipeline.toolpath()
    }

    /// Bytes of the largest toolpath unit (a path with the travel before it) that went into
    /// the move buffer in this job: the least buffer the job's units needed.
    pub fn largest_unit_bytes(&self) -> usize {
        self.pipeline.largest_unit_bytes()
    }

    /// True when the job's last block went to the step generator and it sent every step.
    pub fn motion_finished(&self) -> bool {
        self.state == DeviceState::Done
    }

    /// True while steps may still come: printing or paused.
    pub fn is_active(&self) -> bool {
        matches!(self.state, DeviceState::Printing | DeviceState::Paused)
    }

    /// Fails the running (or idle) job with `failure`; a job that already ended keeps its end.
    fn fail(&mut self, failure: Failure) {
        if self.is_active() || self.state == DeviceState::Idle {
            self.state = DeviceState::Failed;
            self.failure = Slot::Full(failure);
        }
    }

    /// The heater targets the current job wants, degC (hotend, bed): the job's settings while
    /// it prints or is paused, 0 otherwise (idle, done, failed, aborted, stopped), so a board
    /// that applies them every update turns the heaters off when a job ends.
    pub fn heater_targets(&self) -> (i16, i16) {
        if !self.is_active() || self.orphan.get() == Some(&Orphan::Cooled) {
            return (0, 0);
        }
        match (self.job_settings.get(), self.pipeline.gcode_ref()) {
            (_, Some(g)) if self.gcode_job => g.targets(),
            (Some(s), _) => (s.hotend_temp_c, s.bed_temp_c),
            _ => (0, 0),
        }
    }

    /// The part-cooling fan's duty (0..=255) the job wants where the motion is: a sliced
    /// job's moves carry it (by layer time, on bridges, off on the first layer:
    /// [`crate::toolpath::Cooling`]), a G-code job's is its `M106`; off without an active job.
    pub fn fan_duty<const Q: usize>(&self, motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>) -> u8 {
        if self.state != DeviceState::Printing {
            return 0;
        }
        if self.gcode_job {
            return self.pipeline.gcode_ref().map_or(0, |g| g.fan());
        }
        motion.with(|m, _| m.fan())
    }

    /// What the heaters measure (0.1 degC, for the status reports) and whether they are at
    /// their targets: motion waits until they have been once for the job (like M190/M109
    /// before the first layer; the slicer and the toolpath stage work meanwhile). A board that
    /// never calls this has no heaters (the host simulation): its jobs do not wait.
    pub fn set_thermal(&mut self, at_target: bool, hotend_c_x10: i16, bed_c_x10: i16) {
        self.heaters = true;
        self.temps_c_x10 = (hotend_c_x10, bed_c_x10);
        if let (true, Some(g)) = (self.gcode_job, self.pipeline.gcode()) {
            g.thermal(at_target);
        }
        if at_target && self.is_active() {
            self.heated = true;
            self.reheat = false;
        }
    }

    /// A heater fault: the job fails at once with [`ErrorCode::Thermal`] (detail `code`),
    /// its moves are dropped; the board stops the steps and keeps the heaters off.
    pub fn thermal_fault<const Q: usize>(
        &mut self,
        code: u8,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        self.fail(Failure::Thermal { code });
        motion.with(|m, _| m.moves_mut().clear());
    }

    /// A job that waits longer than [`HEAT_WAIT_LIMIT_MS`] (printing, not paused) for its
    /// heaters fails with [`ThermalFault::HeatingTimeout`] (the last line of defence behind
    /// each heater's own checks, which also catch a heater that stalls short of its target).
    fn check_heat_wait<const Q: usize>(
        &mut self,
        now_ms: u32,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        if !(self.state == DeviceState::Printing && self.heaters && self.waits_for_heat()) {
            self.heat_wait_since_ms = None;
            return;
        }
        let since = *self.heat_wait_since_ms.get_or_insert(now_ms);
        if now_ms.wrapping_sub(since) > HEAT_WAIT_LIMIT_MS {
            self.thermal_fault(ThermalFault::HeatingTimeout.code(), motion);
        }
    }

    /// The job waits for its heaters: a sliced job until they reach its targets once, a
    /// G-code job at a heater wait (`M109`, `M190`).
    fn waits_for_heat(&self) -> bool {
        match self.pipeline.gcode_ref() {
            Some(g) if self.gcode_job => g.hold() == Hold::Heat || self.reheat,
            _ => !self.heated || self.reheat,
        }
    }

    /// Starts `job`: every stage set up for it, or the job refused. Never inlined, as the
    /// other cold paths of [`handle_with`](Self::handle_with): their frames stay off the
    /// deepest stack (a batch's layer computation under `handle_with`).
    #[inline(never)]
    fn start<const Q: usize>(
        &mut self,
        job: &JobSpec,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        self.failure = Slot::Empty;
        self.failure_sent = false;
        match self.pipeline.start(&self.machine, job) {
            Ok(layers) => self.layers = layers,
            Err(f) => {
                self.state = DeviceState::Failed;
                self.failure = Slot::Full(f);
                return;
            }
        }
        self.begin(motion);
        self.job_settings = Slot::Full(job.settings);
    }

    /// Starts a G-code job: its input takes the pipeline's scratch (see [`start`](Self::start)
    /// for why this is not inlined).
    #[inline(never)]
    fn start_gcode<const Q: usize>(
        &mut self,
        spec: &GcodeSpec,
        card: Option<crate::card::OpenFile>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        self.failure = Slot::Empty;
        self.failure_sent = false;
        self.pipeline.start_gcode(&self.machine, card);
        self.layers = spec.layers;
        self.begin(motion);
        self.job_settings = Slot::Empty;
        self.gcode_job = true;
    }

    /// The motion half and the job's state from the start, printing.
    fn begin<const Q: usize>(&mut self, motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>) {
        motion.with(|m, _| m.reset(&self.plan_cfg, &self.step_cfg));
        self.triangles = 0;
        self.batch_pos = 0;
        self.report_sent = false;
        self.heated = false;
        self.heat_wait_since_ms = None;
        self.gcode_job = false;
        self.card_job = false;
        self.card_records = Slot::Empty;
        // A job takes the scratch: a file being written to the card, or an STL being sorted,
        // is abandoned.
        self.uploading = false;
        self.preparing = false;
        self.model_ended = false;
        self.toolpath_done = false;
        self.done.clear();
        self.layers_planned = 0;
        self.orphan = Slot::Empty;
        self.resume = Slot::Empty;
        self.state = DeviceState::Printing;
    }

    /// Fails the job for a message that does not fit its state (see [`start`](Self::start)
    /// for why this is not inlined).
    #[inline(never)]
    fn refuse_unexpected(&mut self, message: u8) {
        self.fail(Failure::Unexpected { message });
    }

    /// Takes a host message. Misplaced messages fail the job (never executed).
    pub fn handle<const Q: usize>(
        &mut self,
        msg: &Message<'_>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> Accept {
        self.handle_with(msg, motion, false)
    }

    /// [`handle`](Self::handle); `lend`: the motion half gets the progress points of the
    /// layers this message makes the toolpath stage compute (it generates steps there). The
    /// motion half's gate follows the message ([`MotionAccess::gate`]).
    fn handle_with<const Q: usize>(
        &mut self,
        msg: &Message<'_>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> Accept {
        // A message that stops the motion closes the gate first, so that a feeder elsewhere
        // releases no block after it (its own state change follows).
        if matches!(msg, Message::Pause | Message::Abort | Message::EmergencyStop) {
            motion.gate(false, self.flush());
        }
        let accept = self.handle_message(msg, motion, lend);
        let (allowed, toolpath_done) = self.motion_gate();
        motion.gate(allowed, toolpath_done);
        accept
    }

    fn handle_message<const Q: usize>(
        &mut self,
        msg: &Message<'_>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> Accept {
        match (msg, self.state) {
            (Message::EmergencyStop, _) => {
                self.state = DeviceState::Stopped;
                motion.with(|m, _| m.moves_mut().clear());
            }
            (Message::Abort, s) if s != DeviceState::Stopped => {
                self.state = DeviceState::Aborted;
                motion.with(|m, _| m.moves_mut().clear());
            }
            (Message::JobStart(job), s)
                if !matches!(s, DeviceState::Printing | DeviceState::Paused) =>
            {
                self.start(job, motion)
            }
            (Message::GcodeStart(spec), s)
                if !matches!(s, DeviceState::Printing | DeviceState::Paused) =>
            {
                self.start_gcode(spec, None, motion)
            }
            (Message::Gcode(text), DeviceState::Printing | DeviceState::Paused)
                if self.gcode_job && !self.model_ended =>
            {
                return self.take_gcode(text, false, motion);
            }
            (Message::EndOfModel, DeviceState::Printing | DeviceState::Paused)
                if self.gcode_job && !self.model_ended =>
            {
                return self.take_gcode(&[], true, motion);
            }
            // A new host resumes a parked job.
            (Message::Resume, _) if self.parked() => self.unpark(motion),
            // An orphaned job (its host went silent) parks and waits on its own: a pause or
            // resume still in its receive queue is not for it.
            (Message::Pause | Message::Resume, _) if self.orphan.get().is_some() => {}
            (Message::Pause, DeviceState::Printing) => self.state = DeviceState::Paused,
            (Message::Resume, DeviceState::Paused) => self.state = DeviceState::Printing,
            (Message::Triangles(batch), DeviceState::Printing | DeviceState::Paused)
                if !self.model_ended && !self.gcode_job =>
            {
                return self.take_batch(batch, motion, lend);
            }
            (Message::EndOfModel, DeviceState::Printing | DeviceState::Paused)
                if !self.model_ended && !self.gcode_job =>
            {
                return self.end_model(motion, lend);
            }
            (Message::Hello { .. }, _) => {}
            // A repeated pause/resume is harmless; everything else out of place fails.
            (Message::Pause | Message::Resume, _) => {}
            (m, _) => self.refuse_unexpected(m.type_byte()),
        }
        Accept::Taken
    }

    /// Takes a batch's triangles from where it stopped. Layers are cut one at a time, each
    /// only once the toolpath stage has emitted the layer before into the move buffer; a
    /// batch that has to wait is offered again and resumes here.
    fn take_batch<const Q: usize>(
        &mut self,
        batch: &crate::protocol::TriangleBatch<'_>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> Accept {
        for (i, t) in batch.iter().enumerate().skip(self.batch_pos as usize) {
            while self.pipeline.would_cut(t.z_min()) {
                if !self.emit_moves(motion) {
                    if !self.is_active() {
                        break;
                    }
                    self.batch_pos = i as u32;
                    return Accept::Busy;
                }
                if !self.cut_one(motion, lend) {
                    break;
                }
            }
            if !self.is_active() {
                break;
            }
            self.push_triangle(&t, motion, lend);
        }
        self.batch_pos = 0;
        Accept::Taken
    }

    /// Reads a G-code job's `text` from where it stopped (`end`: the text has ended) into the
    /// move buffer; busy (offered again) while the input waits for room, the motion or the
    /// heaters.
    fn take_gcode<const Q: usize>(
        &mut self,
        text: &[u8],
        end: bool,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> Accept {
        // The gate's flush apart from the input's hold (see `flush`).
        let ended = self.model_ended || self.orphan.get().is_some();
        let (heaters, allowed) = (self.heaters, self.motion_allowed());
        let Some(input) = self.pipeline.gcode() else {
            self.refuse_unexpected(crate::protocol::msg::ty::GCODE);
            return Accept::Taken;
        };
        let mut pos = self.batch_pos as usize;
        let mut sink = GcodeMotion { motion, heaters, allowed, ended };
        let all = input.take(text, &mut pos, end, &mut sink);
        if !all {
            self.batch_pos = pos as u32;
            return Accept::Busy;
        }
        self.batch_pos = 0;
        self.model_ended |= end;
        Accept::Taken
    }

    /// Cuts and builds every layer left, then ends the model (or waits for room in the move
    /// buffer and is offered again).
    fn end_model<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> Accept {
        while self.is_active() {
            if !self.emit_moves(motion) {
                if !self.is_active() {
                    break;
                }
                return Accept::Busy;
            }
            if !self.cut_one(motion, lend) && !self.flush_one(motion, lend) {
                break;
            }
        }
        self.model_ended = true;
        self.finish_model(motion, lend);
        Accept::Taken
    }

    /// The pipeline's result, its failure recorded (the job fails).
    fn record<R>(&mut self, r: Result<R, Failure>) -> Option<R> {
        r.map_err(|f| self.fail(f)).ok()
    }

    /// The motion half as the pipeline sees it while it computes (see [`Lending`]).
    fn computing<'a, const Q: usize, A: MotionAccess<MOVE_BYTES, P, Q>>(
        &self,
        motion: &'a mut A,
        lend: bool,
    ) -> Lending<'a, A, MOVE_BYTES, P, Q> {
        Lending { motion, allowed: self.motion_allowed(), lend }
    }

    fn push_triangle<const Q: usize>(
        &mut self,
        t: &Triangle,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) {
        let mut computing = self.computing(motion, lend);
        let r = self.pipeline.push_triangle(t, &mut computing);
        self.record(r);
        self.triangles += 1;
    }

    /// Emits the toolpath stage's built layer into the move buffer as far as it has room
    /// ([`Stages::emit_moves`], the motion half held meanwhile: one unit of moves at most);
    /// true when no layer is left to emit (the stage may build the next one).
    fn emit_moves<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> bool {
        let pipeline = &mut self.pipeline;
        let r = motion.with(|m, _| pipeline.emit_moves(m.moves_mut()));
        match self.record(r) {
            Some(Emit::Idle) => true,
            Some(Emit::Complete) => self.is_active(),
            Some(Emit::Waiting) | None => false,
        }
    }

    /// Cuts the slicer's next plane and hands its layer to the toolpath stage, then emits
    /// what the move buffer takes of the layer the stage built; false when no plane was
    /// left or on an error. Call only when [`emit_moves`](Self::emit_moves) is done.
    fn cut_one<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> bool {
        let mut computing = self.computing(motion, lend);
        let r = self.pipeline.cut_one(&mut computing);
        let cut = self.record(r);
        self.emit_moves(motion);
        cut == Some(true) && self.is_active()
    }

    /// After the last plane: the toolpath stage builds its next waiting layer, and what the
    /// move buffer takes of it is emitted; false when none was left or on an error. Call
    /// only when [`emit_moves`](Self::emit_moves) is done.
    fn flush_one<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) -> bool {
        let mut computing = self.computing(motion, lend);
        let r = self.pipeline.flush_one(&mut computing);
        let built = self.record(r);
        self.emit_moves(motion);
        built == Some(true) && self.is_active()
    }

    /// Ends the model: every plane is cut and every layer flushed and emitted (or the job
    /// failed).
    fn finish_model<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        lend: bool,
    ) {
        let mut computing = self.computing(motion, lend);
        let r = self.pipeline.finish_slicing(&mut computing);
        if self.record(r).is_some() && self.is_active() {
            let mut computing = self.computing(motion, lend);
            let r = self.pipeline.finish_toolpaths(&mut computing);
            self.record(r);
        }
        self.toolpath_done = true;
    }

    /// Blocks may go to the step generator: printing (not paused) and the heaters reached
    /// the job's targets once (or the board has none).
    fn motion_allowed(&self) -> bool {
        let heated = self.heated || self.gcode_job;
        self.state == DeviceState::Printing && (!self.heaters || (heated && !self.reheat))
    }

    /// The planner may release every block it holds: the model's last moves are in the move
    /// buffer, or a G-code job's input has ended or holds until the motion is done.
    fn flush(&self) -> bool {
        let holds = || self.pipeline.gcode_ref().is_some_and(|g| g.hold() != Hold::None);
        self.toolpath_done
            || self.orphan.get().is_some()
            || (self.gcode_job && (self.model_ended || holds()))
    }

    /// Whether the motion half may release blocks, and whether the model's last moves are in
    /// the move buffer: what a board's motion interrupt passes to [`Motion::feed`].
    pub fn motion_gate(&self) -> (bool, bool) {
        (self.is_active() && self.motion_allowed(), self.flush())
    }

    /// A G-code job's settings whose moves are done take effect; once its text has ended and
    /// its last setting is in effect, its last moves are in the buffer.
    fn apply_gcode_settings<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) {
        let done = motion.with(|m, _| m.generator().blocks_done());
        if let Some(g) = self.pipeline.gcode() {
            g.apply_due(done);
            self.toolpath_done |= self.model_ended && g.finished();
        }
    }

    /// Layer hashes completed since the last call.
    pub fn take_layer_done(&mut self) -> Option<(u32, u64)> {
        self.done.pop_front().map(LayerHash::get)
    }

    /// Bounded work: moves into the planner, the toolpath stage's next paths into the move
    /// buffer, blocks into the generator, steps into the step queue. Returns true when
    /// something happened (a move planned or emitted, a block or a step generated, a layer
    /// closed).
    pub fn poll<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> bool {
        if !self.is_active() {
            return false;
        }
        let (allowed, flush) = (self.motion_allowed(), self.flush());
        motion.gate(allowed, flush);
        let mut worked = match motion.with(|m, out| m.feed(allowed, flush, out)) {
            Ok(w) => w,
            Err(layer) => {
                self.fail(Failure::Plan { layer });
                return true;
            }
        };
        if self.gcode_job {
            self.apply_gcode_settings(motion);
        }
        // The toolpath stage's next paths, as far as the room the planner made allows.
        if !self.gcode_job && self.pipeline.emitting() {
            let before = motion.with(|m, _| m.moves().used_bytes());
            worked |=
                self.emit_moves(motion) || motion.with(|m, _| m.moves().used_bytes()) != before;
            if !self.is_active() {
                return true;
            }
        }
        worked |= self.take_layer_marks(motion);
        if self.done.is_full() {
            // A job from the card ends without a host to take its reports (an orphaned job
            // does not end: it parks).
            if !self.card_job {
                return worked;
            }
            self.done.pop_front();
        }
        // An orphaned job does not end: it parks and waits.
        let done = self.toolpath_done && self.orphan.get().is_none();
        let end = motion.with(|m, out| {
            (done && m.is_idle()).then(|| m.generator().tag().map(|layer| (layer, out.take_hash())))
        });
        if let Some(last) = end {
            if let Some((layer, hash)) = last {
                let _ = self.done.push_back(LayerHash::new(layer, hash));
                self.layers_planned = layer + 1;
            }
            self.state = DeviceState::Done;
            worked = true;
        }
        worked
    }

    /// Completed layers' hashes into the reports; while the reports are full the generator
    /// holds at the next layer (its marks fill up), so no hash is ever dropped. True when one
    /// was taken.
    fn take_layer_marks<const Q: usize>(
        &mut self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> bool {
        let mut took = false;
        loop {
            if self.done.is_full() {
                if !self.keeps_latest_reports() {
                    break;
                }
                self.done.pop_front();
            }
            let Some((layer, hash)) = motion.with(|m, _| m.generator_mut().take_mark()) else {
                break;
            };
            took = true;
            if layer == PARK_TAG {
                continue;
            }
            let _ = self.done.push_back(LayerHash::new(layer, hash));
            self.layers_planned = layer + 1;
            took = true;
        }
        took
    }

    /// The job waits for no host to take its layer reports, it keeps the latest ones: an
    /// orphaned job (its host is gone) and a job from the card (it needs none).
    fn keeps_latest_reports(&self) -> bool {
        self.orphan.get().is_some() || self.card_job
    }

    /// What the job did so far (complete once it is done): steps per axis, final motor
    /// positions and the planned motion's duration, from the step generator.
    pub fn job_report<const Q: usize>(
        &self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
    ) -> JobReport {
        motion.with(|m, _| {
            let gen = m.generator();
            JobReport {
                steps: gen.stats().steps,
                positions: gen.motor_steps(),
                print_ticks: gen.time_q16() >> 16,
            }
        })
    }

    /// The status report; `done_ms` is the print time executed so far (the executor's).
    pub fn status<const Q: usize>(
        &self,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        done_ms: u32,
    ) -> Status {
        let (error, detail) = self.error();
        let (released_q16, used, capacity) = motion.with(|m, _| {
            (m.planner().released_ticks_q16(), m.moves().used_bytes(), m.moves().capacity())
        });
        Status {
            state: self.state,
            layer: self.layers_planned,
            layers: self.layers,
            planned_ms: ((released_q16 >> 16) * 1000 / self.plan_cfg.timer_hz.max(1) as u64) as u32,
            done_ms,
            triangles: self.triangles,
            queue_fill_pct: (used * 100 / capacity.max(1)) as u8,
            error,
            detail,
            hotend_c_x10: self.temps_c_x10.0,
            bed_c_x10: self.temps_c_x10.1,
            heating: self.is_active() && self.heaters && self.waits_for_heat(),
        }
    }

    /// Pumps the link: decodes delivered messages (a message that does not decode is
    /// reported and dropped, never executed), answers `Hello`, sends layer hashes, the
    /// failure in words once a job failed, and a status every `status_every_ms` and at once
    /// on a state change. A dead link orphans the job (it prints what it received, parks and
    /// waits: [`Self::link_lost`]). `lend`: the motion half generates steps at the progress
    /// points of the layers the messages make the toolpath stage compute (a board whose
    /// interrupt generates them does not need it).
    pub fn service<const TX: usize, const RX: usize, const Q: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        now_ms: u32,
        done_ms: u32,
        status_every_ms: u32,
        lend: bool,
    ) {
        if let Err(crate::protocol::LinkError::Dead { silent_ms }) = ep.check(now_ms) {
            self.link_lost(silent_ms, now_ms);
        }
        if ep.session() != self.session {
            self.new_session(ep.session(), now_ms);
        }
        self.check_heat_wait(now_ms, motion);
        let before = self.state;
        self.take_messages(ep, motion, now_ms, lend);
        self.tend_orphan(now_ms, ep.peek().is_none(), motion);
        self.send_parked(ep);
        // An orphaned job keeps its layer reports for a new host.
        let alive = ep.check(now_ms).is_ok();
        while ep.tx_free() > 1 && alive {
            let Some((layer, hash)) = self.take_layer_done() else { break };
            send(ep, &Message::LayerDone { layer, hash });
        }
        let finished = self.state == DeviceState::Done;
        if finished && !self.report_sent && self.done.is_empty() && ep.tx_free() > 1 {
            self.report_sent = send(ep, &Message::JobReport(self.job_report(motion)));
        }
        self.send_failure(ep);
        let due = now_ms.wrapping_sub(self.status_due_ms) < 1 << 31;
        // Every layer report, the job report and the failure go out before a status (the
        // host ends on `Done` or `Failed`).
        let failure_out = self.failure.get().is_none() || self.failure_sent;
        let reported = self.done.is_empty() && (!finished || self.report_sent) && failure_out;
        let status_out = (due || self.state != before) && ep.tx_free() > 0 && reported;
        if status_out && send(ep, &Message::Status(self.status(motion, done_ms))) {
            self.status_due_ms = now_ms.wrapping_add(status_every_ms);
        }
    }

    /// A new host opened link session `session`: the old session's messages that were not
    /// taken are gone (a batch taken in part too: the triangles taken are counted), and a
    /// running job's own host is gone, silent or not (the job parks: [`Self::link_lost`]).
    #[inline(never)]
    fn new_session(&mut self, session: u16, now_ms: u32) {
        self.session = session;
        // A record from the card is read again: a batch taken in part resumes.
        if !self.card_record_lost() {
            self.batch_pos = 0;
        }
        self.waiting_for_room = false;
        self.link_lost(0, now_ms);
    }

    /// A host said hello (at `now_ms`, the clock of [`service`](Self::service)): a status
    /// goes out at once, so that it knows whether a job runs or is parked before it starts
    /// one, and a parked job's news ([`Message::Parked`]) once the job has parked.
    pub fn greeted(&mut self, now_ms: u32) {
        self.status_due_ms = now_ms;
        self.parked_due = self.orphan.get().is_some();
    }

    /// Decodes and handles the delivered messages while the link has room for answers.
    fn take_messages<const TX: usize, const RX: usize, const Q: usize>(
        &mut self,
        ep: &mut Endpoint<TX, RX>,
        motion: &mut impl MotionAccess<MOVE_BYTES, P, Q>,
        now_ms: u32,
        lend: bool,
    ) {
        // An orphaned job takes what it received without room for answers (none go out), and
        // so does a job from the card (it needs no host).
        while ep.tx_free() > 1 || self.orphan.get().is_some() || self.card_job {
            let Some(p) = ep.peek() else { break };
            // A card request waits for the card (`card_service`).
            if is_card_request(p) {
                break;
            }
            // A job from the card takes no model or text from a host.
            use crate::protocol::msg::ty;
            let job_data =
                matches!(p.first(), Some(&(ty::TRIANGLES | ty::END_OF_MODEL | ty::GCODE)));
            if self.card_job && job_data && !self.card_record_at_head() {
                ep.pop();
                continue;
            }
            let emitting = self.is_active() && !self.gcode_job;
            if self.waiting_for_room && emitting && !self.emit_moves(motion) {
                break;
            }
            self.waiting_for_room = false;
            let starts = matches!(p.first(), Some(&(ty::JOB_START | ty::GCODE_START)));
            let fingerprint = if starts { job_fingerprint(p) } else { 0 };
            match Message::decode(p) {
                Ok(Message::Hello { .. }) => {
                    let caps = self.capacities();
                    let m = Message::Capabilities { version: VERSION, capacities: caps };
                    send(ep, &m);
                    self.greeted(now_ms);
                }
                Ok(m) => {
                    if self.handle_with(&m, motion, lend) == Accept::Busy {
                        self.waiting_for_room = true;
                        break;
                    }
                    if starts {
                        self.fingerprint = fingerprint;
                    }
                }
                Err(_) => {
                    let first_byte = p.first().copied().unwrap_or(0);
                    self.fail(Failure::BadMessage { first_byte });
                }
            }
            self.head_taken();
            ep.pop();
        }
    }

    /// A parked job's news to the host that said hello, once it parked (not inlined, as
    /// [`send_failure`](Self::send_failure)).
    #[inline(never)]
    fn send_parked<const TX: usize, const RX: usize>(&mut self, ep: &mut Endpoint<TX, RX>) {
        if !self.parked_due || ep.tx_free() <= 1 {
            return;
        }
        if let Some(parked) = self.parked_job() {
            self.parked_due = !send(ep, &Message::Parked(parked));
        }
    }

    /// The failure in words (`Message::Failure`), once, when the job failed. Never inlined:
    /// its text buffer is on the stack only while it runs, not in `service`'s frame (which is
    /// at the bottom of the deepest stack, a layer's computation).
    #[inline(never)]
    fn send_failure<const TX: usize, const RX: usize>(&mut self, ep: &mut Endpoint<TX, RX>) {
        let Some(failure) = self.failure.get().copied() else { return };
        if self.failure_sent || self.state != DeviceState::Failed || ep.tx_free() <= 1 {
            return;
        }
        let mut text = TextBuf::new();
        let _ = core::fmt::write(&mut text, format_args!("{failure}"));
        self.failure_sent = send(ep, &Message::Failure(text.as_str()));
    }
}

/// A completed layer's hash waiting to be reported, packed into 12 bytes (a `(u32, u64)` takes
/// 16: 32 bytes of RAM over the reports).
#[derive(Debug, Clone, Copy)]
struct LayerHash {
    layer: u32,
    hash: [u32; 2],
}

impl LayerHash {
    fn new(layer: u32, hash: u64) -> Self {
        Self { layer, hash: [hash as u32, (hash >> 32) as u32] }
    }

    fn get(self) -> (u32, u64) {
        (self.layer, u64::from(self.hash[0]) | u64::from(self.hash[1]) << 32)
    }
}

/// The motion half as the pipeline sees it while it computes a layer: each move goes into the
/// move buffer under the motion half's lock, and with `lend` each progress point feeds the
/// motion half (blocks only when `allowed`; inside a computation the toolpath stage is not
/// done). A planning error is left in place for the next [`Printer::poll`] to report.
struct Lending<'a, A, const MOVE_BYTES: usize, const P: usize, const Q: usize> {
    motion: &'a mut A,
    allowed: bool,
    lend: bool,
}

impl<
        A: MotionAccess<MOVE_BYTES, P, Q>,
        const MOVE_BYTES: usize,
        const P: usize,
        const Q: usize,
    > Computing for Lending<'_, A, MOVE_BYTES, P, Q>
{
    fn push_move(&mut self, mv: &PackedMove) -> Result<(), RingFull> {
        self.motion.with(|m, _| m.moves_mut().push(mv))
    }

    fn progress(&mut self) {
        if self.lend {
            let allowed = self.allowed;
            self.motion.with(|m, out| {
                let _ = m.feed(allowed, false, out);
            });
        }
    }
}

/// The motion half as a G-code job's input sees it: the move buffer, the generator's finished
/// blocks, whether the board has heaters, and the motion's gate (`allowed`; the text `ended`).
struct GcodeMotion<'a, A, const MOVE_BYTES: usize, const P: usize, const Q: usize> {
    motion: &'a mut A,
    heaters: bool,
    allowed: bool,
    ended: bool,
}

impl<
        A: MotionAccess<MOVE_BYTES, P, Q>,
        const MOVE_BYTES: usize,
        const P: usize,
        const Q: usize,
    > GcodeSink for GcodeMotion<'_, A, MOVE_BYTES, P, Q>
{
    fn push_move(&mut self, mv: &PackedMove) -> Result<(), RingFull> {
        self.motion.with(|m, _| m.moves_mut().push(mv))
    }

    fn blocks_done(&mut self) -> u32 {
        self.motion.with(|m, _| m.generator().blocks_done())
    }

    fn has_heaters(&self) -> bool {
        self.heaters
    }

    fn holding(&mut self, holds: bool) {
        self.motion.gate(self.allowed, self.ended || holds);
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

/// Text that fits a message after its type byte; what does not fit is cut at a character.
struct TextBuf {
    bytes: [u8; MAX_PAYLOAD - 1],
    len: usize,
}

impl TextBuf {
    fn new() -> Self {
        Self { bytes: [0; MAX_PAYLOAD - 1], len: 0 }
    }

    fn as_str(&self) -> &str {
        // Only whole characters are ever written.
        core::str::from_utf8(&self.bytes[..self.len]).unwrap_or("")
    }
}

impl core::fmt::Write for TextBuf {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        for c in s.chars() {
            let mut utf8 = [0u8; 4];
            let c = c.encode_utf8(&mut utf8).as_bytes();
            let Some(room) = self.bytes.get_mut(self.len..self.len + c.len()) else {
                return Err(core::fmt::Error);
            };
            room.copy_from_slice(c);
            self.len += c.len();
        }
        Ok(())
    }
}

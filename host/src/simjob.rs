//! The simulated printer.
//!
//! The device-side job runner (`strata::printer`), the step executor and the simulated board
//! (`strata::sim`), connected to a [`HostJob`] through an in-memory serial link, all on one virtual
//! clock.
//!
//! Every virtual millisecond: the host and the device exchange what the link carried (at the
//! baud rate, 10 bits per byte, through the seeded [`Faults`]), the device services its
//! endpoint and runs its pipeline, and the executor runs every timer event up to the end of
//! the millisecond on the board's 72 MHz clock. Streaming and printing overlap as on the real
//! printer, so an underrun means the link did not keep ahead of the print.

use std::collections::VecDeque;

use strata::geom::Triangle;
use strata::machine::{MachineConfig, AXES};
use strata::printer::board::LOOKAHEAD_MOVES;
use strata::printer::{MotionHalf, BOARD_CAPACITIES};
use strata::protocol::{
    Capacities, Endpoint, JobSpec, LinkConfig, Message, MAX_PAYLOAD, MAX_WIRE, VERSION,
};
use strata::sim::{SimBoard, SimTiming};
use strata::step::{is_before, Executor, StepQueue, Wake};
use strata::toolpath::ToolpathNeeds;

use crate::card_image::ImageCard;
use crate::preview::PathRecorder;
use crate::session::{HostEndpoint, HostJob, Phase, Source};

strata::printer_type! {
    /// The simulated device: host-sized buffers and the board's lookahead. What it
    /// announces, and so what admission holds a model to, is [`SimOptions::capacities`]: by
    /// default the 64 KB firmware build's (`BOARD_CAPACITIES`).
    pub type SimPrinter = {
        active_triangles: 1024,
        contour_points: 768,
        contour_loops: 48,
        toolpath_points: 1 << 15,
        toolpath_loops: 1 << 11,
        scan_crossings: 1 << 15,
        path_points: 1 << 17,
        window_ring_words: 1 << 17,
        window_spans: 1 << 16,
        move_buffer_bytes: SIM_MOVE_BYTES,
        lookahead_moves: LOOKAHEAD_MOVES,
    };
}

/// The simulated device's move buffer, bytes (room for any job's moves).
pub const SIM_MOVE_BYTES: usize = 1 << 17;

/// The simulated device's motion half (move buffer, planner, generator) and the step queue's
/// producer.
pub type SimMotion<'q, const N: usize> = MotionHalf<'q, SIM_MOVE_BYTES, LOOKAHEAD_MOVES, N>;
/// Device endpoint: 4 frames in flight, 4 receive slots (1.6 KB of payload).
pub type DeviceEndpoint = Endpoint<4, 4>;

const STACK_BYTES: usize = 512 << 20;
const STEP_QUEUE: usize = strata::printer::board::STEP_QUEUE_COMMANDS;

/// Seeded faults on each direction of the link.
#[derive(Debug, Clone, Copy, Default)]
pub struct Faults {
    /// Seed.
    pub seed: u64,
    /// Probability a whole frame is lost.
    pub drop_frame: f64,
    /// Probability a frame is sent twice.
    pub duplicate_frame: f64,
    /// Probability one byte of a frame is flipped.
    pub corrupt_frame: f64,
    /// Probability one byte of a frame is lost.
    pub drop_byte: f64,
    /// Probability a frame waits up to `max_delay_ms` longer (later frames wait behind it).
    pub delay_frame: f64,
    /// Longest extra delay, ms.
    pub max_delay_ms: u32,
    /// From this virtual time on, nothing gets through (a dead link).
    pub cut_at_ms: Option<u32>,
}

impl Faults {
    /// Every fault kind at `rate` (drop, corrupt, duplicate, byte loss, delay), seeded.
    pub fn uniform(rate: f64, seed: u64) -> Self {
        Self {
            seed,
            drop_frame: rate,
            duplicate_frame: rate,
            corrupt_frame: rate,
            drop_byte: rate,
            delay_frame: rate,
            max_delay_ms: 50,
            cut_at_ms: None,
        }
    }
}

/// Options of a simulated job.
#[derive(Debug, Clone, Copy)]
pub struct SimOptions {
    /// Link speed, baud (10 bits per byte).
    pub baud: u32,
    /// Faults on the link.
    pub faults: Faults,
    /// Capacities the device announces.
    pub capacities: Capacities,
    /// Give up after this much virtual time, ms.
    pub max_ms: u64,
    /// Check that every payload the device receives equals one the host sent, in order.
    pub check_delivery: bool,
    /// Record the nozzle path for a preview ([`SimReport::path`]).
    pub preview: bool,
    /// Record the motors' position at the end of every block ([`SimReport::block_ends`]).
    pub block_ends: bool,
    /// The device runs on after the host gave up (a dead link): until it has parked and its
    /// heaters have gone off ([`SimReport::parked_ms`], [`SimReport::heaters_off_ms`]).
    pub device_outlives_host: bool,
    /// How long an orphaned job's heaters hold their targets once parked, ms.
    pub heat_hold_ms: u32,
    /// With `device_outlives_host`: this long after the orphaned job parked, a new host
    /// opens a session on a sound link and resumes the job (`strata print --resume`).
    pub resume_after_ms: Option<u64>,
    /// At this virtual time a new host opens its own session on a sound link and starts the
    /// same job (another `strata print` on the same printer): the running job's host is gone,
    /// and what the device's link held for it is dropped.
    pub new_host_at_ms: Option<u64>,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            baud: 250_000,
            faults: Faults::default(),
            capacities: BOARD_CAPACITIES,
            max_ms: 48 * 3600 * 1000,
            check_delivery: false,
            preview: false,
            block_ends: false,
            device_outlives_host: false,
            heat_hold_ms: strata::printer::DEFAULT_HEAT_HOLD_MS,
            resume_after_ms: None,
            new_host_at_ms: None,
        }
    }
}

/// What a simulated job produced.
#[derive(Debug, Default)]
pub struct SimReport {
    /// Layers of the job.
    pub layers: u32,
    /// From the first step to the last, s.
    pub print_time_s: f64,
    /// Planner's estimate, s.
    pub planned_s: f64,
    /// Filament fed, mm.
    pub filament_mm: f64,
    /// Steps per axis X, Y, Z, E.
    pub steps: [u64; AXES],
    /// Final motor positions X, Y, Z, E, steps (from the start of the job).
    pub positions: [i64; AXES],
    /// From the first step to the last, timer ticks (`print_time_s` exactly).
    pub print_ticks: u64,
    /// Bound every step was checked against, us.
    pub max_step_error_us: f64,
    /// Steps outside the bound.
    pub step_check_failures: u32,
    /// Peak active triangles on the device.
    pub peak_active_triangles: u32,
    /// Peak contour points.
    pub peak_contour_points: u32,
    /// RAM the pipeline needs for this job (slicer at peak needs, toolpath needs, motion).
    pub device_ram_bytes: u64,
    /// Wire bytes per triangle (framing included).
    pub wire_bytes_per_triangle: f64,
    /// Per-layer hashes reported by the device.
    pub layer_hashes: Vec<u64>,
    /// The device's totals (`Message::JobReport`), as the host received them.
    pub job_report: Option<strata::protocol::JobReport>,
    /// The device's last status as the host saw it (state, planned and executed print time).
    pub status: Option<strata::protocol::Status>,
    /// Time from the start of the link to the first step, s (the first layer needs every
    /// triangle below its top layers).
    pub first_step_s: f64,
    /// Time the triangle frames alone take on the wire at the baud rate, s.
    pub wire_time_s: f64,
    /// Time until the last triangle was acknowledged, s.
    pub stream_time_s: f64,
    /// Executor underruns: the commands ran out mid-motion (the link or the pipeline fell
    /// behind a move the planner had to hold).
    pub underruns: u32,
    /// Executor starts (1 when motion never came to rest waiting for data).
    pub starts: u32,
    /// Driver timing violations on the board.
    pub violations: u32,
    /// The board's step hash (every step, with its tick relative to the first).
    pub board_hash: u64,
    /// Triangles sent.
    pub triangles: usize,
    /// Triangles the device took (a job from the card takes them with no host).
    pub device_triangles: u32,
    /// Host link counters: retransmits, bad frames, duplicates.
    pub host_link: strata::protocol::LinkStats,
    /// Device link counters.
    pub device_link: strata::protocol::LinkStats,
    /// Payloads the device received that the host never sent at that position.
    pub delivery_mismatches: u64,
    /// Virtual time at the end, ms.
    pub end_ms: u64,
    /// The nozzle path per layer (with [`SimOptions::preview`]).
    pub path: Option<PathRecorder>,
    /// The motor positions at the end of each block that moves a motor, as the generator
    /// starts it (with [`SimOptions::block_ends`]).
    pub block_ends: Vec<[i64; AXES]>,
    /// The device's state at the end.
    pub device_state: Option<strata::protocol::DeviceState>,
    /// Where an orphaned job's input ended (its host went silent).
    pub resume: Option<strata::printer::ResumePoint>,
    /// When an orphaned job had parked and paused, ms of virtual time.
    pub parked_ms: Option<u64>,
    /// When its heaters went off after that, ms of virtual time.
    pub heaters_off_ms: Option<u64>,
    /// The layer hashes the host that went silent had received (index = layer; 0: none),
    /// when a new host resumed the job ([`SimOptions::resume_after_ms`]); `layer_hashes`
    /// are then the new host's.
    pub first_host_hashes: Option<Vec<u64>>,
}

impl SimReport {
    /// Times the print came to a stop (at a rest point of its plan) waiting for commands:
    /// the link fell behind without an underrun.
    pub fn rest_waits(&self) -> u32 {
        self.starts.saturating_sub(1)
    }
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && ((self.next() >> 11) as f64 / (1u64 << 53) as f64) < p
    }
    fn below(&mut self, n: u64) -> u64 {
        if n == 0 {
            0
        } else {
            self.next() % n
        }
    }
}

/// One direction of the link.
///
/// Frames wait in a transmit queue, leave at the baud rate, suffer the faults and arrive after
/// their delay. Also used by the fault-injecting relay of the hardware-in-the-loop test
/// (`hil::Relay`) on a wall-clock millisecond.
pub struct Wire {
    faults: Faults,
    rng: Rng,
    bytes_per_ms: f64,
    budget: f64,
    /// Bytes waiting for the UART, each with the earliest time it may leave.
    tx: VecDeque<(u64, u8)>,
    /// Bytes that left this millisecond.
    arrived: Vec<u8>,
}

impl Wire {
    /// A wire at `baud` (10 bits per byte) with `faults`; `salt` tells the directions apart.
    pub fn new(faults: Faults, salt: u64, baud: u32) -> Self {
        Self {
            faults,
            rng: Rng(faults.seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ salt | 1),
            bytes_per_ms: baud as f64 / 10.0 / 1000.0,
            budget: 0.0,
            tx: VecDeque::new(),
            arrived: Vec::new(),
        }
    }

    /// Queues one encoded frame (delimiter included), applying the faults.
    pub fn send_frame(&mut self, now_ms: u64, frame: &[u8]) {
        let f = self.faults;
        if self.rng.chance(f.drop_frame) {
            return;
        }
        let mut bytes = frame.to_vec();
        if self.rng.chance(f.corrupt_frame) {
            let i = self.rng.below(bytes.len() as u64) as usize;
            bytes[i] ^= 1 << self.rng.below(8);
        }
        if self.rng.chance(f.drop_byte) {
            let i = self.rng.below(bytes.len() as u64) as usize;
            bytes.remove(i);
        }
        let copies = if self.rng.chance(f.duplicate_frame) { 2 } else { 1 };
        let at = if self.rng.chance(f.delay_frame) {
            now_ms + 1 + self.rng.below(f.max_delay_ms as u64)
        } else {
            now_ms
        };
        for _ in 0..copies {
            self.tx.extend(bytes.iter().map(|&b| (at, b)));
        }
    }

    /// Bytes that arrived in the last [`Wire::tick`].
    pub fn arrived(&self) -> &[u8] {
        &self.arrived
    }

    /// Moves one millisecond's worth of bytes (call once per millisecond, in order).
    pub fn tick(&mut self, now_ms: u64) {
        self.arrived.clear();
        self.budget = (self.budget + self.bytes_per_ms).min(self.bytes_per_ms * 2.0);
        let cut = self.faults.cut_at_ms.is_some_and(|c| now_ms >= c as u64);
        while self.budget >= 1.0 {
            match self.tx.front() {
                Some(&(at, b)) if at <= now_ms => {
                    self.tx.pop_front();
                    self.budget -= 1.0;
                    if !cut {
                        self.arrived.push(b);
                    }
                }
                _ => break,
            }
        }
        if self.tx.is_empty() {
            self.budget = self.budget.min(1.0);
        }
    }
}

/// Runs the job through the simulated printer on a thread with a large stack.
pub fn simulate(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: JobSpec,
    opts: &SimOptions,
) -> Result<SimReport, (String, Box<SimReport>)> {
    simulate_source(Source::Model(tris, job), machine, opts)
}

/// Runs a job of a model or of G-code ([`Source`]) through the simulated printer on a thread
/// with a large stack.
pub fn simulate_source(
    source: Source<'_>,
    machine: &MachineConfig,
    opts: &SimOptions,
) -> Result<SimReport, (String, Box<SimReport>)> {
    simulate_with_card(source, machine, opts, None)
}

/// [`simulate_source`] on a printer with `card` in its slot (a [`Source::Card`] job prints
/// from it).
pub fn simulate_with_card(
    source: Source<'_>,
    machine: &MachineConfig,
    opts: &SimOptions,
    card: Option<ImageCard>,
) -> Result<SimReport, (String, Box<SimReport>)> {
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("simulated-printer".into())
            .stack_size(STACK_BYTES)
            .spawn_scoped(scope, || run(source, machine, opts, card))
            .expect("cannot start the simulation thread")
            .join()
            .unwrap_or_else(|_| Err(("the simulation panicked".into(), Box::default())))
    })
}

fn run(
    source: Source<'_>,
    machine: &MachineConfig,
    opts: &SimOptions,
    mut card: Option<ImageCard>,
) -> Result<SimReport, (String, Box<SimReport>)> {
    let mut printer: Box<SimPrinter> = Box::new(SimPrinter::new(machine));
    printer.set_offset_limit(opts.capacities.toolpath_points as usize);
    let caps = &opts.capacities;
    printer.set_bridge_limits(caps.path_points as usize, caps.scan_crossings as usize);
    let step_cfg = *printer.step_config();
    let timer_hz = step_cfg.timer_hz as u64;
    let ticks_per_ms = timer_hz / 1000;
    let start_tick = 1_000u64;
    let board = SimBoard::new(
        SimTiming::from_config(&step_cfg),
        start_tick,
        PathRecorder::new(opts.preview),
    );
    let mut pins = board.pins();
    let mut queue: StepQueue<STEP_QUEUE> = StepQueue::new();
    let (prod, cons) = queue.split();
    let mut exec = Executor::new(&step_cfg, cons);
    let mut motion: Box<SimMotion<'_, STEP_QUEUE>> = Box::new(MotionHalf::new(prod));

    let mut host_ep: HostEndpoint = Endpoint::new(LinkConfig::default());
    host_ep.open(1);
    let mut dev_ep: DeviceEndpoint = Endpoint::new(LinkConfig::device());
    let mut host = HostJob::of(source);
    if opts.check_delivery {
        host.sent_log = Some(Vec::new());
    }
    let mut h2d = Wire::new(opts.faults, 1, opts.baud);
    let mut d2h = Wire::new(opts.faults, 2, opts.baud);
    let mut frame = [0u8; MAX_WIRE];
    let mut next_wake: Option<u32> = None;
    let mut first_step: Option<u64> = None;
    let mut checked = 0usize;
    let mut rep = SimReport::default();
    let mut outcome: Result<(), String> = Ok(());
    let mut now_ms: u64 = 0;
    let mut done_at: Option<u64> = None;
    let mut block_ends = opts.block_ends.then(Vec::new);
    let mut host_gone = false;
    printer.set_heat_hold_ms(opts.heat_hold_ms);

    loop {
        now_ms += 1;
        let t = now_ms as u32;
        // Link: bytes of this millisecond arrive.
        h2d.tick(now_ms);
        d2h.tick(now_ms);
        host_ep.receive(&d2h.arrived, t);
        let before = dev_ep.rx_len();
        dev_ep.receive(&h2d.arrived, t);
        if let Some(log) = &host.sent_log {
            for i in before..dev_ep.rx_len() {
                let got = dev_ep.get(i).unwrap_or(&[]);
                if log.get(checked).map(Vec::as_slice) != Some(got) {
                    rep.delivery_mismatches += 1;
                }
                checked += 1;
            }
        }
        if opts.new_host_at_ms == Some(now_ms) {
            host_ep = Endpoint::new(LinkConfig::default());
            host_ep.open(2);
            host = HostJob::of(source);
            h2d = Wire::new(Faults::default(), 3, opts.baud);
            d2h = Wire::new(Faults::default(), 4, opts.baud);
        }
        // Host.
        let polled = if host_gone { Ok(Phase::Printing) } else { host.poll(t, &mut host_ep) };
        match polled {
            Ok(Phase::Done) if done_at.is_none() => done_at = Some(now_ms),
            Ok(_) => {}
            Err(e) if opts.device_outlives_host => {
                outcome = Err(e);
                host_gone = true;
            }
            Err(e) => {
                outcome = Err(e);
                break;
            }
        }
        loop {
            let n = host_ep.poll_transmit(t, &mut frame);
            if n == 0 {
                break;
            }
            h2d.send_frame(now_ms, &frame[..n]);
        }
        // Device.
        let done_ms = first_step.map_or(0, |f| ((board.now() - f) / ticks_per_ms) as u32);
        announce_posed(&opts.capacities, &mut dev_ep, &mut printer, t);
        device_turn(
            &mut printer,
            &mut dev_ep,
            &mut motion,
            &mut block_ends,
            card.as_mut(),
            t,
            done_ms,
            500,
            |f| d2h.send_frame(now_ms, f),
        );
        // Motion up to the end of this millisecond.
        let end_tick = start_tick + now_ms * ticks_per_ms;
        let stopped = printer.state() == strata::protocol::DeviceState::Stopped;
        if !stopped {
            if next_wake.is_none() {
                next_wake = wake(exec.on_timer(board.now_u32(), &mut pins));
                if first_step.is_none() && !exec.is_idle() {
                    // Step ticks are hashed relative to the start of motion.
                    first_step = Some(board.now());
                    board.set_hash_origin(board.now());
                }
            }
            while let Some(w) = next_wake {
                if !is_before(w, end_tick as u32) && w != end_tick as u32 {
                    break;
                }
                board.advance_to_u32(w);
                if first_step.is_none() && !exec.is_idle() {
                    first_step = Some(board.now());
                }
                next_wake = wake(exec.on_timer(board.now_u32(), &mut pins));
                printer.poll(&mut *motion);
                note_block_end(&mut block_ends, &motion.motion);
            }
        }
        board.advance_to(end_tick.max(board.now()));
        if done_at.is_some() && exec.is_idle() && printer.motion_finished() {
            break;
        }
        if host_gone {
            let paused = printer.state() == strata::protocol::DeviceState::Paused;
            if paused && rep.parked_ms.is_none() {
                rep.parked_ms = Some(now_ms);
                rep.resume = rep.resume.or(printer.resume_point());
            }
            if paused && printer.heater_targets() == (0, 0) {
                rep.heaters_off_ms = Some(now_ms);
            }
            let resume_at = opts.resume_after_ms.zip(rep.parked_ms).map(|(a, p)| a + p);
            if resume_at.is_some_and(|at| now_ms >= at) && rep.first_host_hashes.is_none() {
                // A new host on a sound link, resuming the job.
                rep.first_host_hashes = Some(std::mem::take(&mut host.progress.layer_hashes));
                host_ep = Endpoint::new(LinkConfig::default());
                host_ep.open(2);
                host = HostJob::of(source).resuming();
                h2d = Wire::new(Faults::default(), 3, opts.baud);
                d2h = Wire::new(Faults::default(), 4, opts.baud);
                host_gone = false;
                outcome = Ok(());
            } else if resume_at.is_none()
                && (!printer.is_active() || rep.heaters_off_ms.is_some())
                && exec.is_idle()
            {
                break;
            }
        }
        if now_ms >= opts.max_ms {
            if !host_gone {
                outcome = Err(format!("the job did not finish within {} s", opts.max_ms / 1000));
            }
            break;
        }
    }
    let gen = motion.motion.generator().stats();
    let tp = printer.toolpath().stats();
    let slice = *printer.slicer().stats();
    rep.layers = printer.layer_count();
    rep.end_ms = now_ms;
    rep.steps = board.axes().map(|a| a.steps);
    rep.positions = board.positions();
    rep.first_step_s = first_step.map_or(0.0, |f| (f - start_tick) as f64 / timer_hz as f64);
    rep.print_ticks = match (first_step, last_step_tick(&board)) {
        (Some(f), Some(l)) => l - f,
        _ => 0,
    };
    rep.print_time_s = rep.print_ticks as f64 / timer_hz as f64;
    rep.planned_s = printer.planned_s(&mut *motion);
    rep.filament_mm = match source {
        Source::Model(..) => tp.filament_um as f64 / 1000.0,
        Source::Gcode(..) | Source::Card { .. } => {
            rep.positions[3] as f64 / machine.steps_per_mm[3].to_num::<f64>()
        }
    };
    rep.block_ends = block_ends.unwrap_or_default();
    rep.device_state = Some(printer.state());
    rep.resume = rep.resume.or(printer.resume_point());
    rep.max_step_error_us = step_cfg.max_error_ticks as f64 * 1e6 / timer_hz as f64;
    rep.step_check_failures = gen.check_failures;
    rep.peak_active_triangles = slice.peak_active;
    rep.peak_contour_points = slice.peak_points;
    rep.device_ram_bytes = device_ram(&slice, &tp.needs);
    rep.triangles = host.progress.triangles_sent;
    rep.device_triangles = printer.status(&mut *motion, 0).triangles;
    rep.wire_bytes_per_triangle = if rep.triangles > 0 {
        host.progress.triangle_wire_bytes as f64 / rep.triangles as f64
    } else {
        0.0
    };
    rep.wire_time_s = host.progress.triangle_wire_bytes as f64 * 10.0 / opts.baud as f64;
    rep.layer_hashes = host.progress.layer_hashes.clone();
    rep.job_report = host.progress.job_report;
    rep.status = host.progress.status;
    rep.stream_time_s = host.progress.stream_done_ms.map_or(0.0, |m| m as f64 / 1000.0);
    rep.underruns = exec.stats().underruns;
    rep.starts = exec.stats().starts;
    rep.violations = board.violation_count();
    rep.board_hash = board.step_hash();
    rep.host_link = *host_ep.stats();
    rep.device_link = *dev_ep.stats();
    if opts.preview {
        rep.path = Some(board.into_observer());
    }
    match outcome {
        Ok(()) => Ok(rep),
        Err(e) => Err((e, Box::new(rep))),
    }
}

fn wake(w: Result<Wake, core::convert::Infallible>) -> Option<u32> {
    match w {
        Ok(Wake::At(t)) => Some(t),
        _ => None,
    }
}

fn last_step_tick<O: strata::sim::EdgeObserver>(board: &SimBoard<O>) -> Option<u64> {
    board.axes().iter().filter_map(|a| a.last_rise).max()
}

/// Answers the `Hello`s at the head of the link with `capacities`: a simulated printer posing
/// as another device announces that device's capacities (the printer would announce its
/// own; its offset engine bands as that device's does: [`SimPrinter::set_offset_limit`]).
pub(crate) fn announce_posed(
    capacities: &Capacities,
    ep: &mut DeviceEndpoint,
    printer: &mut SimPrinter,
    now_ms: u32,
) {
    while ep.tx_free() > 1 {
        let Some(p) = ep.peek() else { break };
        if !matches!(Message::decode(p), Ok(Message::Hello { .. })) {
            break;
        }
        let mut buf = [0u8; MAX_PAYLOAD];
        let m = Message::Capabilities { version: VERSION, capacities: *capacities };
        if let Ok(n) = m.encode(&mut buf) {
            let _ = ep.send(&buf[..n]);
        }
        printer.greeted(now_ms);
        ep.pop();
    }
}

/// One turn of a device's main loop (as the firmware's): the link's messages into the job
/// runner (status every `status_every_ms`; steps generated at the toolpath stage's progress
/// points as the firmware does), its card's requests and a job from it (`card`: the slot's
/// card, if any), up to 64 bounded `poll`s into the step queue, then every
/// frame due out through `send`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn device_turn<const N: usize>(
    printer: &mut SimPrinter,
    ep: &mut DeviceEndpoint,
    motion: &mut SimMotion<'_, N>,
    block_ends: &mut Option<Vec<[i64; AXES]>>,
    card: Option<&mut ImageCard>,
    now_ms: u32,
    done_ms: u32,
    status_every_ms: u32,
    mut send: impl FnMut(&[u8]),
) {
    printer.service(ep, motion, now_ms, done_ms, status_every_ms, true);
    if printer.wants_card(ep) {
        printer.card_service(ep, card, motion);
    }
    for _ in 0..64 {
        let worked = printer.poll(motion);
        note_block_end(block_ends, &motion.motion);
        if !worked {
            break;
        }
    }
    let mut frame = [0u8; MAX_WIRE];
    loop {
        let n = ep.poll_transmit(now_ms, &mut frame);
        if n == 0 {
            break;
        }
        send(&frame[..n]);
    }
}

/// The generator's motor positions when they changed (into `ends`, when recording): it sets
/// them to a block's end as it starts the block, and starts at most one per `feed` (it holds
/// one block waiting), so each change is one block's end.
fn note_block_end<const M: usize, const P: usize>(
    ends: &mut Option<Vec<[i64; AXES]>>,
    motion: &strata::printer::Motion<M, P>,
) {
    if let Some(ends) = ends {
        let motor = motion.generator().motor_steps();
        if ends.last().unwrap_or(&[0; AXES]) != &motor {
            ends.push(motor);
        }
    }
}

/// RAM of a device pipeline sized exactly to this job's needs.
///
/// Slicer, toolpath stage and the scratch they take turns in (the slicer's cut and the layer's
/// points, or the toolpath stage's engine and infill scratch, the largest), planner and step
/// generator and queues (12 KB, the motion test's bound).
pub fn device_ram(slice: &strata::slice::SliceStats, needs: &ToolpathNeeds) -> u64 {
    let slicer = strata::slice::slicer_bytes(slice.peak_active as usize, slice.peak_loops as usize);
    // `SEGMENTS` bounds a layer's segments and its points (repairs may add points).
    let segments = slice.peak_segments.max(slice.peak_points) as usize;
    let cut = strata::scratch::bytes(segments, 0, 0);
    (slicer + needs.stage_bytes() + cut.max(needs.work_bytes())) as u64 + 12 * 1024
}

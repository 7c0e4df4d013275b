//! The main loop shared by every board (the firmware twin of the host's `serve_device`):
//! UART bytes into the protocol endpoint, `Printer::service`, bounded `Printer::poll` into the
//! step queue, frames back out; the executor runs in the board's timer interrupt, planning and
//! step generation also in the feed interrupt below it (`pipeline_motion`).

use strata::machine::{MachineConfig, AXES};
use strata::protocol::{DeviceState, Message, MAX_WIRE};
use strata::step::StepConfig;

use crate::board::{self, Board};
use crate::capacities::{FwEndpoint, FwPrinter, POLLS_PER_LOOP, STATUS_EVERY_MS};
use crate::pipeline_motion::{FwMotion, FwMotionHalf};
use crate::{heat, log, stack};

/// The stock Ender-3 (DESIGN §3).
pub const MACHINE: MachineConfig = MachineConfig::ENDER3;

/// Soft limits: the generator's motor positions (which lead the executor by the whole step
/// queue) must stay inside the build volume plus this margin, mm.
const SOFT_LIMIT_MARGIN_MM: i64 = 1;

/// The axis (and its position in steps) outside the soft limits, if any.
fn soft_limit(machine: &MachineConfig, motor: [i64; AXES]) -> Option<(usize, i64)> {
    (0..3).find_map(|a| {
        let spm = machine.steps_per_mm[a].to_num::<i64>();
        let lo = -SOFT_LIMIT_MARGIN_MM * spm;
        let hi = (machine.build_volume_um[a] as i64 / 1000 + SOFT_LIMIT_MARGIN_MM) * spm;
        (motor[a] < lo || motor[a] > hi).then_some((a, motor[a]))
    })
}

/// Thread mode's phases for the QEMU board's underrun report (`board::set_phase`): other
/// work, a `service` call (slicing, toolpaths), `poll` calls (planning, step generation).
#[cfg(feature = "qemu")]
const PHASE_OTHER: u32 = 0;
#[cfg(feature = "qemu")]
const PHASE_SERVICE: u32 = 1;
#[cfg(feature = "qemu")]
const PHASE_POLL: u32 = 2;

/// UART bytes into the endpoint. Not inlined: its buffer is on the stack only here, not
/// under the printer's deepest calls.
#[inline(never)]
fn receive(board: &mut Board, ep: &mut FwEndpoint, now: u32) {
    let mut rx = [0u8; 64];
    let n = board.read(&mut rx);
    ep.receive(&rx[..n], now);
}

/// The endpoint's frames out on the UART. Not inlined: its `MAX_WIRE` (414 B) buffer is on the
/// stack only here, not under the printer's deepest calls.
#[inline(never)]
fn transmit(board: &mut Board, ep: &mut FwEndpoint, now: u32) {
    let mut frame = [0u8; MAX_WIRE];
    loop {
        let n = ep.poll_transmit(now, &mut frame);
        if n == 0 {
            break;
        }
        board.write(&frame[..n]);
    }
}

/// The main loop's state: the board, the printer and its motion half, the link, the heaters.
struct MainLoop {
    board: Board,
    printer: &'static mut FwPrinter,
    motion: FwMotion,
    ep: &'static mut FwEndpoint,
    heat: heat::Heat,
    cfg: StepConfig,
    /// The printer's state after the last turn.
    state: DeviceState,
    /// A job's opening lines were printed and its closing ones not yet.
    job_open: bool,
    #[cfg(feature = "qemu")]
    cost: crate::cost::Cost,
    /// When the last heartbeat was printed, ms.
    #[cfg(feature = "qemu")]
    hb_ms: u32,
}

/// Runs the printer forever.
pub fn run(
    board: Board,
    printer: &'static mut FwPrinter,
    half: &'static mut FwMotionHalf,
    ep: &'static mut FwEndpoint,
) -> ! {
    let mut main = MainLoop::new(board, printer, half, ep);
    loop {
        main.turn();
    }
}

impl MainLoop {
    /// The loop's state at boot (the step queue set up, the boot lines printed). Not inlined:
    /// its temporaries (a fresh step queue's halves) stay out of `run`'s frame.
    #[inline(never)]
    fn new(
        mut board: Board,
        printer: &'static mut FwPrinter,
        half: &'static mut FwMotionHalf,
        ep: &'static mut FwEndpoint,
    ) -> Self {
        let cfg = board::executor_config(printer.step_config());
        let motion = FwMotion::new(half, &cfg);
        log!(
            "strata firmware: printer {} B, endpoint {} B, step queue {} cmds/axis",
            core::mem::size_of::<FwPrinter>() as u32,
            core::mem::size_of::<FwEndpoint>() as u32,
            crate::capacities::STEP_QUEUE as u32
        );
        board::card_report(&mut board);
        let (used, size) = stack::high_water();
        log!("BOOT stack_used={} stack_size={}", used, size);
        let heat = heat::Heat::new(board.now_ms());
        let state = printer.state();
        MainLoop {
            board,
            printer,
            motion,
            ep,
            heat,
            cfg,
            state,
            job_open: false,
            #[cfg(feature = "qemu")]
            cost: crate::cost::Cost::new(),
            #[cfg(feature = "qemu")]
            hb_ms: 0,
        }
    }

    /// One turn: bytes in, messages handled, heaters, state changes, motion, frames out.
    /// The parts off the deepest stack (a layer's computation inside `serve`) are not inlined,
    /// so their locals stay out of the frames under it.
    #[inline(never)]
    fn turn(&mut self) {
        let now = self.board.now_ms();
        #[cfg(feature = "qemu")]
        self.heartbeat(now);
        receive(&mut self.board, self.ep, now);
        self.serve(now);
        if self.printer.wants_card(self.ep) {
            self.card();
        }
        self.heaters(now);
        let new = self.printer.state();
        if new != self.state {
            self.state_changed(new, now);
        }
        if self.printer.is_active() && !board::with_motion(|m| m.homing()) {
            self.advance();
        }
        if let Some(missed) = board::with_motion(|m| m.take_homed()) {
            log!("HOMED missed_endstops={}", (missed & 7) as u32);
        }
        let finished = self.printer.motion_finished() || !self.printer.is_active();
        let paused = self.printer.state() == DeviceState::Paused;
        // The interrupt's wait at the horizon before the generator runs once more: see
        // `board::after_poll`.
        let waiting = board::waiting();
        self.motion.peek_fed(|m, prod| {
            let gen_blocked = m.generator().waits_on_a_full_queue();
            board::after_poll(prod, finished, paused, gen_blocked, waiting);
        });
        transmit(&mut self.board, self.ep, now);
        if self.job_open {
            self.close_job_when_over();
        }
    }

    /// A heartbeat line every second of a job (QEMU).
    #[cfg(feature = "qemu")]
    #[inline(never)]
    fn heartbeat(&mut self, now: u32) {
        if now.wrapping_sub(self.hb_ms) < 1000 || !self.job_open {
            return;
        }
        self.hb_ms = now;
        self.motion.peek(|_, prod| board::heartbeat(prod));
        let status = self.printer.status(&mut self.motion, 0);
        log!(
            "HB state={} layer={} triangles={}",
            self.printer.state() as u32,
            status.layer,
            status.triangles
        );
    }

    /// One `service` call. Never inlined: its frame is at the bottom of the deepest stack.
    #[inline(never)]
    fn serve(&mut self, now: u32) {
        let done_ms = board::print_done_ms();
        #[cfg(feature = "qemu")]
        board::set_phase(PHASE_SERVICE, self.printer.slicer().stats().layers);
        #[cfg(feature = "qemu")]
        let t0 =
            self.cost.begin(self.ep.peek().is_some(), self.printer, &mut self.motion.generation);
        // No lending: the feed interrupt (PendSV) generates steps while a layer's toolpaths
        // take half a second (`pipeline_motion`).
        self.printer.service(self.ep, &mut self.motion, now, done_ms, STATUS_EVERY_MS, false);
        #[cfg(feature = "qemu")]
        self.cost.end_service(t0, self.printer, &mut self.motion);
        #[cfg(feature = "qemu")]
        board::set_phase(PHASE_OTHER, 0);
    }

    /// The card's requests and a job from the card ([`strata::printer::Printer::card_service`]),
    /// beside `serve`: the card's code and buffer stay off the deepest stack.
    #[inline(never)]
    fn card(&mut self) {
        let card = self.board.card();
        self.printer.card_service(self.ep, card, &mut self.motion);
    }

    /// Heaters (10 Hz): a fault turns everything off in the controller at once; here the
    /// motion stops as for an emergency stop and the job fails.
    #[inline(never)]
    fn heaters(&mut self, now: u32) {
        if let Some(fault) = self.heat.service(&mut self.board, self.printer, &mut self.motion, now)
        {
            self.motion.reset_queue(&self.cfg);
            self.printer.thermal_fault(fault.code(), &mut self.motion);
        }
    }

    /// The printer went from `self.state` to `new`.
    #[inline(never)]
    fn state_changed(&mut self, new: DeviceState, now: u32) {
        let was_active = matches!(self.state, DeviceState::Printing | DeviceState::Paused);
        match new {
            DeviceState::Printing if !was_active => {
                // A new job: clean queue, home X/Y/Z before the first step. Its steps
                // generated before (dropped with the queue) would be lost motion: counted.
                let early: u64 = self.motion.peek(|m, _| m.generator().stats().steps.iter().sum());
                self.motion.reset_queue(&self.cfg);
                board::with_motion(|m| m.start_homing(&MACHINE));
                board::job_started();
                self.heat.job_started(now);
                #[cfg(feature = "qemu")]
                self.cost.job_started();
                self.job_open = true;
                log!("JOB start layers={} early_steps={}", self.printer.layer_count(), early);
            }
            DeviceState::Stopped | DeviceState::Aborted | DeviceState::Failed => {
                // Emergency stop (and abort, failure): no further step, queue cleared,
                // drivers off at once.
                self.motion.reset_queue(&self.cfg);
                if !was_active && !self.job_open {
                    // A job refused or failed within the call that started it: it still
                    // gets its closing lines.
                    board::job_started();
                    #[cfg(feature = "qemu")]
                    self.cost.job_started();
                    self.job_open = true;
                }
            }
            _ => {}
        }
        self.state = new;
    }

    /// Bounded `poll` calls into the step queue, then the soft limits.
    #[inline(never)]
    fn advance(&mut self) {
        #[cfg(feature = "qemu")]
        board::set_phase(PHASE_POLL, self.printer.slicer().stats().layers);
        for _ in 0..POLLS_PER_LOOP {
            #[cfg(feature = "qemu")]
            let t = self.cost.begin_poll();
            let worked = self.printer.poll(&mut self.motion);
            #[cfg(feature = "qemu")]
            self.cost.end_poll(t, worked, self.printer, &mut self.motion);
            if !worked {
                break;
            }
        }
        #[cfg(feature = "qemu")]
        board::set_phase(PHASE_OTHER, 0);
        board::kick();
        let motor = self.motion.peek(|m, _| m.generator().motor_steps());
        if let Some((axis, pos)) = soft_limit(&MACHINE, motor) {
            log!("SOFT LIMIT axis={} steps={}: job aborted", axis as u32, pos);
            self.motion.reset_queue(&self.cfg);
            self.printer.handle(&Message::Abort, &mut self.motion);
        }
    }

    /// The job's closing lines once it is over (done and every step out, or ended).
    #[inline(never)]
    fn close_job_when_over(&mut self) {
        let finished = match self.printer.state() {
            DeviceState::Done => !board::with_motion(|m| m.busy()),
            DeviceState::Failed | DeviceState::Aborted | DeviceState::Stopped => true,
            _ => false,
        };
        if !finished {
            return;
        }
        self.job_open = false;
        board::with_motion(|m| m.disable_if_idle());
        let (err, detail) = self.printer.error();
        log!(
            "JOB end state={} error={} detail={} triangles={} layers={}",
            self.printer.state() as u32,
            err as u32,
            detail,
            self.printer.status(&mut self.motion, 0).triangles,
            self.printer.layer_count()
        );
        #[cfg(feature = "qemu")]
        self.cost.job_ended(self.printer, &mut self.motion);
        board::job_ended();
        self.heat.job_ended();
        let (used, size) = stack::high_water();
        log!("MEM data_bss={} stack_hwm={} stack_size={}", stack::data_bss(), used, size);
    }
}

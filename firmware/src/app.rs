//! The main loop shared by every board (the firmware twin of the host's `serve_device`):
//! UART bytes into the protocol endpoint, `Printer::service`, bounded `Printer::poll` into the
//! step queue, frames back out; the executor runs in the board's timer interrupt.

use strata::machine::{MachineConfig, AXES};
use strata::protocol::{DeviceState, Message, MAX_WIRE};

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

/// Runs the printer forever.
pub fn run(
    mut board: Board,
    printer: &'static mut FwPrinter,
    half: &'static mut FwMotionHalf,
    ep: &'static mut FwEndpoint,
) -> ! {
    let cfg = board::executor_config(printer.step_config());
    let mut motion = FwMotion::new(half, &cfg);
    log!(
        "strata firmware: printer {} B, endpoint {} B, step queue {} cmds/axis",
        core::mem::size_of::<FwPrinter>() as u32,
        core::mem::size_of::<FwEndpoint>() as u32,
        crate::capacities::STEP_QUEUE as u32
    );
    let (used, size) = stack::high_water();
    log!("BOOT stack_used={} stack_size={}", used, size);
    let mut heat = heat::Heat::new(board.now_ms());
    let mut state = printer.state();
    let mut job_open = false;
    #[cfg(feature = "qemu")]
    let mut cost = crate::cost::Cost::new();
    #[cfg(feature = "qemu")]
    let mut hb_ms = 0u32;
    loop {
        let now = board.now_ms();
        #[cfg(feature = "qemu")]
        if now.wrapping_sub(hb_ms) >= 1000 && job_open {
            hb_ms = now;
            board::heartbeat(motion.producer());
            let status = printer.status(&mut motion, 0);
            log!(
                "HB state={} layer={} triangles={}",
                printer.state() as u32,
                status.layer,
                status.triangles
            );
        }
        receive(&mut board, ep, now);
        let done_ms = board::print_done_ms();
        #[cfg(feature = "qemu")]
        let t0 = cost.begin(ep.peek().is_some(), printer, &mut motion.generation);
        // Inside a layer's computation the printer lends its motion half: steps keep being
        // generated while the toolpaths of a large layer take half a second.
        printer.service(ep, &mut motion, now, done_ms, STATUS_EVERY_MS, true);
        #[cfg(feature = "qemu")]
        cost.end_service(t0, printer, &mut motion);
        // Heaters (10 Hz): a fault turns everything off in the controller at once; here the
        // motion stops as for an emergency stop and the job fails.
        if let Some(fault) = heat.service(&mut board, printer, &mut motion, now) {
            motion.reset_queue(&cfg);
            printer.thermal_fault(fault.code(), &mut motion);
        }

        let new = printer.state();
        if new != state {
            let was_active = matches!(state, DeviceState::Printing | DeviceState::Paused);
            match new {
                DeviceState::Printing if !was_active => {
                    // A new job: clean queue, home X/Y/Z before the first step.
                    motion.reset_queue(&cfg);
                    board::with_motion(|m| m.start_homing(&MACHINE));
                    board::job_started();
                    heat.job_started(now);
                    #[cfg(feature = "qemu")]
                    cost.job_started();
                    job_open = true;
                    log!("JOB start layers={}", printer.layer_count());
                }
                DeviceState::Stopped | DeviceState::Aborted | DeviceState::Failed => {
                    // Emergency stop (and abort, failure): no further step, queue cleared,
                    // drivers off at once.
                    motion.reset_queue(&cfg);
                    if !was_active && !job_open {
                        // A job refused or failed within the call that started it: it still
                        // gets its closing lines.
                        board::job_started();
                        #[cfg(feature = "qemu")]
                        cost.job_started();
                        job_open = true;
                    }
                }
                _ => {}
            }
            state = new;
        }

        if printer.is_active() && !board::with_motion(|m| m.homing()) {
            for _ in 0..POLLS_PER_LOOP {
                #[cfg(feature = "qemu")]
                let t = cost.begin_poll();
                let worked = printer.poll(&mut motion);
                #[cfg(feature = "qemu")]
                cost.end_poll(t, worked, printer, &mut motion);
                if !worked {
                    break;
                }
            }
            board::kick();
            let motor = motion.half().generator().motor_steps();
            if let Some((axis, pos)) = soft_limit(&MACHINE, motor) {
                log!("SOFT LIMIT axis={} steps={}: job aborted", axis as u32, pos);
                motion.reset_queue(&cfg);
                printer.handle(&Message::Abort, &mut motion);
            }
        }
        if let Some(missed) = board::with_motion(|m| m.take_homed()) {
            log!("HOMED missed_endstops={}", (missed & 7) as u32);
        }
        {
            let finished = printer.motion_finished() || !printer.is_active();
            let gen_blocked = motion.half().generator().waits_on_a_full_queue();
            let paused = printer.state() == DeviceState::Paused;
            board::after_poll(motion.producer(), finished, paused, gen_blocked);
        }

        transmit(&mut board, ep, now);

        if job_open {
            let finished = match printer.state() {
                DeviceState::Done => !board::with_motion(|m| m.busy()),
                DeviceState::Failed | DeviceState::Aborted | DeviceState::Stopped => true,
                _ => false,
            };
            if finished {
                job_open = false;
                board::with_motion(|m| m.disable_if_idle());
                let (err, detail) = printer.error();
                log!(
                    "JOB end state={} error={} detail={} triangles={} layers={}",
                    printer.state() as u32,
                    err as u32,
                    detail,
                    printer.status(&mut motion, 0).triangles,
                    printer.layer_count()
                );
                #[cfg(feature = "qemu")]
                cost.job_ended(printer, &mut motion);
                board::job_ended();
                heat.job_ended();
                let (used, size) = stack::high_water();
                log!("MEM data_bss={} stack_hwm={} stack_size={}", stack::data_bss(), used, size);
            }
        }
    }
}

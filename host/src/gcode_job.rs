//! A G-code file through the printer's motion half on the host.
//!
//! The core's G-code reader ([`strata::gcode::read`]), the move buffer, the planner, the step
//! generator and the step executor on a simulated board, as the firmware runs them. Time here runs on the simulated board's clock only: the executor is advanced when the
//! step queue is full or the file has ended, so the run never starves the steppers (heater
//! waits take no time: the host has no heaters). Layers are the file's own markers
//! (PrusaSlicer's `;LAYER_CHANGE`, Cura's `;LAYER:n`): each layer's step commands are
//! hashed as the firmware hashes a sliced job's.

use std::collections::BTreeMap;

use strata::gcode::read::{Action, Heater, LineError, LineSplitter, Reader};
use strata::machine::{MachineConfig, AXES};
use strata::move_ring::PackedMove;
use strata::plan::PlanConfig;
use strata::printer::Motion;
use strata::sim::{SimBoard, SimTiming};
use strata::step::{Executor, StepConfig, StepQueue, Wake};

/// Move buffer of the simulated printer, bytes (as the simulated sliced jobs').
const MOVE_BYTES: usize = crate::simjob::SIM_MOVE_BYTES;
/// Planner lookahead, moves.
const LOOKAHEAD: usize = strata::printer::board::LOOKAHEAD_MOVES;
/// Step queue, commands (the boards').
const STEP_QUEUE: usize = strata::printer::board::STEP_QUEUE_COMMANDS;
/// Refused lines kept with their line numbers in the report (all are counted).
const REFUSALS_KEPT: usize = 20;

/// What to record besides the totals.
#[derive(Debug, Clone, Copy, Default)]
pub struct GcodeOptions {
    /// Keep the motor positions at the end of every planner block ([`GcodeReport::block_ends`]).
    pub block_ends: bool,
}

/// What a G-code file did on the simulated printer.
#[derive(Debug, Default)]
pub struct GcodeReport {
    /// Lines read.
    pub lines: u32,
    /// Moves (`G0`/`G1`, `G4`, the travel of each `G28`) given to the planner.
    pub moves: u32,
    /// Commands skipped, by name (`M201`), with their counts.
    pub skipped: BTreeMap<String, u32>,
    /// Lines refused (counted; the first [`REFUSALS_KEPT`] kept with their 1-based numbers).
    pub refused: u32,
    /// The first refusals: line number and why.
    pub refusals: Vec<(u32, LineError)>,
    /// Moves clamped to the build volume.
    pub clamped: u32,
    /// Layers the markers counted (0 for a file without markers: one layer).
    pub layers: u32,
    /// Step-command hash of every layer, in order (FNV-1a, as `LayerDone`).
    pub layer_hashes: Vec<(u32, u64)>,
    /// The planner's print time, s (motion and dwells; heating takes none here).
    pub planned_s: f64,
    /// From the first step to the last on the board, s.
    pub print_time_s: f64,
    /// Steps per axis X, Y, Z, E.
    pub steps: [u64; AXES],
    /// Final motor positions X, Y, Z, E, steps.
    pub positions: [i64; AXES],
    /// The motor positions at the end of each block that moves a motor, as the generator
    /// starts it (with [`GcodeOptions::block_ends`]).
    pub block_ends: Vec<[i64; AXES]>,
    /// Driver timing violations on the board.
    pub violations: u32,
    /// Executor underruns (the commands ran out mid-motion).
    pub underruns: u32,
    /// Steps outside the generator's timing bound.
    pub step_check_failures: u32,
    /// Highest hotend and bed targets set, degC.
    pub max_targets_c: (i16, i16),
    /// Filament the extruder fed (net of retractions), mm.
    pub filament_mm: f64,
}

/// Runs the G-code `text` on a simulated `machine`.
///
/// Errors: the planner refused a move (line number and why); refused lines are not errors
/// (counted in the report, as the printer skips them).
pub fn run_gcode(
    text: &[u8],
    machine: &MachineConfig,
    opts: GcodeOptions,
) -> Result<GcodeReport, String> {
    // The motion half is large: a box keeps it off the stack.
    let mut motion: Box<Motion<MOVE_BYTES, LOOKAHEAD>> = Box::default();
    let plan_cfg = PlanConfig::from_machine(machine);
    let step_cfg = StepConfig::from_machine(machine);
    motion.reset(&plan_cfg, &step_cfg);
    let board = SimBoard::new(SimTiming::from_config(&step_cfg), 0, ());
    let mut pins = board.pins();
    let mut queue: StepQueue<STEP_QUEUE> = StepQueue::new();
    let (mut out, cons) = queue.split();
    let mut exec = Executor::new(&step_cfg, cons);

    let mut rep = GcodeReport::default();
    let mut reader = Reader::new(machine);
    let mut splitter = LineSplitter::new();
    let mut rest = text;
    let mut ended = false;
    let mut layer = 0u32;
    let mut pending: Option<(u32, PackedMove)> = None;
    let mut first_step: Option<u64> = None;
    let mut next_wake: Option<u32> = None;

    loop {
        // Moves into the buffer until it is full or the file has ended.
        while !ended {
            if let Some((_, p)) = &pending {
                if motion.moves_mut().push(p).is_err() {
                    break;
                }
                pending = None;
            }
            let line = if rest.is_empty() {
                ended = true;
                splitter.finish()
            } else {
                let (taken, line) = splitter.take(rest);
                rest = &rest[taken..];
                line
            };
            let Some(line) = line else { continue };
            let number = rep.lines + 1;
            rep.lines = number;
            let action = match line {
                Ok(()) => reader.line(splitter.line()),
                Err(e) => Err(reader.refuse(e)),
            };
            match action {
                Ok(Some(Action::Move(m) | Action::Home { travel: m, .. })) => {
                    pending = Some((number, PackedMove::pack(layer, &m)));
                }
                Ok(Some(Action::Layer(l))) => {
                    layer = l;
                    rep.layers = rep.layers.max(l + 1);
                }
                Ok(Some(Action::Heat { heater, target_c, .. })) => {
                    let t = &mut rep.max_targets_c;
                    match heater {
                        Heater::Hotend => t.0 = t.0.max(target_c),
                        Heater::Bed => t.1 = t.1.max(target_c),
                    }
                }
                Ok(Some(Action::Skipped { letter, code })) => {
                    *rep.skipped.entry(format!("{}{code}", letter as char)).or_default() += 1;
                }
                Ok(_) => {}
                Err(e) => {
                    rep.refused += 1;
                    if rep.refusals.len() < REFUSALS_KEPT {
                        rep.refusals.push((number, e));
                    }
                }
            }
        }
        let input_done = ended && pending.is_none();
        // Motion: moves into the planner, blocks into the generator, steps into the queue.
        let mut worked = false;
        loop {
            let fed = motion
                .feed(true, input_done, &mut out)
                .map_err(|l| format!("the planner refused a move of layer {l}"))?;
            // The generator sets the motors' end position as it starts a block, and starts at
            // most one per `feed` (it holds one block waiting): each change is one block's end.
            let motor = motion.generator().motor_steps();
            if opts.block_ends && rep.block_ends.last().unwrap_or(&[0; AXES]) != &motor {
                rep.block_ends.push(motor);
            }
            while let Some(mark) = motion.generator_mut().take_mark() {
                rep.layer_hashes.push(mark);
            }
            if !fed {
                break;
            }
            worked = true;
        }
        // The executor: one wake (a step edge) at a time, the generator fed after each.
        if next_wake.is_none() {
            next_wake = wake(exec.on_timer(board.now_u32(), &mut pins));
            if first_step.is_none() && !exec.is_idle() {
                first_step = Some(board.now());
            }
        }
        match next_wake {
            Some(w) => {
                let now = board.now();
                board.advance_to(now + u64::from(w.wrapping_sub(now as u32)));
                next_wake = wake(exec.on_timer(w, &mut pins));
            }
            None if input_done
                && motion.moves().is_empty()
                && motion.planner().is_empty()
                && motion.generator().is_idle() =>
            {
                break;
            }
            None if !worked && ended => return Err("the motion stopped with moves left".into()),
            None => {}
        }
    }
    if let Some(tag) = motion.generator().tag() {
        rep.layer_hashes.push((tag, out.take_hash()));
    }
    let stats = reader.stats();
    rep.moves = stats.moves;
    rep.clamped = stats.clamped;
    rep.layers = rep.layers.max(1);
    rep.planned_s =
        motion.planner().released_ticks_q16() as f64 / 65536.0 / f64::from(plan_cfg.timer_hz);
    let last = board.axes().iter().filter_map(|a| a.last_rise).max();
    rep.print_time_s = match (first_step, last) {
        (Some(f), Some(l)) => (l - f) as f64 / f64::from(step_cfg.timer_hz),
        _ => 0.0,
    };
    rep.steps = board.axes().map(|a| a.steps);
    rep.positions = board.positions();
    rep.violations = board.violation_count();
    rep.underruns = exec.stats().underruns;
    rep.step_check_failures = motion.generator().stats().check_failures;
    let spm_e = machine.steps_per_mm[3].to_num::<f64>();
    rep.filament_mm = rep.positions[3] as f64 / spm_e;
    Ok(rep)
}

fn wake(w: Result<Wake, core::convert::Infallible>) -> Option<u32> {
    match w {
        Ok(Wake::At(t)) => Some(t),
        _ => None,
    }
}

//! A G-code job on the device-side job runner: its text in small messages (lines run on
//! across them), settings that take effect where the motion reaches them, heater waits that
//! hold the reading (the motion before them still runs) and leave the step hashes as they are
//! without heaters, and messages out of place refused.

use strata::machine::{MachineConfig, AXES};
use strata::printer::{Accept, Motion, MotionAccess, MotionHalf};
use strata::protocol::{DeviceState, Endpoint, ErrorCode, GcodeSpec, LinkConfig, Message};
use strata::step::{StepProducer, StepQueue};
use strata_testkit::drive::{batch, encode, Rig, Sizes};
use strata_testkit::mesh::{cuboid, to_um};
use strata_testkit::small_printer;

small_printer! {
    type Small = {};
}

type SmallMotion<'q> =
    MotionHalf<'q, { Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }, 32>;

/// Heaters on, a move, a wait for both heaters, then fan changes between moves.
const JOB: &str = "M140 S60\nM104 S200\nG28\nG1 X10 F3000\nM109 S200\nM190 S60\nG1 X20 Y5 E1 F1200\nM106 S128\nG1 X30\nM107\nG1 X40\n";

/// The job's payloads: its start, the text in messages of `chunk` bytes, the end.
fn payloads(text: &str, chunk: usize) -> Vec<Vec<u8>> {
    let spec = GcodeSpec { bytes: text.len() as u32, layers: 0 };
    let mut out = vec![encode(&Message::GcodeStart(spec))];
    out.extend(text.as_bytes().chunks(chunk).map(|c| encode(&Message::Gcode(c))));
    out.push(encode(&Message::EndOfModel));
    out
}

/// What a run saw at each turn.
#[derive(Default)]
struct Seen {
    hashes: Vec<(u32, u64)>,
    positions: [i64; AXES],
    /// Turns at which the heaters were waited for.
    heating_turns: u32,
}

/// Runs [`JOB`] in messages of `chunk` bytes; `heaters`: the board reports heaters that reach
/// their targets at turn 300.
fn run(chunk: usize, heaters: bool) -> Seen {
    let mut p = Box::new(Small::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::executing(&mut q, p.step_config());
    let mut seen = Seen::default();
    rig.drive(&mut *p, &payloads(JOB, chunk), 1_000_000, |p, m: &mut SmallMotion<'_>, turn| {
        let gen = m.motion.generator();
        let (done, x) = (gen.blocks_done(), gen.motor_steps()[0]);
        // The fan follows the motion: on from the end of the second block (X20) to the end
        // of the third (X30), never where it was read.
        assert_eq!(p.fan_duty(m) == 128, (2..3).contains(&done), "blocks done {done}");
        if !heaters {
            return;
        }
        let at_target = turn >= 300;
        if p.status(m, 0).heating {
            seen.heating_turns += 1;
            // Held at the wait: the first move (X10 = 800 steps) ran to its end, no further.
            assert!(x <= 800, "moved past the heater wait: X {x}");
            assert_eq!(p.heater_targets(), (200, 60));
        }
        p.set_thermal(at_target, if at_target { 2000 } else { 250 }, 600);
    });
    assert_eq!(p.state(), DeviceState::Done);
    assert_eq!(p.heater_targets(), (0, 0), "a finished job turns the heaters off");
    seen.hashes = rig.hashes.clone();
    seen.positions = rig.motion.motion.generator().motor_steps();
    let board = rig.board().expect("an executing rig");
    assert_eq!(board.violation_count(), 0);
    assert_eq!(board.positions(), seen.positions, "the board ran every step");
    seen
}

#[test]
fn a_gcode_job_runs_its_moves_with_settings_timed_to_the_motion() {
    let seen = run(7, true);
    // X 40 mm, Y 5 mm at 80 steps/mm; E 1 mm at 93.
    assert_eq!(seen.positions, [3200, 400, 0, 93]);
    assert!(seen.heating_turns > 200, "waited {} turns", seen.heating_turns);
}

#[test]
fn heater_waits_and_message_sizes_leave_the_steps_as_they_are() {
    let with = run(7, true);
    for (chunk, heaters) in [(7, false), (1, false), (200, false), (3, true)] {
        let other = run(chunk, heaters);
        assert_eq!(other.hashes, with.hashes, "chunks of {chunk}, heaters {heaters}");
        assert_eq!(other.positions, with.positions);
    }
}

/// A motion half that is also fed elsewhere, as a board's feed interrupt feeds it: before
/// every access of the job runner, with the gate the runner last set.
struct Interrupted<'q> {
    half: SmallMotion<'q>,
    gate: (bool, bool),
}

impl<'q> MotionAccess<{ Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }, 32>
    for Interrupted<'q>
{
    fn with<R>(
        &mut self,
        f: impl FnOnce(
            &mut Motion<{ Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }>,
            &mut StepProducer<'_, 32>,
        ) -> R,
    ) -> R {
        let (allowed, flush) = self.gate;
        let _ = self.half.motion.feed(allowed, flush, &mut self.half.out);
        f(&mut self.half.motion, &mut self.half.out)
    }

    fn gate(&mut self, allowed: bool, flush: bool) {
        self.gate = (allowed, flush);
    }
}

/// The blocks do not depend on when a feeder elsewhere runs: the gate leaves its flush at a
/// hold's end before the next move goes in (a stale flush would plan the move after a heater
/// wait as the last of the job).
#[test]
fn a_feed_interrupt_gives_the_same_steps() {
    let reference = run(7, true);
    let mut p = Box::new(Small::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let (prod, mut cons) = q.split();
    let mut m = Interrupted { half: MotionHalf::new(prod), gate: (false, false) };
    // The whole text in one message: the moves after the wait go in within the call that
    // ends it, before the runner sets the gate again.
    let msgs = payloads(JOB, JOB.len());
    let (mut next, mut hashes) = (0, Vec::new());
    for turn in 0..1_000_000u32 {
        while next < msgs.len() {
            let msg = Message::decode(&msgs[next]).unwrap();
            match p.handle(&msg, &mut m) {
                Accept::Taken => next += 1,
                Accept::Busy => break,
            }
        }
        p.poll(&mut m);
        p.set_thermal(turn >= 300, if turn >= 300 { 2000 } else { 250 }, 600);
        hashes.extend(std::iter::from_fn(|| p.take_layer_done()));
        for axis in 0..AXES {
            while cons.dequeue(axis).is_some() {}
        }
        if !p.is_active() && next == msgs.len() {
            break;
        }
    }
    assert_eq!(p.state(), DeviceState::Done);
    assert_eq!(hashes, reference.hashes);
    assert_eq!(m.half.motion.generator().motor_steps(), reference.positions);
}

#[test]
fn triangles_in_a_gcode_job_fail_it() {
    let mut p = Box::new(Small::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::executing(&mut q, p.step_config());
    let tris = to_um(&cuboid([100.0, 100.0, 0.0], [106.0, 106.0, 0.8]));
    let mut msgs = payloads("G1 X5 F600\n", 64);
    msgs.insert(2, batch(&tris));
    rig.drive(&mut *p, &msgs, 100_000, |_, _: &mut SmallMotion<'_>, _| {});
    assert_eq!(p.state(), DeviceState::Failed);
    let triangles = strata::protocol::msg::ty::TRIANGLES;
    assert_eq!(p.error(), (ErrorCode::Unexpected, u32::from(triangles)));
}

/// An arc on the printer: its segments go into the move buffer one by one, each a block,
/// and the motors end where the arc does.
#[test]
fn an_arc_runs_as_its_segments() {
    let mut p = Box::new(Small::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::executing(&mut q, p.step_config());
    // A move, then a whole circle of radius 10 mm (62 segments) extruding 5 mm.
    let text = "G1 X110 Y100 F3000\nM83\nG2 X110 Y100 I-10 J0 E5\n";
    rig.drive(&mut *p, &payloads(text, 16), 1_000_000, |_, _: &mut SmallMotion<'_>, _| {});
    assert_eq!(p.state(), DeviceState::Done);
    let gen = rig.motion.motion.generator();
    assert_eq!(gen.blocks_done(), 1 + 62);
    // X 110 mm, Y 100 mm at 80 steps/mm; E 5 mm at 93.
    assert_eq!(gen.motor_steps(), [8800, 8000, 0, 465]);
    assert_eq!(rig.board().unwrap().positions(), [8800, 8000, 0, 465]);
}

/// A job the user had paused stays where it is when its host dies: paused, its heaters held
/// for the hold time, then off; the status says why.
#[test]
fn a_paused_job_whose_host_dies_holds_its_heaters_then_cools() {
    let mut p = Box::new(Small::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut m: Box<SmallMotion<'_>> = Box::new(MotionHalf::new(q.split().0));
    let msgs = payloads(JOB, JOB.len());
    for msg in &msgs[..2] {
        p.handle(&Message::decode(msg).unwrap(), &mut *m);
    }
    for _ in 0..10 {
        p.poll(&mut *m);
    }
    assert_eq!(p.heater_targets(), (200, 60));
    p.handle(&Message::Pause, &mut *m);
    let hold_ms = 60_000;
    p.set_heat_hold_ms(hold_ms);
    p.link_lost(3_000, 1_000);
    let mut ep: Endpoint<4, 4> = Endpoint::new(LinkConfig::device());
    for now in [1_000, 1_000 + hold_ms - 1] {
        p.service(&mut ep, &mut *m, now, 0, 500, false);
        assert_eq!((p.state(), p.heater_targets()), (DeviceState::Paused, (200, 60)), "{now} ms");
    }
    p.service(&mut ep, &mut *m, 1_000 + hold_ms, 0, 500, false);
    assert_eq!((p.state(), p.heater_targets()), (DeviceState::Paused, (0, 0)));
    assert_eq!(p.error(), (ErrorCode::LinkDead, 3_000));
    assert_eq!(p.resume_point(), None, "it never parked");
}

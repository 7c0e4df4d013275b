//! The device-side job runner without a link: misplaced or undecodable messages are never
//! executed, identical jobs give identical layer hashes, pause/resume, abort and emergency
//! stop; and through `service` with a real endpoint pair: hello/capabilities and status.

use strata::geom::Triangle;
use strata::machine::{MachineConfig, AXES};
use strata::printer::{Accept, Motion, MotionAccess, MotionHalf};
use strata::protocol::{DeviceState, Endpoint, ErrorCode, JobSpec, LinkConfig, Message, VERSION};
use strata::step::{StepCmd, StepProducer, StepQueue};
use strata::toolpath::Cooling;
use strata_testkit::drive::{
    batch, batches, carry, encode, job_spec, model_payloads, start, Rig, Sizes,
};
use strata_testkit::mesh::{cuboid, ngon, prism, to_um};
use strata_testkit::rng::Rng;
use strata_testkit::small_printer;

small_printer! {
    type Small = {};
}

/// The motion half of a [`Small`] printer with a step queue of 32 commands an axis.
type SmallMotion<'q> =
    MotionHalf<'q, { Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }, 32>;

/// A motion half for calls outside a drive loop (the producer of `q`).
fn loose_motion(q: &mut StepQueue<32>) -> Box<SmallMotion<'_>> {
    Box::new(MotionHalf::new(q.split().0))
}

fn new_printer() -> Box<Small> {
    Box::new(Small::new(&MachineConfig::default()))
}

/// A closed 6 x 6 x 0.8 mm box at (100, 100) mm, zmin-sorted.
fn block() -> Vec<Triangle> {
    box_at(100.0, 6.0, 0.8)
}

/// A closed `w` x `w` x `h` mm box with its corner at (`o`, `o`) mm, zmin-sorted.
fn box_at(o: f64, w: f64, h: f64) -> Vec<Triangle> {
    to_um(&cuboid([o, o, 0.0], [o + w, o + w, h]))
}

/// The job of `tris`: one top and one bottom layer, no skirt.
fn job(tris: &[Triangle]) -> JobSpec {
    let mut spec = job_spec(tris);
    spec.settings.top_layers = 1;
    spec.settings.bottom_layers = 1;
    spec.options.skirt_loops = 0;
    spec
}

/// Feeds the whole job of the [`block`] and runs it, the steps executed on a simulated board
/// (checked against the drivers' timing); returns layer hashes and the steps per axis.
/// `between` is called every poll with the poll count.
fn run(
    p: &mut Small,
    between: impl FnMut(&mut Small, &mut SmallMotion<'_>, u32),
) -> (Vec<(u32, u64)>, [u64; AXES]) {
    let tris = block();
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::executing(&mut q, p.step_config());
    start(p, &mut rig, job(&tris));
    assert_eq!(p.state(), DeviceState::Printing);
    let payloads = model_payloads(&tris);
    assert_eq!(payloads.len(), 2, "one batch, the end of the model");
    rig.drive(p, &payloads, 1_000_000, between);
    // Every message was taken when offered.
    assert_eq!(rig.busy, 0);
    let board = rig.board().expect("an executing rig");
    assert_eq!(board.violation_count(), 0, "{:?}", board.first_violation());
    (rig.hashes, rig.steps)
}

/// Runs the job with a small step queue drained by `drain(poll, axis)` commands per axis
/// after each poll (an executor that is sometimes fast, sometimes slow); returns the layer
/// hashes and the queued commands per axis.
fn run_draining(
    mut drain: impl FnMut(u32, usize) -> usize,
) -> (Vec<(u32, u64)>, Vec<Vec<StepCmd>>) {
    let mut p = new_printer();
    let tris = block();
    let mut q: StepQueue<8> = StepQueue::new();
    let mut rig = Rig::recording(&mut q).limit_drain(move |turn, axis| drain(turn as u32, axis));
    start(&mut *p, &mut rig, job(&tris));
    rig.drive(&mut *p, &model_payloads(&tris), 10_000_000, |_, _, _| {});
    // Every message was taken when offered.
    assert_eq!(rig.busy, 0);
    assert_eq!(p.state(), DeviceState::Done, "{:?}", p.error());
    rig.drain_all();
    (rig.hashes, rig.commands)
}

#[test]
fn step_commands_and_hashes_do_not_depend_on_how_fast_the_queue_drains() {
    let (h_fast, c_fast) = run_draining(|_, _| usize::MAX);
    assert_eq!(h_fast.iter().map(|h| h.0).collect::<Vec<_>>(), vec![0, 1, 2, 3]);
    // Slow and uneven: one command per axis every few polls, X slowest; then bursts.
    let mut rng = Rng::new(0x2545_f491_4f6c_dd1d);
    let (h_slow, c_slow) = run_draining(|i, axis| {
        let x = rng.u64();
        match (i / 5000) % 3 {
            0 => usize::from(x % (axis as u64 + 3) == 0),
            1 => (x % 3) as usize,
            _ => usize::MAX,
        }
    });
    assert_eq!(c_fast, c_slow, "the command streams differ");
    assert_eq!(h_fast, h_slow);
    // The hashes are those of the commands: a different job changes them.
    assert!(h_fast.windows(2).all(|w| w[0].1 != w[1].1));
}

small_printer! {
    /// A small move buffer: one layer of a 20 mm cube fits, a whole model does not.
    type Tight = { move_buffer_bytes: 4096 };
}

#[test]
fn layers_are_cut_one_at_a_time_as_the_move_buffer_allows() {
    // A 20 x 20 x 10 mm box of 16 triangles in one batch: its last triangles complete every
    // layer at once, 50 layers of moves (tens of kilobytes) against a 4 KB move buffer.
    let tris = box_at(90.0, 20.0, 10.0);
    let mut p: Box<Tight> = Box::new(Tight::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::counting(&mut q);
    start(&mut *p, &mut rig, job(&tris));
    let payloads = model_payloads(&tris);
    assert_eq!(payloads.len(), 2, "one batch, the end of the model");
    rig.drive(&mut *p, &payloads, 50_000_000, |_, _, _| {});
    assert_eq!(p.state(), DeviceState::Done, "{:?}", p.error());
    assert_eq!(rig.hashes.iter().map(|h| h.0).collect::<Vec<_>>(), (0..50).collect::<Vec<u32>>());
    // The batch and the end of the model both had to wait for room, more than once.
    assert!(rig.busy > 10, "{}", rig.busy);
}

small_printer! {
    /// A move buffer smaller than the block's first layer's infill.
    type Cramped = { move_buffer_bytes: 96 };
}

#[test]
fn a_unit_that_overflows_the_move_buffer_fails_the_job_naming_its_layer() {
    let tris = block();
    let mut p: Box<Cramped> = Box::new(Cramped::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::counting(&mut q);
    start(&mut *p, &mut rig, job(&tris));
    // What was accepted stays within the buffer, after every message and every poll.
    let within =
        |m: &Motion<96, 16>| assert!(m.moves().used_bytes() <= 96, "{}", m.moves().used_bytes());
    rig.drive(&mut *p, &model_payloads(&tris), 1_000_000, |_, m, _| within(&m.motion));
    within(&rig.motion.motion);
    // The first layer's solid infill (a 6 mm square: one zigzag of 15 lines, some 30 moves
    // of at least 2 bytes each) cannot fit 96 bytes even in an empty buffer: a typed failure
    // at layer 0 (not a dropped move, not a wait forever).
    assert_eq!(p.state(), DeviceState::Failed);
    assert_eq!(p.error(), (ErrorCode::Moves, 0));
    assert!(p.largest_unit_bytes() <= 96, "{}", p.largest_unit_bytes());
}

#[test]
fn identical_jobs_give_identical_hashes() {
    let mut a = new_printer();
    let (ha, sa) = run(&mut a, |_, _, _| {});
    assert_eq!(a.state(), DeviceState::Done, "{:?}", a.error());
    assert_eq!(ha.len(), 4);
    assert_eq!(ha.iter().map(|h| h.0).collect::<Vec<_>>(), vec![0, 1, 2, 3]);
    let mut b = new_printer();
    let (hb, sb) = run(&mut b, |_, _, _| {});
    assert_eq!(ha, hb);
    assert_eq!(sa, sb);
    assert!(sa[0] > 0 && sa[3] > 0);
    // The runner can run a second job after the first.
    let (hc, _) = run(&mut a, |_, _, _| {});
    assert_eq!(hc, ha);
}

#[test]
fn pause_holds_motion_and_resume_finishes_the_same_job() {
    let mut clean = new_printer();
    let (h0, s0) = run(&mut clean, |_, _, _| {});
    let mut p = new_printer();
    let mut paused_polls = 0;
    let (h1, s1) = run(&mut p, |p, m, i| {
        if i == 20 {
            assert_eq!(p.handle(&Message::Pause, m), Accept::Taken);
        }
        if p.state() == DeviceState::Paused {
            paused_polls += 1;
            if paused_polls == 500 {
                assert_eq!(p.handle(&Message::Resume, m), Accept::Taken);
            }
        }
    });
    assert_eq!(paused_polls, 500);
    assert_eq!(p.state(), DeviceState::Done);
    assert_eq!((h1, s1), (h0, s0));
}

/// A motion half that records the job's gates the runner gives it (a board's feed interrupt
/// releases blocks by them).
struct Gates<'a, 'q> {
    motion: &'a mut SmallMotion<'q>,
    seen: Vec<bool>,
}

impl MotionAccess<{ Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }, 32>
    for Gates<'_, '_>
{
    fn with<R>(
        &mut self,
        f: impl FnOnce(
            &mut Motion<{ Sizes::SMALL.move_buffer_bytes }, { Sizes::SMALL.lookahead_moves }>,
            &mut StepProducer<'_, 32>,
        ) -> R,
    ) -> R {
        self.motion.with(f)
    }

    fn gate(&mut self, allowed: bool, _toolpath_done: bool) {
        self.seen.push(allowed);
    }
}

#[test]
fn a_pause_closes_the_gate_before_the_state_changes_and_resume_opens_it() {
    let mut p = new_printer();
    let (mut paused, mut resumed) = (None, None);
    run(&mut p, |p, m, i| {
        let mut g = Gates { motion: m, seen: Vec::new() };
        if i == 20 {
            p.handle(&Message::Pause, &mut g);
            paused = Some(g.seen);
        } else if i == 21 {
            p.handle(&Message::Resume, &mut g);
            resumed = Some(g.seen);
        }
    });
    // Closed before the message is handled (a feeder elsewhere releases nothing after it),
    // and still closed after; reopened by the resume alone.
    assert_eq!(paused, Some(vec![false, false]));
    assert_eq!(resumed, Some(vec![true]));
    assert_eq!(p.state(), DeviceState::Done);
}

#[test]
fn abort_and_emergency_stop_end_the_job() {
    let mut p = new_printer();
    run(&mut p, |p, m, i| {
        if i == 10 {
            assert_eq!(p.heater_targets(), (200, 60));
            p.handle(&Message::Abort, m);
        }
    });
    assert_eq!(p.state(), DeviceState::Aborted);
    // Heaters and fan off with the job.
    let mut q = StepQueue::new();
    assert_eq!((p.heater_targets(), p.fan_duty(&mut *loose_motion(&mut q))), ((0, 0), 0));
    let mut p = new_printer();
    run(&mut p, |p, m, i| {
        if i == 10 {
            assert_eq!(p.heater_targets(), (200, 60));
            p.handle(&Message::EmergencyStop, m);
            assert_eq!((p.heater_targets(), p.fan_duty(m)), ((0, 0), 0));
        }
        if i == 11 {
            // Nothing restarts a stopped printer but a new job.
            p.handle(&Message::Resume, m);
        }
    });
    assert_eq!(p.state(), DeviceState::Stopped);
}

#[test]
fn misplaced_messages_are_never_executed() {
    let tris = block();
    let bytes = batch(&tris);
    let m = Message::decode(&bytes).unwrap();
    let mut p = new_printer();
    let mut q = StepQueue::new();
    let mut boxed = loose_motion(&mut q);
    let motion = &mut *boxed;
    p.handle(&m, motion);
    assert_eq!(p.state(), DeviceState::Failed);
    assert_eq!(p.error(), (ErrorCode::Unexpected, 0x11));
    assert_eq!(p.slicer().stats().triangles, 0, "triangles before a job were sliced");
    // A job with invalid settings is refused.
    let mut p = new_printer();
    let mut bad = job(&tris);
    bad.settings.layer_height_um = 0;
    p.handle(&Message::JobStart(bad), motion);
    assert_eq!(p.state(), DeviceState::Failed);
    assert_eq!(p.error().0, ErrorCode::BadJob);
}

#[test]
fn service_answers_hello_and_refuses_undecodable_payloads() {
    let mut p = new_printer();
    let mut host: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    host.send(&encode(&Message::Hello { version: 1 })).unwrap();
    host.send(&[0x7f, 1, 2, 3]).unwrap();
    let mut q = StepQueue::new();
    let mut boxed = loose_motion(&mut q);
    let motion = &mut *boxed;
    let mut got = Vec::new();
    for now in 1..200u32 {
        carry(&mut host, &mut dev, now);
        p.service(&mut dev, motion, now, 0, 50, false);
        carry(&mut dev, &mut host, now);
        while let Some(m) = host.peek() {
            got.push(format!("{:?}", Message::decode(m).unwrap()));
            host.pop();
        }
    }
    assert!(got[0].starts_with(&format!("Capabilities {{ version: {VERSION}")), "{got:?}");
    assert!(got[0].contains("active_triangles: 256"), "{got:?}");
    let failed = got.iter().position(|m| m.contains("state: Failed") && m.contains("BadMessage"));
    let words =
        got.iter().position(|m| m == r#"Failure("link: a message of type 0x7f did not decode")"#);
    assert!(words.is_some() && words < failed, "the words before the failed status: {got:?}");
    assert_eq!(p.error(), (ErrorCode::BadMessage, 0x7f));
}

#[test]
fn motion_waits_for_the_heaters_and_a_heater_fault_ends_the_job() {
    let (h_ref, s_ref) = run(&mut new_printer(), |_, _, _| {});
    // A board with heaters: nothing moves until they report being at target, then the job
    // runs exactly as without heaters.
    let mut p = new_printer();
    p.set_thermal(false, 250, 250);
    assert_eq!(p.heater_targets(), (0, 0), "no job, heaters off");
    let mut waited = 0;
    let mut fan_seen = false;
    let (h, s) = run(&mut p, |p, m, i| {
        assert_eq!(p.heater_targets(), (200, 60));
        // The fan stays off on the first layer, comes on from the second (at least the
        // cooling's duty for long layers).
        let layer = m.motion.generator().tag();
        let on = p.fan_duty(m) >= Cooling::DEFAULT.min_duty;
        assert_eq!(on, layer.is_some_and(|l| l >= 1), "layer {layer:?}: {}", p.fan_duty(m));
        fan_seen |= on;
        if i < 300 {
            assert!(p.status(m, 0).heating);
            assert_eq!(
                m.motion.generator().stats().blocks,
                0,
                "moved before the heaters were ready"
            );
            p.set_thermal(false, 1500 + i as i16, 500);
            waited += 1;
        } else {
            p.set_thermal(true, 2000, 600);
            assert!(!p.status(m, 0).heating);
        }
    });
    assert_eq!(waited, 300);
    assert!(fan_seen);
    let mut q = StepQueue::new();
    let mut boxed = loose_motion(&mut q);
    let m = &mut *boxed;
    assert_eq!(p.fan_duty(m), 0, "the fan stops with the job");
    assert_eq!(p.state(), DeviceState::Done);
    assert_eq!((h, s), (h_ref, s_ref));
    assert_eq!(p.heater_targets(), (0, 0), "a finished job turns the heaters off");
    assert_eq!((p.status(m, 0).hotend_c_x10, p.status(m, 0).bed_c_x10), (2000, 600));
    // A heater fault mid-job fails it at once, naming the fault.
    let mut p = new_printer();
    let fault = strata::thermal::ThermalFault::ThermalRunaway(strata::thermal::Heater::Hotend);
    run(&mut p, |p, m, i| {
        p.set_thermal(true, 2000, 600);
        if i == 20 {
            assert!(p.is_active());
            p.thermal_fault(fault.code(), m);
        }
    });
    assert_eq!(p.state(), DeviceState::Failed);
    assert_eq!(p.error(), (ErrorCode::Thermal, u32::from(fault.code())));
    assert_eq!(strata::thermal::ThermalFault::from_code(fault.code()), Some(fault));
    assert_eq!(p.heater_targets(), (0, 0));
}

#[test]
fn a_job_that_waits_too_long_for_its_heaters_fails_naming_it() {
    use strata::thermal::{ThermalFault, HEAT_WAIT_LIMIT_MS};
    let mut p = new_printer();
    let mut host: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let tris = block();
    let mut q = StepQueue::new();
    let mut boxed = loose_motion(&mut q);
    let motion = &mut *boxed;
    assert_eq!(p.handle(&Message::JobStart(job(&tris)), motion), Accept::Taken);
    // A heater stuck just below its target: never at target, no protection trips.
    let mut failed_at = None;
    for s in 0..HEAT_WAIT_LIMIT_MS / 1000 + 2 {
        let now = s * 1000;
        p.set_thermal(false, 1960, 600);
        // A live link both ways (the host acknowledges the status reports).
        for t in now..now + 1000 {
            carry(&mut host, &mut dev, t);
            if t % 100 == 0 {
                p.service(&mut dev, motion, t, 0, 100, false);
            }
            carry(&mut dev, &mut host, t);
            while host.peek().is_some() {
                host.pop();
            }
        }
        if p.state() == DeviceState::Failed && p.error().0 == ErrorCode::Thermal {
            failed_at = Some(now);
            break;
        }
        assert!(p.is_active(), "{:?} at {now} ms", p.error());
    }
    let at = failed_at.expect("the wait never ended");
    // Failed within the second after the limit (the loop checks once a second; the job was
    // still active at every earlier second).
    assert_eq!(at, HEAT_WAIT_LIMIT_MS, "{at}");
    assert_eq!(p.error().1, u32::from(ThermalFault::HeatingTimeout.code()));
    assert_eq!(p.heater_targets(), (0, 0));
}

/// What a job streamed through `service` gave: layer hashes, the command stream per axis,
/// the times the motion half was lent, and how many of them generated steps.
struct Streamed {
    hashes: Vec<(u32, u64)>,
    cmds: Vec<Vec<StepCmd>>,
    /// Accesses to the motion half inside `service` that generated steps (the progress
    /// points it was lent).
    lends_with_steps: u32,
    /// Bytes of the largest toolpath unit that went into the move buffer.
    largest_unit: usize,
    /// Turns after which a received message was still held (waiting for room).
    held: u32,
}

/// The rig's motion half, counting the accesses inside `service` (`inside`) that generated
/// steps, the queue drained after each (an executor that keeps up).
struct Lent<'r, 'q> {
    rig: &'r mut Rig<'q, BUFFERED, 16, 32>,
    inside: bool,
    with_steps: u32,
}

impl MotionAccess<BUFFERED, 16, 32> for Lent<'_, '_> {
    fn with<R>(
        &mut self,
        f: impl FnOnce(&mut Motion<BUFFERED, 16>, &mut StepProducer<'_, 32>) -> R,
    ) -> R {
        let before = self.rig.motion.motion.generator().progress();
        let r = self.rig.motion.with(f);
        let generated = self.rig.motion.motion.generator().progress() != before;
        if self.inside && generated {
            self.with_steps += 1;
            self.rig.drain();
        }
        r
    }
}

/// Streams a 48-sided prism of 10 mm radius, 1.2 mm tall (six layers, one triangle per
/// batch) through the link into
/// `service`; with `generate`, the lent motion half generates steps (and the executor drains
/// them) at every progress point, as the firmware does. The printer uses `limit` bytes of
/// its move buffer.
fn stream_through_service(generate: bool, limit: usize) -> Streamed {
    let mut p: Box<Buffered> = Box::new(Buffered::new(&MachineConfig::default()));
    let ring = ngon(48, 110.0, 110.0, 10.0, 0.0);
    let tris = to_um(&prism(&ring, 0.0, 1.2));
    let mut host: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut outbox = vec![encode(&Message::JobStart(job(&tris)))];
    outbox.extend(tris.iter().map(|t| batch(std::slice::from_ref(t))));
    outbox.push(encode(&Message::EndOfModel));
    let mut outbox = outbox.into_iter();
    let mut pending = outbox.next();
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::recording(&mut q);
    rig.motion.motion.moves_mut().limit(limit);
    let mut held = 0;
    let mut lent = Lent { rig: &mut rig, inside: false, with_steps: 0 };
    for now in 1..2_000_000u32 {
        while let Some(m) = pending.as_ref() {
            if host.send(m).is_err() {
                break;
            }
            pending = outbox.next();
        }
        carry(&mut host, &mut dev, now);
        lent.inside = true;
        p.service(&mut dev, &mut lent, now, 0, 1000, generate);
        lent.inside = false;
        held += u32::from(dev.rx_len() > 0);
        while p.poll(&mut lent) {}
        lent.rig.drain();
        lent.rig.take_hashes(&mut *p);
        carry(&mut dev, &mut host, now);
        while host.peek().is_some() {
            host.pop();
        }
        if p.state() != DeviceState::Printing && p.state() != DeviceState::Idle {
            break;
        }
    }
    assert_eq!(p.state(), DeviceState::Done, "{:?}", p.error());
    let lends_with_steps = lent.with_steps;
    Streamed {
        hashes: rig.hashes,
        cmds: rig.commands,
        lends_with_steps,
        largest_unit: p.largest_unit_bytes(),
        held,
    }
}

#[test]
fn steps_are_generated_while_a_layer_is_computed_and_the_commands_stay_the_same() {
    let lent = stream_through_service(true, BUFFERED);
    let kept = stream_through_service(false, BUFFERED);
    assert_eq!(lent.hashes.len(), 6, "{:?}", lent.hashes);
    // The toolpath stage offered the motion half inside its layers, and the generator made
    // steps there (the earlier layers' moves were waiting); not without lending.
    assert!(lent.lends_with_steps > 0, "no steps generated inside a layer's computation");
    assert_eq!(kept.lends_with_steps, 0);
    // The same commands and hashes either way.
    assert_eq!(lent.cmds, kept.cmds, "the command streams differ");
    assert_eq!(lent.hashes, kept.hashes);
    // A move buffer of exactly the largest path's bytes (with the travel before it):
    // batches wait in the endpoint's slot for the layer before to be emitted, and the
    // commands stay the same.
    assert_eq!(kept.largest_unit, lent.largest_unit);
    assert!(lent.largest_unit > 0 && lent.largest_unit < BUFFERED, "{}", lent.largest_unit);
    let narrow = stream_through_service(true, lent.largest_unit);
    assert_eq!(lent.held, 0);
    assert!(narrow.held > 10, "{}", narrow.held);
    assert_eq!(narrow.largest_unit, lent.largest_unit);
    assert_eq!(narrow.cmds, lent.cmds, "the command streams differ");
    assert_eq!(narrow.hashes, lent.hashes);
}

small_printer! {
    /// A printer whose move buffer holds [`BUFFERED`] bytes, of which its tests use a part
    /// (`MoveRing::limit`).
    type Buffered = { move_buffer_bytes: BUFFERED };
}
/// Bytes of a [`Buffered`] printer's move buffer.
const BUFFERED: usize = 32_768;

/// What [`run_buffered`] saw.
struct BufferedRun {
    hashes: Vec<(u32, u64)>,
    state: DeviceState,
    error: (ErrorCode, u32),
    /// The toolpath stage's largest emission unit, moves.
    largest_unit_moves: u32,
    /// Bytes of the largest unit that went into the move buffer.
    largest_unit: usize,
    /// Moves of the job.
    moves: u64,
    /// Times the batch or the end of the model had to wait.
    busy: u32,
}

/// Runs `tris` (one batch) as `spec` through a printer using `limit` bytes of its move
/// buffer, offering the batch and the end of the model again while the printer is busy,
/// draining the steps.
fn run_buffered(tris: &[Triangle], spec: JobSpec, limit: usize) -> BufferedRun {
    let mut p: Box<Buffered> = Box::new(Buffered::new(&MachineConfig::default()));
    let mut q: StepQueue<32> = StepQueue::new();
    let mut rig = Rig::counting(&mut q);
    rig.motion.motion.moves_mut().limit(limit);
    start(&mut *p, &mut rig, spec);
    let payloads = model_payloads(tris);
    assert_eq!(payloads.len(), 2, "one batch, the end of the model");
    rig.drive(&mut *p, &payloads, 50_000_000, |_, _, _| {});
    let s = p.toolpath().stats();
    BufferedRun {
        hashes: rig.hashes,
        state: p.state(),
        error: p.error(),
        largest_unit_moves: s.max_unit_moves,
        largest_unit: p.largest_unit_bytes(),
        moves: s.extrusion_moves + s.travel_moves + 2 * s.retractions,
        busy: rig.busy,
    }
}

#[test]
fn a_move_buffer_of_one_path_gives_the_hashes_of_a_large_one() {
    // A 20 x 20 x 4 mm box: its top skins' zigzag runs are its largest units (114 moves),
    // about a tenth of its 1,100 moves.
    let tris = box_at(90.0, 20.0, 4.0);
    let mut spec = job(&tris);
    spec.settings.top_layers = 3;
    spec.options.skirt_loops = 1;
    let large = run_buffered(&tris, spec, BUFFERED);
    assert_eq!(large.state, DeviceState::Done, "{:?}", large.error);
    assert_eq!(large.hashes.len(), 20);
    assert_eq!(large.busy, 0);
    let unit = large.largest_unit;
    assert!(u64::from(large.largest_unit_moves) * 8 < large.moves, "{}", large.moves);
    // A unit's moves take at least a header byte each, at most a whole record.
    let moves = large.largest_unit_moves as usize;
    assert!(unit >= moves && unit <= moves * strata::move_ring::MAX_RECORD, "{unit}");
    // A buffer of exactly the largest unit's bytes: the same step commands, with waits.
    let narrow = run_buffered(&tris, spec, unit);
    assert_eq!(narrow.state, DeviceState::Done, "{:?}", narrow.error);
    assert_eq!(narrow.hashes, large.hashes);
    assert_eq!(narrow.largest_unit, unit);
    assert!(narrow.busy > 10, "{}", narrow.busy);
    // One byte less fails the job with a typed error naming the layer, at the first such
    // unit, with the hashes of the layers before it (and does not wait forever).
    let small = run_buffered(&tris, spec, unit - 1);
    assert_eq!(small.state, DeviceState::Failed);
    let (code, layer) = small.error;
    assert_eq!(code, ErrorCode::Moves);
    assert!(layer < 20, "{layer}");
    assert!(small.largest_unit < unit, "{}", small.largest_unit);
    let done = small.hashes.len();
    assert!(done <= layer as usize, "{done} layers reported before layer {layer} failed");
    assert_eq!(small.hashes[..], large.hashes[..done]);
}

small_printer! {
    /// A slicer that holds 8 active triangles (the block's first layer needs its 8 side
    /// triangles, the bottom's 4 and the top's...: more).
    type TinySlicer = { active_triangles: 8 };
}

/// A slicer that runs out of room fails the job with its own error, and the host gets it in
/// words (`Message::Failure`) before the failed status: which stage, which buffer, which
/// layer, how much the printer holds.
#[test]
fn a_stage_failure_reaches_the_host_in_the_stages_words() {
    use strata::printer::Failure;
    use strata::slice::{Resource, SliceError};
    // Two boxes side by side: 32 triangles, every side triangle spans the first plane.
    let mut tris = box_at(100.0, 6.0, 0.8);
    tris.extend(box_at(120.0, 6.0, 0.8));
    tris.sort_by_key(Triangle::z_min);
    let capacity = TinySlicer::CAPACITIES.active_triangles;
    let sides_of_two_boxes = 2 * 8;
    assert!(sides_of_two_boxes > capacity as usize);
    let mut p = Box::new(TinySlicer::new(&MachineConfig::default()));
    let mut host: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    host.send(&encode(&Message::JobStart(job(&tris)))).unwrap();
    for b in batches(&tris) {
        host.send(&b).unwrap();
    }
    let mut q = StepQueue::new();
    let mut motion = Box::new(MotionHalf::<'_, 16384, 16, 32>::new(q.split().0));
    let motion = &mut *motion;
    let mut got = Vec::new();
    for now in 1..500u32 {
        carry(&mut host, &mut dev, now);
        p.service(&mut dev, motion, now, 0, 50, false);
        carry(&mut dev, &mut host, now);
        while let Some(m) = host.peek() {
            match Message::decode(m).unwrap() {
                Message::Failure(words) => got.push(words.to_string()),
                Message::Status(s) if s.state == DeviceState::Failed => {
                    got.push(format!("status {:?} {}", s.error, s.detail))
                }
                _ => {}
            }
            host.pop();
        }
    }
    let layer = 0;
    let expected = SliceError::Capacity { what: Resource::ActiveTriangles, capacity, layer };
    assert_eq!(p.failure(), Some(Failure::Slice(expected)));
    assert_eq!(p.error(), (ErrorCode::Slice, layer));
    // The words first, once, then the failed status (repeated).
    assert_eq!(
        got[0],
        format!("slicer: too many active triangles in layer {layer} (capacity {capacity})")
    );
    assert_eq!(got.iter().filter(|g| g.starts_with("slicer")).count(), 1, "{got:?}");
    assert_eq!(got[1], format!("status Slice {layer}"));
}

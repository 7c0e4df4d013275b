//! The printer drive loop, as a board runs it without a link.
//!
//! A job's messages into a [`Printer`] (each offered again while it answers [`Accept::Busy`]), then
//! turn after turn a `poll`, the step queue drained and the finished layers' hashes taken, until
//! the job ends.
//!
//! A [`Rig`] owns the step queue's two ends and says what becomes of the commands:
//! - [`Rig::counting`]: dequeued at once, their steps counted per axis (a fast executor);
//! - [`Rig::recording`]: dequeued and kept per axis, optionally at most
//!   [`Rig::limit_drain`] commands a turn (a slow or uneven one);
//! - [`Rig::executing`]: run by an [`Executor`] on a [`SimBoard`] whose clock the rig
//!   advances from event to event, kept before the published horizon while the motion does
//!   not rest there (so the executor never underruns for want of a poll), its pins
//!   checked against the drivers' timing.
//!
//! The loop is generic over the printer type through [`Device`] (every [`Printer`] is one,
//! whatever its capacities). [`small_printer!`](crate::small_printer) names a test printer by
//! the capacities it changes from [`Sizes::SMALL`].

use strata::geom::Triangle;
use strata::machine::{PrintSettings, AXES};
pub use strata::printer::Printer;
use strata::printer::{Accept, MotionHalf, Stages};
use strata::protocol::{
    BatchBuilder, DeviceState, Endpoint, JobOptions, JobSpec, Message, MAX_PAYLOAD, MAX_WIRE,
};
use strata::sim::{SimBoard, SimTiming};
use strata::step::{
    is_before, Executor, StepCmd, StepConfig, StepConsumer, StepProducer, StepQueue, Wake,
};

/// What the drive loop needs of a printer whose motion half is `Motion<M, P>`, whatever its
/// other capacities.
pub trait Device<const M: usize, const P: usize> {
    /// [`Printer::handle`].
    fn handle<const Q: usize>(
        &mut self,
        msg: &Message<'_>,
        motion: &mut MotionHalf<'_, M, P, Q>,
    ) -> Accept;
    /// [`Printer::poll`].
    fn poll<const Q: usize>(&mut self, motion: &mut MotionHalf<'_, M, P, Q>) -> bool;
    /// [`Printer::take_layer_done`].
    fn take_layer_done(&mut self) -> Option<(u32, u64)>;
    /// [`Printer::state`].
    fn state(&self) -> DeviceState;
    /// [`Printer::is_active`].
    fn is_active(&self) -> bool;
}

// Inherent methods come first in method resolution: each call below is the printer's own.
impl<Pl: Stages, const M: usize, const P: usize> Device<M, P> for Printer<Pl, M, P> {
    fn handle<const Q: usize>(
        &mut self,
        msg: &Message<'_>,
        motion: &mut MotionHalf<'_, M, P, Q>,
    ) -> Accept {
        self.handle(msg, motion)
    }
    fn poll<const Q: usize>(&mut self, motion: &mut MotionHalf<'_, M, P, Q>) -> bool {
        self.poll(motion)
    }
    fn take_layer_done(&mut self) -> Option<(u32, u64)> {
        self.take_layer_done()
    }
    fn state(&self) -> DeviceState {
        self.state()
    }
    fn is_active(&self) -> bool {
        self.is_active()
    }
}

/// Capacities of a test printer, by the names of [`strata::printer_type!`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[allow(missing_docs)] // the names are `printer_type!`'s
pub struct Sizes {
    pub active_triangles: usize,
    pub contour_points: usize,
    pub contour_loops: usize,
    pub toolpath_points: usize,
    pub toolpath_loops: usize,
    pub scan_crossings: usize,
    pub path_points: usize,
    pub window_ring_words: usize,
    pub window_spans: usize,
    pub move_buffer_bytes: usize,
    pub lookahead_moves: usize,
}

impl Sizes {
    /// A printer for small test parts (a few mm, a few layers): 256 active triangles and
    /// contour points, 16 KB of move buffer, 16 moves of lookahead.
    pub const SMALL: Sizes = Sizes {
        active_triangles: 256,
        contour_points: 256,
        contour_loops: 16,
        toolpath_points: 512,
        toolpath_loops: 32,
        scan_crossings: 1024,
        path_points: 4096,
        window_ring_words: 2048,
        window_spans: 2048,
        move_buffer_bytes: 16384,
        lookahead_moves: 16,
    };
}

/// A [`Printer`] type of [`Sizes::SMALL`] but for the capacities named:
///
/// ```
/// strata_testkit::small_printer! {
///     /// A small move buffer.
///     type Tight = { move_buffer_bytes: 4096 };
/// }
/// assert_eq!(Tight::CAPACITIES.move_buffer_bytes, 4096);
/// assert_eq!(Tight::CAPACITIES.active_triangles, 256);
/// ```
#[macro_export]
macro_rules! small_printer {
    (
        $(#[$meta:meta])*
        $vis:vis type $name:ident = { $($key:ident: $value:expr),* $(,)? };
    ) => {
        $crate::small_printer!(@sized $(#[$meta])* $vis $name,
            ($crate::drive::Sizes { $($key: $value,)* ..$crate::drive::Sizes::SMALL }));
    };
    (@sized $(#[$meta:meta])* $vis:vis $name:ident, $s:tt) => {
        ::strata::printer_type! {
            $(#[$meta])*
            $vis type $name = {
                active_triangles: $s.active_triangles,
                contour_points: $s.contour_points,
                contour_loops: $s.contour_loops,
                toolpath_points: $s.toolpath_points,
                toolpath_loops: $s.toolpath_loops,
                scan_crossings: $s.scan_crossings,
                path_points: $s.path_points,
                window_ring_words: $s.window_ring_words,
                window_spans: $s.window_spans,
                move_buffer_bytes: $s.move_buffer_bytes,
                lookahead_moves: $s.lookahead_moves,
            };
        }
    };
}

/// The job of `tris` with the default settings and options: the model's height is its top.
pub fn job_spec(tris: &[Triangle]) -> JobSpec {
    JobSpec {
        settings: PrintSettings::default(),
        options: JobOptions::default(),
        model_height_um: tris.iter().map(Triangle::z_max).max().unwrap_or(0),
        triangles: tris.len() as u32,
    }
}

/// The payload of `msg`.
pub fn encode(msg: &Message<'_>) -> Vec<u8> {
    let mut buf = [0u8; MAX_PAYLOAD];
    let n = msg.encode(&mut buf).expect("the message encodes");
    buf[..n].to_vec()
}

/// One triangle batch's payload (panics when `tris` do not fit one batch).
pub fn batch(tris: &[Triangle]) -> Vec<u8> {
    let mut b = BatchBuilder::new();
    for t in tris {
        b.push(t).expect("the triangles fit one batch");
    }
    b.payload().to_vec()
}

/// Triangle batches as full as they go, in order.
pub fn batches(tris: &[Triangle]) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut b = BatchBuilder::new();
    let mut rest = tris;
    while !rest.is_empty() {
        let n = b.fill(rest);
        assert!(n > 0, "a triangle outside the wire range");
        out.push(b.payload().to_vec());
        b.clear();
        rest = &rest[n..];
    }
    out
}

/// A model's payloads: the [`batches`] of `tris`, then `EndOfModel`.
pub fn model_payloads(tris: &[Triangle]) -> Vec<Vec<u8>> {
    let mut out = batches(tris);
    out.push(encode(&Message::EndOfModel));
    out
}

/// A whole job's payloads: `JobStart(spec)`, then the [`model_payloads`] of `tris`.
pub fn job_payloads(spec: JobSpec, tris: &[Triangle]) -> Vec<Vec<u8>> {
    let mut out = vec![encode(&Message::JobStart(spec))];
    out.extend(model_payloads(tris));
    out
}

/// Starts the job `spec` on `p` (its motion half in `rig`), asserting the printer takes it at
/// once.
pub fn start<D: Device<M, P>, const M: usize, const P: usize, const N: usize>(
    p: &mut D,
    rig: &mut Rig<'_, M, P, N>,
    spec: JobSpec,
) {
    let taken = p.handle(&Message::JobStart(spec), &mut rig.motion);
    assert_eq!(taken, Accept::Taken, "the job start was refused");
}

/// Moves every frame `from` has due at `now` (ms) into `to`.
pub fn carry<const A: usize, const B: usize, const C: usize, const D: usize>(
    from: &mut Endpoint<A, B>,
    to: &mut Endpoint<C, D>,
    now: u32,
) {
    let mut frame = [0u8; MAX_WIRE];
    while let n @ 1.. = from.poll_transmit(now, &mut frame) {
        to.receive(&frame[..n], now);
    }
}

/// An executor on a simulated board: the board's clock as its step timer (pulses end in
/// the call that raises them). Its clock waits at the horizon as the accelerated QEMU
/// board's does: the call due there is made once the horizon has moved past it.
struct Board<'q, const N: usize> {
    board: SimBoard,
    exec: Executor<'q, N>,
    /// The executor's wake-up that waits for the horizon (`None`: call at the clock).
    wake: Option<u32>,
}

impl<const N: usize> Board<'_, N> {
    /// Runs every event before the horizon (to idle when the motion rests there).
    fn run(&mut self) {
        let mut pins = self.board.pins();
        loop {
            if let Some(t) = self.wake {
                let (horizon, at_rest) = self.exec.horizon();
                if !at_rest && !is_before(t, horizon) {
                    return;
                }
                self.board.advance_to_u32(t);
            }
            let now = self.board.now_u32();
            match self.exec.on_timer_with(now, &mut pins, &mut &self.board) {
                Ok(Wake::At(t)) => self.wake = Some(t),
                Ok(Wake::Idle) => {
                    self.wake = None;
                    return;
                }
                Err(never) => match never {},
            }
        }
    }
}

enum Sink<'q, const N: usize> {
    Count(StepConsumer<'q, N>),
    Record(StepConsumer<'q, N>),
    Execute(Box<Board<'q, N>>),
}

/// A turn's drain limit: commands per axis, from the turn and the axis.
type Limit<'q> = Box<dyn FnMut(u64, usize) -> usize + 'q>;

/// The printer's motion half, the step queue's two ends and what the loop has collected: see
/// the [module](self).
pub struct Rig<'q, const M: usize, const P: usize, const N: usize> {
    /// The printer's motion half (move buffer, planner, generator) and the queue's producer.
    pub motion: MotionHalf<'q, M, P, N>,
    sink: Sink<'q, N>,
    limit: Option<Limit<'q>>,
    /// Layer hashes taken from the printer, in order.
    pub hashes: Vec<(u32, u64)>,
    /// Steps per axis: of the commands dequeued, or executed on the board.
    pub steps: [u64; AXES],
    /// The commands per axis ([`Rig::recording`] only).
    pub commands: Vec<Vec<StepCmd>>,
    /// Offers the printer answered [`Accept::Busy`].
    pub busy: u32,
    /// Turns run.
    pub turns: u64,
}

/// Board tick at which a [`Rig::executing`] board starts.
pub const START_TICK: u64 = 1_000;

impl<'q, const M: usize, const P: usize, const N: usize> Rig<'q, M, P, N> {
    fn new(prod: StepProducer<'q, N>, sink: Sink<'q, N>) -> Self {
        let (hashes, steps, commands) = (Vec::new(), [0; AXES], vec![Vec::new(); AXES]);
        let motion = MotionHalf::new(prod);
        Self { motion, sink, limit: None, hashes, steps, commands, busy: 0, turns: 0 }
    }

    /// Commands are dequeued at once and their steps counted.
    pub fn counting(queue: &'q mut StepQueue<N>) -> Self {
        let (prod, cons) = queue.split();
        Self::new(prod, Sink::Count(cons))
    }

    /// Commands are dequeued and kept in [`Rig::commands`].
    pub fn recording(queue: &'q mut StepQueue<N>) -> Self {
        let (prod, cons) = queue.split();
        Self::new(prod, Sink::Record(cons))
    }

    /// Commands run on an executor configured by `config` (the printer's
    /// `step_config()`), on a board starting at [`START_TICK`].
    pub fn executing(queue: &'q mut StepQueue<N>, config: &StepConfig) -> Self {
        let (prod, cons) = queue.split();
        let board = SimBoard::new(SimTiming::from_config(config), START_TICK, ());
        let exec = Executor::new(config, cons);
        Self::new(prod, Sink::Execute(Box::new(Board { board, exec, wake: None })))
    }

    /// Dequeues at most `limit(turn, axis)` commands per axis a turn (counting and recording
    /// rigs; [`Rig::drain_all`] takes the rest).
    pub fn limit_drain(mut self, limit: impl FnMut(u64, usize) -> usize + 'q) -> Self {
        self.limit = Some(Box::new(limit));
        self
    }

    /// The simulated board ([`Rig::executing`] only): violations, positions, step hash.
    pub fn board(&self) -> Option<&SimBoard> {
        match &self.sink {
            Sink::Execute(b) => Some(&b.board),
            _ => None,
        }
    }

    /// The executor ([`Rig::executing`] only).
    pub fn executor(&self) -> Option<&Executor<'q, N>> {
        match &self.sink {
            Sink::Execute(b) => Some(&b.exec),
            _ => None,
        }
    }

    /// Drains the queue as the rig does, within the turn's limit.
    pub fn drain(&mut self) {
        self.drain_within(true);
    }

    /// Drains the whole queue, whatever the limit.
    pub fn drain_all(&mut self) {
        self.drain_within(false);
    }

    fn drain_within(&mut self, limited: bool) {
        let Self { sink, limit, steps, commands, turns, .. } = self;
        let (cons, record) = match sink {
            Sink::Execute(b) => {
                b.run();
                *steps = b.exec.stats().steps;
                return;
            }
            Sink::Count(cons) => (cons, false),
            Sink::Record(cons) => (cons, true),
        };
        for axis in 0..AXES {
            let most = match limit {
                Some(f) if limited => f(*turns, axis),
                _ => usize::MAX,
            };
            for _ in 0..most {
                let Some(cmd) = cons.dequeue(axis) else { break };
                if let StepCmd::Steps { count, .. } = cmd {
                    steps[axis] += u64::from(count);
                }
                if record {
                    commands[axis].push(cmd);
                }
            }
        }
    }

    /// Takes the printer's finished layers' hashes into [`Rig::hashes`].
    pub fn take_hashes<D: Device<M, P>>(&mut self, p: &mut D) {
        while let Some(h) = p.take_layer_done() {
            self.hashes.push(h);
        }
    }

    /// One turn: a `poll`, the queue drained, the hashes taken.
    pub fn turn<D: Device<M, P>>(&mut self, p: &mut D) {
        p.poll(&mut self.motion);
        self.drain();
        self.take_hashes(p);
        self.turns += 1;
    }

    /// The drive loop: each turn offers the `payloads` not yet taken, in order, until one is
    /// refused ([`Accept::Busy`], counted in [`Rig::busy`]) or the job ended; calls
    /// `between(printer, turn)`; runs a [`turn`](Self::turn). Stops once every payload is
    /// taken and the printer is no longer active, or once its job ended (done, failed,
    /// aborted, stopped), or after `max_turns`.
    pub fn drive<D: Device<M, P>>(
        &mut self,
        p: &mut D,
        payloads: &[Vec<u8>],
        max_turns: u64,
        mut between: impl FnMut(&mut D, &mut MotionHalf<'q, M, P, N>, u32),
    ) {
        let mut next = 0;
        for turn in 0..max_turns {
            while next < payloads.len() && (next == 0 || p.is_active()) {
                let msg = Message::decode(&payloads[next]).expect("the payload decodes");
                match p.handle(&msg, &mut self.motion) {
                    Accept::Taken => next += 1,
                    Accept::Busy => {
                        self.busy += 1;
                        break;
                    }
                }
            }
            between(p, &mut self.motion, turn as u32);
            self.turn(p);
            if !p.is_active() && (next == payloads.len() || p.state() != DeviceState::Idle) {
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::{cuboid, to_um};
    use strata::machine::MachineConfig;

    crate::small_printer! {
        type Small = {};
    }

    #[test]
    fn a_small_printer_has_the_small_sizes_but_for_those_named() {
        crate::small_printer! {
            type Roomy = { move_buffer_bytes: 1 << 16, lookahead_moves: 32 };
        }
        let (small, roomy) = (Small::CAPACITIES, Roomy::CAPACITIES);
        assert_eq!((small.move_buffer_bytes, small.active_triangles), (16384, 256));
        assert_eq!((roomy.move_buffer_bytes, roomy.active_triangles), (1 << 16, 256));
    }

    #[test]
    fn a_job_gives_the_same_hashes_and_steps_whichever_way_its_steps_go() {
        let tris = to_um(&cuboid([100.0, 100.0, 0.0], [104.0, 104.0, 0.6]));
        let payloads = job_payloads(job_spec(&tris), &tris);
        assert_eq!(payloads.len(), 3);
        crate::on_big_stack(|| {
            let run = |how: u8| {
                let mut p = Box::new(Small::new(&MachineConfig::default()));
                let mut q = StepQueue::<32>::new();
                let mut rig = match how {
                    0 => Rig::counting(&mut q),
                    1 => {
                        Rig::recording(&mut q).limit_drain(|turn, axis| (turn as usize + axis) % 3)
                    }
                    _ => Rig::executing(&mut q, p.step_config()),
                };
                rig.drive(&mut *p, &payloads, 10_000_000, |_, _, _| {});
                rig.drain_all();
                assert_eq!(p.state(), DeviceState::Done);
                if let Some(board) = rig.board() {
                    assert_eq!(board.violation_count(), 0);
                    assert_eq!(board.axes().map(|a| a.steps), rig.steps);
                    // The executor catches up with the generator every turn, yet no
                    // direction change came too late for its step.
                    let late = rig.executor().map(|e| e.stats().late_dir_steps);
                    assert_eq!(late, Some(0), "steps delayed for DIR's setup");
                }
                (rig.hashes, rig.steps)
            };
            let counted = run(0);
            assert_eq!(counted.0.len(), 3);
            assert!(counted.1.iter().all(|&s| s > 0), "{:?}", counted.1);
            assert_eq!(run(1), counted);
            assert_eq!(run(2), counted);
        });
    }
}

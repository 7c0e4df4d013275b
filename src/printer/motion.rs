//! The motion half of the job runner: the move buffer, the planner with the layer of each
//! move it holds, and the step generator.

use heapless::Deque;

use crate::machine::AXES;
use crate::move_ring::MoveRing;
use crate::plan::{PlanConfig, Planner};
use crate::step::{StepConfig, StepGenerator, StepProducer};

/// The motion half: moves waiting for the planner, the planner and the step generator.
///
/// The moves are delta-coded into `MOVE_BYTES` bytes ([`MoveRing`]); the planner holds `P` moves
/// of lookahead and the layer of each of its moves that makes a block.
///
/// A planner block goes to the generator when its plan is final ([`Planner::pop`]: its exit
/// speed is already the most any later move could allow, and a dwell always ends at rest), or
/// with its current plan when the planner queue is full or the model has ended
/// (`pop_forced`), never earlier because data happened to be late: the blocks depend only on
/// the job, not on when [`feed`](Self::feed) runs, and the step generator's commands depend
/// only on the blocks. A link that falls behind holds the motion only where the plan still
/// waits for later moves, not a whole lookahead queue early: every layer ends at rest (the
/// planner stops at a layer change, about 27 ms a layer on the sample models), so a layer
/// always runs to its end, and its blocks and steps never depend on the next layer's.
pub struct Motion<const MOVE_BYTES: usize, const P: usize> {
    moves: MoveRing<MOVE_BYTES>,
    planner: Planner<P>,
    /// Layer (low 16 bits) and fan duty (the next 8) of every move in the planner that
    /// makes a block.
    tags: Deque<u32, P>,
    /// The layer of the last move into the planner, plus one (0: none yet).
    planned_layer: u32,
    gen: StepGenerator,
    /// The fan duty of the last block into the generator (0..=255).
    fan: u8,
}

impl<const MOVE_BYTES: usize, const P: usize> Default for Motion<MOVE_BYTES, P> {
    fn default() -> Self {
        Self::EMPTY
    }
}

impl<const MOVE_BYTES: usize, const P: usize> Motion<MOVE_BYTES, P> {
    /// Empty buffers, unconfigured (all zero bytes: a `static` of it is in `.bss`).
    pub const EMPTY: Self = Self {
        moves: MoveRing::new(),
        planner: Planner::empty(),
        tags: Deque::new(),
        planned_layer: 0,
        gen: StepGenerator::empty(),
        fan: 0,
    };

    /// Empties every buffer and starts the planner and the generator at the origin.
    pub fn reset(&mut self, plan: &PlanConfig, step: &StepConfig) {
        self.moves.clear();
        self.planner.reset(plan, [0; AXES]);
        self.tags.clear();
        self.planned_layer = 0;
        self.gen.reset(step, [0; AXES]);
        self.fan = 0;
    }

    /// The move buffer.
    pub fn moves(&self) -> &MoveRing<MOVE_BYTES> {
        &self.moves
    }

    /// The move buffer, to fill.
    pub fn moves_mut(&mut self) -> &mut MoveRing<MOVE_BYTES> {
        &mut self.moves
    }

    /// The planner.
    pub fn planner(&self) -> &Planner<P> {
        &self.planner
    }

    /// The step generator (its statistics, motor positions).
    pub fn generator(&self) -> &StepGenerator {
        &self.gen
    }

    /// The part-cooling fan's duty the toolpath asks for where the motion is (the last block
    /// into the step generator's), 0..=255.
    pub fn fan(&self) -> u8 {
        self.fan
    }

    /// The step generator, to take its layer marks.
    pub fn generator_mut(&mut self) -> &mut StepGenerator {
        &mut self.gen
    }

    /// Every move in the buffer, the planner and the generator is done.
    pub fn is_idle(&self) -> bool {
        self.moves.is_empty() && self.planner.is_empty() && self.gen.is_idle()
    }

    /// Moves into the planner, blocks into the generator (when `allowed`), steps into `out`;
    /// true when something happened. `toolpath_done`: the model's last moves are in the
    /// buffer, so the planner may release its blocks without being full. `Err(layer)`: the
    /// planner refused a move of that layer (it stays at the front of the buffer).
    pub fn feed<const Q: usize>(
        &mut self,
        allowed: bool,
        toolpath_done: bool,
        out: &mut StepProducer<'_, Q>,
    ) -> Result<bool, u32> {
        let planned = self.plan_moves()?;
        let released = allowed && self.release_blocks(toolpath_done);
        Ok(self.generate(out) || planned || released)
    }

    /// Blocks from the planner into the generator while it wants one: any head when the
    /// planner is full or the input is done, otherwise a head whose plan is final; true when
    /// one went (see [`Motion::plan_moves`]).
    #[inline(never)]
    fn release_blocks(&mut self, toolpath_done: bool) -> bool {
        let input_done = toolpath_done && self.moves.is_empty();
        let mut released = false;
        while self.gen.wants_block() {
            let block = if input_done || self.planner.is_full() {
                self.planner.pop_forced()
            } else {
                self.planner.pop()
            };
            let Some(b) = block else { break };
            let tag = self.tags.pop_front().unwrap_or(0);
            self.fan = (tag >> 16) as u8;
            // `wants_block` was true: the generator takes it (tagged with its layer: the
            // generator's commands start afresh where the tag changes).
            let _ = self.gen.load_tagged(b, tag & 0xffff);
            released = true;
        }
        released
    }

    /// Steps into `out`; true when one was generated (see [`Motion::plan_moves`]).
    #[inline(never)]
    fn generate<const Q: usize>(&mut self, out: &mut StepProducer<'_, Q>) -> bool {
        let before = self.gen.progress();
        let _ = self.gen.run(out);
        self.gen.progress() != before
    }

    /// Moves from the buffer into the planner while it has room; true when one went in.
    /// Not inlined, nor is the generator's part of [`Motion::feed`]: a board runs `feed` in an
    /// interrupt on top of thread mode's deepest stack, where only the larger of the two
    /// frames counts.
    #[inline(never)]
    fn plan_moves(&mut self) -> Result<bool, u32> {
        let mut worked = false;
        // Each record is decoded once, when the planner has room for it (it is full most of
        // the time: peeking at the head first would decode it on every call).
        while !self.planner.is_full() {
            let Some(t) = self.moves.pop_front() else { break };
            let queued = self.planner.len();
            // A layer starts at rest: its steps depend on its own blocks only (the generator
            // starts its commands afresh there), so a job paused between two layers resumes
            // with the same steps.
            let layer = u32::from(t.layer) + 1;
            if self.planned_layer != layer {
                if self.planned_layer != 0 {
                    self.planner.rest_here();
                }
                self.planned_layer = layer;
            }
            // The planner had room: any refusal is the move's fault and fails the job.
            self.planner.push(t.unpack()).map_err(|_| u32::from(t.layer))?;
            worked = true;
            // A move that goes nowhere makes no block and has no tag (a dwell makes one).
            if self.planner.len() > queued {
                let _ = self.tags.push_back(u32::from(t.layer) | u32::from(t.fan) << 16);
            }
        }
        Ok(worked)
    }
}

/// The job runner's way to the motion half and the step queue's producer.
///
/// On the host (and in tests) the runner's caller owns both ([`MotionHalf`]): direct access.
/// On a board whose interrupt runs the planner and the step generator, the motion half lives
/// in a `static` that the interrupt and thread mode share: each access is a short critical
/// section that holds that interrupt off (the step interrupt keeps running).
pub trait MotionAccess<const MOVE_BYTES: usize, const P: usize, const Q: usize> {
    /// Runs `f` on the motion half and the step queue's producer.
    fn with<R>(
        &mut self,
        f: impl FnOnce(&mut Motion<MOVE_BYTES, P>, &mut StepProducer<'_, Q>) -> R,
    ) -> R;

    /// The job's gate for a motion half that is also fed elsewhere (a board's feed
    /// interrupt): whether blocks may be released and whether the model's last moves are in
    /// the move buffer, the arguments of [`Motion::feed`] ([`Printer::motion_gate`]). The
    /// runner calls it after every message and at every poll; nothing to do where only the
    /// runner feeds.
    ///
    /// [`Printer::motion_gate`]: super::Printer::motion_gate
    fn gate(&mut self, _allowed: bool, _toolpath_done: bool) {}
}

/// The motion half and the step queue's producer, owned together.
pub struct MotionHalf<'q, const MOVE_BYTES: usize, const P: usize, const Q: usize> {
    /// The motion half.
    pub motion: Motion<MOVE_BYTES, P>,
    /// Where the step generator's commands go.
    pub out: StepProducer<'q, Q>,
}

impl<'q, const MOVE_BYTES: usize, const P: usize, const Q: usize> MotionHalf<'q, MOVE_BYTES, P, Q> {
    /// An empty motion half generating into `out`.
    pub fn new(out: StepProducer<'q, Q>) -> Self {
        Self { motion: Motion::EMPTY, out }
    }
}

impl<const MOVE_BYTES: usize, const P: usize, const Q: usize> MotionAccess<MOVE_BYTES, P, Q>
    for MotionHalf<'_, MOVE_BYTES, P, Q>
{
    fn with<R>(
        &mut self,
        f: impl FnOnce(&mut Motion<MOVE_BYTES, P>, &mut StepProducer<'_, Q>) -> R,
    ) -> R {
        f(&mut self.motion, &mut self.out)
    }
}

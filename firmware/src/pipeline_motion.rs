//! The printer's motion half (move buffer, planner, step generator) and the step queue's
//! producer, as the job runner reaches them ([`MotionAccess`]).

use strata::printer::board::{LOOKAHEAD_MOVES, MOVE_BUFFER_BYTES};
use strata::printer::{Motion, MotionAccess};
use strata::step::{StepConfig, StepProducer};

use crate::board;
use crate::capacities::STEP_QUEUE;
use crate::motion::{fresh_queue, Producer};

/// The firmware's motion half.
pub type FwMotionHalf = Motion<MOVE_BUFFER_BYTES, LOOKAHEAD_MOVES>;

/// Where steps were generated during a measured `service` call (the QEMU build's cost
/// figures): instructions spent in accesses that generated steps, when the last one ended,
/// and the longest stretch without one.
#[cfg(feature = "qemu")]
#[derive(Debug, Clone, Copy, Default)]
pub struct Generation {
    /// Accesses are measured (inside a measured `service` call).
    pub measuring: bool,
    /// Thread instructions in accesses that generated steps.
    pub lent: u64,
    /// Thread instructions when steps were last generated.
    pub generated_at: u64,
    /// The longest stretch without step generation, instructions.
    pub gap_max: u64,
}

/// The motion half and the step queue's producer of the main loop.
pub struct FwMotion {
    motion: &'static mut FwMotionHalf,
    /// Always set (taken only while it is replaced, inside [`FwMotion::reset_queue`]).
    prod: Option<Producer>,
    /// Where steps were generated (QEMU's cost figures).
    #[cfg(feature = "qemu")]
    pub generation: Generation,
}

impl FwMotion {
    /// The motion half `motion` with a fresh step queue (see [`FwMotion::reset_queue`]).
    pub fn new(motion: &'static mut FwMotionHalf, cfg: &StepConfig) -> Self {
        let prod = board::with_motion(|m| {
            let _old_exec = m.halt();
            // SAFETY: no producer or executor exists yet (this is the first queue; the
            // interrupt's executor was just taken).
            let (p, e) = unsafe { fresh_queue(cfg) };
            m.install(e);
            p
        });
        #[cfg(feature = "qemu")]
        let generation = Generation::default();
        Self {
            motion,
            prod: Some(prod),
            #[cfg(feature = "qemu")]
            generation,
        }
    }

    /// A fresh step queue: the interrupt's executor and this producer are replaced together
    /// (the old ones are dropped first); the motion halts, drivers off.
    pub fn reset_queue(&mut self, cfg: &StepConfig) {
        let slot = &mut self.prod;
        board::with_motion(|m| {
            // Both ends of the old queue go away here (neither has a destructor; what matters
            // is that no borrow of the queue outlives this point).
            {
                let _old_exec = m.halt();
                let _old_prod = slot.take();
            }
            // SAFETY: the previous executor and producer are dropped above, inside this
            // critical section, so nothing borrows the queue any more.
            let (p, e) = unsafe { fresh_queue(cfg) };
            m.install(e);
            *slot = Some(p);
        });
    }

    /// The step queue's producer (its fill, for the board).
    pub fn producer(&self) -> &Producer {
        self.prod.as_ref().expect("the step queue is set up")
    }

    /// The motion half.
    pub fn half(&self) -> &FwMotionHalf {
        self.motion
    }
}

impl MotionAccess<MOVE_BUFFER_BYTES, LOOKAHEAD_MOVES, STEP_QUEUE> for FwMotion {
    fn with<R>(
        &mut self,
        f: impl FnOnce(&mut FwMotionHalf, &mut StepProducer<'_, STEP_QUEUE>) -> R,
    ) -> R {
        #[cfg(feature = "qemu")]
        let (t0, s0) = (crate::cost::thread_now(), self.motion.generator().steps_generated());
        let prod = self.prod.as_mut().expect("the step queue is set up");
        let r = f(self.motion, prod);
        #[cfg(feature = "qemu")]
        if self.generation.measuring && self.motion.generator().steps_generated() != s0 {
            let g = &mut self.generation;
            let t1 = crate::cost::thread_now();
            g.gap_max = g.gap_max.max(t0 - g.generated_at.min(t0));
            g.lent += t1 - t0;
            g.generated_at = t1;
        }
        r
    }
}

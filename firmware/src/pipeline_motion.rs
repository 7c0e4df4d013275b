//! The printer's motion half (move buffer, planner, step generator) and the step queue's
//! producer, shared by thread mode and the feed interrupt.
//!
//! # Priorities
//! Three levels, highest first (set by each board's `init`, RTIC-style: hand-rolled because
//! RTIC 2's `#[app]` owns `main` and every interrupt of the image, and the QEMU board's SysTick
//! is both the executor and the emulated clock):
//! 1. the step interrupt (the executor: QEMU's SysTick, the Creality's TIM2), never masked
//!    except by the short `interrupt::free` sections of `board::with_motion`;
//! 2. the feed interrupt, PendSV at [`FEED_PRIORITY`] (the lowest): planning and step
//!    generation until the step queue is full or the planner has nothing to release
//!    ([`feed`]); the board pends it periodically while a job runs (both boards: about once a
//!    millisecond of the chip, QEMU from its SysTick, the Creality from TIM2 and SysTick);
//! 3. thread mode: the protocol, slicing, toolpaths, the heaters. It reaches the motion half
//!    only through [`locked`], which raises BASEPRI to [`FEED_PRIORITY`]: the feed waits, the
//!    executor does not. A thread-mode access holds it for as long as its closure runs (a move
//!    pushed, a poll's feed, the toolpath stage's moves into the buffer); the QEMU build
//!    measures the longest (`COST ... lock_insns_max`).
//!
//! The step commands depend only on the moves and the job's gate, not on which level made
//! them or when, so the steps and their ticks stay those of the host simulation.

use core::cell::UnsafeCell;

use cortex_m::register::{basepri, basepri_max};
use cortex_m_rt::exception;
use strata::printer::board::{LOOKAHEAD_MOVES, MOVE_BUFFER_BYTES};
use strata::printer::{Motion, MotionAccess};
use strata::step::{StepConfig, StepProducer};

use crate::board;
use crate::capacities::STEP_QUEUE;
use crate::motion::{fresh_queue, Producer};

/// The firmware's motion half.
pub type FwMotionHalf = Motion<MOVE_BUFFER_BYTES, LOOKAHEAD_MOVES>;

/// Priority of the feed interrupt (PendSV), and the BASEPRI that masks it: the lowest level
/// (the Creality's STM32F103 implements 4 priority bits, QEMU's lm3s6965 3: either keeps the
/// top bits of the same byte, so the handler and the mask agree on both).
pub const FEED_PRIORITY: u8 = 0xF0;

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
    /// The layer of the blocks the last lent access generated steps for (the generator's
    /// tag).
    pub lent_layer: u32,
}

/// What thread mode and the feed interrupt share.
struct Shared {
    /// Set once at start-up ([`FwMotion::new`]).
    motion: Option<&'static mut FwMotionHalf>,
    /// Taken only while it is replaced, inside [`FwMotion::reset_queue`].
    prod: Option<Producer>,
    /// The job's gate ([`MotionAccess::gate`]): blocks may be released, the model's last
    /// moves are in the buffer.
    allowed: bool,
    toolpath_done: bool,
    /// The longest thread-mode hold of the lock, instructions (QEMU).
    #[cfg(feature = "qemu")]
    lock_max: u32,
    /// The feed interrupt's instructions since thread mode last took them and the layer
    /// whose blocks it generated first (the generator's tag; thread mode takes them often,
    /// so they seldom span a layer's end) (QEMU).
    #[cfg(feature = "qemu")]
    feed_work: (u32, u32),
}

/// The feed interrupt's instructions since start-up (QEMU), SysTick's taken out: written by
/// PendSV only, read by thread mode ([`feed_insns_total`]).
#[cfg(feature = "qemu")]
static FEED_INSNS: [core::sync::atomic::AtomicU32; 2] =
    [core::sync::atomic::AtomicU32::new(0), core::sync::atomic::AtomicU32::new(0)];

/// The feed interrupt's instructions so far (QEMU).
#[cfg(feature = "qemu")]
pub fn feed_insns_total() -> u64 {
    use core::sync::atomic::Ordering::Acquire;
    // Low word, high word: PendSV may run between the reads; a changed high word retries.
    loop {
        let hi = FEED_INSNS[1].load(Acquire);
        let lo = FEED_INSNS[0].load(Acquire);
        if FEED_INSNS[1].load(Acquire) == hi {
            return (hi as u64) << 32 | lo as u64;
        }
    }
}

/// Counts `d` feed-interrupt instructions, of which `work` for the layer whose blocks the
/// generator holds (QEMU; PendSV only).
#[cfg(feature = "qemu")]
fn count_feed(s: &mut Shared, work: u64, d: u64) {
    use core::sync::atomic::Ordering::{Relaxed, Release};
    let (sum, carry) = FEED_INSNS[0].load(Relaxed).overflowing_add(d as u32);
    if carry {
        FEED_INSNS[1].fetch_add(1, Release);
    }
    FEED_INSNS[0].store(sum, Release);
    if work == 0 {
        return;
    }
    let w = &mut s.feed_work;
    if w.1 == 0 {
        w.0 = s.motion.as_deref().and_then(|m| m.generator().tag()).unwrap_or(0);
    }
    w.1 = w.1.saturating_add(work as u32);
}

/// The feed interrupt's instructions since the last call and their layer (QEMU).
#[cfg(feature = "qemu")]
pub fn take_feed_work() -> (u32, u32) {
    locked(|s| core::mem::take(&mut s.feed_work))
}

struct SharedCell(UnsafeCell<Shared>);

// SAFETY: `Shared` is reached only by thread mode inside `locked` (PendSV masked) and by the
// PendSV handler, which cannot preempt that section and which thread mode cannot preempt.
unsafe impl Sync for SharedCell {}

static SHARED: SharedCell = SharedCell(UnsafeCell::new(Shared {
    motion: None,
    prod: None,
    allowed: false,
    toolpath_done: false,
    #[cfg(feature = "qemu")]
    lock_max: 0,
    #[cfg(feature = "qemu")]
    feed_work: (0, 0),
}));

/// Runs `f` on the shared state with the feed interrupt masked (BASEPRI), the step interrupt
/// not. Thread mode only (a handler above PendSV must not call it).
fn locked<R>(f: impl FnOnce(&mut Shared) -> R) -> R {
    let old = basepri::read();
    // Raises BASEPRI only (masks more, never less); restored below.
    basepri_max::write(FEED_PRIORITY);
    #[cfg(feature = "qemu")]
    let t0 = board::insns_now();
    // SAFETY: PendSV, the only other user, is masked until BASEPRI is restored, and thread
    // mode does not nest `locked` (every caller below is a leaf).
    let shared = unsafe { &mut *SHARED.0.get() };
    let r = f(shared);
    #[cfg(feature = "qemu")]
    {
        let held = u32::try_from(board::insns_now() - t0).unwrap_or(u32::MAX);
        shared.lock_max = shared.lock_max.max(held);
    }
    // SAFETY: restores the level this call found.
    unsafe { basepri::write(old) };
    r
}

/// Feeds calls a PendSV makes at most (each plans what fits, releases what the generator
/// takes and generates until the queue is full; one that does nothing ends the run).
const FEEDS_PER_PENDSV: u32 = 64;

/// Planning and step generation until there is nothing to do; true when something was done.
fn feed(s: &mut Shared) -> bool {
    let (Some(m), Some(p)) = (s.motion.as_deref_mut(), s.prod.as_mut()) else { return false };
    let mut worked = false;
    for _ in 0..FEEDS_PER_PENDSV {
        // A planning error stays in place for the printer's next poll to report.
        if m.feed(s.allowed, s.toolpath_done, p) != Ok(true) {
            break;
        }
        worked = true;
    }
    worked
}

#[exception]
fn PendSV() {
    // SAFETY: thread mode reaches `SHARED` only with PendSV masked (`locked`); no other
    // handler reaches it.
    let s = unsafe { &mut *SHARED.0.get() };
    #[cfg(feature = "qemu")]
    let t0 = crate::cost::outside_systick_now();
    let _worked = feed(s);
    // A call that did work counts with its layer; the others (the board pends one once a
    // millisecond whatever the queue holds) are the feed's polling, left out of the figures as
    // thread mode's idle turns are.
    #[cfg(feature = "qemu")]
    {
        let d = crate::cost::outside_systick_now().saturating_sub(t0);
        count_feed(s, if _worked { d } else { 0 }, d);
    }
}

/// Asks for a feed (PendSV runs once no higher level is active).
pub fn pend_feed() {
    cortex_m::peripheral::SCB::set_pendsv();
}

/// The longest thread-mode hold of the motion half's lock so far, instructions (QEMU); the
/// measure restarts.
#[cfg(feature = "qemu")]
pub fn take_lock_max() -> u32 {
    locked(|s| core::mem::take(&mut s.lock_max))
}

/// Thread mode's handle on the shared motion half and the step queue's producer.
pub struct FwMotion {
    /// Where steps were generated (QEMU's cost figures).
    #[cfg(feature = "qemu")]
    pub generation: Generation,
}

impl FwMotion {
    /// The motion half `motion` with a fresh step queue (see [`FwMotion::reset_queue`]).
    pub fn new(motion: &'static mut FwMotionHalf, cfg: &StepConfig) -> Self {
        locked(|s| s.motion = Some(motion));
        let mut m = Self {
            #[cfg(feature = "qemu")]
            generation: Generation::default(),
        };
        m.reset_queue(cfg);
        m
    }

    /// A fresh step queue: the interrupt's executor and this producer are replaced together
    /// (the old ones are dropped first); the motion halts, drivers off. The interrupts are
    /// off only to take the executor out and to put the new one in, not while the queue is
    /// cleared (3 KB: the UART's byte must not wait for it).
    pub fn reset_queue(&mut self, cfg: &StepConfig) {
        locked(|s| {
            // Both ends of the old queue go away here (neither has a destructor; what matters
            // is that no borrow of the queue outlives this point).
            {
                let _old_exec = board::with_motion(|m| m.halt());
                let _old_prod = s.prod.take();
            }
            // SAFETY: the previous executor and producer are dropped above, and the
            // interrupt has none (`halt`): nothing borrows the queue any more.
            let (p, e) = unsafe { fresh_queue(cfg) };
            board::with_motion(|m| m.install(e));
            s.prod = Some(p);
        });
    }

    /// Runs a feed as PendSV's, then `f` on the motion half and the producer, in one
    /// section: what `f` reads of the generator (blocked on a full queue or not) is up to
    /// date with the queue, not as of the last PendSV (the accelerated QEMU board decides
    /// from it whether the executor must stall).
    pub fn peek_fed<R>(&self, f: impl FnOnce(&FwMotionHalf, &Producer) -> R) -> R {
        locked(|s| {
            feed(s);
            let m = s.motion.as_deref().expect("the motion half is set up");
            f(m, s.prod.as_ref().expect("the step queue is set up"))
        })
    }

    /// Runs `f` on the motion half and the step queue's producer (feed masked).
    pub fn peek<R>(&self, f: impl FnOnce(&FwMotionHalf, &Producer) -> R) -> R {
        locked(|s| {
            let m = s.motion.as_deref().expect("the motion half is set up");
            f(m, s.prod.as_ref().expect("the step queue is set up"))
        })
    }
}

impl MotionAccess<MOVE_BUFFER_BYTES, LOOKAHEAD_MOVES, STEP_QUEUE> for FwMotion {
    fn with<R>(
        &mut self,
        f: impl FnOnce(&mut FwMotionHalf, &mut StepProducer<'_, STEP_QUEUE>) -> R,
    ) -> R {
        #[cfg(feature = "qemu")]
        let t0 = crate::cost::thread_now();
        let (r, _generated) = locked(|s| {
            let m = s.motion.as_deref_mut().expect("the motion half is set up");
            let prod = s.prod.as_mut().expect("the step queue is set up");
            // Whether `f` generated steps, and for which layer: the QEMU build's cost
            // figures only.
            #[cfg(feature = "qemu")]
            let s0 = m.generator().progress();
            let r = f(m, prod);
            #[cfg(feature = "qemu")]
            let generated = (m.generator().progress() != s0).then(|| m.generator().tag());
            #[cfg(not(feature = "qemu"))]
            let generated = ();
            (r, generated)
        });
        #[cfg(feature = "qemu")]
        if let (true, Some(tag)) = (self.generation.measuring, _generated) {
            let g = &mut self.generation;
            let t1 = crate::cost::thread_now();
            g.gap_max = g.gap_max.max(t0 - g.generated_at.min(t0));
            g.lent += t1 - t0;
            g.generated_at = t1;
            if let Some(layer) = tag {
                g.lent_layer = layer;
            }
        }
        r
    }

    fn gate(&mut self, allowed: bool, toolpath_done: bool) {
        locked(|s| {
            s.allowed = allowed;
            s.toolpath_done = toolpath_done;
        });
    }
}

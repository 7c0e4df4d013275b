//! What the step interrupt owns: the executor, the step/dir/enable pins, homing, and the step
//! queue between the pipeline (thread mode) and the interrupt.
//!
//! The board's timer interrupt calls [`Motion::event`] at (or after) the time it returned
//! last; thread mode reaches the same [`Motion`] only inside critical sections (the board
//! keeps it in a `cortex_m::interrupt::Mutex`). Everything here is integer work.

use core::cell::UnsafeCell;
use core::convert::Infallible;

use embedded_hal::digital::{OutputPin, PinState};
use strata::machine::MachineConfig;
use strata::step::{Executor, Pins, StepConfig, StepProducer, StepQueue, StepTimer, Wake};

use crate::capacities::STEP_QUEUE;

/// The executor as the firmware uses it.
pub type Exec = Executor<'static, STEP_QUEUE>;
/// The generator's end of the step queue.
pub type Producer = StepProducer<'static, STEP_QUEUE>;

/// The endstops of X, Y, Z as the homing sees them.
pub trait Endstops {
    /// True when `axis`' endstop is hit, after `travelled` homing steps toward it.
    fn hit(&mut self, axis: usize, travelled: u32) -> bool;
}

/// Homing speeds, mm/s (X, Y, Z): Marlin's stock Ender-3 homing feed rates.
const HOME_MM_S: [u32; 3] = [50, 50, 4];
/// Homing gives up after this much travel, mm (an endstop that never triggers).
const HOME_MAX_MM: [u32; 3] = [230, 230, 260];

/// G28-like homing, one axis after the other (X, Y, Z), each toward its min endstop at a
/// constant rate; the axis' position is 0 where the endstop triggers.
#[derive(Debug, Clone, Copy)]
struct Homing {
    axis: usize,
    travelled: u32,
    high: bool,
    interval: [u32; 3],
    limit: [u32; 3],
    high_ticks: u32,
    setup_ticks: u32,
    /// Endstops that did not trigger within the limit (bit per axis).
    missed: u8,
}

/// What the interrupt should do next.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Next {
    /// Call again at this tick.
    At(u32),
    /// Nothing to do: call again after queuing steps (or poll).
    Idle,
    /// The executor waits for the pipeline (underrun): poll again, any time.
    Stalled(u32),
}

/// Everything the step interrupt owns.
pub struct Motion<P, E> {
    exec: Option<Exec>,
    /// STEP, DIR per axis and the shared enable.
    pub pins: Pins<P>,
    /// The endstops.
    pub endstops: E,
    homing: Option<Homing>,
    /// Homing finished since the last [`Motion::take_homed`] (bit 7: done; bits 0-2: missed).
    homed: Option<u8>,
    cfg: StepConfig,
}

impl<P: OutputPin<Error = Infallible>, E: Endstops> Motion<P, E> {
    /// Motion with no executor yet (see [`Motion::restart`]); pins as they are.
    pub fn new(cfg: StepConfig, pins: Pins<P>, endstops: E) -> Self {
        Self { exec: None, pins, endstops, homing: None, homed: None, cfg }
    }

    /// The executor (its counters, positions).
    pub fn exec(&self) -> Option<&Exec> {
        self.exec.as_ref()
    }

    /// Homing or executing steps.
    pub fn busy(&self) -> bool {
        self.homing.is_some() || self.exec.as_ref().is_some_and(|e| !e.is_idle())
    }

    /// Homing in progress.
    pub fn homing(&self) -> bool {
        self.homing.is_some()
    }

    /// `Some(missed endstops bitmask)` once after each homing completes.
    pub fn take_homed(&mut self) -> Option<u8> {
        self.homed.take()
    }

    /// Drops the executor (and with it the queue's consumer end): no step from now on.
    /// STEP pins go low; drivers are disabled.
    pub fn halt(&mut self) -> Option<Exec> {
        self.homing = None;
        for p in &mut self.pins.step {
            let _ = p.set_low();
        }
        self.set_enabled(false);
        self.exec.take()
    }

    /// Installs a fresh executor.
    pub fn install(&mut self, exec: Exec) {
        self.exec = Some(exec);
    }

    /// Drivers on or off (the shared enable pin, active low on every board here).
    pub fn set_enabled(&mut self, on: bool) {
        let level = on != self.cfg.enable_active_low;
        let _ = self.pins.enable.set_state(PinState::from(level));
    }

    /// Turns the drivers off when nothing moves (motors disabled when idle).
    pub fn disable_if_idle(&mut self) {
        if self.homing.is_none() {
            if let Some(e) = &mut self.exec {
                let _ = e.disable(&mut self.pins);
            } else {
                self.set_enabled(false);
            }
        }
    }

    /// Starts homing X, Y, Z (the executor waits until it is done).
    pub fn start_homing(&mut self, machine: &MachineConfig) {
        let hz = self.cfg.timer_hz;
        let spm: [u32; 3] = core::array::from_fn(|a| machine.steps_per_mm[a].to_num::<u32>());
        self.homing = Some(Homing {
            axis: 0,
            travelled: 0,
            high: false,
            interval: core::array::from_fn(|a| hz / (HOME_MM_S[a] * spm[a]).max(1)),
            limit: core::array::from_fn(|a| HOME_MAX_MM[a] * spm[a]),
            high_ticks: self.cfg.step_high_ticks(),
            setup_ticks: self.cfg.ns_to_ticks(self.cfg.driver.dir_setup_ns).max(1),
            missed: 0,
        });
        self.homed = None;
        self.set_enabled(true);
        // Toward min: DIR at the level of negative motion, then wait the setup time.
        for a in 0..3 {
            let _ = self.pins.dir[a].set_state(PinState::from(self.cfg.invert_dir[a]));
        }
    }

    /// Services the event due at `now` (a homing step edge or the executor's events);
    /// `timer` is the step timer's clock, read by the executor to end its STEP pulses in the
    /// same call.
    #[inline]
    pub fn event(&mut self, now: u32, timer: &mut impl StepTimer) -> Next {
        if let Some(h) = &mut self.homing {
            return match home_step(h, now, &mut self.pins, &mut self.endstops) {
                Some(next) => Next::At(next),
                None => {
                    self.homed = Some(0x80 | h.missed);
                    self.homing = None;
                    // The executor starts from idle with its lead time: at least the DIR
                    // setup after homing's last edge.
                    Next::At(now.wrapping_add(self.cfg.step_high_ticks()))
                }
            };
        }
        let Some(exec) = &mut self.exec else { return Next::Idle };
        let w = match exec.on_timer_with(now, &mut self.pins, timer) {
            Ok(w) => w,
            Err(e) => match e {},
        };
        match w {
            Wake::Idle => Next::Idle,
            Wake::At(t) if exec.is_stalled() => Next::Stalled(t),
            Wake::At(t) => Next::At(t),
        }
    }
}

/// One homing edge at `now`; `None` when every axis is home.
fn home_step<P: OutputPin<Error = Infallible>, E: Endstops>(
    h: &mut Homing,
    now: u32,
    pins: &mut Pins<P>,
    ends: &mut E,
) -> Option<u32> {
    if h.axis >= 3 {
        return None;
    }
    let a = h.axis;
    if h.high {
        let _ = pins.step[a].set_low();
        h.high = false;
        return Some(now.wrapping_add(h.interval[a].saturating_sub(h.high_ticks).max(1)));
    }
    if h.travelled >= h.limit[a] || ends.hit(a, h.travelled) {
        if h.travelled >= h.limit[a] {
            h.missed |= 1 << a;
        }
        h.axis += 1;
        h.travelled = 0;
        if h.axis >= 3 {
            return None;
        }
        // The next axis' DIR was set at the start; give it the setup time anyway.
        return Some(now.wrapping_add(h.setup_ticks));
    }
    let _ = pins.step[a].set_high();
    h.high = true;
    h.travelled += 1;
    Some(now.wrapping_add(h.high_ticks))
}

/// The step queue in a static, re-initialised on every motion reset (emergency stop, abort).
struct QueueCell(UnsafeCell<StepQueue<STEP_QUEUE>>);

// SAFETY: the queue is only reached through `fresh_queue`, whose callers guarantee that no
// producer or consumer of the previous split exists any more; after a split the two ends are
// an SPSC pair (one in thread mode, one in the interrupt), which heapless' spsc supports.
unsafe impl Sync for QueueCell {}

static QUEUE: QueueCell = QueueCell(UnsafeCell::new(StepQueue::new()));

/// A new, empty queue split into a producer and an executor for `cfg`.
///
/// # Safety
/// Every [`Producer`] and [`Exec`] returned by an earlier call must have been dropped (they
/// borrow the same static queue).
pub unsafe fn fresh_queue(cfg: &StepConfig) -> (Producer, Exec) {
    // SAFETY: by the contract above nothing else borrows the queue now, so this is the only
    // reference to it; the halves it hands out borrow it for 'static from here on.
    let q: &'static mut StepQueue<STEP_QUEUE> = unsafe { &mut *QUEUE.0.get() };
    *q = StepQueue::new();
    let (p, c) = q.split();
    (p, Executor::new(cfg, c))
}

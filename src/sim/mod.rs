//! Simulated stepper backend: the board's pin and timer interface with a clock you advance by
//! hand, for the integration tests, the host's simulated printer and the QEMU firmware.
//!
//! A [`SimBoard`] owns the clock (a `u64` tick count; the executor sees its low 32 bits, so
//! runs can cross the `u32` wrap) and nine [`SimPin`]s (STEP and DIR per axis, the shared
//! enable) implementing `embedded-hal`'s [`OutputPin`]. Every level change is an edge at the
//! current tick. The board itself, without allocation:
//! - checks the driver timing ([`SimTiming`]): STEP high and low times, DIR setup before a
//!   rising STEP edge, no DIR change while STEP is high, no step while the drivers are
//!   disabled; it counts violations and keeps the first ([`Violation`]) and the smallest
//!   margins seen;
//! - counts steps and reconstructs each axis' position (DIR level, inversion);
//! - keeps a running FNV-1a hash over `(axis, direction, tick - origin)` of every step, which
//!   host simulation and firmware can compare;
//! - passes every edge and step to an [`EdgeObserver`] (`()` ignores them; the tests record
//!   them into `Vec`s).

use core::cell::{Cell, Ref, RefCell};
use core::convert::Infallible;

use embedded_hal::digital::{ErrorType, OutputPin};

use crate::machine::AXES;
use crate::step::{Pins, StepConfig, StepTimer};

/// One of the simulated pins.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PinId {
    /// STEP of an axis (0 = X .. 3 = E).
    Step(u8),
    /// DIR of an axis.
    Dir(u8),
    /// The shared enable pin.
    Enable,
}

/// A level change of a pin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Edge {
    /// Which pin.
    pub pin: PinId,
    /// New level.
    pub high: bool,
    /// Board tick of the change.
    pub tick: u64,
}

/// Receives the board's edges and steps as they happen.
pub trait EdgeObserver {
    /// A pin changed level.
    fn on_edge(&mut self, _edge: &Edge) {}
    /// A rising STEP edge: `axis` moved one step (`positive` direction) to `position`.
    fn on_step(&mut self, _axis: usize, _positive: bool, _tick: u64, _position: i64) {}
}

impl EdgeObserver for () {}

/// The driver timing the board checks, in ticks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SimTiming {
    /// Shortest allowed STEP high time.
    pub min_high_ticks: u64,
    /// Shortest allowed STEP low time.
    pub min_low_ticks: u64,
    /// Shortest allowed DIR-change-to-rising-STEP time.
    pub dir_setup_ticks: u64,
    /// DIR low means positive, per axis.
    pub invert_dir: [bool; AXES],
    /// Enable is active low.
    pub enable_active_low: bool,
}

impl SimTiming {
    /// The limits of `config`'s driver, measured exactly (`ns` rounded up to ticks).
    pub fn from_config(config: &StepConfig) -> Self {
        Self {
            min_high_ticks: config.ns_to_ticks(config.driver.step_high_ns) as u64,
            min_low_ticks: config.ns_to_ticks(config.driver.step_low_ns) as u64,
            dir_setup_ticks: config.ns_to_ticks(config.driver.dir_setup_ns) as u64,
            invert_dir: config.invert_dir,
            enable_active_low: config.enable_active_low,
        }
    }
}

/// What went wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ViolationKind {
    /// STEP was high for less than the minimum.
    PulseTooShort,
    /// STEP was low for less than the minimum between two pulses.
    LowTooShort,
    /// A rising STEP edge came less than the setup time after a DIR change.
    DirSetup,
    /// DIR changed while STEP was high.
    DirDuringPulse,
    /// A step while the drivers were disabled.
    StepWhileDisabled,
}

const KINDS: usize = 5;

/// A timing violation.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Violation {
    /// What.
    pub kind: ViolationKind,
    /// Axis.
    pub axis: u8,
    /// Board tick.
    pub tick: u64,
    /// The measured time that was too short, ticks (0 where not a duration).
    pub measured_ticks: u64,
}

/// Per-axis record of the board.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisRecord {
    /// Position in steps (reconstructed from STEP and DIR).
    pub position: i64,
    /// Steps taken.
    pub steps: u64,
    /// Tick of the last rising STEP edge.
    pub last_rise: Option<u64>,
    /// Shortest STEP high time seen, ticks.
    pub min_high_seen: Option<u64>,
    /// Shortest STEP low time seen, ticks.
    pub min_low_seen: Option<u64>,
    /// Shortest DIR setup seen before a step, ticks.
    pub min_setup_seen: Option<u64>,
    last_fall: Option<u64>,
    dir_change: Option<u64>,
    step_high: bool,
    dir_high: bool,
}

#[derive(Debug, Clone)]
struct SimState {
    axes: [AxisRecord; AXES],
    enable_high: bool,
    violations: [u32; KINDS],
    first_violation: Option<Violation>,
    hash: u64,
    hash_origin: u64,
    edges: u64,
}

/// The simulated board: clock, pins, checks and an observer.
#[derive(Debug)]
pub struct SimBoard<O = ()> {
    now: Cell<u64>,
    timing: SimTiming,
    state: RefCell<SimState>,
    observer: RefCell<O>,
}

/// A simulated output pin of a [`SimBoard`].
#[derive(Debug)]
pub struct SimPin<'b, O> {
    board: &'b SimBoard<O>,
    id: PinId,
}

impl<O: EdgeObserver> ErrorType for SimPin<'_, O> {
    type Error = Infallible;
}

impl<O: EdgeObserver> OutputPin for SimPin<'_, O> {
    fn set_low(&mut self) -> Result<(), Infallible> {
        self.board.edge(self.id, false);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        self.board.edge(self.id, true);
        Ok(())
    }
}

impl<O: EdgeObserver> SimBoard<O> {
    /// A board at `start_tick` with every STEP and DIR pin low and the drivers disabled
    /// (enable at its inactive level, as the board's pull-up holds it).
    pub fn new(timing: SimTiming, start_tick: u64, observer: O) -> Self {
        Self {
            now: Cell::new(start_tick),
            timing,
            state: RefCell::new(SimState {
                axes: [AxisRecord::default(); AXES],
                enable_high: timing.enable_active_low,
                violations: [0; KINDS],
                first_violation: None,
                hash: crate::step::FNV_OFFSET,
                hash_origin: start_tick,
                edges: 0,
            }),
            observer: RefCell::new(observer),
        }
    }

    /// The nine pins.
    pub fn pins(&self) -> Pins<SimPin<'_, O>> {
        let pin = |id| SimPin { board: self, id };
        Pins {
            step: core::array::from_fn(|a| pin(PinId::Step(a as u8))),
            dir: core::array::from_fn(|a| pin(PinId::Dir(a as u8))),
            enable: pin(PinId::Enable),
        }
    }

    /// Current tick.
    pub fn now(&self) -> u64 {
        self.now.get()
    }

    /// Current tick as the executor's wrapping timer sees it.
    pub fn now_u32(&self) -> u32 {
        self.now.get() as u32
    }

    /// Advances the clock to `tick` (never backwards).
    pub fn advance_to(&self, tick: u64) {
        self.now.set(self.now.get().max(tick));
    }

    /// Advances to the next time whose low 32 bits are `tick` (wrap-aware; no move if `tick`
    /// is not after now).
    pub fn advance_to_u32(&self, tick: u32) {
        let d = tick.wrapping_sub(self.now_u32()) as i32;
        if d > 0 {
            self.now.set(self.now.get() + d as u64);
        }
    }

    /// Step hashes count ticks from `tick` (default: the start tick).
    pub fn set_hash_origin(&self, tick: u64) {
        self.state.borrow_mut().hash_origin = tick;
    }

    /// Running FNV-1a hash of every step `(axis, direction, tick - origin as u32 LE)`.
    pub fn step_hash(&self) -> u64 {
        self.state.borrow().hash
    }

    /// Per-axis records.
    pub fn axes(&self) -> [AxisRecord; AXES] {
        self.state.borrow().axes
    }

    /// Positions in steps.
    pub fn positions(&self) -> [i64; AXES] {
        self.state.borrow().axes.map(|a| a.position)
    }

    /// Number of violations of each kind, in [`ViolationKind`] order.
    pub fn violations(&self) -> [u32; KINDS] {
        self.state.borrow().violations
    }

    /// Total number of violations.
    pub fn violation_count(&self) -> u32 {
        self.state.borrow().violations.iter().sum()
    }

    /// The first violation.
    pub fn first_violation(&self) -> Option<Violation> {
        self.state.borrow().first_violation
    }

    /// Edges seen.
    pub fn edge_count(&self) -> u64 {
        self.state.borrow().edges
    }

    /// The drivers are enabled.
    pub fn enabled(&self) -> bool {
        self.state.borrow().enable_high != self.timing.enable_active_low
    }

    /// The observer.
    pub fn observer(&self) -> Ref<'_, O> {
        self.observer.borrow()
    }

    /// Takes the observer back.
    pub fn into_observer(self) -> O {
        self.observer.into_inner()
    }

    fn edge(&self, pin: PinId, high: bool) {
        let tick = self.now.get();
        let t = &self.timing;
        let mut st = self.state.borrow_mut();
        let enabled = st.enable_high != t.enable_active_low;
        let mut found: [Option<(ViolationKind, u64)>; 2] = [None; 2];
        let mut step: Option<(usize, bool, i64)> = None;
        let axis = match pin {
            PinId::Step(a) | PinId::Dir(a) => a as usize,
            PinId::Enable => 0,
        };
        match pin {
            PinId::Step(_) => {
                let a = &mut st.axes[axis];
                if a.step_high == high {
                    return;
                }
                a.step_high = high;
                if high {
                    if !enabled {
                        found[0] = Some((ViolationKind::StepWhileDisabled, 0));
                    }
                    if let Some(f) = a.last_fall {
                        let low = tick - f;
                        a.min_low_seen = Some(a.min_low_seen.map_or(low, |m| m.min(low)));
                        if low < t.min_low_ticks {
                            found[0] = Some((ViolationKind::LowTooShort, low));
                        }
                    }
                    if let Some(d) = a.dir_change {
                        if a.last_rise.map_or(true, |r| d >= r) {
                            let setup = tick - d;
                            a.min_setup_seen =
                                Some(a.min_setup_seen.map_or(setup, |m| m.min(setup)));
                            if setup < t.dir_setup_ticks {
                                found[1] = Some((ViolationKind::DirSetup, setup));
                            }
                        }
                    }
                    let positive = a.dir_high != t.invert_dir[axis];
                    a.position += if positive { 1 } else { -1 };
                    a.steps += 1;
                    a.last_rise = Some(tick);
                    step = Some((axis, positive, a.position));
                } else {
                    let width = tick - a.last_rise.unwrap_or(tick);
                    a.min_high_seen = Some(a.min_high_seen.map_or(width, |m| m.min(width)));
                    if width < t.min_high_ticks {
                        found[0] = Some((ViolationKind::PulseTooShort, width));
                    }
                    a.last_fall = Some(tick);
                }
            }
            PinId::Dir(_) => {
                let a = &mut st.axes[axis];
                if a.dir_high == high {
                    return;
                }
                if a.step_high {
                    found[0] = Some((ViolationKind::DirDuringPulse, 0));
                }
                a.dir_high = high;
                a.dir_change = Some(tick);
            }
            PinId::Enable => {
                if st.enable_high == high {
                    return;
                }
                st.enable_high = high;
            }
        }
        st.edges += 1;
        for (kind, measured) in found.into_iter().flatten() {
            st.violations[kind as usize] += 1;
            st.first_violation.get_or_insert(Violation {
                kind,
                axis: axis as u8,
                tick,
                measured_ticks: measured,
            });
        }
        if let Some((axis, positive, _)) = step {
            let rel = tick.wrapping_sub(st.hash_origin) as u32;
            let mut bytes = [0u8; 6];
            bytes[0] = axis as u8;
            bytes[1] = positive as u8;
            bytes[2..].copy_from_slice(&rel.to_le_bytes());
            st.hash = crate::step::fnv(st.hash, &bytes);
        }
        drop(st);
        let mut obs = self.observer.borrow_mut();
        obs.on_edge(&Edge { pin, high, tick });
        if let Some((axis, positive, position)) = step {
            obs.on_step(axis, positive, tick, position);
        }
    }
}

/// The simulated board's clock: waiting moves it on (to the exact tick).
impl<O: EdgeObserver> StepTimer for &SimBoard<O> {
    fn now(&mut self) -> u32 {
        self.now_u32()
    }
    fn wait_until(&mut self, t: u32) {
        self.advance_to_u32(t);
    }
}

#[cfg(test)]
mod exec_tests;

#[cfg(test)]
mod tests {
    use super::*;

    fn timing() -> SimTiming {
        SimTiming::from_config(&StepConfig::default())
    }

    /// One step on `axis` with `high` ticks of pulse, starting `at`.
    fn pulse<O: EdgeObserver>(
        b: &SimBoard<O>,
        pins: &mut Pins<SimPin<'_, O>>,
        axis: usize,
        at: u64,
        high: u64,
    ) {
        b.advance_to(at);
        pins.step[axis].set_high().unwrap();
        b.advance_to(at + high);
        pins.step[axis].set_low().unwrap();
    }

    #[test]
    fn clean_steps_count_and_hash() {
        let b = SimBoard::new(timing(), 100, ());
        let mut p = b.pins();
        p.enable.set_low().unwrap();
        assert!(b.enabled());
        p.dir[0].set_high().unwrap();
        b.advance_to(200);
        pulse(&b, &mut p, 0, 300, 72);
        pulse(&b, &mut p, 0, 500, 80);
        // Z is inverted: DIR low is positive.
        pulse(&b, &mut p, 2, 600, 72);
        assert_eq!(b.violation_count(), 0, "{:?}", b.first_violation());
        assert_eq!(b.positions(), [2, 0, 1, 0]);
        let h = b.step_hash();
        // The same steps on another board starting elsewhere hash the same (relative ticks).
        let b2 = SimBoard::new(timing(), 1_000_100, ());
        let mut p2 = b2.pins();
        p2.enable.set_low().unwrap();
        p2.dir[0].set_high().unwrap();
        pulse(&b2, &mut p2, 0, 1_000_300, 72);
        pulse(&b2, &mut p2, 0, 1_000_500, 80);
        pulse(&b2, &mut p2, 2, 1_000_600, 72);
        assert_eq!(b2.step_hash(), h);
        // One tick later is another hash.
        let b3 = SimBoard::new(timing(), 100, ());
        let mut p3 = b3.pins();
        p3.enable.set_low().unwrap();
        p3.dir[0].set_high().unwrap();
        pulse(&b3, &mut p3, 0, 300, 72);
        pulse(&b3, &mut p3, 0, 501, 80);
        pulse(&b3, &mut p3, 2, 600, 72);
        assert_ne!(b3.step_hash(), h);
    }

    #[test]
    fn every_violation_kind_is_caught() {
        let b = SimBoard::new(timing(), 0, ());
        let mut p = b.pins();
        // Drivers still disabled.
        pulse(&b, &mut p, 1, 100, 72);
        assert_eq!(b.first_violation().unwrap().kind, ViolationKind::StepWhileDisabled);
        p.enable.set_low().unwrap();
        // 71 ticks high: under 1 us.
        pulse(&b, &mut p, 0, 1_000, 71);
        // 50 ticks low before the next rise.
        pulse(&b, &mut p, 0, 1_121, 72);
        // DIR 10 ticks before a rise (needs 15 = 200 ns).
        b.advance_to(2_000);
        p.dir[0].set_high().unwrap();
        pulse(&b, &mut p, 0, 2_010, 72);
        // DIR while STEP is high.
        b.advance_to(3_000);
        p.step[0].set_high().unwrap();
        b.advance_to(3_010);
        p.dir[0].set_low().unwrap();
        b.advance_to(3_100);
        p.step[0].set_low().unwrap();
        assert_eq!(b.violations(), [1, 1, 1, 1, 1]);
        assert_eq!(b.first_violation().unwrap().axis, 1);
    }
}

//! QEMU `lm3s6965evb` (Cortex-M3, 64 KB RAM; or `mps2-an385` with 4 MB, see
//! [`qemu_machine`]): UART0 for the protocol, virtual step/dir pins, virtual endstops, an
//! accelerated print clock, semihosting for logs.
//!
//! # Clocks
//! Run QEMU with `-icount shift=0`: one instruction is one nanosecond of virtual time. The
//! system clock is set to 200 MHz (SYSDIV = 1 in QEMU's model of the Stellaris RCC), so one
//! SysTick count is 5 ns = 5 instructions (mps2-an385: 25 MHz, 40 instructions). SysTick
//! fires every [`RELOAD`] counts (10,000 instructions on both); counting
//! its wraps gives a 64-bit instruction clock ([`insns_now`]), from which the protocol's
//! millisecond clock (1 ms = 1,000,000 instructions) and the cost figures are derived. The
//! `CLOCK` line at start-up gives the wrap counter's address, so the host harness runs its
//! side of the link on the same emulated time (`strata_host::hil::QemuClock`).
//!
//! # Accelerated print time
//! The print must not run in real time. Each SysTick interrupt moves a *virtual print clock*
//! (72 MHz ticks, `StepConfig::timer_hz`) straight to the executor's next wake time and runs
//! `Executor::on_timer` there, at most [`EVENTS_PER_TICK`] times per interrupt, so QEMU
//! prints as fast as thread mode keeps the step queue filled. The clock never moves to or
//! past the queue's horizon (`Executor::horizon`) while the motion does not rest there:
//! accelerated time would otherwise turn every slicing burst into an underrun and shift the
//! step timing. The interrupt waits at the horizon instead, and lets the executor run into
//! it only when thread mode says so ([`after_poll`]): at the end of the job (the final rest),
//! when paused, and in a true deadlock (a step queue is full behind the horizon: the
//! generator then waits for the executor to stall, exactly as on the host simulation). With
//! the same executor configuration (1 ms start lead) the executed steps, their ticks (the
//! step hash) and the print time equal the host simulation's.
//!
//! # Real-time print clock (`qemu-realtime`)
//! The board `qemu-rt` (feature `qemu-realtime`) runs the print clock at the chip's speed
//! instead: print ticks (72 MHz cycles) are the instructions executed times a stated cycles
//! per instruction ([`CPI_X10`] / 10, `STRATA_QEMU_CPI_X10` at build time, default 2.0: flash
//! wait states at 72 MHz, interrupts, bus contention), and each SysTick interrupt runs every
//! executor event whose wake time that clock has reached, whatever thread mode is doing. No
//! wait at the horizon: an empty step queue mid-move is an underrun, counted with its stall
//! time and the thread's phase ([`set_phase`]) instead of prevented. The `RT` line at the end
//! of a job gives the figures, among them the minimum step-queue slack: the print time queued
//! ahead of the executor at one SysTick less the time until the next one (a bound that stays
//! safe although events run up to one SysTick period, 10,000 instructions, after their wake
//! time: a slack that never goes below zero proves the queue never ran dry). Runs without an
//! underrun execute the same steps at the same ticks as the accelerated clock.
//!
//! # Simulated heaters
//! [`Plant`] is a first-order thermal model of the hotend and the bed (ambient 25 °C) driven by
//! the duties the controller writes, read back as 16-conversion ADC sums through the
//! thermistor equation (EPCOS 100k, beta 4092, 4.7 kΩ pull-up, 12 bits, ±1 count of noise per
//! conversion). The model is the stock Ender-3's (`tests/thermal_model`: hotend 40 W,
//! 25 J/K, 0.12 W/K; bed 220 W, 550 J/K, 2 W/K) with the heat capacities divided by
//! [`PLANT_SCALE`] (100): the time constants (hotend 208 s, bed 275 s) become 2.1 s and
//! 2.75 s of the millisecond clock, so a job reaches 200/60 °C in about 2 s instead of
//! minutes (QEMU counts one instruction per nanosecond: real heat-ups would take hours of
//! wall time). The controller runs on the unscaled clock: every protection (max/min
//! temperature, heating watch, runaway, watchdog) keeps its real periods. Two settings follow
//! the plant ([`THERMAL_CONFIG`]): the PID gains are time-scaled by the same factor (Ki × 100,
//! Kd / 100: the stock gains would see a plant 100 times faster than the one they were tuned
//! on and stall short of the target), and the at-target residency is 0.5 s instead of 10 s.
//!
//! # Virtual pins
//! STEP/DIR/EN are virtual: each rising STEP edge adds `(axis, direction, tick - origin)` to
//! an FNV-1a hash (the host simulation's `SimBoard` hash) and counts the step per axis; the
//! origin is the print clock where the executor first starts in a job (as the host
//! simulation's `first_step`), so homing is not in the hash. The interrupt cost figures
//! (`COST isr_...`) leave the pins' bookkeeping out: a real pin write is one store. STEP
//! falls are not recorded (only rises are hashed); the executor ends each pulse on
//! [`EmuTimer`], an emulation of the board's cycle counter whose cost beyond a real read
//! (one load) the figures leave out too. Both overheads are calibrated at start-up.

use core::cell::RefCell;
use core::convert::Infallible;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use cortex_m::interrupt::{self, Mutex};
use cortex_m::peripheral::scb::SystemHandler;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use embedded_hal::digital::{ErrorType, OutputPin};
use strata::machine::AXES;
use strata::step::{Pins, StepConfig, StepTimer};

use strata::thermal::{PidGains, Temp, ThermalConfig};

use super::qemu_machine;
use crate::heat::IsrWatch;
use crate::log;
use crate::motion::{Endstops, Motion, Next, Producer};

/// Heat capacities of the simulated heaters are the stock Ender-3's divided by this.
pub const PLANT_SCALE: f32 = 100.0;

/// The controller's configuration on QEMU: the Ender-3's, with the PID gains time-scaled to
/// the plant (hotend 30 / 1.5 x 100 / 80 / 100, bed 90 / 2.5 x 100 / 300 / 100) and a 0.5 s
/// residency (see the module docs); protections unchanged.
pub const THERMAL_CONFIG: ThermalConfig = {
    let mut c = ThermalConfig::for_machine(&crate::app::MACHINE);
    c.hotend.gains = PidGains {
        kp: Temp::const_from_int(30),
        ki: Temp::const_from_int(150),
        kd: Temp::lit("0.8"),
    };
    c.bed.gains = PidGains {
        kp: Temp::const_from_int(90),
        ki: Temp::const_from_int(250),
        kd: Temp::lit("3"),
    };
    c.hotend.residency_ms = 500;
    c.bed.residency_ms = 500;
    c
};

/// Fault injection for a manual check of the fault path: an image built with
/// `STRATA_QEMU_SENSOR_OPEN_MS=N` reads the hotend's thermistor as open (full scale) from N ms
/// of the clock on.
const SENSOR_OPEN_MS: Option<&str> = option_env!("STRATA_QEMU_SENSOR_OPEN_MS");

/// Ambient temperature of the simulated heaters, °C.
const AMBIENT_C: f32 = 25.0;
/// Integration step of the plant, ms.
const PLANT_STEP_MS: u32 = 10;

/// One simulated heater: `C dT/dt = P duty - (k + k_fan fan) (T - ambient)`.
struct HeaterSim {
    temp: f32,
    capacity: f32,
    power: f32,
    loss: f32,
    fan_loss: f32,
}

impl HeaterSim {
    fn step(&mut self, duty: u8, fan: u8, dt_s: f32) {
        let loss = self.loss + self.fan_loss * fan as f32 / 255.0;
        let p = self.power * duty as f32 / 255.0 - loss * (self.temp - AMBIENT_C);
        self.temp += p / self.capacity * dt_s;
    }
}

/// `e^x` for the thermistor equation (no libm in `no_std`): `2^(x log2 e)`, the fraction by
/// a degree-6 polynomial (relative error below 1e-6 here).
fn exp_f32(x: f32) -> f32 {
    let y = (x * core::f32::consts::LOG2_E).clamp(-126.0, 126.0);
    let n = if y < 0.0 { y as i32 - 1 } else { y as i32 };
    let f = (y - n as f32) * core::f32::consts::LN_2;
    // e^f, 0 <= f < ln 2.
    let p = 1.0
        + f * (1.0
            + f * (0.5 + f * (1.0 / 6.0 + f * (1.0 / 24.0 + f * (1.0 / 120.0 + f / 720.0)))));
    p * f32::from_bits(((n + 127) as u32) << 23)
}

/// A 12-bit conversion of the EPCOS 100k (beta 4092) at `t` °C behind a 4.7 kΩ pull-up.
fn adc_of_temp(t: f32) -> f32 {
    let r = 100e3 * exp_f32(4092.0 * (1.0 / (t + 273.15) - 1.0 / 298.15));
    4096.0 * r / (r + 4700.0)
}

/// The simulated hotend and bed, driven by the duties last written.
struct Plant {
    hotend: HeaterSim,
    bed: HeaterSim,
    duty: (u8, u8, u8),
    last_ms: u32,
    noise: u32,
}

impl Plant {
    const fn new() -> Self {
        Self {
            hotend: HeaterSim {
                temp: AMBIENT_C,
                capacity: 25.0 / PLANT_SCALE,
                power: 40.0,
                loss: 0.12,
                fan_loss: 0.03,
            },
            bed: HeaterSim {
                temp: AMBIENT_C,
                capacity: 550.0 / PLANT_SCALE,
                power: 220.0,
                loss: 2.0,
                fan_loss: 0.0,
            },
            duty: (0, 0, 0),
            last_ms: 0,
            noise: 0x2545_f491,
        }
    }

    /// Runs the model up to `now_ms` with the duties last written (at most a minute at once).
    fn advance(&mut self, now_ms: u32) {
        let gap = now_ms.wrapping_sub(self.last_ms).min(60_000);
        let steps = gap / PLANT_STEP_MS;
        self.last_ms = self.last_ms.wrapping_add(gap - gap % PLANT_STEP_MS);
        if gap == 60_000 {
            self.last_ms = now_ms;
        }
        let (h, b, f) = if WATCH_TRIPPED.load(Ordering::Relaxed) { (0, 0, 0) } else { self.duty };
        let dt = PLANT_STEP_MS as f32 / 1000.0;
        for _ in 0..steps {
            self.hotend.step(h, f, dt);
            self.bed.step(b, 0, dt);
        }
    }

    /// 16 conversions of a sensor at `t` °C, each with -1, 0 or +1 count of noise.
    fn sum(&mut self, t: f32) -> u16 {
        let v = adc_of_temp(t);
        let mut sum = 0u32;
        for _ in 0..16 {
            self.noise ^= self.noise << 13;
            self.noise ^= self.noise >> 17;
            self.noise ^= self.noise << 5;
            let n = (self.noise >> 8) % 3;
            let c = (v + n as f32 - 1.0 + 0.5).clamp(0.0, 4095.0) as u32;
            sum += c;
        }
        sum as u16
    }
}

/// The main-loop watchdog seen from SysTick (one tick a millisecond).
static WATCH: Mutex<RefCell<IsrWatch>> = Mutex::new(RefCell::new(IsrWatch::new()));
/// The main loop stalled: the simulated heaters are forced off (a real board's IWDG would
/// reset it 0.5 s later).
static WATCH_TRIPPED: AtomicBool = AtomicBool::new(false);

pub use super::qemu_machine::RELOAD;

/// `digits` as a number (a build-time setting; `default` when unset or not a number).
#[cfg(feature = "qemu-realtime")]
const fn parse_or(digits: Option<&str>, default: u64) -> u64 {
    let Some(d) = digits else { return default };
    let b = d.as_bytes();
    if b.is_empty() {
        return default;
    }
    let (mut i, mut v) = (0, 0u64);
    while i < b.len() {
        if !b[i].is_ascii_digit() || v > u32::MAX as u64 {
            return default;
        }
        v = v * 10 + (b[i] - b'0') as u64;
        i += 1;
    }
    v
}

/// Cycles (72 MHz print ticks) per instruction x 10 of the real-time print clock
/// (`qemu-realtime`); the step timer's reads within an executor call use it too (1.5 on the
/// accelerated clock, the figure of the interrupt's cost budget).
#[cfg(feature = "qemu-realtime")]
pub const CPI_X10: u64 = {
    let v = parse_or(option_env!("STRATA_QEMU_CPI_X10"), 20);
    assert!(v >= 5 && v <= 100, "STRATA_QEMU_CPI_X10: 5 to 100 (0.5 to 10 cycles an instruction)");
    v
};
#[cfg(not(feature = "qemu-realtime"))]
pub const CPI_X10: u64 = 15;
/// Executor events one SysTick interrupt runs at most on the real-time clock (more are due:
/// the interrupt cannot keep up, counted as an overrun).
#[cfg(feature = "qemu-realtime")]
const RT_EVENTS_PER_TICK: u32 = 256;
/// Executor events (`on_timer` calls) per interrupt at most (accelerated clock).
#[cfg(not(feature = "qemu-realtime"))]
pub const EVENTS_PER_TICK: u32 = 6;
/// The virtual endstops trigger after this much homing travel, mm (X, Y, Z).
const HOME_TRAVEL_MM: [u32; 3] = [5, 5, 2];

/// A virtual output pin.
#[derive(Debug, Clone, Copy)]
pub enum VPin {
    /// STEP of an axis.
    Step(u8),
    /// DIR of an axis.
    Dir(u8),
    /// Shared enable.
    Enable,
}

/// The state behind the virtual pins.
struct VBoard {
    now: u64,
    origin: u64,
    hash: u64,
    /// Steps per axis (4 G steps: 46 km of filament) and positions, u32 and i32 to keep the
    /// 64 KB builds' statics inside their stack reserve.
    steps: [u32; AXES],
    position: [i32; AXES],
    dir_high: [bool; AXES],
    step_high: [bool; AXES],
    invert: [bool; AXES],
    enable_high: bool,
    steps_disabled: u32,
    /// Print clock of the last rising STEP edge.
    last_rise: u64,
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

impl VBoard {
    const fn new() -> Self {
        Self {
            now: 0,
            origin: 0,
            hash: FNV_OFFSET,
            steps: [0; AXES],
            position: [0; AXES],
            dir_high: [false; AXES],
            step_high: [false; AXES],
            invert: [false, false, true, false],
            enable_high: true,
            steps_disabled: 0,
            last_rise: 0,
        }
    }

    fn edge(&mut self, pin: VPin, high: bool) {
        match pin {
            VPin::Step(a) => {
                let a = a as usize;
                let rise = high && !self.step_high[a];
                self.step_high[a] = high;
                if rise {
                    if self.enable_high {
                        self.steps_disabled += 1;
                    }
                    let positive = self.dir_high[a] != self.invert[a];
                    self.steps[a] += 1;
                    self.last_rise = self.now;
                    self.position[a] += if positive { 1 } else { -1 };
                    let rel = self.now.wrapping_sub(self.origin) as u32;
                    let mut h = self.hash;
                    for b in [a as u8, positive as u8].into_iter().chain(rel.to_le_bytes()) {
                        h ^= b as u64;
                        h = h.wrapping_mul(FNV_PRIME);
                    }
                    self.hash = h;
                }
            }
            VPin::Dir(a) => self.dir_high[a as usize] = high,
            VPin::Enable => self.enable_high = high,
        }
    }
}

static VB: Mutex<RefCell<VBoard>> = Mutex::new(RefCell::new(VBoard::new()));
/// SysTick counts x 16 spent in the virtual pins' bookkeeping (hash, counters, and the
/// measuring around it), which a real pin (one store to GPIO BSRR) does not cost: the
/// interrupt's cost figures and [`EmuTimer`] leave it out.
static PIN_COUNTS_X16: AtomicU32 = AtomicU32::new(0);
/// What a virtual pin write costs outside the window `vpin_edge` measures itself (the
/// SysTick reads, the sum above, the call), SysTick counts x 16 per write: calibrated at
/// start-up ([`calibrate_pins`]).
static PIN_OVERHEAD_X16: AtomicU32 = AtomicU32::new(0);

#[inline(always)]
fn vpin_edge(pin: VPin, high: bool) {
    let c0 = SYST::get_current();
    interrupt::free(|cs| VB.borrow(cs).borrow_mut().edge(pin, high));
    let c1 = SYST::get_current();
    let d = if c1 <= c0 { c0 - c1 } else { c0 + RELOAD - c1 };
    let x16 = (d << 4).wrapping_add(PIN_OVERHEAD_X16.load(Ordering::Relaxed));
    let sum = PIN_COUNTS_X16.load(Ordering::Relaxed).wrapping_add(x16);
    PIN_COUNTS_X16.store(sum, Ordering::Relaxed);
}

/// Virtual pin bookkeeping since `x16_0` (a [`PIN_COUNTS_X16`] value), SysTick counts.
#[inline(always)]
fn pin_counts_since(x16_0: u32) -> u32 {
    PIN_COUNTS_X16.load(Ordering::Relaxed).wrapping_sub(x16_0) >> 4
}

/// Measures [`PIN_OVERHEAD_X16`]: 64 writes of a pin that does not change (DIR of X low,
/// as at reset), timed as a whole, less what they measured themselves. The loop's own few
/// instructions per write stay counted: they stand for the real write (address, store).
/// Runs with the SysTick counter on and its interrupt off.
fn calibrate_pins() {
    let mut pin = VPin::Dir(0);
    let p0 = PIN_COUNTS_X16.load(Ordering::Relaxed);
    let c0 = SYST::get_current();
    for _ in 0..64 {
        let _ = core::hint::black_box(&mut pin).set_low();
    }
    let c1 = SYST::get_current();
    let total = if c1 <= c0 { c0 - c1 } else { c0 + RELOAD - c1 };
    let measured = PIN_COUNTS_X16.load(Ordering::Relaxed).wrapping_sub(p0);
    PIN_OVERHEAD_X16.store((total << 4).saturating_sub(measured) / 64, Ordering::Relaxed);
}

impl ErrorType for VPin {
    type Error = Infallible;
}

impl OutputPin for VPin {
    fn set_low(&mut self) -> Result<(), Infallible> {
        vpin_edge(*self, false);
        Ok(())
    }

    fn set_high(&mut self) -> Result<(), Infallible> {
        vpin_edge(*self, true);
        Ok(())
    }
}

/// The step timer during an executor call, as a 72 MHz Cortex-M3 at [`CPI_X10`] / 10 cycles
/// per instruction would read it: the print clock at the call's start plus the instructions
/// run since (SysTick counts of 5 instructions, 7.5 ticks each at 1.5; mps2-an385: 40 and 60) without
/// the virtual pins' bookkeeping (a real pin write is one store). The executor waits on it for the end of a
/// STEP pulse, so the interrupt's cost includes that wait. This emulation costs more than
/// the board's read of its cycle counter (one load): the cost figures leave that out for
/// the first two reads of a call (the one after the rising edge and the wait's first
/// check) and count any further read (a spin) in full. The clock itself includes the
/// emulation's time (it must move on while spinning), so a wait here ends up to a read's
/// emulation earlier than on the board.
struct EmuTimer {
    start: u32,
    /// SysTick value and [`PIN_COUNTS_X16`] at the call's start.
    c0: u32,
    pins0: u32,
    /// Reads so far.
    reads: u32,
    /// In [`StepTimer::wait_until`]: reads there are not edges.
    waiting: bool,
    /// The latest read right after a rising edge, ticks after the call's start.
    edge_max: u32,
}

/// What an [`EmuTimer::now`] costs beyond one instruction, SysTick counts x 16: calibrated
/// at start-up ([`calibrate_timer`]).
static TIMER_OVERHEAD_X16: AtomicU32 = AtomicU32::new(0);

impl EmuTimer {
    /// The emulation's cost beyond the board's in the first two reads, SysTick counts.
    fn overhead_counts(&self) -> u32 {
        (self.reads.min(2) * TIMER_OVERHEAD_X16.load(Ordering::Relaxed)) >> 4
    }
}

impl StepTimer for EmuTimer {
    // A call of its own: the same instructions in the calibration as in the executor.
    #[inline(never)]
    fn now(&mut self) -> u32 {
        let c1 = SYST::get_current();
        let d = if c1 <= self.c0 { self.c0 - c1 } else { self.c0 + RELOAD - c1 };
        self.reads += 1;
        // CPI_X10 / 10 cycles (72 MHz ticks) per instruction, `PERIOD_NS` instructions per
        // count.
        let ticks_x10 = CPI_X10 as u32 * PERIOD_NS.load(Ordering::Relaxed);
        let since = d.saturating_sub(pin_counts_since(self.pins0)) * ticks_x10 / 10;
        if !self.waiting {
            self.edge_max = self.edge_max.max(since);
        }
        self.start.wrapping_add(since)
    }

    fn wait_until(&mut self, t: u32) {
        self.waiting = true;
        while strata::step::is_before(self.now(), t) {}
        self.waiting = false;
    }
}

/// Measures [`TIMER_OVERHEAD_X16`]: 64 reads (calls) timed as a whole, less the same loop
/// without them and one instruction (a fifth of a count; mps2-an385: a fortieth) per read. Runs with the SysTick counter on
/// and its interrupt off.
fn calibrate_timer() {
    let counts = |c0: u32, c1: u32| if c1 <= c0 { c0 - c1 } else { c0 + RELOAD - c1 };
    let mut t = EmuTimer {
        start: 0,
        c0: SYST::get_current(),
        pins0: PIN_COUNTS_X16.load(Ordering::Relaxed),
        reads: 0,
        waiting: false,
        edge_max: 0,
    };
    let a0 = SYST::get_current();
    for _ in 0..64 {
        core::hint::black_box(&mut t);
    }
    let a1 = SYST::get_current();
    for _ in 0..64 {
        core::hint::black_box(core::hint::black_box(&mut t).now());
    }
    let b1 = SYST::get_current();
    let reads_x16 = (counts(a1, b1).saturating_sub(counts(a0, a1)) << 4) / 64;
    let one_insn_x16 = 16 / PERIOD_NS.load(Ordering::Relaxed).max(1);
    TIMER_OVERHEAD_X16.store(reads_x16.saturating_sub(one_insn_x16), Ordering::Relaxed);
}

/// Virtual endstops: hit after a fixed travel.
pub struct VEnds;

impl Endstops for VEnds {
    fn hit(&mut self, axis: usize, travelled: u32) -> bool {
        let spm = [80, 80, 400];
        travelled >= HOME_TRAVEL_MM[axis] * spm[axis]
    }
}

/// The motion type of this board.
pub type BoardMotion = Motion<VPin, VEnds>;

/// What the SysTick interrupt owns.
struct Isr {
    motion: BoardMotion,
    /// The virtual print clock, 72 MHz ticks.
    clock: u64,
    next: Next,
    /// Print clock at the executor's first start in this job, and when it last went idle.
    start: Option<u64>,
    end: u64,
    /// `on_timer` calls that did work (not idle polls), SysTick counts spent in them in
    /// total and at most.
    calls: u64,
    call_counts: u64,
    call_max: u32,
    /// The longest a rising edge came after its call's start (its commanded tick), ticks.
    edge_max: u32,
    /// Non-zero while held at the horizon: the number of that wait (accelerated clock).
    #[cfg(not(feature = "qemu-realtime"))]
    blocked: u32,
    #[cfg(not(feature = "qemu-realtime"))]
    epoch: u32,
    /// The real-time clock's figures of this job.
    #[cfg(feature = "qemu-realtime")]
    rt: RtStats,
}

/// What thread mode is doing, for the real-time clock's underrun report ([`set_phase`]).
static PHASE: AtomicU32 = AtomicU32::new(0);

/// Thread mode's phase (`phase`: 0 other, 1 a `service` call (slicing, toolpaths), 2 a
/// `poll` (planning, step generation)) and the slicer's layer, for the underrun report.
pub fn set_phase(phase: u32, layer: u32) {
    PHASE.store(phase << 24 | layer.min(0xFF_FFFF), Ordering::Relaxed);
}

/// The real-time clock's figures of a job (`qemu-realtime`), print ticks; [`NONE`] marks an
/// absent clock value (48 B: the 64 KB build's stack reserve holds with them).
#[cfg(feature = "qemu-realtime")]
#[derive(Debug, Clone, Copy)]
struct RtStats {
    /// Print clock since which the executor is stalled (an underrun), or `NONE`.
    stalled_since: u64,
    stall_total: u64,
    stall_max: u32,
    /// The first underrun's [`PHASE`] and print clock from the job's first step (`NONE`
    /// without one).
    first_phase: u32,
    first_tick: u64,
    /// The unrested horizon at the last SysTick (absolute print clock), or `NONE`.
    horizon: u64,
    /// Minimum of that horizon less the print clock at the next SysTick (`i32::MAX`: none).
    min_slack: i32,
    /// SysTick interrupts that left due events for the next one (the interrupt fell behind).
    overruns: u32,
}

/// An absent print clock value in [`RtStats`].
#[cfg(feature = "qemu-realtime")]
const NONE: u64 = u64::MAX;

#[cfg(feature = "qemu-realtime")]
impl RtStats {
    const fn new() -> Self {
        Self {
            stalled_since: NONE,
            stall_total: 0,
            stall_max: 0,
            first_phase: 0,
            first_tick: NONE,
            horizon: NONE,
            min_slack: i32::MAX,
            overruns: 0,
        }
    }
}

/// The wait at the horizon the interrupt is in (0: none), for thread mode.
static BLOCKED: AtomicU32 = AtomicU32::new(0);
/// Thread mode lets the executor run into the horizon of this wait (a deadlock: a full
/// queue behind it, which only a stall resolves; or a pause).
static ALLOW: AtomicU32 = AtomicU32::new(0);
/// No more blocks come in this job: the executor may come to rest.
static FINAL: AtomicBool = AtomicBool::new(true);

static ISR: Mutex<RefCell<Option<Isr>>> = Mutex::new(RefCell::new(None));
/// SysTick wraps (instruction clock, high part).
static WRAPS: AtomicU32 = AtomicU32::new(0);
/// SysTick counts spent in the SysTick handler in total (thread time = total - this).
static ISR_COUNTS_LO: AtomicU32 = AtomicU32::new(0);
static ISR_COUNTS_HI: AtomicU32 = AtomicU32::new(0);
/// Nanoseconds (= instructions under `-icount shift=0`) per SysTick count.
static PERIOD_NS: AtomicU32 = AtomicU32::new(5);

impl Isr {
    /// May the executor be run at `t`? Not at or past an unrested horizon (that would be an
    /// underrun only accelerated time makes: the pipeline has not caught up yet), nor into a
    /// rest point while more blocks come (the host simulation's generator is always there
    /// first), unless thread mode allowed it for this wait (a true deadlock, or a pause).
    #[cfg(not(feature = "qemu-realtime"))]
    fn may_run(&mut self, t: u32) -> bool {
        if self.motion.homing() {
            return true;
        }
        let Some(e) = self.motion.exec() else { return true };
        if e.is_idle() {
            return true;
        }
        let (h, rest) = e.horizon();
        if strata::step::is_before(t, h) {
            return true;
        }
        if (rest && FINAL.load(Ordering::Acquire))
            || (self.blocked != 0 && ALLOW.load(Ordering::Acquire) == self.blocked)
        {
            return true;
        }
        if self.blocked == 0 {
            self.epoch = self.epoch.wrapping_add(1).max(1);
            self.blocked = self.epoch;
            BLOCKED.store(self.epoch, Ordering::Release);
        }
        false
    }

    #[cfg(not(feature = "qemu-realtime"))]
    fn run(&mut self, cs: &interrupt::CriticalSection) {
        for _ in 0..EVENTS_PER_TICK {
            // Idle or stalled: poll at the same instant (the print clock waits).
            let t = match self.next {
                Next::At(t) => t,
                Next::Idle | Next::Stalled(_) => self.clock as u32,
            };
            if !self.may_run(t) {
                return;
            }
            if self.blocked != 0 {
                self.blocked = 0;
                BLOCKED.store(0, Ordering::Release);
            }
            // Straight to the next wake (wrap-aware, never backwards).
            let d = t.wrapping_sub(self.clock as u32) as i32;
            self.fire(cs, self.clock + d.max(0) as u64);
            if matches!(self.next, Next::Idle | Next::Stalled(_)) {
                break;
            }
        }
    }

    /// Runs the executor's event at print clock `at` (not before the clock), with the
    /// interrupt's cost figures and the job's start and end.
    fn fire(&mut self, cs: &interrupt::CriticalSection, at: u64) {
        self.clock = at;
        VB.borrow(cs).borrow_mut().now = self.clock;
        let homing = self.motion.homing();
        let was_idle = self.motion.exec().map_or(true, |e| e.is_idle());
        let p0 = PIN_COUNTS_X16.load(Ordering::Relaxed);
        // The timer set up before the count starts (the board's costs nothing to set up).
        let mut timer = EmuTimer {
            start: self.clock as u32,
            c0: 0,
            pins0: p0,
            reads: 0,
            waiting: false,
            edge_max: 0,
        };
        let c0 = SYST::get_current();
        timer.c0 = c0;
        self.next = self.motion.event(self.clock as u32, &mut timer);
        let c1 = SYST::get_current();
        self.edge_max = self.edge_max.max(timer.edge_max);
        let pins = pin_counts_since(p0) + timer.overhead_counts();
        let idle_poll = was_idle && self.next == Next::Idle;
        if !homing && !idle_poll {
            let d = if c1 <= c0 { c0 - c1 } else { c0 + RELOAD - c1 };
            // Without the virtual pins' bookkeeping (a real pin write is one store) and
            // the timer emulation (a real read is one load).
            let d = d.saturating_sub(pins);
            self.calls += 1;
            self.call_counts += d as u64;
            self.call_max = self.call_max.max(d);
            if was_idle && self.start.is_none() {
                // The print clock of the job starts where the executor first leaves
                // idle (as the host simulation's `first_step`); steps hash from there.
                self.start = Some(self.clock);
                let mut vb = VB.borrow(cs).borrow_mut();
                vb.origin = self.clock;
                vb.hash = FNV_OFFSET;
                vb.steps = [0; AXES];
                vb.position = [0; AXES];
                vb.last_rise = 0;
            }
            if self.next == Next::Idle {
                self.end = self.clock;
            }
        }
    }

    /// The real-time clock (`qemu-realtime`): every event due by `now` (print ticks =
    /// instructions x CPI) at its own wake time; idle and stalled polls at `now`. Underruns
    /// and the queue's slack are recorded, nothing waits.
    #[cfg(feature = "qemu-realtime")]
    fn run_realtime(&mut self, cs: &interrupt::CriticalSection) {
        let now = insns_now() * CPI_X10 / 10;
        let running = |m: &BoardMotion| m.exec().is_some_and(|e| !e.is_idle()) && !m.homing();
        // Slack: the horizon seen at the last interrupt against this one's clock.
        let h = core::mem::replace(&mut self.rt.horizon, NONE);
        if h != NONE && running(&self.motion) && self.start.is_some() {
            let slack = (h as i64 - now as i64).clamp(i32::MIN as i64, i32::MAX as i64 - 1);
            self.rt.min_slack = self.rt.min_slack.min(slack as i32);
        }
        let mut events = 0;
        loop {
            let at = match self.next {
                Next::At(t) => {
                    self.clock + (t.wrapping_sub(self.clock as u32) as i32).max(0) as u64
                }
                Next::Idle | Next::Stalled(_) => now.max(self.clock),
            };
            if at > now {
                break;
            }
            if events == RT_EVENTS_PER_TICK {
                self.rt.overruns += 1;
                break;
            }
            events += 1;
            self.fire(cs, at);
            self.track_stall();
            if matches!(self.next, Next::Idle | Next::Stalled(_)) {
                break;
            }
        }
        if running(&self.motion) {
            let e = self.motion.exec().expect("running");
            let (h, rest) = e.horizon();
            if !rest && !e.is_stalled() {
                self.rt.horizon =
                    self.clock.wrapping_add(h.wrapping_sub(self.clock as u32) as i32 as i64 as u64);
            }
        }
    }

    /// Stall bookkeeping after an event (`qemu-realtime`).
    #[cfg(feature = "qemu-realtime")]
    fn track_stall(&mut self) {
        let stalled = self.motion.exec().is_some_and(|e| e.is_stalled());
        let since = self.rt.stalled_since;
        if stalled && since == NONE {
            self.rt.stalled_since = self.clock;
            if self.rt.first_tick == NONE {
                self.rt.first_tick = self.clock - self.start.unwrap_or(self.clock);
                self.rt.first_phase = PHASE.load(Ordering::Relaxed);
            }
        } else if !stalled && since != NONE {
            let d = self.clock - since;
            self.rt.stall_total += d;
            self.rt.stall_max = self.rt.stall_max.max(d.min(u32::MAX as u64) as u32);
            self.rt.stalled_since = NONE;
        }
    }
}

#[exception]
fn SysTick() {
    let c0 = SYST::get_current();
    let wraps = WRAPS.fetch_add(1, Ordering::Relaxed).wrapping_add(1);
    interrupt::free(|cs| {
        if let Some(isr) = ISR.borrow(cs).borrow_mut().as_mut() {
            #[cfg(not(feature = "qemu-realtime"))]
            isr.run(cs);
            #[cfg(feature = "qemu-realtime")]
            isr.run_realtime(cs);
        }
        // Every millisecond (100 wraps of 10 us): the main-loop watchdog.
        if wraps % WRAPS_PER_WATCH_MS == 0
            && !WATCH.borrow(cs).borrow_mut().tick(1)
            && !WATCH_TRIPPED.swap(true, Ordering::Relaxed)
        {
            log!("HEAT WATCHDOG main loop stalled: heaters forced off");
        }
    });
    // The feed interrupt tops the step queue up after this one, once a millisecond of the
    // chip as the Creality's TIM2 pends it.
    if wraps % WRAPS_PER_FEED == 0 {
        crate::pipeline_motion::pend_feed();
    }
    let c1 = SYST::get_current();
    let d = if c1 <= c0 { c0 - c1 } else { c0 + RELOAD - c1 };
    // Only this handler writes these (thread mode reads them).
    let lo = ISR_COUNTS_LO.load(Ordering::Relaxed);
    let (sum, carry) = lo.overflowing_add(d);
    if carry {
        ISR_COUNTS_HI.fetch_add(1, Ordering::Relaxed);
    }
    ISR_COUNTS_LO.store(sum, Ordering::Relaxed);
}

/// Instructions in a millisecond of the firmware's clock (protocol, heaters, status): QEMU's
/// virtual time (one a nanosecond) on the accelerated board; the chip's time at
/// [`CPI_X10`] / 10 cycles an instruction on the real-time one (36,000 at 2.0), so that
/// thread mode's periodic work comes as often per print second as on the board.
#[cfg(not(feature = "qemu-realtime"))]
const INSNS_PER_MS: u64 = 1_000_000;
#[cfg(feature = "qemu-realtime")]
const INSNS_PER_MS: u64 = 72_000 * 10 / CPI_X10;
/// SysTick wraps (10,000 instructions) between two feed interrupts: a millisecond of the
/// 72 MHz chip at [`CPI_X10`] / 10 cycles an instruction, rounded down (48,000 instructions at
/// 1.5: 4 wraps; 36,000 at 2.0: 3), as the Creality board feeds once a millisecond.
const WRAPS_PER_FEED: u32 = (72_000 * 10 / CPI_X10 / 10_000) as u32;
/// SysTick wraps (10,000 instructions) per millisecond of the main-loop watchdog, rounded up
/// (the real-time board's at 2.0: 4 wraps, 1.11 ms: lenient by 11 %).
const WRAPS_PER_WATCH_MS: u32 = INSNS_PER_MS.div_ceil(10_000) as u32;

/// Instructions executed since start-up (SysTick counts x 5 ns, `-icount shift=0`).
pub fn insns_now() -> u64 {
    loop {
        let w = WRAPS.load(Ordering::Acquire);
        let v = SYST::get_current();
        if WRAPS.load(Ordering::Acquire) == w {
            let counts = w as u64 * RELOAD as u64 + (RELOAD - 1 - v.min(RELOAD - 1)) as u64;
            return counts * PERIOD_NS.load(Ordering::Relaxed) as u64;
        }
    }
}

/// Instructions spent in the SysTick handler so far.
pub fn isr_insns_total() -> u64 {
    loop {
        let hi = ISR_COUNTS_HI.load(Ordering::Acquire);
        let lo = ISR_COUNTS_LO.load(Ordering::Acquire);
        if ISR_COUNTS_HI.load(Ordering::Acquire) == hi {
            return ((hi as u64) << 32 | lo as u64) * PERIOD_NS.load(Ordering::Relaxed) as u64;
        }
    }
}

/// The PL011 UART, the clocks and the simulated heaters.
pub struct Board {
    _syst: SYST,
    plant: Plant,
    /// The SD card, once it answered.
    card: Option<Card>,
}

/// The board's SD card (SSI0; the mps2-an385 board has none).
#[cfg(not(feature = "qemu-mps2"))]
pub type Card = strata::card::sd::SdCard<qemu_machine::SdBus>;
/// The board's SD card (SSI0; the mps2-an385 board has none).
#[cfg(feature = "qemu-mps2")]
pub type Card = strata::card::NoCard;

impl Board {
    /// The SD card, started when it has not answered yet (it stays started: QEMU's card does
    /// not answer a second start-up); `None` when the slot is empty or the card does not
    /// answer.
    #[cfg(not(feature = "qemu-mps2"))]
    pub fn card(&mut self) -> Option<&mut Card> {
        self.started_card().ok()
    }

    /// [`Board::card`], or why the card did not start.
    #[cfg(not(feature = "qemu-mps2"))]
    fn started_card(&mut self) -> Result<&mut Card, strata::card::sd::SdError> {
        if self.card.is_none() {
            let mut card = strata::card::sd::SdCard::new(qemu_machine::SdBus::new());
            card.start()?;
            self.card = Some(card);
        }
        self.card.as_mut().ok_or(strata::card::sd::SdError::NotStarted)
    }

    /// The mps2-an385 board has no SD card.
    #[cfg(feature = "qemu-mps2")]
    pub fn card(&mut self) -> Option<&mut Card> {
        self.card.as_mut()
    }

    /// Milliseconds of virtual time (1,000,000 instructions each).
    pub fn now_ms(&mut self) -> u32 {
        (insns_now() / INSNS_PER_MS) as u32
    }

    /// Bytes waiting in the UART's receive FIFO, up to `buf.len()`.
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        let mut n = 0;
        while n < buf.len() {
            let Some(b) = qemu_machine::uart_read() else { break };
            buf[n] = b;
            n += 1;
        }
        n
    }

    /// The hotend's and the bed's thermistors at `now_ms`: 16-conversion sums.
    pub fn read_thermistors(&mut self, now_ms: u32) -> (u16, u16) {
        self.plant.advance(now_ms);
        let (h, b) = (self.plant.hotend.temp, self.plant.bed.temp);
        let (h, b) = (self.plant.sum(h), self.plant.sum(b));
        match SENSOR_OPEN_MS.and_then(|s| s.parse::<u32>().ok()) {
            Some(t) if now_ms >= t => (strata::thermal::thermistor::SUM_MAX, b),
            _ => (h, b),
        }
    }

    /// Heater and fan duties (0..=255) from `now_ms` on (off once the watchdog tripped).
    pub fn set_heaters(&mut self, now_ms: u32, hotend: u8, bed: u8, fan: u8) {
        self.plant.advance(now_ms);
        self.plant.duty = (hotend, bed, fan);
    }

    /// Sends `bytes` (waits while the transmit FIFO is full).
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            qemu_machine::uart_write(b);
        }
    }
}

/// The executor's configuration: the generator's as is (1 ms start lead, as the host
/// simulation, so the print time and the step hash compare).
pub fn executor_config(cfg: &StepConfig) -> StepConfig {
    *cfg
}

/// After thread mode's polls: tells the interrupt whether the job's last block is queued
/// (`finished`: the motion may come to rest), and lets it run into the horizon it waits at
/// when that is a deadlock (the generator stopped at a full step queue, `gen_blocked`, and
/// a queue is full behind the horizon: it waits for the executor to stall) or the job is
/// paused. A queue that is merely full while the generator waits for blocks (the host is
/// slow) is no deadlock: the motion waits at the horizon, as the host simulation's never
/// runs dry there.
///
/// `waiting` is [`waiting`] read before the generator last ran (`gen_blocked`): a wait
/// still on then froze the queue before that run, so `gen_blocked` is that queue's (one
/// read after the run could come from a wait that began after it, the executor having
/// freed room the generator has not seen yet: a stall the simulation does not have).
pub fn after_poll(prod: &Producer, finished: bool, paused: bool, gen_blocked: bool, waiting: u32) {
    FINAL.store(finished, Ordering::Release);
    let b = BLOCKED.load(Ordering::Acquire);
    let deadlock = gen_blocked && (0..AXES).any(|a| prod.free(a) == 0);
    if b != 0 && b == waiting && (paused || deadlock) {
        ALLOW.store(b, Ordering::Release);
    }
}

/// The wait at the horizon the interrupt is in (0: none; a new number for each wait).
pub fn waiting() -> u32 {
    BLOCKED.load(Ordering::Acquire)
}

/// Brings up the UART, the clock and the SysTick-driven virtual motion.
pub fn init(cfg: &StepConfig) -> Board {
    let mut cp = cortex_m::Peripherals::take().expect("taken once");
    PERIOD_NS.store(qemu_machine::init(), Ordering::Relaxed);

    let pins = Pins {
        step: core::array::from_fn(|a| VPin::Step(a as u8)),
        dir: core::array::from_fn(|a| VPin::Dir(a as u8)),
        enable: VPin::Enable,
    };
    interrupt::free(|cs| {
        VB.borrow(cs).borrow_mut().invert = cfg.invert_dir;
        ISR.borrow(cs).replace(Some(Isr {
            motion: Motion::new(*cfg, pins, VEnds),
            clock: 0,
            next: Next::Idle,
            start: None,
            end: 0,
            calls: 0,
            call_counts: 0,
            call_max: 0,
            edge_max: 0,
            #[cfg(not(feature = "qemu-realtime"))]
            blocked: 0,
            #[cfg(not(feature = "qemu-realtime"))]
            epoch: 0,
            #[cfg(feature = "qemu-realtime")]
            rt: RtStats::new(),
        }));
    });
    // SAFETY: priorities are set before either interrupt is enabled: SysTick (the executor
    // and the clock) highest, PendSV (the feed) lowest; see `pipeline_motion`.
    unsafe {
        cp.SCB.set_priority(SystemHandler::SysTick, 0);
        cp.SCB.set_priority(SystemHandler::PendSV, crate::pipeline_motion::FEED_PRIORITY);
    }
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(RELOAD - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_counter();
    calibrate_pins();
    calibrate_timer();
    cp.SYST.enable_interrupt();
    log!(
        "board qemu-{}: sysclk period {} ns, SysTick every {} counts, pin overhead {}/16 counts, timer emulation {}/16 counts",
        qemu_machine::NAME,
        PERIOD_NS.load(Ordering::Relaxed),
        RELOAD,
        PIN_OVERHEAD_X16.load(Ordering::Relaxed),
        TIMER_OVERHEAD_X16.load(Ordering::Relaxed)
    );
    // Where the host harness reads the emulated time (QEMU's monitor, `xp`): the wrap
    // counter's address and the nanoseconds of one wrap (RELOAD counts of PERIOD_NS).
    log!(
        "CLOCK wraps_at={} wrap_ns={}",
        &WRAPS as *const AtomicU32 as u32,
        RELOAD as u64 * PERIOD_NS.load(Ordering::Relaxed) as u64 * 1_000_000 / INSNS_PER_MS
    );
    Board { _syst: cp.SYST, plant: Plant::new(), card: None }
}

/// The SD card's root directory into the log at start-up: a `CARD <size> <name>` line per
/// file (`CARD dir <name>` per directory), then `CARD end files=<n> fat=<16|32>
/// high_capacity=<0|1>`; or `CARD none: <why>` (no card, not formatted, unreadable).
#[cfg(not(feature = "qemu-mps2"))]
#[inline(never)]
pub fn card_report(board: &mut Board) {
    use strata::card::fat::{FatType, Volume};
    let card = match board.started_card() {
        Ok(card) => card,
        Err(e) => {
            log!("CARD none: {}", e);
            return;
        }
    };
    let vol = match Volume::mount(card) {
        Ok(v) => v,
        Err(e) => {
            log!("CARD none: {}", e);
            return;
        }
    };
    let mut dir = vol.root();
    let mut files = 0u32;
    loop {
        match dir.next(&vol, card) {
            Ok(Some(e)) if e.is_dir => log!("CARD dir {}", e.name()),
            Ok(Some(e)) => {
                files += 1;
                log!("CARD {} {}", e.size, e.name());
            }
            Ok(None) => break,
            Err(e) => {
                log!("CARD none: {}", e);
                return;
            }
        }
    }
    let fat = if vol.fat_type == FatType::Fat16 { 16 } else { 32 };
    let hc = u32::from(card.is_high_capacity());
    log!("CARD end files={} fat={} high_capacity={}", files, fat, hc);
}

/// The mps2-an385 board has no SD card.
#[cfg(feature = "qemu-mps2")]
pub fn card_report(_board: &mut Board) {}

/// Runs `f` on the interrupt's motion state (inside a critical section).
pub fn with_motion<R>(f: impl FnOnce(&mut BoardMotion) -> R) -> R {
    interrupt::free(|cs| {
        let mut isr = ISR.borrow(cs).borrow_mut();
        let isr = isr.as_mut().expect("board::init ran");
        f(&mut isr.motion)
    })
}

/// Whether the executor has started in this job (the first step is due or done).
pub fn motion_started() -> bool {
    interrupt::free(|cs| ISR.borrow(cs).borrow().as_ref().is_some_and(|i| i.start.is_some()))
}

/// Nothing to do: SysTick polls the executor anyway.
pub fn kick() {}

/// Print time executed in this job, ms (virtual print clock).
pub fn print_done_ms() -> u32 {
    interrupt::free(|cs| {
        let isr = ISR.borrow(cs).borrow();
        let isr = isr.as_ref().expect("board::init ran");
        let end = if isr.motion.busy() { isr.clock } else { isr.end };
        isr.start.map_or(0, |s| (end.saturating_sub(s) / 72_000) as u32)
    })
}

/// A job begins: print-time and ISR accounting restart.
pub fn job_started() {
    interrupt::free(|cs| {
        if let Some(isr) = ISR.borrow(cs).borrow_mut().as_mut() {
            isr.start = None;
            isr.end = isr.clock;
            isr.calls = 0;
            isr.call_counts = 0;
            isr.call_max = 0;
            isr.edge_max = 0;
            #[cfg(feature = "qemu-realtime")]
            {
                isr.rt = RtStats::new();
            }
        }
        FINAL.store(false, Ordering::Release);
    });
}

fn last_rise_tick(cs: &interrupt::CriticalSection) -> u64 {
    VB.borrow(cs).borrow().last_rise
}

/// A job ended: the executor's cost and the virtual pins' record.
pub fn job_ended() {
    let (calls, counts, max, print_ticks, underruns, late_dir, edge_max) = interrupt::free(|cs| {
        let isr = ISR.borrow(cs).borrow();
        let isr = isr.as_ref().expect("board::init ran");
        let stats = isr.motion.exec().map(|e| e.stats());
        let (underruns, late_dir) = stats.map_or((0, 0), |s| (s.underruns, s.late_dir_steps));
        // From the executor's first start to the last rising STEP edge (as the simulation).
        let ticks = isr.start.map_or(0, |s| last_rise_tick(cs).saturating_sub(s));
        (isr.calls, isr.call_counts, isr.call_max, ticks, underruns, late_dir, isr.edge_max)
    });
    let (steps, pos, hash, bad) = interrupt::free(|cs| {
        let vb = VB.borrow(cs).borrow();
        (vb.steps, vb.position, vb.hash, vb.steps_disabled)
    });
    let ns = PERIOD_NS.load(Ordering::Relaxed) as u64;
    log!(
        "COST isr_calls={} isr_insns_total={} isr_insns_max={} steps={}",
        calls,
        counts * ns,
        max as u64 * ns,
        steps.iter().map(|&s| u64::from(s)).sum::<u64>()
    );
    log!(
        "STEPS x={} y={} z={} e={} pos_x={} pos_y={} pos_z={} pos_e={} hash={:016x} print_ticks={} waits={} steps_disabled={} late_dir_steps={} edge_ticks_max={}",
        steps[0],
        steps[1],
        steps[2],
        steps[3],
        pos[0],
        pos[1],
        pos[2],
        pos[3],
        hash,
        print_ticks,
        underruns,
        bad,
        late_dir,
        edge_max
    );
    #[cfg(feature = "qemu-realtime")]
    realtime_report(underruns);
}

/// The real-time clock's line of a job: `RT cpi_x10=.. underruns=.. stall_ticks=..
/// stall_max_ticks=.. slack_samples=.. min_slack_ticks=.. first_underrun_tick=..
/// first_underrun_phase=.. first_underrun_layer=.. overruns=..` (print ticks; the minimum
/// slack means something when `slack_samples=1`, the first underrun's fields when
/// `underruns` is not 0).
#[cfg(feature = "qemu-realtime")]
fn realtime_report(underruns: u32) {
    let rt = interrupt::free(|cs| ISR.borrow(cs).borrow().as_ref().expect("board::init ran").rt);
    let (tick, phase) =
        if rt.first_tick == NONE { (0, 0) } else { (rt.first_tick, rt.first_phase) };
    let sampled = rt.min_slack != i32::MAX;
    log!(
        "RT cpi_x10={} underruns={} stall_ticks={} stall_max_ticks={} slack_samples={} min_slack_ticks={} first_underrun_tick={} first_underrun_phase={} first_underrun_layer={} overruns={}",
        CPI_X10,
        underruns,
        rt.stall_total,
        rt.stall_max,
        sampled as u32,
        if sampled { rt.min_slack } else { 0 },
        tick,
        phase >> 24,
        phase & 0xFF_FFFF,
        rt.overruns
    );
}

/// A debug line about the motion (`HB ...`).
pub fn heartbeat(prod: &Producer) {
    let (clock, blocked, homing, idle, stalled, h, rest, calls) = interrupt::free(|cs| {
        let isr = ISR.borrow(cs).borrow();
        let isr = isr.as_ref().expect("board::init ran");
        let e = isr.motion.exec();
        let (h, rest) = e.map_or((0, false), |e| e.horizon());
        (
            isr.clock,
            BLOCKED.load(Ordering::Relaxed),
            isr.motion.homing() as u32,
            e.map_or(1, |e| e.is_idle() as u32),
            e.map_or(0, |e| e.is_stalled() as u32),
            h,
            rest as u32,
            isr.calls,
        )
    });
    log!(
        "HB clock={} blocked={} homing={} idle={} stalled={} horizon={} rest={} calls={} q={},{},{},{} final={}",
        clock,
        blocked,
        homing,
        idle,
        stalled,
        h,
        rest,
        calls,
        prod.len(0) as u32,
        prod.len(1) as u32,
        prod.len(2) as u32,
        prod.len(3) as u32,
        FINAL.load(Ordering::Relaxed) as u32
    );
}

//! Creality 4.2.2 / 4.2.7 (STM32F103RET6, 72 MHz from the 8 MHz HSE): pin maps of
//! DESIGN §3, USART1 (PA9/PA10) at 250000 baud, endstops PA5/PA6/PA7 (pull-up, high = hit),
//! shared driver enable PC3 (active low), defmt logs over RTT. Received bytes go through the
//! USART1 interrupt into a 512-byte ring (thread mode may be slicing for milliseconds).
//!
//! # Step timing
//! The executor's clock is the DWT cycle counter (32 bits at 72 MHz = `StepConfig::timer_hz`,
//! wrapping as the executor expects). TIM2 (16 bits, 72 MHz, free running) raises its
//! compare-1 interrupt at the executor's next wake: the interrupt reads the cycle counter,
//! runs every due event (at most [`EVENTS_PER_IRQ`]) and sets the compare to the next wake,
//! or 60000 ticks ahead when the wake is further away (the handler then just re-arms).
//! STEP pulses usually end in the interrupt that raised them: the executor reads the cycle
//! counter after the rising edge and lowers STEP once the driver's high time has passed
//! (busy-waiting what its own work did not take).
//!
//! # Heaters
//! - Thermistors: ADC1 (12 bits, 239.5-cycle sampling at 9 MHz, about 28 us a conversion),
//!   hotend PC5 (IN15), bed PC4 (IN14); each reading sums 16 conversions
//!   ([`Board::read_thermistors`], about 0.9 ms of thread mode every 100 ms).
//! - PWM: TIM5 (free: TIM2 is the step timer, and TIM5's channels 1-3 sit on PA0-PA2 without
//!   a remap on the high-density STM32F103RE; TIM2's own outputs on those pins stay
//!   disabled), channel 1 fan PA0, channel 2 hotend PA1, channel 3 bed PA2, at 10 Hz with 255
//!   steps (Marlin's slow soft PWM for heaters; the bed MOSFET switches slowly): duty `d`
//!   is high for `d` of 255 counts, 255 is fully on. The compare values are written at once
//!   (no preload). The pins stay inputs (the board's gate pull-downs hold the MOSFETs off)
//!   until TIM5 runs with every duty at 0, then become its outputs: heaters are low from
//!   reset on.
//! - Watchdog: the IWDG (LSI, 500 ms) starts at boot; SysTick (every 10 ms) feeds it only
//!   while the main loop's thermal updates keep kicking [`IsrWatch`] (2 s deadline). Once it
//!   expires, SysTick forces every duty to 0 and stops feeding: the IWDG resets the board
//!   within 500 ms, and every heater starts off again. The IWDG stops while a debugger halts
//!   the core.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering};

use cortex_m::interrupt::{free, Mutex};
use cortex_m::peripheral::scb::SystemHandler;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{DWT, NVIC};
use cortex_m_rt::exception;
use heapless::spsc::{Consumer as QConsumer, Producer as QProducer, Queue};
use static_cell::ConstStaticCell;
use stm32f1xx_hal::adc::{Adc, SampleTime};
use stm32f1xx_hal::gpio::{
    Analog, ErasedPin, Input, Output, PinState, PullUp, PushPull, PA5, PA6, PA7, PC4, PC5, PC7,
};
use stm32f1xx_hal::pac::{self, interrupt, Interrupt, ADC1, TIM2, TIM5, USART1};
use stm32f1xx_hal::prelude::*;
use stm32f1xx_hal::rcc;
use stm32f1xx_hal::serial::{Config, Rx, Serial, Tx};
use stm32f1xx_hal::watchdog::IndependentWatchdog;
use strata::step::{is_before, Pins, StepConfig, StepTimer};
use strata::thermal::thermistor::Oversampler;
use strata::thermal::ThermalConfig;

use crate::heat::IsrWatch;
use crate::log;
use crate::motion::{Endstops, Motion, Next};

/// Bytes the USART1 receive interrupt buffers while thread mode slices or plans (about 20 ms
/// of the link; a frame lost to a full ring is resent by the protocol).
const RX_RING: usize = 512;

/// The receive ring between the USART1 interrupt and thread mode.
static RX_QUEUE: ConstStaticCell<Queue<u8, RX_RING>> = ConstStaticCell::new(Queue::new());
/// What the USART1 interrupt owns: the receiver and the ring's producer end.
type RxIsr = (Rx<USART1>, QProducer<'static, u8, RX_RING>);
static RX: Mutex<RefCell<Option<RxIsr>>> = Mutex::new(RefCell::new(None));

#[interrupt]
fn USART1() {
    free(|cs| {
        if let Some((rx, q)) = RX.borrow(cs).borrow_mut().as_mut() {
            loop {
                match rx.read() {
                    // A full ring drops the byte: the protocol resends the frame.
                    Ok(b) => {
                        let _ = q.enqueue(b);
                    }
                    Err(nb::Error::WouldBlock) => break,
                    // Overrun, framing, noise: the flag is cleared; the frame's CRC fails.
                    Err(nb::Error::Other(_)) => {}
                }
            }
        }
    });
}

/// The controller's configuration: the Ender-3's defaults (gains, protections, residency).
pub const THERMAL_CONFIG: ThermalConfig = ThermalConfig::for_machine(&crate::app::MACHINE);

/// SysTick period, ms (the watchdog's tick).
const SYSTICK_MS: u32 = 10;
/// The IWDG's timeout, ms.
const IWDG_MS: u32 = 500;
/// TIM5 prescaler: 72 MHz / 28125 = 2560 Hz counts, 255 counts a period (10 Hz PWM).
const PWM_PSC: u32 = 28_125 - 1;

/// What SysTick owns: the PWM timer, the IWDG and the main-loop watch.
struct Heaters {
    tim: TIM5,
    iwdg: IndependentWatchdog,
    watch: IsrWatch,
}

impl Heaters {
    /// Duties (0..=255): fan CH1 (PA0), hotend CH2 (PA1), bed CH3 (PA2).
    fn set(&mut self, hotend: u8, bed: u8, fan: u8) {
        // SAFETY: CCRx take any 16-bit value; 0..=255 against ARR 254 is 0..=100 %.
        unsafe {
            self.tim.ccr1().write(|w| w.bits(fan as u32));
            self.tim.ccr2().write(|w| w.bits(hotend as u32));
            self.tim.ccr3().write(|w| w.bits(bed as u32));
        }
    }
}

static HEATERS: Mutex<RefCell<Option<Heaters>>> = Mutex::new(RefCell::new(None));

#[exception]
fn SysTick() {
    // The feed interrupt also runs every SysTick (10 ms), whatever the executor does.
    crate::pipeline_motion::pend_feed();
    free(|cs| {
        if let Some(h) = HEATERS.borrow(cs).borrow_mut().as_mut() {
            if h.watch.tick(SYSTICK_MS) {
                h.iwdg.feed();
            } else {
                // The main loop stalled: heaters off, no more feeding (the IWDG resets).
                h.set(0, 0, 0);
            }
        }
    });
}

/// Link speed (the CH340 bridge; the host's default).
pub const BAUD: u32 = 250_000;
/// NVIC priorities (0 highest; see `init`).
const PRIORITY_STEP: u8 = 0x00;
const PRIORITY_UART: u8 = 0x40;
const PRIORITY_SYSTICK: u8 = 0x80;

/// Events handled per interrupt at most (then the interrupt comes back after [`MIN_ARM`],
/// letting USART1 in): USART1 must read each byte within one byte time (40 us at 250000 baud,
/// 2,880 cycles) or the next one overruns it, and TIM2 sits above it: 3 events of the worst
/// executor call measured (712 cycles, `tools/job-cost`) take 2,136 cycles, 8 would take
/// 5,696. One call serves every axis due at its time, so more than one event an interrupt
/// happens only when the interrupt came late.
const EVENTS_PER_IRQ: u32 = 3;
/// Longest compare step of the 16-bit timer, ticks.
const MAX_ARM: u32 = 60_000;
/// Shortest compare step (the handler's own latency), ticks.
const MIN_ARM: u32 = 100;

/// An output pin of this board.
pub type Pin = ErasedPin<Output<PushPull>>;

/// X, Y, Z endstops (pull-up inputs; the switch pulls high when hit).
pub struct Ends {
    x: PA5<Input<PullUp>>,
    y: PA6<Input<PullUp>>,
    z: PA7<Input<PullUp>>,
}

impl Endstops for Ends {
    fn hit(&mut self, axis: usize, _travelled: u32) -> bool {
        match axis {
            0 => self.x.is_high(),
            1 => self.y.is_high(),
            _ => self.z.is_high(),
        }
    }
}

/// The motion type of this board.
pub type BoardMotion = Motion<Pin, Ends>;

/// The step timer: the DWT cycle counter (72 MHz), which the executor reads to end a STEP
/// pulse in the interrupt that raised it (busy-waiting the rest of the 1 us when needed).
struct CycleCounter;

impl StepTimer for CycleCounter {
    #[inline(always)]
    fn now(&mut self) -> u32 {
        DWT::cycle_count()
    }
}

struct Isr {
    motion: BoardMotion,
    tim: TIM2,
    next: Next,
}

static ISR: Mutex<RefCell<Option<Isr>>> = Mutex::new(RefCell::new(None));

impl Isr {
    /// Runs what is due and arms the compare for the next event.
    fn run(&mut self) {
        let mut n = 0;
        let wake = loop {
            let now = DWT::cycle_count();
            match self.next {
                Next::At(t) if is_before(now, t) => break Some(t),
                _ => {}
            }
            if n == EVENTS_PER_IRQ {
                break Some(now.wrapping_add(MIN_ARM));
            }
            n += 1;
            self.next = self.motion.event(now, &mut CycleCounter);
            match self.next {
                Next::At(_) => {}
                // Poll: new commands or the horizon moving on (thread mode also pends the
                // interrupt after queuing steps).
                Next::Stalled(t) => break Some(t),
                Next::Idle => break None,
            }
        };
        let now = DWT::cycle_count();
        // A wake that passed meanwhile (or is about to) comes back after the shortest arm.
        let delta = wake.map_or(MAX_ARM, |w| {
            (w.wrapping_sub(now) as i32).clamp(MIN_ARM as i32, MAX_ARM as i32) as u32
        });
        let cnt = self.tim.cnt().read().bits();
        // SAFETY: CCR1 takes any 16-bit value.
        self.tim.ccr1().write(|w| unsafe { w.bits((cnt + delta) & 0xFFFF) });
    }
}

/// The feed interrupt is pended at least this often while the executor runs, cycles (1 ms).
const FEED_PERIOD_CYCLES: u32 = 72_000;
/// Cycle counter at the last feed request from TIM2.
static FEED_PENDED_AT: AtomicU32 = AtomicU32::new(0);

#[interrupt]
fn TIM2() {
    free(|cs| {
        if let Some(isr) = ISR.borrow(cs).borrow_mut().as_mut() {
            isr.tim.sr().modify(|_, w| w.cc1if().clear_bit());
            isr.run();
        }
    });
    // The feed interrupt tops the step queue up once a millisecond while steps run.
    let now = DWT::cycle_count();
    if now.wrapping_sub(FEED_PENDED_AT.load(Ordering::Relaxed)) >= FEED_PERIOD_CYCLES {
        FEED_PENDED_AT.store(now, Ordering::Relaxed);
        crate::pipeline_motion::pend_feed();
    }
}

/// USART1, the millisecond clock and the thermistors.
/// The board's SD card, on SDIO.
pub type Card = super::sdio::Sdio;

pub struct Board {
    tx: Tx<USART1>,
    rx: QConsumer<'static, u8, RX_RING>,
    last: u32,
    cycles: u64,
    adc: Adc<ADC1>,
    hotend_sensor: PC5<Analog>,
    bed_sensor: PC4<Analog>,
    /// The card detect switch (low with a card in).
    card_detect: PC7<Input<PullUp>>,
    /// The card, once it started (dropped when it leaves the slot).
    card: Option<Card>,
}

impl Board {
    /// The SD card, started when it is in the slot and has not started yet; `None` when the
    /// slot is empty or the card does not start.
    pub fn card(&mut self) -> Option<&mut Card> {
        if self.card_detect.is_high() {
            self.card = None;
            return None;
        }
        if self.card.is_none() {
            match Card::start() {
                Ok(card) => self.card = Some(card),
                Err(e) => log!("CARD none: {}", e),
            }
        }
        self.card.as_mut()
    }

    /// Milliseconds since start-up (the cycle counter, extended to 64 bits here).
    pub fn now_ms(&mut self) -> u32 {
        let c = DWT::cycle_count();
        self.cycles += c.wrapping_sub(self.last) as u64;
        self.last = c;
        (self.cycles / 72_000) as u32
    }

    /// Bytes received (from the interrupt's ring), up to `buf.len()`.
    pub fn read(&mut self, buf: &mut [u8]) -> usize {
        let mut n = 0;
        while n < buf.len() {
            let Some(b) = self.rx.dequeue() else { break };
            buf[n] = b;
            n += 1;
        }
        n
    }

    /// The hotend's (PC5) and the bed's (PC4) thermistors: 16 conversions summed each (a
    /// failed conversion reads 0, a shorted sensor).
    pub fn read_thermistors(&mut self, _now_ms: u32) -> (u16, u16) {
        let mut sums = [0u16; 2];
        for (i, sum) in sums.iter_mut().enumerate() {
            let mut o = Oversampler::new();
            loop {
                let raw: u16 = if i == 0 {
                    nb::block!(self.adc.read(&mut self.hotend_sensor)).unwrap_or(0)
                } else {
                    nb::block!(self.adc.read(&mut self.bed_sensor)).unwrap_or(0)
                };
                if let Some(s) = o.push(raw) {
                    *sum = s;
                    break;
                }
            }
        }
        (sums[0], sums[1])
    }

    /// Heater and fan duties (0..=255); all off once the main-loop watchdog expired.
    pub fn set_heaters(&mut self, _now_ms: u32, hotend: u8, bed: u8, fan: u8) {
        let off = crate::heat::expired();
        free(|cs| {
            if let Some(h) = HEATERS.borrow(cs).borrow_mut().as_mut() {
                if off {
                    h.set(0, 0, 0);
                } else {
                    h.set(hotend, bed, fan);
                }
            }
        });
    }

    /// Sends `bytes` (blocking).
    pub fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            while self.tx.write_u8(b).is_err() {}
        }
    }
}

/// The executor's configuration: the generator's as is.
pub fn executor_config(cfg: &StepConfig) -> StepConfig {
    *cfg
}

/// Nothing to tell the interrupt: real time never runs ahead of the pipeline artificially.
pub fn after_poll(
    _prod: &crate::motion::Producer,
    _finished: bool,
    _paused: bool,
    _gen_blocked: bool,
    _waiting: u32,
) {
}

/// No wait at a horizon on real time (see [`after_poll`]).
pub fn waiting() -> u32 {
    0
}

/// Clocks, pins, USART1, TIM2 and the cycle counter.
pub fn init(cfg: &StepConfig) -> Board {
    let mut cp = cortex_m::Peripherals::take().expect("taken once");
    let dp = pac::Peripherals::take().expect("taken once");
    let mut flash = dp.FLASH.constrain();
    let mut rcc = dp.RCC.freeze(
        rcc::Config::hse(8.MHz()).sysclk(72.MHz()).hclk(72.MHz()).pclk1(36.MHz()).pclk2(72.MHz()),
        &mut flash.acr,
    );
    let mut afio = dp.AFIO.constrain(&mut rcc);
    let mut gpioa = dp.GPIOA.split(&mut rcc);
    let mut gpiob = dp.GPIOB.split(&mut rcc);
    let mut gpioc = dp.GPIOC.split(&mut rcc);
    let mut gpiod = dp.GPIOD.split(&mut rcc);

    // The IWDG first (500 ms): fed by SysTick from here on while the main loop runs.
    let mut iwdg = IndependentWatchdog::new(dp.IWDG);
    iwdg.stop_on_debug(&dp.DBGMCU, true);
    iwdg.start(IWDG_MS.millis());
    // PB3/PB4 are JTAG after reset: JTAG off, SWD stays.
    let (_pa15, pb3, pb4) = afio.mapr.disable_jtag(gpioa.pa15, gpiob.pb3, gpiob.pb4);

    let low = PinState::Low;
    let pc2 = gpioc.pc2.into_push_pull_output_with_state(&mut gpioc.crl, low).erase();
    let pb9 = gpiob.pb9.into_push_pull_output_with_state(&mut gpiob.crh, low).erase();
    let pb8 = gpiob.pb8.into_push_pull_output_with_state(&mut gpiob.crh, low).erase();
    let pb7 = gpiob.pb7.into_push_pull_output_with_state(&mut gpiob.crl, low).erase();
    let pb6 = gpiob.pb6.into_push_pull_output_with_state(&mut gpiob.crl, low).erase();
    let pb5 = gpiob.pb5.into_push_pull_output_with_state(&mut gpiob.crl, low).erase();
    let pb4 = pb4.into_push_pull_output_with_state(&mut gpiob.crl, low).erase();
    let pb3 = pb3.into_push_pull_output_with_state(&mut gpiob.crl, low).erase();
    // Drivers off (PC3 active low) until something moves.
    let enable = gpioc.pc3.into_push_pull_output_with_state(&mut gpioc.crl, PinState::High).erase();
    // DESIGN §3: 4.2.2 X step PC2 dir PB9, Y PB8/PB7, Z PB6/PB5, E PB4/PB3; the 4.2.7
    // swaps step and dir on every axis.
    #[cfg(feature = "creality-v422")]
    let (step, dir) = ([pc2, pb8, pb6, pb4], [pb9, pb7, pb5, pb3]);
    #[cfg(feature = "creality-v427")]
    let (step, dir) = ([pb9, pb7, pb5, pb3], [pc2, pb8, pb6, pb4]);
    let pins = Pins { step, dir, enable };
    let ends = Ends {
        x: gpioa.pa5.into_pull_up_input(&mut gpioa.crl),
        y: gpioa.pa6.into_pull_up_input(&mut gpioa.crl),
        z: gpioa.pa7.into_pull_up_input(&mut gpioa.crl),
    };

    let serial: Serial<USART1, PushPull, stm32f1xx_hal::gpio::Floating> = Serial::new(
        dp.USART1,
        (gpioa.pa9, gpioa.pa10),
        Config::default().baudrate(BAUD.bps()),
        &mut rcc,
    );
    let (tx, mut rx) = serial.split();
    let (rx_prod, rx_cons) = RX_QUEUE.take().split();
    rx.listen();
    free(|cs| RX.borrow(cs).replace(Some((rx, rx_prod))));

    cp.DCB.enable_trace();
    cp.DWT.enable_cycle_counter();

    // Thermistors: ADC1, PC5 hotend, PC4 bed.
    let mut adc = Adc::new(dp.ADC1, &mut rcc);
    adc.set_sample_time(SampleTime::T_239);
    let hotend_sensor = gpioc.pc5.into_analog(&mut gpioc.crl);
    let bed_sensor = gpioc.pc4.into_analog(&mut gpioc.crl);

    // The SD card: SDIO (its clock is HCLK's), D0-D3 PC8-PC11, CK PC12, CMD PD2; detect PC7.
    let _d0 = gpioc.pc8.into_alternate_push_pull(&mut gpioc.crh);
    let _d1 = gpioc.pc9.into_alternate_push_pull(&mut gpioc.crh);
    let _d2 = gpioc.pc10.into_alternate_push_pull(&mut gpioc.crh);
    let _d3 = gpioc.pc11.into_alternate_push_pull(&mut gpioc.crh);
    let _ck = gpioc.pc12.into_alternate_push_pull(&mut gpioc.crh);
    let _cmd = gpiod.pd2.into_alternate_push_pull(&mut gpiod.crl);
    let card_detect = gpioc.pc7.into_pull_up_input(&mut gpioc.crl);

    // Heater and fan PWM: TIM5 (72 MHz: APB1 36 MHz x 2), 10 Hz, every duty 0 before the
    // pins become its outputs.
    // SAFETY: as for TIM2 below (TIM5's and SDIO's clock enable bits only, single thread).
    let rcc_regs = unsafe { &*pac::RCC::ptr() };
    rcc_regs.apb1enr().modify(|_, w| w.tim5en().set_bit());
    rcc_regs.ahbenr().modify(|_, w| w.sdioen().set_bit());
    let tim5 = dp.TIM5;
    // SAFETY (the `bits` writes): PSC, ARR and CCRx take any 16-bit value; CCMR1/2 = PWM
    // mode 1 (OCxM = 110) without preload on channels 1-3; CCER enables their outputs,
    // active high.
    unsafe {
        tim5.psc().write(|w| w.bits(PWM_PSC));
        tim5.arr().write(|w| w.bits(254));
        tim5.ccr1().write(|w| w.bits(0));
        tim5.ccr2().write(|w| w.bits(0));
        tim5.ccr3().write(|w| w.bits(0));
        tim5.ccmr1_output().write(|w| w.bits((0b110 << 4) | (0b110 << 12)));
        tim5.ccmr2_output().write(|w| w.bits(0b110 << 4));
        tim5.ccer().write(|w| w.bits((1 << 0) | (1 << 4) | (1 << 8)));
    }
    tim5.egr().write(|w| w.ug().set_bit());
    tim5.cr1().write(|w| w.cen().set_bit());
    let _fan = gpioa.pa0.into_alternate_push_pull(&mut gpioa.crl);
    let _hotend = gpioa.pa1.into_alternate_push_pull(&mut gpioa.crl);
    let _bed = gpioa.pa2.into_alternate_push_pull(&mut gpioa.crl);
    free(|cs| {
        HEATERS.borrow(cs).replace(Some(Heaters { tim: tim5, iwdg, watch: IsrWatch::new() }));
    });
    cp.SYST.set_clock_source(SystClkSource::Core);
    cp.SYST.set_reload(72_000 * SYSTICK_MS - 1);
    cp.SYST.clear_current();
    cp.SYST.enable_interrupt();
    cp.SYST.enable_counter();

    // TIM2: 72 MHz (APB1 36 MHz x 2), free running over 16 bits, compare 1 interrupt.
    // SAFETY: a read-modify-write of TIM2's clock enable bit only, before any interrupt
    // runs; the HAL's `Rcc` does not touch APB1ENR concurrently (single thread here).
    rcc_regs.apb1enr().modify(|_, w| w.tim2en().set_bit());
    let tim = dp.TIM2;
    // SAFETY (the `bits` writes below): PSC, ARR and CCR1 take any 16-bit value; writing 0 to
    // SR clears its flags.
    tim.psc().write(|w| unsafe { w.bits(0) });
    tim.arr().write(|w| unsafe { w.bits(0xFFFF) });
    tim.ccr1().write(|w| unsafe { w.bits(MAX_ARM) });
    tim.egr().write(|w| w.ug().set_bit());
    tim.sr().write(|w| unsafe { w.bits(0) });
    tim.dier().write(|w| w.cc1ie().set_bit());
    tim.cr1().write(|w| w.cen().set_bit());

    free(|cs| {
        ISR.borrow(cs).replace(Some(Isr {
            motion: Motion::new(*cfg, pins, ends),
            tim,
            next: Next::Idle,
        }));
    });
    // Priorities (0 highest; the STM32F103 keeps the top 4 bits), set before the interrupts
    // are unmasked: TIM2 (the executor) above USART1 (a byte every 40 us at 250000 baud, which
    // waits at most EVENTS_PER_IRQ executor events), SysTick (heaters, watchdog) and PendSV
    // (the feed, `pipeline_motion`) below.
    // SAFETY: set before either NVIC interrupt is unmasked; SysTick and PendSV only change
    // order (their handlers share nothing unguarded with these).
    unsafe {
        cp.NVIC.set_priority(Interrupt::TIM2, PRIORITY_STEP);
        cp.NVIC.set_priority(Interrupt::USART1, PRIORITY_UART);
        cp.SCB.set_priority(SystemHandler::SysTick, PRIORITY_SYSTICK);
        cp.SCB.set_priority(SystemHandler::PendSV, crate::pipeline_motion::FEED_PRIORITY);
    }
    // SAFETY: the handlers only touch `ISR` and `RX`, set up above.
    unsafe {
        NVIC::unmask(Interrupt::TIM2);
        NVIC::unmask(Interrupt::USART1);
    }
    log!("board creality: 72 MHz, USART1 {} baud", BAUD);
    Board {
        tx,
        rx: rx_cons,
        last: DWT::cycle_count(),
        cycles: 0,
        adc,
        hotend_sensor,
        bed_sensor,
        card_detect,
        card: None,
    }
}

/// Runs `f` on the interrupt's motion state (inside a critical section).
pub fn with_motion<R>(f: impl FnOnce(&mut BoardMotion) -> R) -> R {
    free(|cs| {
        let mut isr = ISR.borrow(cs).borrow_mut();
        f(&mut isr.as_mut().expect("board::init ran").motion)
    })
}

/// Whether the executor has stepped in this job (homing aside).
pub fn motion_started() -> bool {
    with_motion(|m| m.exec().is_some_and(|e| e.stats().steps.iter().any(|&n| n > 0)))
}

/// Steps were queued: run the interrupt now (an idle executor starts).
pub fn kick() {
    NVIC::pend(Interrupt::TIM2);
}

static PRINT: Mutex<RefCell<(u32, u32)>> = Mutex::new(RefCell::new((0, 0)));

/// Print time executed in this job, ms (cycle counter while the motion is busy).
pub fn print_done_ms() -> u32 {
    free(|cs| {
        let busy = ISR.borrow(cs).borrow().as_ref().is_some_and(|i| i.motion.busy());
        let mut p = PRINT.borrow(cs).borrow_mut();
        let now = DWT::cycle_count();
        if busy {
            let (ms, last) = *p;
            let d = now.wrapping_sub(last);
            let whole = d / 72_000;
            *p = (ms + whole, last.wrapping_add(whole * 72_000));
        } else {
            p.1 = now;
        }
        p.0
    })
}

/// A job begins.
pub fn job_started() {
    free(|cs| *PRINT.borrow(cs).borrow_mut() = (0, DWT::cycle_count()));
}

/// A job ended.
pub fn job_ended() {
    let steps = with_motion(|m| m.exec().map(|e| e.stats().steps).unwrap_or_default());
    log!("STEPS x={} y={} z={} e={}", steps[0], steps[1], steps[2], steps[3]);
}

/// Whether a card started at boot (its files are listed over the link: `strata card ls`).
pub fn card_report(board: &mut Board) {
    if board.card().is_some() {
        log!("CARD started");
    }
}

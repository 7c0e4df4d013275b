//! Heaters and fan: the core's [`ThermalController`] driven from the main loop (issue 8).
//!
//! Every [`UPDATE_MS`] of the board's millisecond clock the main loop reads both thermistors
//! (16-conversion sums, hotend PC5, bed PC4), applies the job's targets, calls
//! [`ThermalController::update`] and writes the three duties (hotend PA1, bed PA2, fan PA0).
//! After each update it kicks the main-loop watchdog ([`kick`]); the board's periodic
//! interrupt runs an [`IsrWatch`] that feeds the hardware watchdog only while those kicks
//! keep coming, and forces the heaters off when they stop (the IWDG then resets the board).
//!
//! Each update gives the printer the job's targets back (`Printer::heater_targets`: 0 without
//! an active job, so the heaters go off when a job ends, fails, is aborted or stopped) and
//! reports what the heaters measure (`Printer::set_thermal`: the printer holds the motion
//! until the job's targets were reached once, like M190/M109). A fault (latched by the
//! controller: every output is already zero) is returned once by [`Heat::service`]: the main
//! loop stops the motion as for an emergency stop and fails the job
//! (`Printer::thermal_fault` with [`ThermalFault::code`]).

use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use static_cell::ConstStaticCell;
use strata::thermal::{Heater, ThermalController, ThermalFault, Watchdog};

use crate::board::{self, Board};
use crate::capacities::FwPrinter;
use crate::log;
use crate::pipeline_motion::FwMotion;

/// Control period, ms (the controller expects about 10 Hz).
pub const UPDATE_MS: u32 = 100;

/// The controller (hotend, bed, fan): static, built at compile time.
static CONTROLLER: ConstStaticCell<ThermalController> =
    ConstStaticCell::new(ThermalController::new(board::THERMAL_CONFIG));

/// Main-loop kicks so far (the interrupt's [`IsrWatch`] watches it change).
static KICKS: AtomicU32 = AtomicU32::new(0);
/// Set by the interrupt once the main loop missed its deadline (never cleared: the hardware
/// watchdog resets the board).
static EXPIRED: AtomicBool = AtomicBool::new(false);

/// The main loop is alive (after a thermal update).
fn kick() {
    KICKS.fetch_add(1, Ordering::Release);
}

/// Whether the interrupt found the main loop stalled (heaters are forced off then).
pub fn expired() -> bool {
    EXPIRED.load(Ordering::Acquire)
}

/// The interrupt's half of the main-loop watchdog: the core's [`Watchdog`] on the
/// interrupt's own millisecond count, kicked whenever [`KICKS`] moved.
pub struct IsrWatch {
    wd: Watchdog,
    seen: u32,
    ms: u32,
}

impl IsrWatch {
    /// A watch kicked at start-up (the boot gets one timeout of grace).
    pub const fn new() -> Self {
        Self { wd: Watchdog::new(0, strata::thermal::watchdog::DEFAULT_TIMEOUT_MS), seen: 0, ms: 0 }
    }

    /// `elapsed_ms` passed: true while the main loop kicks in time (feed the hardware
    /// watchdog); false once it stopped (force the heaters off, stop feeding).
    pub fn tick(&mut self, elapsed_ms: u32) -> bool {
        self.ms = self.ms.wrapping_add(elapsed_ms);
        let k = KICKS.load(Ordering::Acquire);
        if k != self.seen {
            self.seen = k;
            self.wd.kick(self.ms);
        }
        if EXPIRED.load(Ordering::Relaxed) || self.wd.expired(self.ms) {
            EXPIRED.store(true, Ordering::Release);
            return false;
        }
        true
    }
}

/// The main loop's side of the heaters.
pub struct Heat {
    ctl: &'static mut ThermalController,
    next_ms: u32,
    last_ms: Option<u32>,
    /// Longest gap between two updates so far, ms (the main loop's longest turn, roughly).
    max_gap_ms: u32,
    /// When the current job started, and whether it has been at target once.
    job_ms: Option<u32>,
    heated: bool,
    reported: bool,
}

impl Heat {
    /// Takes the static controller (once).
    pub fn new(now_ms: u32) -> Self {
        Self {
            ctl: CONTROLLER.take(),
            next_ms: now_ms,
            last_ms: None,
            max_gap_ms: 0,
            job_ms: None,
            heated: false,
            reported: false,
        }
    }

    /// A job starts: its wait for the targets begins.
    pub fn job_started(&mut self, now_ms: u32) {
        self.job_ms = Some(now_ms);
        self.heated = false;
    }

    /// The job ended: a `HEAT` line with the temperatures and the longest update gap.
    pub fn job_ended(&mut self) {
        let st = self.ctl.status();
        log!(
            "HEAT end hotend_x10={} bed_x10={} max_gap_ms={} fault_code_plus_1={}",
            st.hotend.temp_decidegrees(),
            st.bed.temp_decidegrees(),
            self.max_gap_ms,
            st.fault.map_or(0, |f| f.code() as u32 + 1)
        );
        self.job_ms = None;
    }

    /// Called every main-loop turn: a thermal update when one is due. Returns a fault when it
    /// is first seen (every output is already off), and again while a job is active after
    /// that (the fault stays latched until a reboot: later jobs fail at once).
    pub fn service(
        &mut self,
        board: &mut Board,
        printer: &mut FwPrinter,
        motion: &mut FwMotion,
        now_ms: u32,
    ) -> Option<ThermalFault> {
        if (now_ms.wrapping_sub(self.next_ms) as i32) < 0 {
            return None;
        }
        // Steady 10 Hz; after a long turn, the next one a whole period later.
        self.next_ms = self.next_ms.wrapping_add(UPDATE_MS);
        if (now_ms.wrapping_sub(self.next_ms) as i32) >= 0 {
            self.next_ms = now_ms.wrapping_add(UPDATE_MS);
        }
        if let Some(last) = self.last_ms {
            self.max_gap_ms = self.max_gap_ms.max(now_ms.wrapping_sub(last));
        }
        self.last_ms = Some(now_ms);

        if expired() {
            self.ctl.trip(ThermalFault::Watchdog);
        }
        // The job's targets every update (0 without an active job: heaters off).
        let (hotend_c, bed_c) = printer.heater_targets();
        if self.ctl.fault().is_none() && self.ctl.set_targets(now_ms, hotend_c, bed_c).is_err() {
            // The printer validated the job against the machine: should not happen.
            log!("HEAT target refused hotend={} bed={}", hotend_c, bed_c);
            let _ = self.ctl.set_targets(now_ms, 0, 0);
        }
        // The part-cooling fan as the job wants it (off on the first layer and without a job).
        self.ctl.set_fan(printer.fan_duty(motion));
        let (hotend_sum, bed_sum) = board.read_thermistors(now_ms);
        let out = self.ctl.update(now_ms, hotend_sum, bed_sum);
        board.set_heaters(now_ms, out.hotend_pwm, out.bed_pwm, out.fan_pwm);
        kick();

        let st = self.ctl.status();
        let at = self.ctl.at_target();
        printer.set_thermal(at, st.hotend.temp_decidegrees(), st.bed.temp_decidegrees());
        if let Some(start) = self.job_ms {
            if at && !self.heated && out.fault.is_none() {
                self.heated = true;
                log!(
                    "HEAT at_target ms={} hotend_x10={} bed_x10={} targets={},{} motion_started={}",
                    now_ms.wrapping_sub(start),
                    st.hotend.temp_decidegrees(),
                    st.bed.temp_decidegrees(),
                    hotend_c,
                    bed_c,
                    board::motion_started() as u32
                );
            }
        }
        let fault = out.fault?;
        if !self.reported {
            self.reported = true;
            let heater = fault.heater().map_or("-", Heater::name);
            log!(
                "HEAT FAULT {} heater={} code={} hotend_x10={} bed_x10={}",
                fault.name(),
                heater,
                fault.code() as u32,
                st.hotend.temp_decidegrees(),
                st.bed.temp_decidegrees()
            );
            return Some(fault);
        }
        // Latched until a reboot: a job started since fails at once.
        printer.is_active().then_some(fault)
    }
}

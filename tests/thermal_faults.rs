//! Every protection trips in its fault scenario on the f64 model, within Marlin's bounds, and
//! turns everything off in the same update.

mod thermal_model;

use strata::thermal::watchdog::{Watchdog, DEFAULT_TIMEOUT_MS};
use strata::thermal::{Heater, Outputs, ThermalError, ThermalFault};
use thermal_model::{Sim, STEP_MS};

/// One control step, s: the runaway period counts from the last reading inside the
/// hysteresis, so the first reading below it is up to one step later.
const STEP_S: f64 = 1.5 * STEP_MS as f64 / 1000.0;

/// Heats both heaters to 200/60 and holds a while.
fn printing(seed: u64) -> Sim {
    let mut sim = Sim::new(seed);
    sim.ctl.set_targets(0, 200, 60).unwrap();
    assert_eq!(sim.run(300.0, |_| {}), None);
    assert!(sim.ctl.at_target());
    sim
}

fn assert_all_off(out: Outputs, fault: ThermalFault) {
    assert_eq!(out, Outputs { hotend_pwm: 0, bed_pwm: 0, fan_pwm: 0, fault: Some(fault) });
}

/// Runs until a fault (at most `limit_s`), returning it, the time since the start of the run
/// and the time since the controller's reading first went below `below` (if it did).
fn run_to_fault(
    sim: &mut Sim,
    heater: Heater,
    below: f64,
    limit_s: f64,
) -> (ThermalFault, f64, Option<f64>) {
    let t0 = sim.secs();
    let mut low_since = None;
    let fault = sim.run(limit_s, |s| {
        let st = s.ctl.status();
        let read: f64 = match heater {
            Heater::Hotend => st.hotend.temp,
            Heater::Bed => st.bed.temp,
        }
        .to_num();
        if s.out.fault.is_none() {
            if read < below {
                low_since.get_or_insert(s.secs());
            } else {
                low_since = None;
            }
        }
    });
    let fault = fault.unwrap_or_else(|| panic!("no fault within {limit_s} s"));
    assert_all_off(sim.out, fault);
    let now = sim.secs();
    (fault, now - t0, low_since.map(|l| now - l))
}

#[test]
fn sensor_disconnected_or_shorted_trips_in_one_update() {
    for (heater, open, expected) in [
        (Heater::Hotend, true, ThermalFault::SensorOpen(Heater::Hotend)),
        (Heater::Bed, true, ThermalFault::SensorOpen(Heater::Bed)),
        (Heater::Hotend, false, ThermalFault::SensorShorted(Heater::Hotend)),
        (Heater::Bed, false, ThermalFault::SensorShorted(Heater::Bed)),
    ] {
        let mut sim = printing(11);
        sim.ctl.set_fan(255);
        let m = match heater {
            Heater::Hotend => &mut sim.hotend,
            Heater::Bed => &mut sim.bed,
        };
        if open {
            m.open = true;
        } else {
            m.shorted = true;
        }
        let out = sim.step();
        assert_all_off(out, expected);
        assert_eq!(expected.heater(), Some(heater));
        println!("{expected}: heaters off in the update that read it");
        // Latched: reconnecting does not turn anything back on.
        sim.hotend.open = false;
        sim.hotend.shorted = false;
        sim.bed.open = false;
        sim.bed.shorted = false;
        assert_all_off(sim.step(), expected);
        assert_eq!(sim.ctl.set_targets(sim.now_ms, 200, 60), Err(ThermalError::Faulted(expected)));
    }
}

#[test]
fn sensor_unplugged_at_power_on_trips_at_once() {
    let mut sim = Sim::new(3);
    sim.bed.open = true;
    assert_all_off(sim.step(), ThermalFault::SensorOpen(Heater::Bed));
}

#[test]
fn cold_reading_below_5_c_is_a_min_temp_fault() {
    // A sensor out of its block in a cold place (or a bad connection reading high resistance,
    // short of full scale): 3 C.
    let mut sim = Sim::new(5);
    sim.ctl.set_targets(0, 200, 60).unwrap();
    assert_eq!(sim.run(20.0, |_| {}), None);
    sim.hotend.sensor = 3.0;
    sim.hotend.sensor_tau = 1e12; // the sensor no longer follows the block
    let (fault, t, _) = run_to_fault(&mut sim, Heater::Hotend, 0.0, 2.0);
    assert_eq!(fault, ThermalFault::MinTemp(Heater::Hotend));
    println!("sensor reading 3 C: {fault} after {t:.1} s (through the reading filter)");
    assert!(t <= 1.0);
}

#[test]
fn loose_hotend_cartridge_while_holding_is_thermal_runaway_after_40_s() {
    let mut sim = printing(21);
    sim.hotend.power_scale = 0.02;
    let (fault, since_loss, below) = run_to_fault(&mut sim, Heater::Hotend, 196.0, 120.0);
    assert_eq!(fault, ThermalFault::ThermalRunaway(Heater::Hotend));
    let below = below.unwrap();
    println!("loose hotend cartridge while holding: {fault} {since_loss:.1} s after the loss, {below:.1} s below 196 C");
    // Marlin: THERMAL_PROTECTION_PERIOD (40 s) below target - 4 C.
    assert!((40.0 - STEP_S..=40.0 + STEP_S).contains(&below), "{below}");
    assert!(since_loss <= 40.0 + 15.0, "{since_loss}");
}

#[test]
fn loose_hotend_cartridge_while_heating_is_heating_failed() {
    let mut sim = Sim::new(22);
    sim.ctl.set_targets(0, 200, 0).unwrap();
    assert_eq!(sim.run(30.0, |_| {}), None);
    sim.hotend.power_scale = 0.02;
    let (fault, since_loss, _) = run_to_fault(&mut sim, Heater::Hotend, 0.0, 120.0);
    assert_eq!(fault, ThermalFault::HeatingFailed(Heater::Hotend));
    println!("loose hotend cartridge while heating: {fault} {since_loss:.1} s after the loss");
    // Marlin: WATCH_TEMP_PERIOD 20 s for +2 C; the loss can fall anywhere in a window.
    assert!(since_loss <= 2.0 * 20.0 + 1.0, "{since_loss}");
}

#[test]
fn loose_bed_heater_while_holding_is_thermal_runaway_after_20_s() {
    let mut sim = printing(23);
    sim.bed.power_scale = 0.0;
    let (fault, since_loss, below) = run_to_fault(&mut sim, Heater::Bed, 58.0, 180.0);
    assert_eq!(fault, ThermalFault::ThermalRunaway(Heater::Bed));
    let below = below.unwrap();
    println!("loose bed heater while holding: {fault} {since_loss:.1} s after the loss, {below:.1} s below 58 C");
    assert!((20.0 - STEP_S..=20.0 + STEP_S).contains(&below), "{below}");
    assert!(since_loss <= 20.0 + 40.0, "{since_loss}");
}

#[test]
fn dead_bed_heater_while_heating_is_heating_failed() {
    let mut sim = Sim::new(24);
    sim.ctl.set_targets(0, 0, 60).unwrap();
    assert_eq!(sim.run(20.0, |_| {}), None);
    sim.bed.power_scale = 0.0;
    let (fault, since_loss, _) = run_to_fault(&mut sim, Heater::Bed, 0.0, 300.0);
    assert_eq!(fault, ThermalFault::HeatingFailed(Heater::Bed));
    println!("dead bed heater while heating: {fault} {since_loss:.1} s after the loss");
    assert!(since_loss <= 2.0 * 60.0 + 1.0, "{since_loss}");
}

#[test]
fn fan_blowing_hard_on_the_block_is_thermal_runaway() {
    let mut sim = printing(31);
    // A fan duct pointed at the block: 0.3 W/K more loss at 100 % (the heater would need 73 W
    // to hold 200 C; it has 40).
    sim.hotend.fan_loss = 0.3;
    sim.ctl.set_fan(255);
    let (fault, since_on, below) = run_to_fault(&mut sim, Heater::Hotend, 196.0, 120.0);
    assert_eq!(fault, ThermalFault::ThermalRunaway(Heater::Hotend));
    let below = below.unwrap();
    println!("fan blowing on the block: {fault} {since_on:.1} s after the fan came on, {below:.1} s below 196 C");
    assert!((40.0 - STEP_S..=40.0 + STEP_S).contains(&below), "{below}");
    assert!(since_on <= 40.0 + 20.0, "{since_on}");
}

#[test]
fn part_fan_at_full_with_headroom_never_trips() {
    let mut sim = printing(32);
    let mut worst = 0.0f64;
    for k in 0..10 {
        sim.ctl.set_fan(if k % 2 == 0 { 255 } else { 0 });
        assert_eq!(sim.run(60.0, |s| worst = worst.max(200.0 - s.hotend.sensor)), None);
    }
    println!("part fan 0 <-> 100 % every minute for 10 min: hotend dipped at most {worst:.2} C");
    assert!(worst < 4.0);
}

#[test]
fn heater_stuck_on_trips_max_temp_at_the_limit() {
    for (heater, target, limit) in [(Heater::Hotend, 200, 275.0), (Heater::Bed, 60, 115.0)] {
        let mut sim = Sim::new(41);
        sim.ctl
            .set_targets(
                0,
                if heater == Heater::Hotend { target } else { 0 },
                if heater == Heater::Bed { target } else { 0 },
            )
            .unwrap();
        match heater {
            Heater::Hotend => sim.hotend.stuck_on = true,
            Heater::Bed => sim.bed.stuck_on = true,
        }
        let (fault, t, _) = run_to_fault(&mut sim, heater, 0.0, 900.0);
        assert_eq!(fault, ThermalFault::MaxTemp(heater));
        let sensor = match heater {
            Heater::Hotend => sim.hotend.sensor,
            Heater::Bed => sim.bed.sensor,
        };
        println!("{heater:?} stuck on: {fault} after {t:.1} s with the sensor at {sensor:.2} C (limit {limit} C)");
        assert!((limit - 0.5..=limit + 1.0).contains(&sensor), "{sensor}");
    }
}

#[test]
fn watchdog_expires_when_the_main_loop_stalls_and_the_heaters_stay_off() {
    let mut sim = printing(51);
    let mut dog = Watchdog::new(sim.now_ms, DEFAULT_TIMEOUT_MS);
    // The loop runs: kicked after each update, the interrupt's check passes.
    for _ in 0..100 {
        let out = sim.step();
        assert!(out.hotend_pwm > 0);
        dog.kick(sim.now_ms);
        assert_eq!(dog.check(sim.now_ms + 50), Ok(()));
    }
    // The loop stalls: the interrupt keeps checking every 10 ms.
    let stalled_at = sim.now_ms;
    let mut t = stalled_at;
    let fault = loop {
        t += 10;
        if let Err(f) = dog.check(t) {
            break f;
        }
        assert!(t - stalled_at <= DEFAULT_TIMEOUT_MS);
    };
    assert_eq!(fault, ThermalFault::Watchdog);
    assert_eq!(t - stalled_at, DEFAULT_TIMEOUT_MS + 10);
    sim.ctl.trip(fault);
    sim.now_ms = t;
    assert_all_off(sim.step(), ThermalFault::Watchdog);
    // After the board reset: a new controller starts with every heater off.
    sim.ctl.reset();
    let out = sim.step();
    assert_eq!((out.hotend_pwm, out.bed_pwm, out.fan_pwm, out.fault), (0, 0, 0, None));
}

#[test]
fn status_reports_the_temperatures() {
    let mut sim = printing(61);
    sim.step();
    let st = sim.ctl.status();
    assert!((st.hotend.temp.to_num::<f64>() - sim.hotend.sensor).abs() < 0.3);
    assert!((st.bed.temp.to_num::<f64>() - sim.bed.sensor).abs() < 0.3);
    assert_eq!((st.hotend.target_c, st.bed.target_c, st.fault), (200, 60, None));
    assert!((1995..=2005).contains(&st.hotend.temp_decidegrees()));
}

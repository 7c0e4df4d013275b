//! The controller driving the f64 thermal model: heat-up, hold, a normal print.

mod thermal_model;

use strata::machine::PrintSettings;
use strata::thermal::Heater;
use thermal_model::Sim;

/// Heats one heater to its target and measures: time to first reach, overshoot of the block
/// and of the sensor, then the largest deviation over `hold_s` of steady state after settling.
struct Run {
    reached_s: f64,
    at_target_s: f64,
    overshoot_sensor: f64,
    overshoot_block: f64,
    hold_dev: f64,
}

fn heat(heater: Heater, target: i16, settle_s: f64, hold_s: f64) -> Run {
    let mut sim = Sim::new(0x5eed_0001);
    sim.ctl.set_target(heater, 0, target).unwrap();
    let tgt = f64::from(target);
    let temps = |s: &Sim| match heater {
        Heater::Hotend => (s.hotend.sensor, s.hotend.block),
        Heater::Bed => (s.bed.sensor, s.bed.block),
    };
    let (mut reached, mut at_target, mut os_s, mut os_b) = (None, None, f64::MIN, f64::MIN);
    let fault = sim.run(settle_s, |s| {
        let (ts, tb) = temps(s);
        if reached.is_none() && ts >= tgt - 1.0 {
            reached = Some(s.secs());
        }
        if at_target.is_none() && s.ctl.heater_at_target(heater) {
            at_target = Some(s.secs());
        }
        os_s = os_s.max(ts - tgt);
        os_b = os_b.max(tb - tgt);
    });
    assert_eq!(fault, None);
    let mut dev = 0.0f64;
    let fault = sim.run(hold_s, |s| {
        let (ts, tb) = temps(s);
        os_s = os_s.max(ts - tgt);
        os_b = os_b.max(tb - tgt);
        dev = dev.max((ts - tgt).abs());
        // The controller's own (filtered) reading holds too.
        let st = s.ctl.status();
        let read: f64 = match heater {
            Heater::Hotend => st.hotend.temp,
            Heater::Bed => st.bed.temp,
        }
        .to_num();
        dev = dev.max((read - tgt).abs());
        assert!(s.ctl.heater_at_target(heater));
    });
    assert_eq!(fault, None);
    let run = Run {
        reached_s: reached.expect("never reached the target"),
        at_target_s: at_target.expect("never at target"),
        overshoot_sensor: os_s,
        overshoot_block: os_b,
        hold_dev: dev,
    };
    println!(
        "{heater:?} 25 -> {target} C: within 1 C after {:.1} s, at_target (10 s dwell) after {:.1} s, \
         overshoot sensor {:.2} C block {:.2} C, largest deviation over {hold_s} s of hold {:.2} C",
        run.reached_s, run.at_target_s, run.overshoot_sensor, run.overshoot_block, run.hold_dev
    );
    run
}

#[test]
fn hotend_heats_25_to_200_without_overshoot_and_holds_within_1_c() {
    let run = heat(Heater::Hotend, 200, 240.0, 60.0);
    assert!(run.overshoot_sensor <= 5.0 && run.overshoot_block <= 5.0);
    assert!(run.hold_dev <= 1.0);
    assert!(run.reached_s < 180.0);
}

#[test]
fn bed_heats_25_to_60_without_overshoot_and_holds_within_1_c() {
    let run = heat(Heater::Bed, 60, 300.0, 60.0);
    assert!(run.overshoot_sensor <= 5.0 && run.overshoot_block <= 5.0);
    assert!(run.hold_dev <= 1.0);
    assert!(run.reached_s < 240.0);
}

#[test]
fn hotend_heats_to_the_machine_maximum_without_tripping() {
    let run = heat(Heater::Hotend, 260, 300.0, 60.0);
    assert!(run.overshoot_sensor <= 5.0 && run.overshoot_block <= 5.0);
    assert!(run.hold_dev <= 1.0);
}

/// A whole job: settings applied, wait for both (bed first then hotend, like M190/M109), ten
/// minutes of printing with the part fan toggling between off, 50 % and 100 % every 30 s,
/// then everything off at the end: no fault, and the hold stays tight through the fan steps.
#[test]
fn normal_print_with_fan_toggling_trips_nothing() {
    let mut sim = Sim::new(0xfeed_beef);
    sim.ctl.apply_settings(0, &PrintSettings::default()).unwrap();
    let fault = sim.run(600.0, |s| {
        let _ = s;
    });
    assert_eq!(fault, None);
    // (Reached well before ten minutes; the wait is the job's.)
    assert!(sim.ctl.at_target(), "not at target after 10 min of heating");
    let waited = sim.secs();
    let mut worst = (0.0f64, 0.0f64);
    let mut fault = None;
    for k in 0..20 {
        sim.ctl.set_fan([0, 128, 255, 64][k % 4]);
        fault = fault.or(sim.run(30.0, |s| {
            worst.0 = worst.0.max((s.hotend.sensor - 200.0).abs());
            worst.1 = worst.1.max((s.bed.sensor - 60.0).abs());
        }));
    }
    assert_eq!(fault, None);
    println!(
        "normal print after {waited} s of heating: 600 s with the fan toggling, largest deviation \
         hotend {:.2} C, bed {:.2} C",
        worst.0, worst.1
    );
    assert!(worst.0 < 4.0 && worst.1 < 2.0, "{worst:?}");
    sim.ctl.all_off();
    let out = sim.step();
    assert_eq!((out.hotend_pwm, out.bed_pwm, out.fan_pwm, out.fault), (0, 0, 0, None));
    assert_eq!(sim.run(120.0, |_| {}), None);
}

/// The job's wait: `at_target` only after both heaters have dwelt inside the window.
#[test]
fn at_target_waits_for_both_heaters_and_the_dwell() {
    let mut sim = Sim::new(7);
    sim.ctl.set_targets(0, 200, 60).unwrap();
    let mut first = None;
    sim.run(400.0, |s| {
        if first.is_none() && s.ctl.at_target() {
            first = Some(s.secs());
            assert!((s.hotend.sensor - 200.0).abs() <= 1.0 && (s.bed.sensor - 60.0).abs() <= 1.0);
        }
    });
    let first = first.expect("never at target");
    println!("both heaters at target after {first:.1} s");
    assert!(sim.ctl.at_target());
    sim.ctl.set_target(Heater::Hotend, sim.now_ms, 210).unwrap();
    sim.step();
    assert!(!sim.ctl.at_target());
}

/// The defaults are not tuned to one exact plant: hotends of 20–30 J/K and 35–45 W, beds of
/// 450–650 J/K, each heated and held with the fan toggling, never overshoot 5 °C or trip.
#[test]
fn defaults_are_robust_to_plant_variation() {
    let mut worst_os = (0.0f64, 0.0f64);
    for (i, (cap, power, bed_cap)) in
        [(20.0, 45.0, 450.0), (30.0, 35.0, 650.0), (20.0, 35.0, 650.0), (30.0, 45.0, 450.0)]
            .into_iter()
            .enumerate()
    {
        let mut sim = Sim::new(100 + i as u64);
        sim.hotend.capacity = cap;
        sim.hotend.power = power;
        sim.bed.capacity = bed_cap;
        sim.ctl.set_targets(0, 200, 60).unwrap();
        let mut fault = sim.run(400.0, |s| {
            worst_os.0 = worst_os.0.max(s.hotend.sensor - 200.0).max(s.hotend.block - 200.0);
            worst_os.1 = worst_os.1.max(s.bed.sensor - 60.0).max(s.bed.block - 60.0);
        });
        for k in 0..10 {
            sim.ctl.set_fan(if k % 2 == 0 { 255 } else { 0 });
            fault = fault.or(sim.run(30.0, |_| {}));
        }
        assert_eq!(fault, None);
        assert!(sim.ctl.at_target());
    }
    println!(
        "plant variations: worst overshoot hotend {:.2} C, bed {:.2} C",
        worst_os.0, worst_os.1
    );
    assert!(worst_os.0 <= 5.0 && worst_os.1 <= 5.0);
}

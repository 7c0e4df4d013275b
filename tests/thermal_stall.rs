//! The thermal stall trips: a heater that stalls inside the watch band, short of its target,
//! fails with `HEATING FAILED` once the approach period has passed since its first reading in
//! the band, never earlier, and no normal heat-up comes near that period. Everything runs on
//! the f64 model of `tests/thermal_model`; expected times come from the protection constants
//! and the model's own (sensor) temperatures, not from the controller.

mod thermal_model;

use strata::machine::MachineConfig;
use strata::printer::board::{BoardPrinter, LOOKAHEAD_MOVES, MOVE_BUFFER_BYTES};
use strata::printer::MotionHalf;
use strata::step::StepQueue;

/// The board's motion half with a step queue of 64 commands an axis.
type BoardMotion<'q> = MotionHalf<'q, MOVE_BUFFER_BYTES, LOOKAHEAD_MOVES, 64>;
use strata::protocol::{
    DeviceState, Endpoint, ErrorCode, JobOptions, JobSpec, LinkConfig, Message, MAX_WIRE,
};
use strata::thermal::protect::{BED_APPROACH_MS, HOTEND_APPROACH_MS, WATCH_HYSTERESIS_C};
use strata::thermal::{
    Heater, PidGains, ProtectParams, Temp, ThermalConfig, ThermalController, ThermalFault,
    HEAT_WAIT_LIMIT_MS,
};
use thermal_model::{HeaterModel, Sim, STEP_MS};

/// One control step, s.
const STEP_S: f64 = STEP_MS as f64 / 1000.0;
/// The controller's reading stays this close to the model's sensor, °C (checked every step:
/// it bounds when the reading can first be inside the band, from the sensor's crossings).
const READ_EPS: f64 = 0.5;
/// Room temperatures the periods are derived over, °C.
const ROOMS: [f64; 3] = [15.0, 25.0, 35.0];
/// Each approach period is at least this many times the slowest normal last stretch (then
/// rounded up to the minute).
const SAFETY: f64 = 2.0;
/// Noise seeds each normal heat-up is measured with.
const SEEDS: [u64; 3] = [0x5eed_0018, 0x5eed_0019, 0x5eed_001a];

fn machine() -> MachineConfig {
    MachineConfig::default()
}

fn params(h: Heater) -> ProtectParams {
    let cfg = ThermalConfig::for_machine(&machine());
    match h {
        Heater::Hotend => cfg.hotend.protect,
        Heater::Bed => cfg.bed.protect,
    }
}

/// The watch band, °C, from Marlin's constants: the heating watch only arms more than
/// `WATCH_TEMP_INCREASE + TEMP_HYSTERESIS` below the target.
fn band(h: Heater) -> f64 {
    f64::from(params(h).watch_increase_c) + f64::from(WATCH_HYSTERESIS_C) + 1.0
}

/// The approach period, s.
fn period_s(h: Heater) -> f64 {
    f64::from(match h {
        Heater::Hotend => HOTEND_APPROACH_MS,
        Heater::Bed => BED_APPROACH_MS,
    }) / 1000.0
}

fn reading(s: &Sim, h: Heater) -> f64 {
    let st = s.ctl.status();
    match h {
        Heater::Hotend => st.hotend.temp,
        Heater::Bed => st.bed.temp,
    }
    .to_num()
}

fn model(s: &mut Sim, h: Heater) -> &mut HeaterModel {
    match h {
        Heater::Hotend => &mut s.hotend,
        Heater::Bed => &mut s.bed,
    }
}

fn sensor(s: &Sim, h: Heater) -> f64 {
    match h {
        Heater::Hotend => s.hotend.sensor,
        Heater::Bed => s.bed.sensor,
    }
}

/// Both heaters in a room at `room` °C, ±2 counts of noise.
fn sim_in(seed: u64, room: f64) -> Sim {
    let mut sim = Sim::new(seed);
    sim.hotend = HeaterModel::hotend().in_room(room);
    sim.bed = HeaterModel::bed().in_room(room);
    sim
}

/// The power scale at which `m` at full duty (fan at `fan`, 0..=1) holds `t` °C at most.
fn scale_to_stall_at(m: &HeaterModel, t: f64, fan: f64) -> f64 {
    (m.loss + m.fan_loss * fan) * (t - m.ambient) / m.power
}

/// A heat-up watched step by step: when the model's sensor (at the time of each reading)
/// first reached `band_lo` and `band_hi`, when the reading first reached the target, the
/// fault and its time.
#[derive(Debug, Default)]
struct Watched {
    sensor_at_lo_s: Option<f64>,
    sensor_at_hi_s: Option<f64>,
    reading_in_band_s: Option<f64>,
    reading_at_target_s: Option<f64>,
    fault: Option<(ThermalFault, f64)>,
    sensor_at_fault: f64,
}

/// Runs `seconds` (or to a fault) with `heater` heating to `target`; `each` may change the
/// model after every step. Checks the reading against the sensor every step.
fn watch(
    sim: &mut Sim,
    heater: Heater,
    target: f64,
    seconds: f64,
    mut each: impl FnMut(&mut Sim, &Watched),
) -> Watched {
    let (lo, hi) = (target - band(heater) - READ_EPS, target - band(heater) + READ_EPS);
    let mut w = Watched::default();
    let mut sensed = sensor(sim, heater);
    let steps = (seconds / STEP_S).round() as u32;
    for _ in 0..steps {
        let out = sim.step();
        let (t, r) = (sim.secs(), reading(sim, heater));
        if let Some(f) = out.fault {
            w.fault = Some((f, t));
            w.sensor_at_fault = sensor(sim, heater);
            break;
        }
        assert!((r - sensed).abs() <= READ_EPS, "reading {r:.2} vs sensor {sensed:.2} at {t} s");
        if sensed >= lo {
            w.sensor_at_lo_s.get_or_insert(t);
        }
        if sensed >= hi {
            w.sensor_at_hi_s.get_or_insert(t);
        }
        if r >= target - band(heater) {
            w.reading_in_band_s.get_or_insert(t);
        }
        if r >= target {
            w.reading_at_target_s.get_or_insert(t);
        }
        each(sim, &w);
        sensed = sensor(sim, heater);
    }
    w
}

/// The period is derived here: every normal first heat-up of the stock model (targets from a
/// low one to the machine's maximum, rooms at 15 to 35 °C, the hotend with the part fan off
/// and at full, three noise seeds) trips nothing, and its last stretch (first reading inside
/// the band to first reading at the target) is measured; the period must be the slowest
/// times [`SAFETY`], rounded up to the minute.
#[test]
fn approach_periods_are_twice_the_slowest_normal_last_stretch_rounded_up() {
    let m = machine();
    for (heater, targets) in [
        (Heater::Hotend, [170, 200, 230, m.max_hotend_temp_c]),
        (Heater::Bed, [40, 60, 80, m.max_bed_temp_c]),
    ] {
        let mut worst = (0.0f64, 0, 0.0, 0);
        // Only the hotend's model loses heat to the fan.
        let fans: &[u8] = if heater == Heater::Hotend { &[0, 255] } else { &[0] };
        let runs = targets.into_iter().flat_map(|t| {
            ROOMS.into_iter().flat_map(move |r| {
                fans.iter().flat_map(move |&f| SEEDS.map(|seed| (t, r, f, seed)))
            })
        });
        for (target, room, fan, seed) in runs {
            let mut sim = sim_in(seed, room);
            sim.ctl.set_fan(fan);
            sim.ctl.set_target(heater, 0, target).unwrap();
            let tgt = f64::from(target);
            let w = watch(&mut sim, heater, tgt, 1200.0, |_, _| {});
            let label =
                format!("{heater:?} to {target} C, room {room} C, fan {fan}, seed {seed:x}");
            assert_eq!(w.fault, None, "{label}");
            let (Some(a), Some(b)) = (w.reading_in_band_s, w.reading_at_target_s) else {
                panic!("{label}: never reached {w:?}")
            };
            println!(
                "{label}: in the band at {a:.1} s, at target at {b:.1} s: last stretch {:.1} s",
                b - a
            );
            if b - a > worst.0 {
                worst = (b - a, target, room, fan);
            }
        }
        let (slowest, target, room, fan) = worst;
        let want_s = (SAFETY * slowest / 60.0).ceil() * 60.0;
        println!(
            "{heater:?}: slowest last stretch {slowest:.1} s ({target} C, room {room} C, fan \
             {fan}); period {} s = {SAFETY} x that rounded up to the minute ({:.2} x)",
            period_s(heater),
            period_s(heater) / slowest
        );
        assert_eq!(period_s(heater), want_s, "{heater:?}: re-derive the approach period");
    }
}

/// The stalls of a cold heat-up: the heater heats normally until its sensor is at
/// `cut_at_c` below the target, then its power drops to what holds `stall_c` below it at
/// full duty. With the approach deadline: `HEATING FAILED` exactly one period after the
/// reading entered the band (bounded through the sensor's crossings). Without it (the
/// deadline pushed out of reach), nothing trips in the whole 25-minute run: the gap Marlin
/// has.
/// Unchanged (no power drop), the same heater reaches its target and trips nothing.
fn cold_stall(heater: Heater, target: i16, stall_c: f64, cut_at_c: f64, seed: u64) {
    let tgt = f64::from(target);
    let run = |approach: bool, cut: bool| {
        let mut sim = sim_in(seed, 25.0);
        if !approach {
            let mut cfg = *sim.ctl.config();
            cfg.hotend.protect.approach_period_ms = u32::MAX / 4;
            cfg.bed.protect.approach_period_ms = u32::MAX / 4;
            sim.ctl = ThermalController::new(cfg);
        }
        sim.ctl.set_target(heater, 0, target).unwrap();
        let mut cut_done = false;
        let w = watch(&mut sim, heater, tgt, 1500.0, |s, _| {
            if cut && !cut_done && sensor(s, heater) >= tgt - cut_at_c {
                cut_done = true;
                let m = model(s, heater);
                m.power_scale = scale_to_stall_at(m, tgt - stall_c, 0.0);
            }
        });
        (w, cut_done)
    };
    let label = format!("{heater:?} to {target} C stalling {stall_c} C short");

    let (normal, _) = run(true, false);
    assert_eq!(normal.fault, None, "{label}: the normal heat-up tripped");
    assert!(normal.reading_at_target_s.is_some());

    let (gap, cut) = run(false, true);
    assert!(cut && gap.reading_at_target_s.is_none(), "{label}: {gap:?}");
    assert_eq!(gap.fault, None, "{label}: an older protection caught it: {gap:?}");

    let (w, _) = run(true, true);
    let (fault, at) = w.fault.unwrap_or_else(|| panic!("{label}: no fault: {w:?}"));
    assert_eq!(fault, ThermalFault::HeatingFailed(heater), "{label}");
    let (lo, hi) = (w.sensor_at_lo_s.unwrap(), w.sensor_at_hi_s.unwrap());
    let p = period_s(heater);
    println!(
        "{label}: sensor crossed the band edge -{READ_EPS}/+{READ_EPS} C at {lo:.1}/{hi:.1} s, \
         {fault} at {at:.1} s with the sensor at {:.2} C (period {p} s)",
        w.sensor_at_fault
    );
    assert!(at >= lo + p - 1e-6 && at <= hi + p + 1e-6, "{label}: {at} not in {lo}+{p}..{hi}+{p}");
    assert!((w.sensor_at_fault - (tgt - stall_c)).abs() < 1.0, "{label}: {}", w.sensor_at_fault);
}

#[test]
fn hotend_stalled_3_c_short_of_its_target_trips_one_period_after_entering_the_band() {
    cold_stall(Heater::Hotend, 200, 3.0, 2.0, 0x1803);
}

#[test]
fn hotend_stalled_5_c_short_of_its_target_trips_one_period_after_entering_the_band() {
    cold_stall(Heater::Hotend, 200, 5.0, 4.0, 0x1805);
}

#[test]
fn bed_stalled_3_c_short_of_its_target_trips_one_period_after_entering_the_band() {
    cold_stall(Heater::Bed, 60, 3.0, 2.0, 0x1813);
}

#[test]
fn bed_stalled_5_c_short_of_its_target_trips_one_period_after_entering_the_band() {
    cold_stall(Heater::Bed, 60, 5.0, 4.0, 0x1815);
}

/// A target raised by less than the band (the next job 5 °C hotter): the heating watch never
/// arms, so the approach deadline is the only check and starts at the first update after the
/// change. A heater that can hold only `stall_c` below the new target trips one period
/// (plus that update) later, never earlier; the same heater at full power reaches the target
/// and holds it for twice the period without a fault.
#[test]
fn a_target_raised_inside_the_band_is_reached_or_trips_one_period_later() {
    for (heater, target) in [(Heater::Hotend, 200i16), (Heater::Bed, 60)] {
        let tgt = f64::from(target);
        for stall_c in [None, Some(3.0), Some(5.0)] {
            let mut sim = sim_in(0x1820 + target as u64, 25.0);
            // Holding `stall` below the target (5 °C if the heater is sound), settled.
            let start = tgt - stall_c.unwrap_or(5.0);
            sim.ctl.set_target(heater, 0, start as i16).unwrap();
            assert_eq!(sim.run(600.0, |_| {}), None);
            assert!(sim.ctl.heater_at_target(heater));
            if let Some(stall) = stall_c {
                let m = model(&mut sim, heater);
                m.power_scale = scale_to_stall_at(m, tgt - stall, 0.0);
            }
            let t0 = sim.secs();
            sim.ctl.set_target(heater, sim.now_ms, target).unwrap();
            let p = period_s(heater);
            let w = watch(&mut sim, heater, tgt, 2.0 * p, |_, _| {});
            match stall_c {
                None => {
                    assert_eq!(w.fault, None, "{heater:?}");
                    let reached = w.reading_at_target_s.expect("never reached") - t0;
                    println!(
                        "{heater:?} {start} -> {target} C, sound: at target after {reached:.1} s"
                    );
                    assert!(reached < p / SAFETY, "{reached}");
                    assert!(sim.ctl.heater_at_target(heater));
                }
                Some(stall) => {
                    let (fault, at) = w.fault.expect("no fault");
                    assert_eq!(fault, ThermalFault::HeatingFailed(heater));
                    assert_eq!(w.reading_at_target_s, None);
                    let after = at - t0;
                    println!(
                        "{heater:?} {start} -> {target} C, holding {stall} C short: {fault} \
                         {after:.1} s after the change, sensor at {:.2} C",
                        w.sensor_at_fault
                    );
                    assert!((p..=p + 1.5 * STEP_S).contains(&after), "{after}");
                    assert!((w.sensor_at_fault - (tgt - stall)).abs() < 1.0);
                }
            }
        }
    }
}

/// The QEMU board's plant (`firmware/src/board/qemu.rs`: heat capacities / 100, no sensor
/// lag, ±1 count of noise) with its configuration (PID gains time-scaled by 100, 0.5 s
/// residency; protections, and so the approach periods, on the unscaled clock): heat-ups to
/// the job's default targets and to the machine's maxima, in a 15 °C room, fan off and at
/// full, reach their targets within seconds and trip nothing.
#[test]
fn the_qemu_boards_time_scaled_heat_up_never_comes_near_the_period() {
    let m = machine();
    let mut cfg = ThermalConfig::for_machine(&m);
    // As `firmware::board::qemu::THERMAL_CONFIG`.
    cfg.hotend.gains =
        PidGains { kp: Temp::from_num(30), ki: Temp::from_num(150), kd: Temp::lit("0.8") };
    cfg.bed.gains =
        PidGains { kp: Temp::from_num(90), ki: Temp::from_num(250), kd: Temp::from_num(3) };
    cfg.hotend.residency_ms = 500;
    cfg.bed.residency_ms = 500;
    for (targets, room, fan) in
        [((200, 60), 25.0, 0u8), ((m.max_hotend_temp_c, m.max_bed_temp_c), 15.0, 255)]
    {
        let mut sim = sim_in(0x9e3c, room);
        sim.noise = 1.0;
        for h in [&mut sim.hotend, &mut sim.bed] {
            h.capacity /= 100.0;
            // The sensor is the block (one model substep of lag).
            h.sensor_tau = STEP_S / 4.0;
        }
        sim.ctl = ThermalController::new(cfg);
        sim.ctl.set_fan(fan);
        sim.ctl.set_targets(0, targets.0, targets.1).unwrap();
        let (mut entered, mut reached) = ([None::<f64>; 2], [None::<f64>; 2]);
        let fault = sim.run(60.0, |s| {
            for (i, (h, t)) in
                [(Heater::Hotend, targets.0), (Heater::Bed, targets.1)].into_iter().enumerate()
            {
                let (r, t) = (reading(s, h), f64::from(t));
                if r >= t - band(h) {
                    entered[i].get_or_insert(s.secs());
                }
                if r >= t {
                    reached[i].get_or_insert(s.secs());
                }
            }
        });
        assert_eq!(fault, None);
        assert!(sim.ctl.at_target());
        let last = [0, 1].map(|i| reached[i].unwrap() - entered[i].unwrap());
        println!(
            "QEMU plant to {targets:?} C, room {room} C, fan {fan}: last stretch hotend {:.1} s, \
             bed {:.1} s",
            last[0], last[1]
        );
        assert!(
            last[0] < period_s(Heater::Hotend) / 10.0 && last[1] < period_s(Heater::Bed) / 10.0
        );
    }
}

/// The job's view, driven as the firmware's main loop drives it (`firmware/src/heat.rs`):
/// a hotend that stalls 3 °C short fails the job with `HEATING FAILED: hotend` one period
/// after entering the band, long before the job's own wait limit.
#[test]
fn a_job_whose_hotend_stalls_fails_naming_it_before_the_wait_limit() {
    let mut p = Box::new(BoardPrinter::new(&machine()));
    let mut host: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut dev: Endpoint<4, 4> = Endpoint::new(LinkConfig::default());
    let mut frame = [0u8; MAX_WIRE];
    let spec = JobSpec {
        settings: strata::machine::PrintSettings::default(),
        options: JobOptions::default(),
        model_height_um: 800,
        triangles: 12,
    };
    let target = f64::from(spec.settings.hotend_temp_c);
    let mut queue = StepQueue::<64>::new();
    let mut motion = Box::new(BoardMotion::new(queue.split().0));
    let motion = &mut *motion;
    let _ = p.handle(&Message::JobStart(spec), motion);
    assert_eq!(p.state(), DeviceState::Printing);
    let mut sim = sim_in(0x1830, 25.0);
    let mut cut = false;
    let mut entered_lo = None;
    let mut entered_hi = None;
    let mut failed = None;
    let mut sensed = sim.hotend.sensor;
    for _ in 0..(HEAT_WAIT_LIMIT_MS / STEP_MS + 10) {
        let (h, b) = p.heater_targets();
        if sim.ctl.fault().is_none() {
            sim.ctl.set_targets(sim.now_ms, h, b).unwrap();
        }
        sim.ctl.set_fan(p.fan_duty(motion));
        let out = sim.step();
        let now = sim.now_ms;
        let st = sim.ctl.status();
        p.set_thermal(sim.ctl.at_target(), st.hotend.temp_decidegrees(), st.bed.temp_decidegrees());
        if let Some(f) = out.fault {
            p.thermal_fault(f.code(), motion);
        }
        let r: f64 = st.hotend.temp.to_num();
        assert!((r - sensed).abs() <= READ_EPS, "reading {r:.2} vs sensor {sensed:.2}");
        for (edge, at) in [(-READ_EPS, &mut entered_lo), (READ_EPS, &mut entered_hi)] {
            if sensed >= target - band(Heater::Hotend) + edge {
                at.get_or_insert(sim.secs());
            }
        }
        if !cut && sim.hotend.sensor >= target - 2.0 {
            cut = true;
            sim.hotend.power_scale = scale_to_stall_at(&sim.hotend, target - 3.0, 0.0);
        }
        sensed = sim.hotend.sensor;
        // A live link both ways.
        while let n @ 1.. = host.poll_transmit(now, &mut frame) {
            dev.receive(&frame[..n], now);
        }
        p.service(&mut dev, motion, now, 0, 100, false);
        while let n @ 1.. = dev.poll_transmit(now, &mut frame) {
            host.receive(&frame[..n], now);
        }
        while host.peek().is_some() {
            host.pop();
        }
        if !p.is_active() {
            failed = Some(sim.secs());
            break;
        }
    }
    let at = failed.expect("the job never ended");
    let fault = ThermalFault::HeatingFailed(Heater::Hotend);
    assert_eq!(p.state(), DeviceState::Failed);
    assert_eq!(p.error(), (ErrorCode::Thermal, u32::from(fault.code())));
    assert_eq!(p.heater_targets(), (0, 0));
    let (lo, hi, per) = (entered_lo.unwrap(), entered_hi.unwrap(), period_s(Heater::Hotend));
    println!(
        "job: hotend stalled 3 C short: failed with {fault} at {at:.1} s (band entered \
         {lo:.1}..{hi:.1} s, period {per} s; the job's wait limit {} s)",
        HEAT_WAIT_LIMIT_MS / 1000
    );
    assert!(at >= lo + per - 1e-6 && at <= hi + per + 1e-6, "{at}");
    assert!(at * 1000.0 < f64::from(HEAT_WAIT_LIMIT_MS));
}

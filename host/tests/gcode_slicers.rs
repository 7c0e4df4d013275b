//! PrusaSlicer's and CuraEngine's G-code of `xyz_20mm_cube.stl` (`tests/data/gcode/`, made by
//! `make_fixtures.sh` there) streamed through the protocol into the simulated printer: every
//! move ends exactly on the step an independent f64 reading of the file puts it, the board's
//! steps and timing check out, and the print time is the planner's.

use std::path::PathBuf;

use strata::machine::MachineConfig;
use strata::printer::{GCODE_PARK_RETRACT_UM, PARK_LIFT_UM, PARK_XY_UM};
use strata::protocol::DeviceState;
use strata::step::{nearest_step, step_position_q32};
use strata_host::gcode_file;
use strata_host::session::Source;
use strata_host::simjob::{simulate_source, Faults, SimOptions, SimReport};

const ENDER3: MachineConfig = MachineConfig::ENDER3;

fn fixture(name: &str) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/data/gcode").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// The motor position (steps) after every move of `text`, read with f64 and Marlin's rules
/// for the commands slicers write: G0/G1, G28, G90/G91 (every axis), M82/M83, G92, targets
/// clamped to the bed.
fn reference_positions(text: &str) -> Vec<[i64; 4]> {
    let spm = ENDER3.steps_per_mm.map(|r| r.to_num::<f64>());
    let volume = ENDER3.build_volume_um.map(|um| f64::from(um) / 1000.0);
    let (mut logical, mut machine) = ([0.0f64; 4], [0.0f64; 4]);
    let (mut absolute, mut absolute_e) = (true, true);
    let mut out = Vec::new();
    for line in text.lines() {
        let code = line.split(';').next().unwrap_or("");
        let mut words = code.split_whitespace();
        let Some(cmd) = words.next() else { continue };
        let params: Vec<(usize, f64)> = words
            .filter_map(|w| {
                let axis = "XYZE".find(w.chars().next()?)?;
                Some((axis, w[1..].parse::<f64>().unwrap_or(0.0)))
            })
            .collect();
        match cmd {
            "G0" | "G1" => {
                for &(a, v) in &params {
                    let relative = if a == 3 { !absolute_e } else { !absolute };
                    let target = if relative { logical[a] + v } else { v };
                    machine[a] += target - logical[a];
                    if a < 3 {
                        machine[a] = machine[a].clamp(0.0, volume[a]);
                    }
                    logical[a] = target;
                }
                if !params.is_empty() {
                    out.push(core::array::from_fn(|a| (machine[a] * spm[a]).round() as i64));
                }
            }
            "G28" => {
                let named: Vec<usize> = params.iter().map(|p| p.0).filter(|&a| a < 3).collect();
                for a in if named.is_empty() { vec![0, 1, 2] } else { named } {
                    (logical[a], machine[a]) = (0.0, 0.0);
                }
                out.push(core::array::from_fn(|a| (machine[a] * spm[a]).round() as i64));
            }
            "G90" => (absolute, absolute_e) = (true, true),
            "G91" => (absolute, absolute_e) = (false, false),
            "M82" => absolute_e = true,
            "M83" => absolute_e = false,
            "G92" => params.iter().for_each(|&(a, v)| logical[a] = v),
            _ => {}
        }
    }
    out
}

/// `positions` with each run of equal positions kept once, from the origin.
fn distinct(positions: impl IntoIterator<Item = [i64; 4]>) -> Vec<[i64; 4]> {
    let mut out = vec![[0; 4]];
    for p in positions {
        if out.last() != Some(&p) {
            out.push(p);
        }
    }
    out
}

fn check(name: &str, slicer_estimate_s: f64) -> (SimReport, gcode_file::GcodeScan) {
    let text = fixture(name);
    let scan = gcode_file::scan(&text, &ENDER3).unwrap();
    let opts = SimOptions { block_ends: true, ..SimOptions::default() };
    let rep = simulate_source(Source::Gcode(&text, scan.spec), &ENDER3, &opts)
        .unwrap_or_else(|(e, _)| panic!("{name}: {e}"));
    let want = distinct(reference_positions(std::str::from_utf8(&text).unwrap()));
    let got = distinct(rep.block_ends.iter().copied());
    let first_difference = want.iter().zip(&got).position(|(w, g)| w != g);
    if let Some(i) = first_difference {
        let around = |v: &[[i64; 4]]| v[i.saturating_sub(2)..(i + 3).min(v.len())].to_vec();
        eprintln!("{name}: expected {:?}, ran {:?}", around(&want), around(&got));
        eprintln!("{} moves, {} block ends", scan.moves, rep.block_ends.len());
    }
    assert_eq!(first_difference, None, "{name}: first differing position");
    assert_eq!(want.len(), got.len(), "{name}: positions");
    assert_eq!(rep.positions, *want.last().unwrap(), "{name}: the board's final position");
    assert_eq!(scan.refusals, []);
    assert_eq!(
        (scan.refused, rep.violations, rep.underruns, rep.step_check_failures),
        (0, 0, 0, 0)
    );
    // The board ran the planner's time: from the first step to the last is the plan but for
    // the half steps at either end (5 ms at most: Z's 1.25 um from rest at 100 mm/s^2).
    assert!(
        (rep.print_time_s - rep.planned_s).abs() < 10e-3,
        "{} vs {}",
        rep.print_time_s,
        rep.planned_s
    );
    // The slicers estimate with their own motion models (PrusaSlicer: Marlin's jerk; Cura:
    // its own): the same print within a quarter.
    let ratio = rep.planned_s / slicer_estimate_s;
    assert!(
        (0.75..1.25).contains(&ratio),
        "{name}: {} s planned, slicer {slicer_estimate_s} s",
        rep.planned_s
    );
    assert_eq!(scan.spec.layers, 100, "{name}: 20 mm in 0.2 mm layers");
    assert_eq!(rep.layer_hashes.len(), 100, "{name}: a hash per layer");
    eprintln!(
        "{name}: {} lines, {} moves, planned {:.1} s (slicer {slicer_estimate_s} s), filament {:.1} mm, skipped {:?}",
        scan.lines, scan.moves, rep.planned_s, rep.filament_mm, scan.skipped
    );
    (rep, scan)
}

#[test]
fn prusaslicer_cube_ends_every_move_on_its_step() {
    // `; estimated printing time (normal mode) = 41m 3s` (tests/data/gcode/README.md).
    let (_, scan) = check("xyz_20mm_cube_prusaslicer.gcode", 2463.0);
    assert!(scan.skipped.contains_key("M201") && scan.skipped.contains_key("M204"));
}

#[test]
fn cura_cube_ends_every_move_on_its_step() {
    // CuraEngine's `Print time (s): 1797` (tests/data/gcode/README.md).
    check("xyz_20mm_cube_cura.gcode", 1797.0);
}

/// The host dies 35 s into streaming PrusaSlicer's cube (its start code waits 23 s): the printer runs every complete line
/// it received, exactly as the file says, then parks (retract 5 mm, lift 10 mm, back left
/// corner) and pauses; the resume point is the end of a move of the file.
#[test]
fn a_gcode_print_whose_host_dies_runs_what_it_has_then_parks() {
    let name = "xyz_20mm_cube_prusaslicer.gcode";
    let text = fixture(name);
    let scan = gcode_file::scan(&text, &ENDER3).unwrap();
    let opts = SimOptions {
        faults: Faults { cut_at_ms: Some(35_000), ..Faults::default() },
        device_outlives_host: true,
        heat_hold_ms: 10_000,
        block_ends: true,
        ..SimOptions::default()
    };
    let (e, rep) = simulate_source(Source::Gcode(&text, scan.spec), &ENDER3, &opts).unwrap_err();
    assert!(e.contains("link dead"), "{e}");
    assert_eq!(rep.device_state, Some(DeviceState::Paused));
    let resume = rep.resume.expect("a resume point");
    let steps = |um: [i32; 4]| {
        core::array::from_fn(|a| nearest_step(step_position_q32(um[a], ENDER3.steps_per_mm[a])))
    };
    // What ran before parking is the file's beginning, move for move.
    let want = distinct(reference_positions(std::str::from_utf8(&text).unwrap()));
    let got = distinct(rep.block_ends.iter().copied());
    let (ran, park) = got.split_at(got.len() - 3);
    assert!(ran.len() > 100 && ran.len() < want.len(), "{} of {} positions", ran.len(), want.len());
    assert_eq!(ran, &want[..ran.len()]);
    assert_eq!(*ran.last().unwrap(), steps(resume.position_um));
    // Then: retract, lift, park.
    let mut at = resume.position_um;
    at[3] -= GCODE_PARK_RETRACT_UM;
    assert_eq!(park[0], steps(at));
    at[2] += PARK_LIFT_UM;
    assert_eq!(park[1], steps(at));
    at[0] = PARK_XY_UM[0];
    at[1] = ENDER3.build_volume_um[1] - PARK_XY_UM[1];
    assert_eq!(park[2], steps(at));
    assert_eq!(rep.positions, steps(at));
    assert_eq!((rep.underruns, rep.violations), (0, 0));
    eprintln!(
        "{name}: the host died at 35 s; {} of {} positions ran, paused at layer {}, heaters off \
         {} ms after parking",
        ran.len(),
        want.len(),
        resume.layer,
        rep.heaters_off_ms.unwrap() - rep.parked_ms.unwrap()
    );
}

/// The host dies 35 s into streaming PrusaSlicer's cube and a new host resumes it: the
/// printer reheats (after its heaters went off, or not), brings the nozzle back (over the
/// part, down, primed) and reads on from the line after the last it had read. Every move of
/// the file runs once, in order, at its step; the motors end where the uninterrupted run's
/// did; every layer's hash is the uninterrupted run's but the one it stopped in (its motion
/// came to rest mid-layer, as the uninterrupted run's did not).
#[test]
fn a_gcode_print_whose_host_dies_resumes_where_it_stopped() {
    let name = "xyz_20mm_cube_prusaslicer.gcode";
    let text = fixture(name);
    let scan = gcode_file::scan(&text, &ENDER3).unwrap();
    let source = Source::Gcode(&text, scan.spec);
    let clean = simulate_source(source, &ENDER3, &SimOptions::default()).unwrap();
    let want = distinct(reference_positions(std::str::from_utf8(&text).unwrap()));
    let steps = |um: [i32; 4]| -> [i64; 4] {
        core::array::from_fn(|a| nearest_step(step_position_q32(um[a], ENDER3.steps_per_mm[a])))
    };
    for resume_after_ms in [2_000, 20_000] {
        let opts = SimOptions {
            faults: Faults { cut_at_ms: Some(35_000), ..Faults::default() },
            device_outlives_host: true,
            heat_hold_ms: 10_000,
            resume_after_ms: Some(resume_after_ms),
            block_ends: true,
            ..SimOptions::default()
        };
        let rep = simulate_source(source, &ENDER3, &opts).unwrap();
        assert_eq!(rep.device_state, Some(DeviceState::Done));
        assert_eq!(rep.heaters_off_ms.is_some(), resume_after_ms > 10_000);
        let stop = rep.resume.expect("a resume point");
        let got = distinct(rep.block_ends.iter().copied());
        // The park (retract, lift, back left corner), then the unpark (over the part, down,
        // primed: back where it stopped).
        let mut retracted = stop.position_um;
        retracted[3] -= GCODE_PARK_RETRACT_UM;
        let k = got.iter().position(|p| *p == steps(retracted)).expect("the park");
        assert_eq!(got[k - 1], steps(stop.position_um));
        let mut lifted = retracted;
        lifted[2] += PARK_LIFT_UM;
        let mut over = lifted;
        (over[0], over[1]) = (stop.position_um[0], stop.position_um[1]);
        assert_eq!(got[k + 1], steps(lifted));
        assert_eq!(&got[k + 3..k + 6], &[steps(over), steps(retracted), steps(stop.position_um)]);
        // Every move of the file once, in order.
        let ran: Vec<_> = got[..k].iter().chain(&got[k + 6..]).copied().collect();
        assert_eq!(ran, want, "resumed after {resume_after_ms} ms");
        assert_eq!(rep.positions, clean.positions);
        let first = rep.first_host_hashes.clone().unwrap();
        let differ: Vec<usize> = (0..clean.layer_hashes.len())
            .filter(|&l| {
                let heard = [first.get(l), rep.layer_hashes.get(l)];
                heard.iter().flatten().any(|&&h| h != 0 && h != clean.layer_hashes[l])
            })
            .collect();
        assert_eq!(differ, [stop.layer as usize], "layers whose hash differs");
        for l in stop.layer as usize + 1..clean.layer_hashes.len() {
            assert_eq!(rep.layer_hashes.get(l), Some(&clean.layer_hashes[l]), "layer {l}");
        }
        assert_eq!((rep.underruns, rep.violations), (0, 0));
        eprintln!(
            "{name}: stopped in layer {} of {}, resumed {resume_after_ms} ms after parking",
            stop.layer, clean.layers
        );
    }
}

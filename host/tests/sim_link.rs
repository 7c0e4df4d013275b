//! The simulated printer over a lossy link: seeded drop/corrupt/duplicate/byte-loss/delay on
//! both directions; the job completes with the clean run's per-layer hashes (and the same
//! step counts, no underrun) up to 5 % loss, no corrupted or foreign payload reaches the device's job
//! runner, and a dead link ends the job with a clear error within bounded virtual time on the
//! host, while the printer parks and pauses.

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::printer::{PARK_LIFT_UM, PARK_XY_UM};
use strata::protocol::{DeviceState, JobSpec};
use strata::step::{nearest_step, step_position_q32};
use strata_host::hil::banded_cylinder;
use strata_host::simjob::{simulate, Faults, SimOptions, SimReport};
use strata_testkit::drive::job_spec;

fn small_job() -> (Vec<Triangle>, JobSpec) {
    // A closed cylinder, one band (its sides span every layer).
    let tris = banded_cylinder(5_000.0, 1_600, 256, 1_600);
    let job = job_spec(&tris);
    assert_eq!(job.model_height_um, 1_600);
    (tris, job)
}

fn run(faults: Faults) -> Result<SimReport, (String, Box<SimReport>)> {
    let (tris, job) = small_job();
    let opts = SimOptions { faults, check_delivery: true, ..SimOptions::default() };
    simulate(&tris, &MachineConfig::default(), job, &opts)
}

#[test]
fn lossy_links_give_the_clean_run_hashes() {
    let clean = run(Faults::default()).unwrap();
    eprintln!(
        "clean: {} layers, print {:.1} s, {} triangles, {:.2} B/triangle, host link {:?}",
        clean.layers,
        clean.print_time_s,
        clean.triangles,
        clean.wire_bytes_per_triangle,
        clean.host_link
    );
    assert_eq!(clean.layer_hashes.len(), clean.layers as usize);
    // The device's totals over the wire match what the simulated board counted.
    let report = clean.job_report.expect("a job report");
    assert_eq!(report.steps, clean.steps);
    assert_eq!(report.positions, clean.positions);
    assert_eq!(clean.underruns, 0);
    assert_eq!(clean.violations, 0);
    assert_eq!(clean.delivery_mismatches, 0);
    assert_eq!(clean.host_link.retransmits, 0);
    assert_eq!(clean.device_link.no_room, 0, "the host exceeded the device's credits");
    for (rate, seed) in [(0.01, 1), (0.05, 2), (0.05, 3)] {
        let r = run(Faults::uniform(rate, seed)).unwrap();
        eprintln!("loss {rate} seed {seed}: host {:?} device {:?}", r.host_link, r.device_link);
        assert!(r.device_link.bad_frames > 0 && r.host_link.retransmits > 0);
        assert_eq!(r.delivery_mismatches, 0, "a corrupted frame reached the device");
        assert_eq!(r.layer_hashes, clean.layer_hashes);
        assert_eq!(r.steps, clean.steps);
        assert_eq!(r.underruns, 0);
        // The step commands depend on the blocks only: without an underrun every step edge
        // reaches the pins at the same tick (relative to the first step) as in the clean run.
        assert_eq!(r.board_hash, clean.board_hash);
        assert_eq!(r.job_report, clean.job_report);
        assert_eq!(r.violations, 0);
        assert_eq!(r.starts, 1);
    }
}

#[test]
fn a_dead_link_ends_the_job_with_a_clear_error() {
    let cut = 2_000;
    let (e, rep) = run(Faults { cut_at_ms: Some(cut), ..Faults::default() }).unwrap_err();
    eprintln!("{e} (at {} ms)", rep.end_ms);
    assert!(e.contains("link dead"), "{e}");
    assert!(rep.end_ms <= cut as u64 + 3_500, "{}", rep.end_ms);
}

/// The host dies while streaming: the printer prints the layers it has, parks the nozzle off
/// the part (retracted, lifted, at the back left) and pauses, holding its heaters for the
/// hold time, then cools. Where the input ended is kept for a resume.
#[test]
fn a_dead_host_leaves_the_print_parked_and_paused() {
    let (tris, job) = small_job();
    let hold_ms = 30_000;
    let opts = SimOptions {
        faults: Faults { cut_at_ms: Some(300), ..Faults::default() },
        device_outlives_host: true,
        heat_hold_ms: hold_ms,
        ..SimOptions::default()
    };
    let machine = MachineConfig::default();
    let (e, rep) = simulate(&tris, &machine, job, &opts).unwrap_err();
    assert!(e.contains("link dead"), "{e}");
    assert_eq!(rep.device_state, Some(DeviceState::Paused));
    let resume = rep.resume.expect("a resume point");
    assert!(resume.layer + 1 < rep.layers, "layer {} of {}", resume.layer, rep.layers);
    // Parked 10 mm in from the back left corner (80 steps/mm), 10 mm above where the print
    // stopped (400 steps/mm), the filament retracted by the job's retraction (93 steps/mm).
    let steps =
        |um: i32, axis: usize| nearest_step(step_position_q32(um, machine.steps_per_mm[axis]));
    let y_park = machine.build_volume_um[1] - PARK_XY_UM[1];
    let z_park = resume.position_um[2] + PARK_LIFT_UM;
    let e_park = resume.position_um[3] - job.settings.retract_length_um;
    assert_eq!(
        rep.positions,
        [steps(PARK_XY_UM[0], 0), steps(y_park, 1), steps(z_park, 2), steps(e_park, 3)]
    );
    assert_eq!(resume.retracted_um, job.settings.retract_length_um);
    assert_eq!((rep.underruns, rep.violations), (0, 0));
    // The heaters hold for the hold time after parking, then go off.
    let (parked, off) = (rep.parked_ms.unwrap(), rep.heaters_off_ms.unwrap());
    assert!(off - parked >= hold_ms as u64 && off - parked <= hold_ms as u64 + 2, "{parked} {off}");
}

/// A host that dies after sending the whole model loses nothing: the job ends as usual.
#[test]
fn a_host_that_dies_after_the_whole_model_loses_nothing() {
    let clean = run(Faults::default()).unwrap();
    let (tris, job) = small_job();
    let opts = SimOptions {
        faults: Faults {
            cut_at_ms: Some(clean.stream_time_s as u32 * 1000 + 1_000),
            ..Faults::default()
        },
        device_outlives_host: true,
        ..SimOptions::default()
    };
    let (_, rep) = simulate(&tris, &MachineConfig::default(), job, &opts).unwrap_err();
    assert_eq!(rep.device_state, Some(DeviceState::Done));
    assert_eq!(rep.positions, clean.positions);
    assert_eq!(rep.resume, None);
}

/// The host dies mid-job and a new host resumes it (`strata print --resume`): the printer
/// reheats, brings the nozzle back and prints on. Every layer either host heard of has the
/// uninterrupted run's hash, the new host hears of every layer after the one where the print
/// stopped, and the motors end where the uninterrupted run's did (no filament or position
/// lost: the park and unpark moves cancel exactly).
#[test]
fn a_resumed_job_ends_as_an_uninterrupted_one() {
    let clean = run(Faults::default()).unwrap();
    let (tris, job) = small_job();
    for (cut_ms, resume_after_ms, hold_ms) in [(300, 2_000, 30_000), (700, 40_000, 30_000)] {
        let opts = SimOptions {
            faults: Faults { cut_at_ms: Some(cut_ms), ..Faults::default() },
            device_outlives_host: true,
            heat_hold_ms: hold_ms,
            resume_after_ms: Some(resume_after_ms),
            ..SimOptions::default()
        };
        let rep = simulate(&tris, &MachineConfig::default(), job, &opts).unwrap();
        let first = rep.first_host_hashes.clone().expect("a new host resumed the job");
        let stop = rep.resume.expect("a resume point").layer as usize;
        eprintln!(
            "cut {cut_ms} ms: stopped after layer {stop} of {}, first host heard {} layers, \
             cooled {:?}",
            clean.layers,
            first.iter().filter(|&&h| h != 0).count(),
            rep.heaters_off_ms
        );
        assert!(stop + 1 < clean.layers as usize, "the cut came after the last layer");
        for (layer, &want) in clean.layer_hashes.iter().enumerate() {
            for heard in [&first, &rep.layer_hashes] {
                let got = heard.get(layer).copied().unwrap_or(0);
                assert!(got == 0 || got == want, "layer {layer}: {got:x} vs {want:x}");
            }
            if layer > stop {
                assert_eq!(rep.layer_hashes.get(layer), Some(&want), "layer {layer}");
            }
        }
        assert_eq!(rep.layer_hashes.len(), clean.layer_hashes.len());
        assert_eq!(rep.positions, clean.positions);
        let report = rep.job_report.expect("a job report");
        assert_eq!(report.positions, clean.positions);
        assert_eq!((rep.underruns, rep.violations), (0, 0));
        assert_eq!(rep.device_state, Some(DeviceState::Done));
        // Cooled or not: the second run waited past the heaters' hold.
        assert_eq!(rep.heaters_off_ms.is_some(), resume_after_ms > hold_ms as u64);
    }
}

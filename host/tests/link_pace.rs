//! Admission for the link (`strata_host::admission::admit_job_paced`): a model whose triangles
//! the link cannot stream as fast as the printer prints them is simplified until it can, and the
//! simulated printer (its executor's underruns and stops for want of commands: the independent
//! judge) confirms both the problem and the cure. A model the link keeps ahead of is left alone.

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::printer::board::BOARD_CAPACITIES;
use strata_host::admission::{self, admit_job_paced, Admission};
use strata_host::simjob::{simulate, SimOptions, SimReport};
use strata_testkit::drive::job_spec;
use strata_testkit::mesh::{cuboid, sphere, to_um};

/// A common baud rate of Ender-3 firmware (Marlin's default), slower than the simulation's.
const BAUD: u32 = 115_200;
/// Sphere centre (mm) and radius (mm): a 3 mm bead at the bed's centre.
const C_MM: [f64; 3] = [110.0, 110.0, 1.5];
const R_MM: f64 = 1.5;
/// Allowed deviation, mm (the acceptance's).
const MAX_DEVIATION_MM: f64 = 0.05;

/// Times the printer waited for the link: the executor reached the end of the queued
/// commands mid-motion (an underrun) or at a stop with the print not done (a restart).
fn link_waits(r: &SimReport) -> u32 {
    r.underruns + r.rest_waits()
}

fn sim(tris: &[Triangle]) -> SimReport {
    let machine = MachineConfig::default();
    let opts = SimOptions { baud: BAUD, capacities: BOARD_CAPACITIES, ..SimOptions::default() };
    let job = strata::protocol::JobSpec { triangles: tris.len() as u32, ..job_spec(tris) };
    simulate(tris, &machine, job, &opts).map_err(|(e, _)| e).unwrap()
}

#[test]
fn a_dense_bead_is_simplified_until_the_link_keeps_ahead() {
    // 129,600 triangles (20 B each on the wire: 225 s at 115200 baud) for a 3 mm bead that
    // prints in under two minutes (15 layers, each slowed to the printer's 5 s minimum; the
    // device takes 57,600 as fast as it prints them: it releases the moves whose plan is
    // final without waiting for the next layer's).
    let tris = to_um(&sphere(C_MM, R_MM, 360, 180));
    let machine = MachineConfig::default();
    let job = job_spec(&tris);
    assert!(link_waits(&sim(&tris)) > 0, "streamed whole, the printer must wait for the link");
    let paced =
        admit_job_paced(&tris, &machine, &job, &BOARD_CAPACITIES, MAX_DEVIATION_MM, BAUD).unwrap();
    assert!(paced.pace.keeps_ahead(), "{:?}", paced.pace);
    let Admission::Simplified(s) = &paced.admission else {
        panic!("the bead fits the printer whole: only the link can have simplified it")
    };
    assert!(s.max_deviation_mm <= MAX_DEVIATION_MM, "{}", s.max_deviation_mm);
    // The simplification keeps original vertices (on the sphere): every corner within 1 um
    // (their rounding) of the analytic radius.
    for p in s.triangles.iter().flat_map(|t| t.v) {
        let d = [p.x, p.y, p.z]
            .iter()
            .zip(C_MM)
            .map(|(&um, c)| (um as f64 / 1e3 - c).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!((d - R_MM).abs() < 2e-3, "a corner {d} mm from the centre");
    }
    let waits = link_waits(&sim(&s.triangles));
    assert_eq!(waits, 0, "the simplified bead must stream ahead of its print");
}

#[test]
fn a_model_the_link_keeps_ahead_of_is_streamed_unchanged() {
    // 12 triangles for a 20 mm cube: the link is idle most of the print.
    let tris = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]));
    let machine = MachineConfig::default();
    let paced = admit_job_paced(
        &tris,
        &machine,
        &job_spec(&tris),
        &BOARD_CAPACITIES,
        MAX_DEVIATION_MM,
        BAUD,
    )
    .unwrap();
    assert!(matches!(paced.admission, Admission::Unchanged(_)));
    assert!(paced.pace.keeps_ahead() && paced.pace.stream_s < 0.1, "{:?}", paced.pace);
    // The whole print's time from the planner: 100 layers of a 20 mm cube take minutes.
    assert!(paced.times.total_s > 60.0 && paced.times.starts_s.len() == 100, "{:?}", paced.pace);
    assert!(paced.times.starts_s.windows(2).all(|w| w[0] <= w[1]));
    assert!(paced.times.extrudes.iter().all(|&x| x), "every layer of a cube extrudes");
}

#[test]
fn a_wall_thinner_than_a_line_has_layers_that_extrude_nothing() {
    // 0.1 mm thick: less than the narrowest line the printer lays (thin walls are reported,
    // not printed), on a 20 mm cube so that the job has extruding layers too.
    let mut tris = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 2.0]));
    tris.extend(to_um(&cuboid([100.0, 125.0, 0.0], [120.0, 125.1, 4.0])));
    tris.sort_by_key(Triangle::z_min);
    let job = job_spec(&tris);
    let (_, times) =
        admission::toolpath_pass(&tris, &MachineConfig::default(), &job, None).unwrap();
    // Layers of 0.2 mm: the cube's 10 extrude, the wall's 10 above it do not.
    assert_eq!(times.extrudes.len(), 20, "{:?}", times.extrudes);
    assert!(times.extrudes[..10].iter().all(|&x| x), "{:?}", times.extrudes);
    assert!(!times.extrudes[10..].iter().any(|&x| x), "{:?}", times.extrudes);
}

#[test]
fn a_bead_whose_layers_wait_out_their_minimum_time_streams_ahead_of_its_waits() {
    // A 2 mm bead: 10 layers, each short of the 5 s minimum even at the 10 mm/s floor, so each
    // ends lifted off the part, waiting (retract, lift, dwell). The device holds a layer's
    // last moves until the next layer's arrive only where their plan can still change: the
    // wait is final, so the admission's per-layer print times (which count it) hold.
    let tris = to_um(&sphere([110.0, 110.0, 1.0], 1.0, 240, 120));
    let machine = MachineConfig::default();
    let job = job_spec(&tris);
    let paced =
        admit_job_paced(&tris, &machine, &job, &BOARD_CAPACITIES, MAX_DEVIATION_MM, BAUD).unwrap();
    assert!(paced.pace.keeps_ahead(), "{:?}", paced.pace);
    let rep = sim(paced.admission.triangles(&tris));
    // Z steps (400 per mm): the 2 mm rise, and each waiting layer's lift up and back down.
    let (rise, lift) = (2 * 400, 2 * 3 * 400);
    assert!(rep.steps[2] >= rise + 5 * lift, "layers must wait lifted: Z steps {}", rep.steps[2]);
    assert_eq!(link_waits(&rep), 0, "a link that keeps ahead must never hold the print: {rep:?}");
}

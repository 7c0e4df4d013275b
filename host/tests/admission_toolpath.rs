//! Admission simplifies for the toolpath stage too: a model whose slicer needs fit but whose
//! loop points do not is simplified (within the measured deviation) until both fit, and the
//! admitted mesh's own toolpath needs (measured again, independently of the admission's
//! search) fit the device.

use strata::machine::MachineConfig;
use strata::printer::board::BOARD_CAPACITIES;
use strata::protocol::Capacities;
use strata_host::admission::{
    admit_job, hausdorff_mm, toolpath_peaks_limited, toolpath_shortfalls, Admission,
};
use strata_testkit::drive::job_spec;
use strata_testkit::mesh::{sphere, to_um};

#[test]
fn loop_points_beyond_the_device_are_simplified_away() {
    // A 12 mm ball of 128 x 64 facets: 128 contour points at its equator, more than this
    // device's 96 loop points, and a slicer that holds every layer whole.
    let tris = to_um(&sphere([110.0, 110.0, 6.0], 6.0, 128, 64));
    let caps = Capacities {
        active_triangles: 4096,
        contour_points: 4096,
        contour_loops: 64,
        toolpath_points: 96,
        ..BOARD_CAPACITIES
    };
    let machine = MachineConfig::default();
    let job = job_spec(&tris);
    let limit = Some(&caps);
    let whole = toolpath_peaks_limited(&tris, &machine, &job, limit);
    assert!(
        whole.map_or(true, |p| !toolpath_shortfalls(&p, &caps).is_empty()),
        "the whole ball must not fit the toolpath stage"
    );
    let max_deviation_mm = 0.05;
    let Admission::Simplified(s) =
        admit_job(&tris, &machine, &job, &caps, max_deviation_mm).unwrap()
    else {
        panic!("the ball must be simplified")
    };
    assert!(s.max_deviation_mm <= max_deviation_mm, "{}", s.max_deviation_mm);
    assert!(hausdorff_mm(&tris, &s.triangles) <= max_deviation_mm + 1e-3);
    let peaks = toolpath_peaks_limited(&s.triangles, &machine, &job, limit).unwrap();
    assert_eq!(toolpath_shortfalls(&peaks, &caps), Vec::<String>::new());
}

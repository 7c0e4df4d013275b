//! Extrusion over air of the overhang test parts and 3DBenchy, measured by the independent
//! checker `strata_testkit::overhang` on the toolpath stage's extrusions (default settings).
//!
//! Prints a table (`--nocapture`): part, extruded mm, and over air in % of it: anchored
//! bridges, sparse infill and supports (counted apart: they span the lines below by design),
//! true air.
//! Bridge-like parts print with at most 0.2 % of their extrusion over true air
//! ([`bridges_leave_almost_no_true_air`]); without bridges they do not.

mod toolpath_support;

use std::time::Instant;

use strata::gcode::type_name;
use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::ToolpathConfig;
use strata_testkit::check::pt;
use strata_testkit::mesh::{
    bridge_part, cuboid, overhang_parts, tee_part, tunnel_part, wedge_part, TriMm,
};
use strata_testkit::models::{load_placed, shared_models};
use strata_testkit::overhang::{over_air, Extrusion, Layer, OverAir, TABLE_HEAD};
use toolpath_support::{default_run, extrusions, layer_starts, run_cfg, TpRun};

/// The extrusions of a run, per layer, as the checker takes them: each its feature's `;TYPE:`
/// name (a bridge when `Bridge infill` or `Overhang perimeter`) and the configured line width
/// (the stage's moves carry no width).
fn checker_layers(run: &TpRun) -> Vec<Layer> {
    let width = f64::from(PrintSettings::default().line_width_um);
    run.layers
        .iter()
        .zip(layer_starts(run))
        .map(|(l, start)| Layer {
            z_um: f64::from(l.z_um),
            extrusions: extrusions(l, start)
                .into_iter()
                .map(|(a, b, f, _)| Extrusion::new(pt(a), pt(b), width, type_name(f)))
                .collect(),
        })
        .collect()
}

/// Summed length of a run's extrusions, mm, from its integer end points.
fn extruded_mm(run: &TpRun) -> f64 {
    let starts = layer_starts(run);
    let len = |(a, b, _, _): &(strata::geom::Point2, strata::geom::Point2, _, _)| {
        f64::from(b.x - a.x).hypot(f64::from(b.y - a.y))
    };
    run.layers.iter().zip(starts).flat_map(|(l, s)| extrusions(l, s)).map(|e| len(&e)).sum::<f64>()
        / 1000.0
}

/// A part's run and what the checker measured on it; asserts the checker's extruded length is
/// the run's.
fn measure(name: &str, run: &TpRun) -> OverAir {
    let air = over_air(&checker_layers(run));
    let want = extruded_mm(run);
    assert!(
        (air.extruded_mm - want).abs() <= 1e-9 * want,
        "{name}: checker extruded {} mm, the extrusions {want} mm",
        air.extruded_mm
    );
    air
}

/// The cube and the overhang parts, at (100, 100) mm: name and mesh.
fn parts() -> Vec<(&'static str, Vec<TriMm>)> {
    let mut parts = vec![("cube 20 mm", cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]))];
    parts.extend(overhang_parts(100.0, 100.0));
    parts
}

#[test]
fn overhang_table_and_the_checker_counts_every_extrusion() {
    let mut table = format!("{TABLE_HEAD}\n");
    let mut notes = String::new();
    for (name, mesh) in parts() {
        let air = measure(name, &default_run(&mesh));
        table += &format!("{}\n", air.row(name));
        notes += &format!("{name}: true air by feature: {}\n", air.describe_worst(0));
    }
    // 3DBenchy (225,154 triangles) in release runs only: a debug build takes minutes.
    if let Some(dir) = shared_models().filter(|_| !cfg!(debug_assertions)) {
        let machine = MachineConfig::default();
        let settings = PrintSettings::default();
        let tris = load_placed(&dir.join("3DBenchy.stl"), &machine);
        let run = run_cfg(&tris, &settings, ToolpathConfig::new(&machine, &settings))
            .unwrap_or_else(|e| panic!("3DBenchy: {e}"));
        let segments: usize = checker_layers(&run).iter().map(|l| l.extrusions.len()).sum();
        let t = Instant::now();
        let air = measure("3DBenchy", &run);
        let took = t.elapsed();
        table += &format!("{}\n", air.row("3DBenchy"));
        notes += &format!(
            "3DBenchy: {segments} segments checked in {took:?}; {}\n",
            air.describe_worst(
                std::env::var("WORST").ok().and_then(|v| v.parse().ok()).unwrap_or(3)
            )
        );
    }
    eprintln!("{table}\n{notes}");
}

/// Perimeters only, not "nothing over air": the first solid layer under the top spans the
/// sparse infill below it (true air today, unless printed as a bridge).
#[test]
fn a_cube_has_no_perimeter_over_air() {
    let air = measure("cube", &default_run(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0])));
    for f in ["External perimeter", "Perimeter"] {
        assert_eq!(air.true_air_of(f), 0.0, "cube {f}: {}", air.describe_worst(3));
    }
}

#[test]
fn a_45_degree_overhang_has_no_perimeter_over_air() {
    // Each layer's perimeters reach h tan 45 deg = 0.2 mm past the ones below, within the
    // checker's w/2 + h tan 50 deg.
    let air = measure("wedge 45", &default_run(&wedge_part(100.0, 100.0, 45.0)));
    for f in ["External perimeter", "Perimeter"] {
        assert_eq!(air.true_air_of(f), 0.0, "wedge 45 {f}: {}", air.describe_worst(3));
    }
}

#[test]
fn the_checker_sees_the_overhang_of_the_t() {
    let air = measure("T", &default_run(&tee_part(100.0, 100.0)));
    // The bar's underside beyond the stem: 2 x 15 mm x 10 mm, covered at the line width
    // (0.45 mm) by the bar's first layer, all of it over air; half of that length at least.
    let underside_mm = 2.0 * 15.0 * 10.0 / 0.45;
    let over = air.true_air_mm + air.anchored_bridge_mm;
    assert!(over >= underside_mm / 2.0, "T: {over:.0} mm over air; {}", air.describe_worst(3));
}

#[test]
fn bridges_leave_almost_no_true_air() {
    let settings = PrintSettings::default();
    let machine = MachineConfig::default();
    for (name, mesh) in
        [("bridge", bridge_part(100.0, 100.0)), ("upside-down U", tunnel_part(100.0, 100.0))]
    {
        // Without bridges (solid skin over the gap and over sparse infill): far above.
        let mut cfg = ToolpathConfig::new(&machine, &settings);
        cfg.bridges = false;
        let run = run_cfg(&strata_testkit::mesh::to_um(&mesh), &settings, cfg).unwrap();
        let without = measure(name, &run).true_air_percent();
        assert!(without > 1.0, "{name} without bridges: {without:.2} %");
        let air = measure(name, &default_run(&mesh));
        // At most 0.2 % of the extruded length in true air.
        assert!(
            air.true_air_percent() <= 0.2,
            "{name}: {:.2} %; {}",
            air.true_air_percent(),
            air.describe_worst(5)
        );
    }
}

//! Every model under `../shared/models` to G-code: no error, the README's layer counts, solid
//! first and last layers, G-code consistent with the toolpath counters; the top of
//! `xyz_20mm_cube.stl` covered. In debug builds the models over 1 MB (3DBenchy, the scaled
//! trimeshes, rockerarm, bunny, fertility, rear_case, bwb) are left to the release run
//! (`cargo test --release --test toolpath_models`) and to `examples/toolpath_report.rs`.

mod toolpath_support;

use std::path::Path;

use strata::gcode::{GcodeOptions, GcodeWriter};
use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::{Feature, ToolpathConfig};
use strata_testkit::models::{big_machine, load_placed, readme_layers, shared_models};
use toolpath_support::{check_containment, extrusions, layer_starts, run_cfg, top_coverage, TpRun};

/// Line width, um.
const W: f64 = 450.0;

fn machine_for(file: &str) -> MachineConfig {
    if file == "plate_holes.stl" {
        big_machine()
    } else {
        MachineConfig::default()
    }
}

fn toolpaths(path: &Path, machine: &MachineConfig) -> TpRun {
    let tris = load_placed(path, machine);
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(machine, &settings);
    run_cfg(&tris, &settings, cfg).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// G-code of a run, written as the host does; checks it against the run's counters.
fn gcode_of(run: &TpRun, machine: &MachineConfig, file: &str) {
    let settings = PrintSettings::default();
    let cfg = ToolpathConfig::new(machine, &settings);
    let mut w = GcodeWriter::new(String::new(), GcodeOptions::default(), &cfg);
    w.start(machine, &settings, &cfg).unwrap();
    for l in &run.layers {
        w.event(&strata::toolpath::ToolEvent::LayerStart {
            index: l.index,
            z_um: l.z_um,
            height_um: l.height_um,
        })
        .unwrap();
        for m in &l.moves {
            w.event(&strata::toolpath::ToolEvent::Move(*m)).unwrap();
        }
    }
    w.end(machine, &cfg).unwrap();
    let st = *w.stats();
    assert_eq!(st.layers, run.stats.layers, "{file}");
    assert_eq!(st.extrusion_moves, run.stats.extrusion_moves, "{file}");
    assert_eq!(st.retractions, run.stats.retractions, "{file}");
    let text = w.into_inner();
    assert_eq!(text.matches(";LAYER_CHANGE").count() as u32, run.stats.layers, "{file}");
}

fn check_model(dir: &Path, file: &str, layers: u32) {
    let machine = machine_for(file);
    let run = toolpaths(&dir.join(file), &machine);
    assert_eq!(run.layers.len() as u32, layers, "{file}: layers");
    assert_eq!(run.stats.open_chains, 0, "{file}: offset chains left open");
    // First and last layers: no sparse infill.
    for l in [run.layers.first().unwrap(), run.layers.last().unwrap()] {
        assert!(
            l.moves.iter().all(|m| m.feature != Feature::InternalInfill),
            "{file} layer {}: sparse infill on a first/last layer",
            l.index
        );
    }
    gcode_of(&run, &machine, file);
    let s = &run.stats;
    eprintln!(
        "{file}: {} layers, {} retractions, {:.0} mm travel, {} stops, {} thin islands",
        s.layers,
        s.retractions,
        s.travel_um as f64 / 1000.0,
        s.stops,
        s.thin_islands
    );
}

/// Models a debug build slices in reasonable time (under 1 MB).
fn small(dir: &Path, file: &str) -> bool {
    std::fs::metadata(dir.join(file)).map(|m| m.len() < 1_000_000).unwrap_or(false)
}

#[test]
fn every_model_slices_to_gcode_with_readme_layer_counts() {
    let Some(dir) = shared_models() else { return };
    let rows = readme_layers(&dir);
    assert!(rows.len() >= 30, "README rows: {}", rows.len());
    let mut done = 0;
    for row in &rows {
        if cfg!(debug_assertions) && !small(&dir, &row.file) {
            continue;
        }
        check_model(&dir, &row.file, row.layers);
        done += 1;
    }
    eprintln!("{done} models");
}

#[test]
fn xyz_cube_top_is_covered_and_every_extrusion_inside() {
    let Some(dir) = shared_models() else { return };
    let run = toolpaths(&dir.join("xyz_20mm_cube.stl"), &MachineConfig::default());
    assert_eq!(run.layers.len(), 100);
    let last = run.layers.len() - 1;
    let top = top_coverage(&run, last, W);
    let (cov, area) = (top.fraction, top.area_mm2);
    eprintln!("xyz cube top: {area:.1} mm^2 covered {:.3} %", cov * 100.0);
    assert!(cov >= 0.99 && area > 300.0, "{cov} {area}");
    let starts = layer_starts(&run);
    let mut n = 0;
    for (l, s) in run.layers.iter().zip(starts).step_by(7) {
        n += extrusions(l, s).len();
    }
    assert!(n > 1000);
    check_containment(&run, "xyz cube", W, 15.0, 7);
}

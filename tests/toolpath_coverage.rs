//! Top and bottom surface coverage of the toolpath stage's extrusions on analytic parts and on
//! every shared model, measured by the independent checker `strata_testkit::coverage` against
//! the model's own sections (cut from the mesh in `f64`, not the slicer's loops).
//!
//! Prints a table (`--nocapture`): model, counted top area (mm^2, after the checker's erosion
//! of slivers), its covered %, the same for the bottom, and the layer surface with the most
//! open area. Skipped models, with the reason: `embodier_bin.stl` (broken, README), models
//! under 5 mm (the trimeshes' originals at about 1 mm, numpy-stl's parser cases), and in
//! debug builds the files over 1 MB (left to the release run). The acceptance bound of the
//! issue (98 % top, 95 % bottom on every model) is [`every_model_meets_the_acceptance_bound`],
//! ignored until gap fill is built. `scripts/coverage_prusa.sh` measures PrusaSlicer's G-code
//! of the same models with the same checker.

mod toolpath_support;

use std::path::Path;
use std::time::{Duration, Instant};

use strata::gcode::type_name;
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::ToolpathConfig;
use strata_testkit::check::pt;
use strata_testkit::coverage::{
    covers, layer_pgm, mesh_sections, surface_coverage, Coverage, Line, SurfaceLayer, EROSION_UM,
    TABLE_HEAD,
};
use strata_testkit::mesh::{cuboid, to_um, TriMm};
use strata_testkit::models::{big_machine, placed_sorted, readme_layers, shared_models};
use toolpath_support::{extrusions, layer_starts, run_cfg, TpRun};

/// The checker's layers of a run of `tris`: each layer's section cut from the mesh at its
/// mid-layer plane, and its covering extrusions at the configured line width (the stage's
/// moves carry no width).
fn checker_layers(run: &TpRun, tris: &[Triangle]) -> Vec<SurfaceLayer> {
    let width = f64::from(PrintSettings::default().line_width_um);
    let planes: Vec<f64> =
        run.layers.iter().map(|l| f64::from(l.z_um) - f64::from(l.height_um) / 2.0).collect();
    let sections = mesh_sections(tris, &planes);
    run.layers
        .iter()
        .zip(layer_starts(run))
        .zip(sections)
        .map(|((l, start), section)| SurfaceLayer {
            section,
            lines: extrusions(l, start)
                .into_iter()
                .filter(|e| covers(type_name(e.2)))
                .map(|(a, b, _, _)| Line { a: pt(a), b: pt(b), width_um: width })
                .collect(),
        })
        .collect()
}

/// The toolpath stage's run of `tris` (placed, sorted) with the default settings, measured.
fn measure(name: &str, tris: &[Triangle], machine: &MachineConfig) -> (Coverage, Duration) {
    let settings = PrintSettings::default();
    let run = run_cfg(tris, &settings, ToolpathConfig::new(machine, &settings))
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    let layers = checker_layers(&run, tris);
    let t = Instant::now();
    let c = surface_coverage(&layers);
    let took = t.elapsed();
    // STRATA_DUMP=prefix:LAYER writes that layer's top and bottom of every model as pictures.
    let dump = std::env::var("STRATA_DUMP").ok();
    if let Some((prefix, l)) = dump.as_deref().and_then(|d| d.split_once(':')) {
        let l: usize = l.parse().expect("STRATA_DUMP=prefix:LAYER");
        let file = name.replace('/', "_");
        for (side, top) in [("top", true), ("bottom", false)] {
            let pgm = layer_pgm(&layers, l.min(layers.len() - 1), top, EROSION_UM);
            std::fs::write(format!("{prefix}_{file}_{l}_{side}.pgm"), pgm).unwrap();
        }
    }
    (c, took)
}

fn measure_mesh(name: &str, mesh: &[TriMm]) -> Coverage {
    measure(name, &to_um(mesh), &MachineConfig::default()).0
}

/// Why a shared model is left out before it is read, if it is.
fn skip_file(dir: &Path, file: &str) -> Option<&'static str> {
    if file == "embodier_bin.stl" {
        return Some("broken mesh (README: 21 bodies, not watertight)");
    }
    let big = std::fs::metadata(dir.join(file)).map_or(true, |m| m.len() >= 1_000_000);
    (cfg!(debug_assertions) && big).then_some("over 1 MB: release runs only")
}

/// The largest extent of a mesh, um.
fn size_um(tris: &[Triangle]) -> i32 {
    let extent = |k: usize| {
        let (lo, hi) = tris.iter().flat_map(|t| t.v).fold((i32::MAX, i32::MIN), |(lo, hi), p| {
            let c = [p.x, p.y, p.z][k];
            (lo.min(c), hi.max(c))
        });
        hi - lo
    };
    (0..3).map(extent).max().unwrap_or(0)
}

/// Models smaller than this are parser cases or unscaled originals, not prints, um.
const TINY_UM: i32 = 5_000;

/// Every shared model that is not skipped: file name and what the checker measured.
fn shared_model_coverage() -> Vec<(String, Coverage)> {
    let Some(dir) = shared_models() else { return Vec::new() };
    let rows = readme_layers(&dir);
    assert!(rows.len() >= 30, "README rows: {}", rows.len());
    let mut out = Vec::new();
    let mut notes = String::new();
    for row in &rows {
        if let Some(why) = skip_file(&dir, &row.file) {
            notes += &format!("{}: skipped, {why}\n", row.file);
            continue;
        }
        let machine = big_machine();
        let bytes = std::fs::read(dir.join(&row.file)).expect("a listed model");
        let tris = match placed_sorted(&bytes, &machine) {
            Ok(t) if size_um(&t) >= TINY_UM => t,
            Ok(t) => {
                let mm = f64::from(size_um(&t)) / 1000.0;
                notes += &format!("{}: skipped, tiny ({mm:.2} mm)\n", row.file);
                continue;
            }
            Err(e) => {
                notes += &format!("{}: skipped, not read: {e}\n", row.file);
                continue;
            }
        };
        let t = Instant::now();
        let (c, checked) = measure(&row.file, &tris, &machine);
        notes += &format!(
            "{}: {:.1} s, the checker {checked:.1?}; exposed {:.1} mm^2 top, {:.1} bottom \
             before the erosion\n",
            row.file,
            t.elapsed().as_secs_f64(),
            c.top.exposed_mm2(),
            c.bottom.exposed_mm2()
        );
        out.push((row.file.clone(), c));
    }
    let table: String = out.iter().map(|(f, c)| format!("{}\n", c.row(f))).collect();
    eprintln!("{TABLE_HEAD}\n{table}\n{notes}");
    out
}

#[test]
fn a_cube_and_stepped_blocks_are_covered_top_and_bottom() {
    // A 20 mm cube: 400 mm^2 of top (its last layer) and of bottom (its first).
    let c = measure_mesh("cube", &cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]));
    for (side, cells) in [("top", c.top), ("bottom", c.bottom)] {
        assert!((cells.exposed_mm2() - 400.0).abs() < 4.0, "cube {side}: {cells:?}");
        assert!(cells.fraction() >= 0.99, "cube {side}: {}", c.row("cube"));
    }
    // Three steps, 30, 20 and 10 mm square, 3 mm each: tops of 900 - 400, 400 - 100 and 100
    // mm^2 on layers 14, 29 and 44, the bottom of 900 mm^2 on layer 0 only.
    let mut steps = cuboid([95.0, 95.0, 0.0], [125.0, 125.0, 3.0]);
    steps.extend(cuboid([100.0, 100.0, 3.0], [120.0, 120.0, 6.0]));
    steps.extend(cuboid([105.0, 105.0, 6.0], [115.0, 115.0, 9.0]));
    let c = measure_mesh("steps", &steps);
    let exposed: Vec<(usize, i64, i64)> = c
        .layers
        .iter()
        .map(|l| {
            (l.index, l.top.exposed_mm2().round() as i64, l.bottom.exposed_mm2().round() as i64)
        })
        .collect();
    assert_eq!(exposed, [(0, 0, 900), (14, 500, 0), (29, 300, 0), (44, 100, 0)]);
    assert!(c.top.fraction() >= 0.99 && c.bottom.fraction() >= 0.99, "{}", c.row("steps"));
}

#[test]
fn coverage_table_of_the_shared_models() {
    let all = shared_model_coverage();
    for (file, c) in &all {
        if file == "xyz_20mm_cube.stl" {
            assert!(c.top.fraction() >= 0.99 && c.bottom.fraction() >= 0.99, "{}", c.row(file));
        }
        if file == "embodier_asc.stl" {
            // A 20 x 20 x 10 mm box (README): 400 mm^2 of top and of bottom.
            let (top, bottom) = (c.top.exposed_mm2(), c.bottom.exposed_mm2());
            assert!((top - 400.0).abs() < 4.0 && (bottom - 400.0).abs() < 4.0, "{top} {bottom}");
        }
    }
    // The debug run measures the models under 1 MB, the release run all but the skipped.
    let want = if cfg!(debug_assertions) { 7 } else { 14 };
    assert!(all.len() >= want, "{} models measured", all.len());
}

/// The acceptance bound: 98 % of the top and 95 % of the bottom surfaces covered on
/// every shared model.
#[test]
#[ignore = "gap fill not yet built"]
fn every_model_meets_the_acceptance_bound() {
    let failing: Vec<String> = shared_model_coverage()
        .iter()
        .filter(|(_, c)| c.top.fraction() < 0.98 || c.bottom.fraction() < 0.95)
        .map(|(f, c)| c.row(f))
        .collect();
    assert!(failing.is_empty(), "below 98 % top or 95 % bottom:\n{}", failing.join("\n"));
}

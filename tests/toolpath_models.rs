//! Every model under `../shared/models` to G-code: no error, the README's layer counts, solid
//! first and last layers, G-code consistent with the toolpath counters; the top of
//! `xyz_20mm_cube.stl` covered. In debug builds the models over 1 MB (3DBenchy, the scaled
//! trimeshes, rockerarm, bunny, fertility, rear_case, bwb) are left to the release run
//! (`cargo test --release --test toolpath_models`) and to `examples/toolpath_report.rs`.

mod common;
mod slice_support;
mod toolpath_support;

use std::path::Path;

use slice_support::load_placed;
use strata::gcode::{GcodeOptions, GcodeWriter};
use strata::machine::{MachineConfig, PrintSettings};
use strata::toolpath::{Feature, ToolpathConfig};
use toolpath_support::{extrusions, layer_starts, run_cfg, TpRun};

/// (file, layers @0.2) for every README row with a layer count.
fn readme_layers(readme: &Path) -> Vec<(String, u32)> {
    let text = std::fs::read_to_string(readme).expect("read README.md");
    let mut rows = Vec::new();
    for line in text.lines() {
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        if cells.len() < 11 || !cells[1].ends_with(".stl") {
            continue;
        }
        if let Ok(layers) = cells[9].parse() {
            rows.push((cells[1].to_string(), layers));
        }
    }
    rows
}

/// Large enough for plate_holes (203 x 305 mm).
fn big_machine() -> MachineConfig {
    let mut m = MachineConfig::default();
    m.build_volume_um = [400_000, 400_000, 250_000];
    m
}

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
    let Some(dir) = common::shared_models() else { return };
    let rows = readme_layers(&dir.join("README.md"));
    assert!(rows.len() >= 30, "README rows: {}", rows.len());
    let mut done = 0;
    for (file, layers) in &rows {
        if cfg!(debug_assertions) && !small(&dir, file) {
            continue;
        }
        check_model(&dir, file, *layers);
        done += 1;
    }
    eprintln!("{done} models");
}

#[test]
fn xyz_cube_top_is_covered_and_every_extrusion_inside() {
    let Some(dir) = common::shared_models() else { return };
    let run = toolpaths(&dir.join("xyz_20mm_cube.stl"), &MachineConfig::default());
    assert_eq!(run.layers.len(), 100);
    let last = run.layers.len() - 1;
    let (cov, area) = coverage::top(&run, last);
    eprintln!("xyz cube top: {area:.1} mm^2 covered {:.3} %", cov * 100.0);
    assert!(cov >= 0.99 && area > 300.0, "{cov} {area}");
    let starts = layer_starts(&run);
    let mut n = 0;
    for (l, s) in run.layers.iter().zip(starts).step_by(7) {
        n += extrusions(l, s).len();
    }
    assert!(n > 1000);
    coverage::contained(&run, 15.0, 7);
}

/// Raster coverage and containment in f64 (same models as tests/toolpath_analytic.rs).
mod coverage {
    use super::toolpath_support::{
        extrusions, inside, layer_starts, point_seg_dist as seg_dist, pt, TpRun,
    };
    use strata::toolpath::Feature;

    const W: f64 = 450.0;
    const CELL: f64 = 50.0;

    /// Covered fraction and area (mm^2) of layer `l`'s top surface.
    pub fn top(run: &TpRun, l: usize) -> (f64, f64) {
        let layer = &run.layers[l];
        let next = run.layers.get(l + 1);
        let starts = layer_starts(run);
        let pts: Vec<(f64, f64)> =
            layer.contours.iter().flat_map(|(c, _)| c.iter().map(|&p| pt(p))).collect();
        let lo = pts.iter().fold((f64::MAX, f64::MAX), |m, p| (m.0.min(p.0), m.1.min(p.1)));
        let hi = pts.iter().fold((f64::MIN, f64::MIN), |m, p| (m.0.max(p.0), m.1.max(p.1)));
        let nx = ((hi.0 - lo.0) / CELL).ceil() as usize + 1;
        let ny = ((hi.1 - lo.1) / CELL).ceil() as usize + 1;
        let centre =
            |i: usize, j: usize| (lo.0 + (i as f64 + 0.5) * CELL, lo.1 + (j as f64 + 0.5) * CELL);
        let mut cells = vec![false; nx * ny];
        for (a, b, f, _) in extrusions(layer, starts[l]) {
            if f == Feature::Skirt {
                continue;
            }
            let (a, b) = (pt(a), pt(b));
            let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
            let (ux, uy) = ((b.0 - a.0) / len, (b.1 - a.1) / len);
            let i0 = ((a.0.min(b.0) - W - lo.0) / CELL).floor().max(0.0) as usize;
            let i1 = (((a.0.max(b.0) + W - lo.0) / CELL).ceil() as usize).min(nx - 1);
            let j0 = ((a.1.min(b.1) - W - lo.1) / CELL).floor().max(0.0) as usize;
            let j1 = (((a.1.max(b.1) + W - lo.1) / CELL).ceil() as usize).min(ny - 1);
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let c = centre(i, j);
                    let (px, py) = (c.0 - a.0, c.1 - a.1);
                    let along = px * ux + py * uy;
                    if (0.0..=len).contains(&along) && (px * uy - py * ux).abs() <= W / 2.0 {
                        cells[j * nx + i] = true;
                    }
                }
            }
        }
        let (mut t, mut c) = (0usize, 0usize);
        for j in 0..ny {
            for i in 0..nx {
                let p = centre(i, j);
                if inside(&layer.contours, p) && !next.is_some_and(|n| inside(&n.contours, p)) {
                    t += 1;
                    c += usize::from(cells[j * nx + i]);
                }
            }
        }
        (c as f64 / t.max(1) as f64, t as f64 * CELL * CELL / 1e6)
    }

    /// Every extrusion but the skirt at least `W/2 - tol` inside the contour (every
    /// `every`-th layer): endpoints inside, distance to every contour edge.
    pub fn contained(run: &TpRun, tol: f64, every: usize) {
        let starts = layer_starts(run);
        for (l, s) in run.layers.iter().zip(starts).step_by(every) {
            for (a, b, f, _) in extrusions(l, s) {
                if f == Feature::Skirt {
                    continue;
                }
                let (a, b) = (pt(a), pt(b));
                assert!(inside(&l.contours, a) && inside(&l.contours, b), "layer {}", l.index);
                for (c, _) in &l.contours {
                    for k in 0..c.len() {
                        let (p, q) = (pt(c[k]), pt(c[(k + 1) % c.len()]));
                        // Segments do not cross (endpoints inside and far from every edge
                        // checked below), so the distance is an endpoint distance.
                        let d = seg_dist(a, p, q)
                            .min(seg_dist(b, p, q))
                            .min(seg_dist(p, a, b))
                            .min(seg_dist(q, a, b));
                        assert!(d >= W / 2.0 - tol, "layer {} {f:?}: {d:.1} um", l.index);
                    }
                }
            }
        }
    }
}

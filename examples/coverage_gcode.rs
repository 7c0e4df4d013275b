//! Top and bottom surface coverage of any slicer's G-code, measured by
//! `strata_testkit::coverage` (the instrument of `tests/toolpath_coverage.rs`) against the
//! model's own sections, for `scripts/coverage_prusa.sh`.
//!
//! `coverage_gcode [--erosion UM,UM,...] NAME=MODEL.stl=FILE.gcode ...`: one markdown table row
//! per file (and per erosion, default the checker's `EROSION_UM`). The model is placed as
//! PrusaSlicer places it with `--center 200,200`: its bounding box centred on (200, 200) mm,
//! dropped to z = 0 (the placement of `strata_testkit::models::big_machine`'s bed). Its layers
//! are cut at mid-layer, 0.2 mm apart from 0.1 mm; each G-code layer goes to the plane half a
//! layer below its height.
//!
//! `STRATA_DUMP=prefix:LAYER` also writes that layer's top and bottom of every file as PGM
//! pictures (`coverage::layer_pgm`).
//!
//! Run: `cargo run --release --example coverage_gcode -- cube=cube.stl=cube.gcode`.

use std::path::Path;
use std::time::Instant;

use strata_testkit::coverage::{
    layer_pgm, lines_of, mesh_sections, surface_coverage_eroded, SurfaceLayer, EROSION_UM,
    TABLE_HEAD,
};
use strata_testkit::models::{big_machine, load_placed};
use strata_testkit::overhang::layers_from_gcode;

/// Line width before a file's first `;WIDTH:` comment, um.
const DEFAULT_WIDTH_UM: f64 = 450.0;

/// Layer height (and first layer height) the G-code was sliced with, um.
const LAYER_UM: f64 = 200.0;

/// The checker's layers of a model and its G-code; also the G-code layers no plane took.
fn layers(stl: &Path, gcode: &str) -> (Vec<SurfaceLayer>, usize) {
    let tris = load_placed(stl, &big_machine());
    let top = tris.iter().map(|t| f64::from(t.z_max())).fold(0.0, f64::max);
    let planes: Vec<f64> =
        (0..).map(|k| LAYER_UM / 2.0 + LAYER_UM * f64::from(k)).take_while(|&z| z < top).collect();
    let mut layers: Vec<SurfaceLayer> = mesh_sections(&tris, &planes)
        .into_iter()
        .map(|section| SurfaceLayer { section, lines: Vec::new() })
        .collect();
    let mut stray = 0;
    for l in layers_from_gcode(gcode, DEFAULT_WIDTH_UM) {
        let k = ((l.z_um - LAYER_UM) / LAYER_UM).round();
        match layers.get_mut(k.max(0.0) as usize) {
            Some(layer) if k >= 0.0 => layer.lines.extend(lines_of(&l.extrusions)),
            _ => stray += 1,
        }
    }
    (layers, stray)
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let mut erosions = vec![EROSION_UM];
    if args.first().map(String::as_str) == Some("--erosion") && args.len() >= 2 {
        erosions = args[1].split(',').map(|v| v.parse().expect("--erosion UM,UM,...")).collect();
        args.drain(..2);
    }
    if args.is_empty() || args.iter().any(|a| a.split('=').count() != 3) {
        eprintln!("usage: coverage_gcode [--erosion UM,UM,...] NAME=MODEL.stl=FILE.gcode ...");
        std::process::exit(2);
    }
    let mut notes = String::new();
    let mut rows: Vec<Vec<String>> = vec![Vec::new(); erosions.len()];
    for arg in &args {
        let mut parts = arg.split('=');
        let (name, stl, gcode) =
            (parts.next().unwrap(), parts.next().unwrap(), parts.next().unwrap());
        let text = std::fs::read_to_string(gcode).unwrap_or_else(|e| panic!("{gcode}: {e}"));
        let (layers, stray) = layers(Path::new(stl), &text);
        // STRATA_DUMP=prefix:LAYER writes that layer's top and bottom as pictures.
        if let Some((prefix, l)) =
            std::env::var("STRATA_DUMP").ok().as_ref().and_then(|d| d.split_once(':'))
        {
            let l: usize = l.parse().expect("STRATA_DUMP=prefix:LAYER");
            for (side, top) in [("top", true), ("bottom", false)] {
                let pgm = layer_pgm(&layers, l, top, erosions[0]);
                std::fs::write(format!("{prefix}_{name}_{l}_{side}.pgm"), pgm).unwrap();
            }
        }
        for (k, &erosion) in erosions.iter().enumerate() {
            let t = Instant::now();
            let c = surface_coverage_eroded(&layers, erosion);
            let took = t.elapsed();
            rows[k].push(c.row(name));
            if k == 0 {
                notes += &format!(
                    "{name}: {} layers ({stray} G-code layers without a plane), checked in \
                     {took:?}; exposed {:.1} mm^2 top, {:.1} bottom before the erosion\n",
                    layers.len(),
                    c.top.exposed_mm2(),
                    c.bottom.exposed_mm2()
                );
            }
        }
    }
    for (erosion, rows) in erosions.iter().zip(rows) {
        println!("erosion {erosion} um\n\n{TABLE_HEAD}");
        for r in rows {
            println!("{r}");
        }
        println!();
    }
    println!("{notes}");
}

//! Extrusion over air of any slicer's G-code, measured by `strata_testkit::overhang` (the
//! instrument of `tests/toolpath_overhang.rs`), for `scripts/overhang_prusa.sh`.
//!
//! - `overhang_gcode stl DIR`: writes the overhang parts (and a 20 mm cube) as binary STL files
//!   with normals into DIR, one per part, named after it;
//! - `overhang_gcode check NAME=FILE.gcode ...`: one markdown table row per file (part,
//!   extruded mm, anchored bridge %, sparse infill over air %, true air %), then each file's
//!   true air per feature and its worst layers.
//!
//! Run: `cargo run --release --example overhang_gcode -- check part=part.gcode`.

use std::path::Path;
use std::time::Instant;

use strata::stl::RawTriangle;
use strata_testkit::mesh::{cuboid, overhang_parts, to_f32, TriMm};
use strata_testkit::overhang::{layers_from_gcode, over_air, TABLE_HEAD};
use strata_testkit::stl::binary;

/// Line width before a file's first `;WIDTH:` comment, um.
const DEFAULT_WIDTH_UM: f64 = 450.0;

/// A part's file name: its name without spaces or slashes.
fn file_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect()
}

/// The mesh as a binary STL with unit normals (PrusaSlicer 2.5 refuses some meshes whose
/// normals are zero).
fn stl_bytes(mesh: &[TriMm]) -> Vec<u8> {
    let facets: Vec<RawTriangle> = to_f32(mesh)
        .into_iter()
        .map(|v| {
            let d = |i: usize, k: usize| f64::from(v[i][k]) - f64::from(v[0][k]);
            let n = [
                d(1, 1) * d(2, 2) - d(1, 2) * d(2, 1),
                d(1, 2) * d(2, 0) - d(1, 0) * d(2, 2),
                d(1, 0) * d(2, 1) - d(1, 1) * d(2, 0),
            ];
            let len = n.iter().map(|c| c * c).sum::<f64>().sqrt();
            RawTriangle { normal: n.map(|c| (c / len) as f32), vertices: v }
        })
        .collect();
    binary(b"strata overhang part", facets.len() as u32, &facets)
}

fn write_stls(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let mut parts = vec![("cube 20 mm", cuboid([0.0; 3], [20.0, 20.0, 20.0]))];
    parts.extend(overhang_parts(0.0, 0.0));
    for (name, mesh) in parts {
        let path = dir.join(format!("{}.stl", file_name(name)));
        std::fs::write(&path, stl_bytes(&mesh))
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        println!("{}", path.display());
    }
}

fn check(files: &[String]) {
    println!("{TABLE_HEAD}");
    let mut notes = String::new();
    for arg in files {
        let (name, path) = arg.split_once('=').unwrap_or((arg, arg));
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let layers = layers_from_gcode(&text, DEFAULT_WIDTH_UM);
        let segments: usize = layers.iter().map(|l| l.extrusions.len()).sum();
        let t = Instant::now();
        let air = over_air(&layers);
        let took = t.elapsed();
        println!("{}", air.row(name));
        notes += &format!(
            "{name}: {} layers, {segments} segments in {took:?}; {}\n",
            layers.len(),
            air.describe_worst(2)
        );
    }
    println!("\n{notes}");
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        Some("stl") if args.len() == 2 => write_stls(Path::new(&args[1])),
        Some("check") => check(&args[1..]),
        _ => {
            eprintln!("usage: overhang_gcode stl DIR | overhang_gcode check NAME=FILE.gcode ...");
            std::process::exit(2);
        }
    }
}

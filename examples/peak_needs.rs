//! Peak needs of every model in `../shared/models` at 0.2 mm layers: the slicer capacities a
//! device needs (active triangles, segments = contour points, loops per layer) and what they
//! cost in RAM. Run: `cargo run --release --example peak_needs [MODELS_DIR]`.

use std::path::{Path, PathBuf};

use strata::geom::Triangle;
use strata::machine::PrintSettings;
use strata::slice::{peak_needs, slicer_bytes, SliceConfig, SliceScratch};
use strata_testkit::models::{self, placed_sorted};

/// The model placed on a bed big enough for plate_holes (203 x 305 mm).
fn load(path: &Path) -> Option<Vec<Triangle>> {
    placed_sorted(&std::fs::read(path).ok()?, &models::big_machine()).ok()
}

/// Peak loops per layer, from a real slicing run (host capacities, on a big-stack thread).
fn peak_loops(tris: &[Triangle], config: SliceConfig) -> u32 {
    strata_testkit::on_big_stack(|| {
        let mut slicer = Box::new(HostSlicer::new(config).unwrap());
        let mut work = Box::new(SliceScratch::new());
        for t in tris {
            slicer.push(t, &mut *work, &mut |_| {}).unwrap();
        }
        slicer.finish(&mut *work, &mut |_| {}).unwrap().peak_loops
    })
}

fn main() {
    let dir = std::env::args().nth(1).map(PathBuf::from).unwrap_or_else(models::dir);
    let files = models::stl_files_below(&dir);
    println!(
        "| model | triangles | layers | span no plane | peak active (layer) | peak points (layer) \
         | peak loops | device RAM at these capacities |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for path in files {
        let name = path.strip_prefix(&dir).unwrap_or(&path).display().to_string();
        let Some(tris) = load(&path) else {
            println!("| {name} | (not loadable) | | | | | | |");
            continue;
        };
        let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
        let config = SliceConfig::new(&PrintSettings::default(), top).unwrap();
        let n = peak_needs(&tris, &config).unwrap();
        let loops = peak_loops(&tris, config);
        let (active, points) = (n.active_triangles as usize, n.contour_points as usize);
        // The slicer and the cut in its scratch.
        let ram = slicer_bytes(active, loops as usize) + strata::scratch::bytes(points, 0, 0);
        let idle = tris.len() as u32 - n.spanning_triangles;
        println!(
            "| {name} | {} | {} | {:.0} % | {} ({}) | {} ({}) | {loops} | {:.1} KB |",
            tris.len(),
            n.layers,
            100.0 * f64::from(idle) / tris.len().max(1) as f64,
            n.active_triangles,
            n.active_layer,
            n.contour_points,
            n.points_layer,
            ram as f64 / 1024.0
        );
    }
}

strata::slicer_type! {
    type HostSlicer = { active_triangles: 65536, contour_points: 65536, contour_loops: 4096 };
}

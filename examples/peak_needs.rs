//! Peak needs of every model in `../shared/models` at 0.2 mm layers: the slicer capacities a
//! device needs (active triangles, segments = contour points, loops per layer) and what they
//! cost in RAM. Run: `cargo run --release --example peak_needs [MODELS_DIR]`.

use std::path::{Path, PathBuf};

use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::place::{Bounds, Placement};
use strata::slice::{peak_needs, slicer_bytes, SliceConfig, SliceScratch, Slicer};

fn stl_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<PathBuf> =
        std::fs::read_dir(dir).expect("read models dir").map(|e| e.unwrap().path()).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            stl_files(&p, out);
        } else if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("stl")) {
            out.push(p);
        }
    }
}

fn load(path: &Path) -> Option<Vec<Triangle>> {
    let bytes = std::fs::read(path).ok()?;
    let mut raw = Vec::new();
    let mut bounds = Bounds::EMPTY;
    strata::stl::read_all(&bytes, &mut |t| {
        bounds.include(&t);
        raw.push(t);
    })
    .ok()?;
    // Big enough for plate_holes (203 x 305 mm).
    let mut machine = MachineConfig::default();
    machine.build_volume_um = [400_000, 400_000, 250_000];
    let placement = Placement::on_bed(&bounds, &machine).ok()?;
    let mut tris: Vec<Triangle> = raw.iter().map(|t| placement.apply(t)).collect();
    tris.sort_by_key(Triangle::z_min);
    Some(tris)
}

/// Peak loops per layer, from a real slicing run (host capacities, on a big-stack thread).
fn peak_loops(tris: &[Triangle], config: SliceConfig) -> u32 {
    std::thread::scope(|s| {
        std::thread::Builder::new()
            .stack_size(64 << 20)
            .spawn_scoped(s, || {
                let mut slicer = Box::new(Slicer::<65536, 65536, 4096>::new(config).unwrap());
                let mut work = Box::new(SliceScratch::new());
                for t in tris {
                    slicer.push(t, &mut *work, &mut |_| {}).unwrap();
                }
                slicer.finish(&mut *work, &mut |_| {}).unwrap().peak_loops
            })
            .unwrap()
            .join()
            .unwrap()
    })
}

fn main() {
    let dir = std::env::args()
        .nth(1)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/models"));
    let mut files = Vec::new();
    stl_files(&dir, &mut files);
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

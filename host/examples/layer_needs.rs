//! What models need of the 64 KB board per layer, as admission streams them: for each STL,
//! admission against `BOARD_CAPACITIES` within a deviation (`DEV`, mm, default 0.05), then the
//! triangles, the measured deviation, the slicer's peaks and every toolpath peak with the layer
//! where it peaks, or the refusal.
//!
//! `DEV=0.05 cargo run --release -p strata-host --example layer_needs -- MODEL.stl...`

use strata::machine::MachineConfig;
use strata::printer::board::BOARD_CAPACITIES;
use strata_host::admission::{admit_job_timed, Admission};
use strata_host::model;
use strata_testkit::drive::job_spec;

fn main() {
    let machine = MachineConfig::default();
    let dev: f64 = std::env::var("DEV").ok().and_then(|v| v.parse().ok()).unwrap_or(0.05);
    for path in std::env::args().skip(1) {
        let loaded = match model::load(std::path::Path::new(&path)) {
            Ok(m) => m,
            Err(e) => {
                println!("{path}: {e}");
                continue;
            }
        };
        let tris = match loaded.placed_sorted(&machine) {
            Ok(t) => t,
            Err(e) => {
                println!("{path}: {e}");
                continue;
            }
        };
        let job = job_spec(&tris);
        match admit_job_timed(&tris, &machine, &job, &BOARD_CAPACITIES, dev) {
            Ok((a, p, _)) => {
                let (n, d, needs) = match &a {
                    Admission::Unchanged(n) => (tris.len(), 0.0, *n),
                    Admission::Simplified(s) => (s.triangles.len(), s.max_deviation_mm, s.needs),
                };
                println!(
                    "{path}: {n} triangles, deviation {d:.4} mm, active triangles {}, contour \
                     points {}",
                    needs.active_triangles, needs.contour_points
                );
                let peaks = [
                    ("contour loops", p.contour_loops),
                    ("loop points / offset edges", p.points),
                    ("toolpath loops", p.loops),
                    ("scanline crossings", p.crossings),
                    ("path points", p.path_points),
                    ("window words", p.ring_words),
                    ("window spans", p.spans),
                    ("largest unit, bytes", p.unit_bytes),
                ];
                for (what, peak) in peaks {
                    println!("  {what}: {} (layer {})", peak.value, peak.layer);
                }
            }
            Err(e) => println!("{path}: refused: {}", e.replace('\n', " ")),
        }
    }
}

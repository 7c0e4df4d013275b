//! Admission control of one model against the Creality board's capacities: unchanged,
//! simplified (triangles, measured deviation, peak needs) or refused (the message), and the
//! time it took.
//!
//! Run: `cargo run --release -p strata-host --example admission_report -- MODEL [BOUND_MM]`.

use std::path::Path;
use std::time::Instant;

use strata::machine::{MachineConfig, PrintSettings};
use strata::printer::CREALITY_CAPACITIES;
use strata::slice::SliceConfig;
use strata_host::admission::{admit, hausdorff_mm, Admission};
use strata_host::model;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().ok_or("usage: admission_report MODEL [BOUND_MM]")?;
    let bound: f64 = args.get(1).map_or(Ok(0.02), |b| b.parse()).map_err(|e| format!("{e}"))?;
    let machine = MachineConfig::default();
    let tris = model::load(Path::new(path))?.placed_sorted(&machine)?;
    let top = tris.iter().map(|t| t.z_max()).max().unwrap_or(0);
    let cfg = SliceConfig::new(&PrintSettings::default(), top).map_err(|e| e.to_string())?;
    let t0 = Instant::now();
    let result = admit(&tris, &cfg, &CREALITY_CAPACITIES, bound);
    let secs = t0.elapsed().as_secs_f64();
    match result {
        Ok(Admission::Unchanged(n)) => println!(
            "{path}: unchanged, {} triangles, peak active {}, points {} ({secs:.1} s)",
            tris.len(),
            n.active_triangles,
            n.contour_points
        ),
        Ok(Admission::Simplified(s)) => {
            // An independent re-measurement of the result against the original.
            let again = hausdorff_mm(&tris, &s.triangles);
            println!(
                "{path}: simplified {} -> {} triangles within {bound} mm: measured deviation \
                 {:.4} mm (re-measured {again:.4}), peak active {}, points {} ({secs:.1} s)",
                s.triangles_in,
                s.triangles.len(),
                s.max_deviation_mm,
                s.needs.active_triangles,
                s.needs.contour_points
            )
        }
        Err(e) => println!("{path}: refused ({secs:.1} s): {e}"),
    }
    Ok(())
}

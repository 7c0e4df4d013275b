//! Every model of `../shared/models/` through admission control and the simulated printer at
//! 250000 baud (release builds only: `cargo test --release -p strata-host --test models_sim
//! -- --nocapture` prints the figures; `STRATA_MODELS=3DBenchy.stl` runs only that one).
//!
//! - 3DBenchy does not fit the protocol's specified Creality capacities (1024 active
//!   triangles, 768 contour points: `CREALITY_CAPACITIES`); it is refused at 0.02 mm, simplified
//!   within 0.1 mm (the measured deviation and triangle count are printed) and prints in
//!   simulation (the 64 KB firmware build, `BOARD_CAPACITIES`, holds far less);
//! - models that fit are streamed unchanged;
//! - streaming stays ahead of printing for every model whose print lasts at least twice its
//!   transfer (every real-size model): the link and the printer share one virtual clock and, once motion has started,
//!   the step executor never runs dry (no underrun); before the first step the first layer's triangles (all those starting below
//!   the layers its skins wait for) must arrive, which the printed "first step at" shows;
//! - the wire cost per triangle and the time to stream all of 3DBenchy at 250000 baud.

use std::path::PathBuf;

use strata::machine::{MachineConfig, PrintSettings};
use strata::printer::CREALITY_CAPACITIES;
use strata::protocol::frame::wire_len;
use strata::protocol::{JobOptions, JobSpec};
use strata::slice::SliceConfig;
use strata_host::admission::{admit, Admission};
use strata_host::model;
use strata_host::simjob::{simulate, SimOptions};
use strata_testkit::drive::batches;
use strata_testkit::models;

fn models() -> Vec<PathBuf> {
    let dir = models::dir();
    // The top-level models and their real-size versions (`scaled_mm/`).
    let mut v = models::stl_files(&dir);
    if dir.join("scaled_mm").is_dir() {
        v.extend(models::stl_files(&dir.join("scaled_mm")));
    }
    v.sort();
    // STRATA_MODELS=name,name runs only those files.
    if let Ok(only) = std::env::var("STRATA_MODELS") {
        v.retain(|p| only.split(',').any(|n| p.file_name().is_some_and(|f| f == n)));
    }
    v
}

#[test]
#[cfg_attr(debug_assertions, ignore = "release only: whole models")]
fn every_model_streams_ahead_of_printing() {
    let machine = MachineConfig::default();
    let settings = PrintSettings::default();
    for path in models() {
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let m = model::load(&path).unwrap();
        let tris = match m.placed_sorted(&machine) {
            Ok(t) => t,
            Err(e) => {
                eprintln!("{name}: skipped, {e}");
                continue;
            }
        };
        // Streaming the whole model as it is, at 250000 baud (10 bits per byte).
        let bytes: usize = batches(&tris).iter().map(|b| wire_len(b)).sum();
        let top = tris.iter().map(|t| t.z_max()).max().unwrap();
        let cfg = SliceConfig::new(&settings, top).unwrap();
        // Refused at the default 0.02 mm error: say so, then stream it simplified further.
        let admitted = admit(&tris, &cfg, &CREALITY_CAPACITIES, 0.02).or_else(|e| {
            assert!(e.contains("does not fit the printer"), "{name}: {e}");
            eprintln!("{name}: refused at 0.02 mm: {e}; trying 0.1 mm");
            admit(&tris, &cfg, &CREALITY_CAPACITIES, 0.1)
        });
        let admitted = match admitted {
            Ok(a) => a,
            Err(e) => {
                eprintln!("{name}: refused at 0.1 mm too: {e}");
                continue;
            }
        };
        let (tris, note) = match admitted {
            Admission::Unchanged(n) => (
                tris,
                format!(
                    "unchanged (peak active {}, points {})",
                    n.active_triangles, n.contour_points
                ),
            ),
            Admission::Simplified(s) => {
                let n = format!(
                    "simplified {} -> {} triangles, measured deviation {:.3} mm (bound {}), \
                     peak active {}, points {}",
                    s.triangles_in,
                    s.triangles.len(),
                    s.max_deviation_mm,
                    s.error_bound_mm,
                    s.needs.active_triangles,
                    s.needs.contour_points
                );
                (s.triangles, n)
            }
        };
        let job = JobSpec {
            settings,
            options: JobOptions::default(),
            model_height_um: top,
            triangles: tris.len() as u32,
        };
        // The device announces what admission held the model to (and offsets as such a
        // device does).
        let opts = SimOptions { capacities: CREALITY_CAPACITIES, ..SimOptions::default() };
        let rep =
            simulate(&tris, &machine, job, &opts).unwrap_or_else(|(e, _)| panic!("{name}: {e}"));
        eprintln!(
            "{name}: {note}; whole model {} triangles = {bytes} bytes = {:.1} s at 250000 baud \
             ({:.2} B/triangle); streamed {} triangles ({:.1} s of wire time), first step at \
             {:.1} s, print {:.0} s, {} layers, underruns {}, device RAM needed {} B",
            m.triangles.len(),
            bytes as f64 / 25_000.0,
            bytes as f64 / m.triangles.len() as f64,
            rep.triangles,
            rep.wire_time_s,
            rep.first_step_s,
            rep.print_time_s,
            rep.layers,
            rep.underruns,
            rep.device_ram_bytes
        );
        if rep.print_time_s >= 2.0 * rep.wire_time_s {
            assert_eq!(rep.underruns, 0, "{name}: the stream fell behind the print");
            assert_eq!(rep.rest_waits(), 0, "{name}: the print stopped to wait for the link");
        } else {
            // A print not even twice as long as its transfer (the unscaled fertility, rockerarm,
            // bunny and torus meshes: 2 to 12 layers printed in 2 to 32 s) cannot be streamed
            // ahead at this baud rate: motion may stop between layers to wait (counted as
            // underruns mid-move or as stops at rest; the executor resumes).
            eprintln!(
                "{name}: print shorter than twice the transfer: {} underruns, {} stops",
                rep.underruns,
                rep.rest_waits()
            );
        }
        assert_eq!(rep.violations, 0, "{name}");
        assert_eq!(rep.layer_hashes.len(), rep.layers as usize, "{name}");
        if name == "3DBenchy.stl" {
            assert!(note.starts_with("simplified"), "{note}");
        }
        if name == "xyz_20mm_cube.stl" {
            assert!(note.starts_with("unchanged"), "{note}");
        }
    }
}

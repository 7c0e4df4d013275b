//! Figures of the quadric simplifier against meshopt at one measured deviation (release only,
//! ignored: `cargo test --release -p strata-host --test qem_figures -- --ignored --nocapture`;
//! `STRATA_QEM_MM=0.05` sets the deviation, `STRATA_MODELS=3DBenchy.stl,...` the models).
//!
//! Per model: triangles in and out, the measured two-sided deviation (admission's
//! `hausdorff_mm`), the peak active triangles and contour points at the default settings
//! (`strata::slice::peak_needs`) and the time, for the quadric simplifier at a bound just under
//! the deviation and for meshopt at the fewest triangles (bisection on its target count) whose
//! measured deviation is within it.

use std::time::Instant;

use meshopt::{simplify_decoder, SimplifyOptions};
use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::slice::{peak_needs, SliceConfig};
use strata_host::admission::hausdorff_mm;
use strata_host::simplify::{weld, Options, Simplifier};
use strata_testkit::models;

const MODELS: &str = "3DBenchy.stl,scaled_mm/stanford_bunny_x60.stl,\
                      scaled_mm/fertility_genus4_x80.stl,scaled_mm/rockerarm_genus1_x40.stl,\
                      rockerarm_genus1.stl,torus3_genus3.stl";

fn needs(tris: &[Triangle]) -> (u32, u32) {
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    let config = SliceConfig::new(&PrintSettings::default(), top).unwrap();
    let n = peak_needs(tris, &config).unwrap();
    (n.active_triangles, n.contour_points)
}

fn sorted(mut t: Vec<Triangle>) -> Vec<Triangle> {
    t.sort_by_key(Triangle::z_min);
    t
}

/// meshopt towards `target` triangles (no error limit), on original vertices.
fn meshopt(tris: &[Triangle], target: usize) -> Vec<Triangle> {
    let (points, indices) = weld(tris);
    let pos: Vec<[f32; 3]> =
        points.iter().map(|p| [p.x as f32 / 1e3, p.y as f32 / 1e3, p.z as f32 / 1e3]).collect();
    let idx = simplify_decoder(
        &indices,
        &pos,
        target * 3,
        f32::MAX,
        SimplifyOptions::ErrorAbsolute,
        None,
    );
    idx.chunks_exact(3).map(|c| Triangle { v: [0, 1, 2].map(|k| points[c[k] as usize]) }).collect()
}

#[test]
#[ignore = "figures: release, minutes"]
fn qem_against_meshopt() {
    let Some(dir) = models::shared_models() else { return };
    let dev: f64 = std::env::var("STRATA_QEM_MM").ok().and_then(|s| s.parse().ok()).unwrap_or(0.05);
    let list = std::env::var("STRATA_MODELS").unwrap_or_else(|_| MODELS.to_string());
    let machine = MachineConfig::default();
    println!(
        "| model | tris in | peak act/pts in | QEM tris | QEM dev mm | QEM act/pts | QEM s | \
         meshopt tris | meshopt dev mm | meshopt act/pts | meshopt s |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for name in list.split(',') {
        let tris = models::load_placed(&dir.join(name), &machine);
        let (a0, p0) = needs(&tris);
        let t = Instant::now();
        let (points, indices) = weld(&tris);
        let mut s = Simplifier::new(&points, &indices, Options::default());
        s.run(dev * 0.97 - 0.001);
        let q = sorted(s.triangles());
        let q_s = t.elapsed().as_secs_f64();
        let q_dev = hausdorff_mm(&tris, &q);
        let (qa, qp) = needs(&q);
        eprintln!("{name}: {:?}", s.stats());
        // meshopt: the fewest triangles within `dev` (bisection on the count).
        let t = Instant::now();
        let (mut lo, mut hi) = (4usize, tris.len());
        let mut best = (tris.clone(), 0.0);
        for _ in 0..12 {
            if hi - lo <= hi / 100 {
                break;
            }
            let mid = lo + (hi - lo) / 2;
            let m = sorted(meshopt(&tris, mid));
            let d = hausdorff_mm(&tris, &m);
            if d <= dev {
                hi = mid;
                best = (m, d);
            } else {
                lo = mid;
            }
        }
        let m_s = t.elapsed().as_secs_f64();
        let (ma, mp) = needs(&best.0);
        println!(
            "| {name} | {} | {a0}/{p0} | {} | {q_dev:.4} | {qa}/{qp} | {q_s:.1} | {} | {:.4} | \
             {ma}/{mp} | {m_s:.1} |",
            tris.len(),
            q.len(),
            best.0.len(),
            best.1
        );
    }
}

//! Admission control against the device's capacities (`strata_host::admission::admit_job`):
//! the slicer's needs (simplification held to a measured deviation, checked here against an
//! analytic sphere), the toolpath stage's needs and the move buffer, and a model that fits
//! streamed unchanged through the simulated printer. Small models: fast in debug builds.

use std::collections::HashSet;

use strata::geom::{Point3, Triangle};
use strata::machine::MachineConfig;
use strata::printer::{Accept, CREALITY_CAPACITIES};
use strata::protocol::{Capacities, DeviceState, ErrorCode, JobOptions, JobSpec, Message};
use strata::slice::{SliceConfig, SliceScratch};
use strata::step::StepQueue;
use strata_host::admission::{admit_job, hausdorff_mm, toolpath_peaks, Admission};
use strata_host::model;
use strata_host::simjob::{device_ram, simulate, SimOptions};
use strata_testkit::drive::{job_payloads, job_spec, model_payloads, start, Rig};
use strata_testkit::mesh::{cuboid, holed_block, sphere, to_um};
use strata_testkit::on_big_stack;
use strata_testkit::stl::write_mesh;

/// Sphere centre (um) and radius (mm): resting on the bed at the bed's centre.
const C: [f64; 3] = [110_000.0, 110_000.0, 5_000.0];
const R_MM: f64 = 5.0;

/// A UV sphere of `lon` x `lat` ([`sphere`]) around [`C`], its vertices rounded to the um
/// grid and shared between triangles, outward winding, sorted by lowest z.
fn uv_sphere(lon: usize, lat: usize) -> Vec<Triangle> {
    to_um(&sphere(C.map(|um| um / 1000.0), R_MM, lon, lat))
}

/// How far a triangle's flat face lies inside the sphere, mm: its corners are on the sphere,
/// so the face's point nearest the centre is the farthest from the sphere, at
/// `R - distance(centre, triangle)`. That distance is the plane's, `distance(centre, plane)`,
/// when the foot of the perpendicular lies inside the triangle (an acute triangle: its
/// circumcentre), else the nearest edge's (an obtuse sliver, whose plane passes far inside the
/// sphere though the face stays near it).
fn sphere_deviation_mm(t: &Triangle) -> f64 {
    type V = [f64; 3];
    let sub = |a: V, b: V| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: V, b: V| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let cross = |a: V, b: V| {
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    };
    let p = t.v.map(|p| [p.x as f64 / 1e3, p.y as f64 / 1e3, p.z as f64 / 1e3]);
    let c = C.map(|x| x / 1e3);
    let n = cross(sub(p[1], p[0]), sub(p[2], p[0]));
    let nn = dot(n, n);
    let h = dot(sub(c, p[0]), n) / nn;
    let foot = [c[0] - h * n[0], c[1] - h * n[1], c[2] - h * n[2]];
    // Inside when the foot is on the inner side of every edge.
    let inside = (0..3).all(|k| {
        let (a, b) = (p[k], p[(k + 1) % 3]);
        dot(cross(sub(b, a), sub(foot, a)), n) >= 0.0
    });
    let d = if inside {
        h.abs() * nn.sqrt()
    } else {
        (0..3)
            .map(|k| {
                let (a, b) = (p[k], p[(k + 1) % 3]);
                let ab = sub(b, a);
                let s = (dot(sub(c, a), ab) / dot(ab, ab)).clamp(0.0, 1.0);
                let q = sub(c, [a[0] + s * ab[0], a[1] + s * ab[1], a[2] + s * ab[2]]);
                dot(q, q).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    };
    R_MM - d
}

/// The job of `tris` with the default settings, without a skirt.
fn job(tris: &[Triangle]) -> JobSpec {
    let mut spec = job_spec(tris);
    spec.options.skirt_loops = 0;
    spec
}

/// A closed box [x0, x1] x [y0, y1] x [0, h], um ([`cuboid`]), sorted by lowest z.
fn cuboid_um(x0: i32, x1: i32, y0: i32, y1: i32, h: i32) -> Vec<Triangle> {
    let mm = |um: i32| f64::from(um) / 1000.0;
    to_um(&cuboid([mm(x0), mm(y0), 0.0], [mm(x1), mm(y1), mm(h)]))
}

#[test]
fn a_fine_sphere_is_simplified_to_fit_within_the_measured_deviation() {
    let tris = uv_sphere(96, 48);
    let original: HashSet<Point3> = tris.iter().flat_map(|t| t.v).collect();
    let orig_sag = tris.iter().map(sphere_deviation_mm).fold(0.0, f64::max);
    assert!(orig_sag < 0.01, "{orig_sag}");
    let caps = Capacities { active_triangles: 150, contour_points: 150, ..CREALITY_CAPACITIES };
    let machine = MachineConfig::default();
    let job = job(&tris);
    let bound = 0.1;
    let Admission::Simplified(s) = admit_job(&tris, &machine, &job, &caps, bound).unwrap() else {
        panic!("the sphere should need simplification");
    };
    assert!(s.triangles.len() < tris.len() / 2, "{} triangles", s.triangles.len());
    // The result fits (the slicer's peaks and the toolpath's needs, remeasured here).
    assert!(s.needs.active_triangles <= 150 && s.needs.contour_points <= 150, "{:?}", s.needs);
    let peaks = toolpath_peaks(&s.triangles, &machine, &job).unwrap();
    assert!(peaks.needs.crossings <= caps.scan_crossings, "{:?}", peaks.needs);
    // The measured deviation is within the bound and agrees with an independent estimate.
    assert!(s.max_deviation_mm <= bound, "{}", s.max_deviation_mm);
    assert!((hausdorff_mm(&tris, &s.triangles) - s.max_deviation_mm).abs() < 1e-9);
    // Oracle: every corner is an original vertex (on the sphere) or one the quadric
    // simplifier placed, within the measured deviation of the original (which lies within its
    // sag inside the sphere). A flat face deviates inwards from the sphere by at most
    // R - distance(centre, face) (the plane's distance when the perpendicular's foot lies
    // inside the face); that is within the measured deviation (from the original mesh,
    // sampled: 10 % slack) plus the original's own sag.
    let mut worst: f64 = 0.0;
    for t in &s.triangles {
        for p in t.v {
            let d = [p.x, p.y, p.z].map(f64::from);
            let rho = (0..3).map(|k| (d[k] - C[k]).powi(2)).sum::<f64>().sqrt() / 1e3;
            let off = (rho - R_MM).abs();
            assert!(
                original.contains(&p) || off <= s.max_deviation_mm + orig_sag + 0.001,
                "{p:?} is {off:.4} mm off the sphere"
            );
        }
        worst = worst.max(sphere_deviation_mm(t));
    }
    assert!(
        worst <= 1.1 * s.max_deviation_mm + orig_sag,
        "face {worst:.4} mm inside the sphere, measured {:.4} mm",
        s.max_deviation_mm
    );
    assert!(worst > 0.0);
}

#[test]
fn a_model_that_cannot_fit_is_refused_naming_what() {
    let tris = uv_sphere(48, 24);
    let caps = Capacities { active_triangles: 4, contour_points: 4, ..CREALITY_CAPACITIES };
    let e = admit_job(&tris, &MachineConfig::default(), &job(&tris), &caps, 0.1).unwrap_err();
    assert!(e.contains("does not fit the printer"), "{e}");
    assert!(e.contains("active triangles") && e.contains("contour points"), "{e}");
    assert!(e.contains("the printer holds 4 and 4"), "{e}");
}

#[test]
fn toolpath_needs_beyond_the_printer_are_refused_naming_the_resource() {
    let tris = cuboid_um(100_000, 120_000, 100_000, 110_000, 1_000);
    let machine = MachineConfig::default();
    let job = job(&tris);
    let peaks = toolpath_peaks(&tris, &machine, &job).unwrap();
    assert!(peaks.needs.crossings > 8, "{:?}", peaks.needs);
    // Where the needs peak: every layer's outline is the same 4 corners, so the first layer
    // built holds the points peak; the solid bottom layer has the most infill crossings; the
    // window holds most once the top layer arrived.
    assert_eq!((peaks.points.value, peaks.points.z_um), (4, 200), "{peaks:?}");
    assert_eq!(peaks.crossings.z_um, 200, "{peaks:?}");
    assert_eq!(peaks.ring_words.z_um, 1_000, "{peaks:?}");
    assert_eq!(peaks.layers, 5);
    // The slicer fits; the scanline crossings do not.
    let caps = Capacities { scan_crossings: 8, ..CREALITY_CAPACITIES };
    let e = admit_job(&tris, &machine, &job, &caps, 0.02).unwrap_err();
    assert!(e.contains("toolpath memory"), "{e}");
    let want = format!(
        "layer at {:.2} mm needs {} scanline crossings; the printer holds 8: the part's \
         cross-section is too large",
        peaks.crossings.z_um as f64 / 1000.0,
        peaks.needs.crossings
    );
    assert!(e.contains(&want), "{e}\nwant {want}");
    assert!(!e.contains("path points"), "{e}");
    // Every toolpath resource is named when it does not fit.
    let tiny = Capacities {
        toolpath_points: 2,
        toolpath_loops: 0,
        scan_crossings: 2,
        path_points: 2,
        window_ring_words: 2,
        window_spans: 0,
        move_buffer_bytes: 8,
        contour_loops: 0,
        ..CREALITY_CAPACITIES
    };
    let e = admit_job(&tris, &machine, &job, &tiny, 0.02).unwrap_err();
    for what in [
        "toolpath loop points and offset edges; the printer holds 2",
        "toolpath loops; the printer holds 0",
        "needs 1 contour loops; the printer holds 0",
        "scanline crossings; the printer holds 2",
        "toolpath path points; the printer holds 2",
        "the skin window at 1.00 mm needs",
        "contour words; the printer holds 2",
        "scanline spans; the printer holds 0",
        "bytes of buffered toolpath moves for one path (with the travel before it); the \
         printer's move buffer holds 8 bytes",
    ] {
        assert!(e.contains(what), "{what}: {e}");
    }
}

/// Ten separate blocks: every layer has ten loops. A slicer that keeps eight a layer is
/// refused (the device would stop at the first layer), one that keeps ten is not.
#[test]
fn more_loops_a_layer_than_the_slicer_keeps_are_refused() {
    let tris: Vec<Triangle> = {
        let mut t: Vec<Triangle> = (0..10)
            .flat_map(|k| {
                let x = 60_000 + k * 10_000;
                cuboid_um(x, x + 5_000, 100_000, 105_000, 600)
            })
            .collect();
        t.sort_by_key(|t| t.z_min());
        t
    };
    let machine = MachineConfig::default();
    let job = job(&tris);
    let peaks = toolpath_peaks(&tris, &machine, &job).unwrap();
    assert_eq!(peaks.contour_loops.value, 10, "{peaks:?}");
    let eight = Capacities { contour_loops: 8, ..CREALITY_CAPACITIES };
    let e = admit_job(&tris, &machine, &job, &eight, 0.02).unwrap_err();
    assert!(e.contains("needs 10 contour loops; the printer holds 8"), "{e}");
    let ten = Capacities { contour_loops: 10, ..CREALITY_CAPACITIES };
    assert!(admit_job(&tris, &machine, &job, &ten, 0.02).is_ok());
}

#[test]
fn a_small_model_that_fits_is_streamed_unchanged() {
    let tris = cuboid_um(100_000, 106_000, 100_000, 104_000, 600);
    let machine = MachineConfig::default();
    let job = job(&tris);
    let caps = CREALITY_CAPACITIES;
    let Admission::Unchanged(needs) = admit_job(&tris, &machine, &job, &caps, 0.02).unwrap() else {
        panic!("a 16-triangle box fits");
    };
    assert!(needs.active_triangles <= 12);
    let peaks = toolpath_peaks(&tris, &machine, &job).unwrap();
    assert_eq!(peaks.layers, 3);
    assert!(peaks.unit_bytes.value > 0);
    let opts = SimOptions { capacities: caps, ..SimOptions::default() };
    let rep = simulate(&tris, &machine, job, &opts).unwrap_or_else(|(e, _)| panic!("{e}"));
    assert_eq!(rep.triangles, tris.len());
    assert_eq!(rep.layers, 3);
    assert_eq!(rep.layer_hashes.len(), 3);
}

/// `strata simulate --json`: `device_ram_bytes` is the RAM of a device sized exactly to the
/// needs admission checks (the slicer's peaks, the toolpath needs of `toolpath_peaks`), and
/// `device_needs` are those needs as announced capacities: a printer announcing exactly them
/// admits the model unchanged, one unit less of any is refused naming it.
#[test]
fn simulate_reports_the_ram_and_capacities_admission_checks() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("holed.stl");
    write_mesh(&path, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_strata"))
        .args(["simulate", path.to_str().unwrap(), "--json", "--skirt-loops", "0"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let machine = MachineConfig::default();
    let tris = model::load(&path).unwrap().placed_sorted(&machine).unwrap();
    let job = job(&tris);
    let peaks = toolpath_peaks(&tris, &machine, &job).unwrap();
    // The slicer's peaks, from the core slicer directly.
    let cfg = SliceConfig::new(&job.settings, job.model_height_um).unwrap();
    let stats = on_big_stack(|| {
        let mut slicer = Box::new(NeedsSlicer::new(cfg).unwrap());
        let mut work = Box::new(SliceScratch::new());
        for t in &tris {
            slicer.push(t, &mut *work, &mut |_| {}).unwrap();
        }
        slicer.finish(&mut *work, &mut |_| {}).unwrap()
    });
    assert_eq!(doc["device_ram_bytes"], device_ram(&stats, &peaks.needs));
    let n = &doc["device_needs"];
    assert_eq!(n["toolpath_ram_bytes"], peaks.needs.bytes() as u64);
    let field = |k: &str| n[k].as_u64().unwrap_or_else(|| panic!("{k}: {n}")) as u32;
    let exact = Capacities {
        active_triangles: field("active_triangles"),
        contour_points: field("contour_points"),
        move_buffer_bytes: field("move_buffer_bytes"),
        toolpath_points: field("toolpath_points"),
        toolpath_loops: field("toolpath_loops"),
        scan_crossings: field("scan_crossings"),
        path_points: field("path_points"),
        window_ring_words: field("window_ring_words"),
        window_spans: field("window_spans"),
        ..CREALITY_CAPACITIES
    };
    assert_eq!(exact.active_triangles, stats.peak_active);
    assert_eq!(exact.scan_crossings, peaks.needs.crossings);
    let tris = model::load(&path).unwrap().placed_sorted(&machine).unwrap();
    let admitted = admit_job(&tris, &machine, &job, &exact, 0.02).unwrap();
    assert!(matches!(admitted, Admission::Unchanged(_)));
    let less = [
        (
            "toolpath loop points",
            Capacities { toolpath_points: exact.toolpath_points - 1, ..exact },
        ),
        ("toolpath loops", Capacities { toolpath_loops: exact.toolpath_loops - 1, ..exact }),
        ("scanline crossings", Capacities { scan_crossings: exact.scan_crossings - 1, ..exact }),
        ("toolpath path points", Capacities { path_points: exact.path_points - 1, ..exact }),
        ("contour words", Capacities { window_ring_words: exact.window_ring_words - 1, ..exact }),
        ("scanline spans", Capacities { window_spans: exact.window_spans - 1, ..exact }),
        (
            "bytes of buffered toolpath moves",
            Capacities { move_buffer_bytes: exact.move_buffer_bytes - 1, ..exact },
        ),
    ];
    for (what, caps) in less {
        let e = admit_job(&tris, &machine, &job, &caps, 0.02).unwrap_err();
        assert!(e.contains(what), "{what}: {e}");
    }
}

strata::printer_type! {
    /// A printer with a 64 KB move buffer (a small model's every layer fits it unplanned).
    type Roomy = {
        active_triangles: 1024,
        contour_points: 768,
        contour_loops: 48,
        toolpath_points: 2048,
        toolpath_loops: 64,
        scan_crossings: 4096,
        path_points: 8192,
        window_ring_words: 8192,
        window_spans: 4096,
        move_buffer_bytes: 1 << 16,
        lookahead_moves: 32,
    };
}

/// Takes the job and the whole model without planning a move (no `poll`): every layer's
/// moves stay in the move buffer. Returns the bytes in use and the state and error.
fn buffer_unplanned(tris: &[Triangle], job: JobSpec) -> (usize, DeviceState, ErrorCode) {
    let payloads = job_payloads(job, tris);
    assert_eq!(payloads.len(), 3, "the job, one batch, the end of the model");
    on_big_stack(|| {
        let mut p = Box::new(Roomy::new(&MachineConfig::default()));
        let mut q: StepQueue<32> = StepQueue::new();
        let mut rig = Rig::counting(&mut q);
        for m in &payloads {
            assert_eq!(p.handle(&Message::decode(m).unwrap(), &mut rig.motion), Accept::Taken);
        }
        (rig.motion.motion.moves().used_bytes(), p.state(), p.error().0)
    })
}

/// Two small jobs for the move buffer's checks: a box with a skirt, and a tall thin wall
/// without one.
fn unit_cases() -> Vec<(Vec<Triangle>, JobSpec)> {
    [
        (cuboid_um(100_000, 112_000, 100_000, 109_000, 1_000), 1),
        (cuboid_um(60_000, 61_500, 150_000, 190_000, 2_200), 0),
    ]
    .into_iter()
    .map(|(tris, skirt_loops)| {
        let options = JobOptions { skirt_loops, ..JobOptions::default() };
        let spec = JobSpec { options, ..job(&tris) };
        (tris, spec)
    })
    .collect()
}

/// Admission codes the job's moves as the device's move buffer codes them (the coding's
/// state running on across layers): a printer that plans nothing holds, after the whole
/// model, exactly the bytes admission counted, and more than the largest unit's.
#[test]
fn admission_counts_the_bytes_the_move_buffer_holds() {
    let machine = MachineConfig::default();
    for (tris, spec) in unit_cases() {
        let peaks = toolpath_peaks(&tris, &machine, &spec).unwrap();
        let (held, state, error) = buffer_unplanned(&tris, spec);
        assert_eq!((state, error), (DeviceState::Printing, ErrorCode::None));
        assert!(peaks.layers >= 5, "{}", peaks.layers);
        assert_eq!(held as u64, peaks.move_bytes);
        assert!(u64::from(peaks.unit_bytes.value) < peaks.move_bytes);
    }
}

/// What a job did on a printer: the end state, the error, the layer hashes, the largest
/// unit's bytes.
struct Limited {
    state: DeviceState,
    error: (ErrorCode, u32),
    hashes: Vec<(u32, u64)>,
    largest: usize,
}

/// What a job did on a [`Roomy`] printer using `limit` bytes of its move buffer, fed and
/// drained as a device is.
fn run_limited(tris: &[Triangle], job: JobSpec, limit: usize) -> Limited {
    let payloads = model_payloads(tris);
    assert_eq!(payloads.len(), 2, "one batch, the end of the model");
    on_big_stack(|| {
        let mut p = Box::new(Roomy::new(&MachineConfig::default()));
        let mut q: StepQueue<32> = StepQueue::new();
        let mut rig = Rig::counting(&mut q);
        rig.motion.motion.moves_mut().limit(limit);
        start(&mut *p, &mut rig, job);
        rig.drive(&mut *p, &payloads, 50_000_000, |_, _, _| {});
        Limited {
            state: p.state(),
            error: p.error(),
            hashes: rig.hashes,
            largest: p.largest_unit_bytes(),
        }
    })
}

/// The largest unit's bytes admission reports are what a device needs: a printer whose move
/// buffer holds exactly them prints the job (the hashes of a roomy one), one byte less fails
/// it with `ErrorCode::Moves` at the layer admission named, and admission refuses a printer
/// announcing one byte less.
#[test]
fn the_largest_unit_admission_reports_is_the_buffer_a_printer_needs() {
    let machine = MachineConfig::default();
    for (tris, spec) in unit_cases() {
        let peaks = toolpath_peaks(&tris, &machine, &spec).unwrap();
        let unit = peaks.unit_bytes.value as usize;
        let roomy = run_limited(&tris, spec, 1 << 16);
        assert_eq!(roomy.state, DeviceState::Done, "{:?}", roomy.error);
        assert_eq!(roomy.largest, unit);
        let exact = run_limited(&tris, spec, unit);
        assert_eq!(exact.state, DeviceState::Done, "{:?}", exact.error);
        assert_eq!(exact.hashes, roomy.hashes);
        assert_eq!(exact.largest, unit);
        let short = run_limited(&tris, spec, unit - 1);
        assert_eq!(short.state, DeviceState::Failed);
        assert_eq!(short.error, (ErrorCode::Moves, peaks.unit_bytes.layer));
        assert_eq!(short.hashes[..], roomy.hashes[..short.hashes.len()]);
        let caps = Capacities { move_buffer_bytes: peaks.unit_bytes.value, ..CREALITY_CAPACITIES };
        assert!(admit_job(&tris, &machine, &spec, &caps, 0.02).is_ok());
        let less = Capacities { move_buffer_bytes: peaks.unit_bytes.value - 1, ..caps };
        let e = admit_job(&tris, &machine, &spec, &less, 0.02).unwrap_err();
        let want = format!(
            "layer at {:.2} mm needs {unit} bytes of buffered toolpath moves for one path",
            peaks.unit_bytes.z_um as f64 / 1000.0
        );
        assert!(e.contains(&want), "{e}\nwant {want}");
    }
}

strata::slicer_type! {
    type NeedsSlicer = { active_triangles: 4096, contour_points: 4096, contour_loops: 256 };
}

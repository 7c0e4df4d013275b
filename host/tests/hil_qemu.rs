//! Hardware in the loop: the firmware's QEMU build (Cortex-M3 `lm3s6965evb`, 64 KB RAM,
//! UART0 on a unix socket) prints the sample models streamed by the real host code
//! (`strata_host::serial::print` after the handshake and admission control), and its
//! per-layer hashes, final state and planned print time (protocol messages), and its steps
//! per axis, final positions, executed print time and step hash (its `STEPS` line) equal the
//! host simulation of the same job (`strata_host::simjob::simulate`, what
//! `strata simulate --json` reports) bit for bit; then again through a seeded fault-injecting
//! relay (frame drop, byte corruption and loss, duplication, delay at 3 % per frame each, on
//! both directions at 250000 baud): every model on the 64 KB build (the mps2 run clean only;
//! `STRATA_HIL_LOSSY_ALL=1` adds its lossy run too). Every QEMU job also heats its
//! simulated hotend and bed first: the firmware's `HEAT at_target` line must come before the
//! first step, and no thermal fault may trip.
//!
//! How to run:
//!
//! ```text
//! apt-get install qemu-system-arm             # once
//! scripts/build_firmware.sh qemu               # target/firmware/qemu/strata-firmware.elf (release)
//! scripts/build_firmware.sh qemu-mps2          # LM8UU unsimplified (4 MB of RAM)
//! cargo test -p strata-host --test hil_qemu -- --nocapture
//! cargo test -p strata-host --test hil_qemu -- --nocapture --include-ignored qemu_   # + models
//! ```
//!
//! All four models print on the 64 KB build: embodier_asc, the cube and embodier_hotend_v2
//! unsimplified, embodier_LM8UU_8p2pi simplified by admission for the slicer with its offsets
//! done in bands (see the note above `qemu_embodier_lm8uu`). LM8UU also runs unsimplified on
//! the same firmware built for QEMU's mps2-an385 (Cortex-M3, 4 MB of RAM;
//! `scripts/build_firmware.sh qemu-mps2`), with the same comparison. Every job's stack must
//! stay [`RAM_HEADROOM`] clear of the statics.
//!
//! `STRATA_QEMU` and `STRATA_FIRMWARE_ELF` override where QEMU and the image are looked for
//! (`STRATA_HIL_RT_ELF` the real-time image's, say one built at another CPI);
//! `STRATA_HIL_ECHO=1` copies QEMU's output (the firmware's `COST`/`MEM` lines) to stderr as
//! it comes. Without QEMU or the image the QEMU tests fail when `CI` is set and are skipped
//! with the reason printed otherwise. The harness itself (relay, timeouts, comparison) also
//! runs against the in-process simulated printer (`serve_device`), which needs neither.
//!
//! Time is the device's: the host's link, the relay and every budget below run on QEMU's
//! instruction clock (or the in-process printer's turns), read through QEMU's monitor, so the
//! suite decides the same on an idle machine and on one whose cores are busy elsewhere.
//! Nothing can hang: QEMU's UART must accept within `hil::QEMU_ACCEPT_LIMIT` (wall time: no
//! emulation has started), the link counts as dead after the protocol's 3 s of the device's
//! silence, every job ends past its budget of emulated time ([`QEMU_JOB_MS`]), a device clock
//! that stands still for a minute of wall time is an error, and QEMU is killed on drop. The
//! reference simulation runs on a second thread while QEMU prints.

#![cfg(unix)]

use std::os::unix::net::UnixStream;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use strata_host::clock::LinkClock;
use strata_host::serial::{Port, ServeOptions};

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::printer::CREALITY_CAPACITIES;
use strata::protocol::{Capacities, DeviceState, JobSpec};
use strata::step::StepConfig;
use strata_host::gcode_file;
use strata_host::hil::{self, banded_cylinder, Costs, Qemu, Relay, SimDevice};
use strata_host::model;
use strata_host::session::{CardWrite, Progress, Source};
use strata_host::simjob::{simulate, simulate_source, Faults, SimOptions, SimReport};
use strata_testkit::drive::job_spec;

/// Faults of the lossy runs: 3 % of frames each dropped, corrupted, shortened by a byte,
/// duplicated and delayed (up to 50 ms), on both directions, at 250000 baud.
const LOSS: f64 = 0.03;
const BAUD: u32 = hil::BAUD;
/// Budget of one QEMU job in emulated time, ms (the longest, embodier_hotend_v2 through the
/// lossy relay, takes 16 s of QEMU's clock: each job's line below says how long it took).
const QEMU_JOB_MS: u32 = 600_000;
/// The same on the real-time board, whose clock is the chip's: the print itself takes its
/// print time there (the longest sample model, embodier_hotend_v2, about 50 minutes).
const REALTIME_JOB_MS: u32 = 4 * 3_600_000;
/// Budget of the firmware's closing lines after the job's last report, ms of emulated time.
const CLOSING_LINES_MS: u32 = 30_000;
/// RAM a job must leave untouched (painted) below its deepest stack use: the statics and the
/// stack share the board's RAM (a stack that reaches the statics corrupts them silently), and
/// the 64 KB boards keep 2 KB free for what comes next (`RAM_HEADROOM` in
/// `scripts/build_firmware.sh`, which checks the statics against the deepest stack seen here).
const RAM_HEADROOM: u64 = 2048;
/// The sample models of the end-to-end test.
const MODELS: [&str; 4] =
    ["embodier_asc.stl", "xyz_20mm_cube.stl", "embodier_hotend_v2.stl", "embodier_LM8UU_8p2pi.stl"];

/// QEMU and the image of the 64 KB build (or, with `Some(board)`, of that build), or `None`
/// (skip) with the reason printed; under CI a missing piece fails the test.
fn qemu_or_skip(test: &str, board: Option<&str>) -> Option<(PathBuf, PathBuf)> {
    let found = match (board, std::env::var_os("STRATA_HIL_RT_ELF")) {
        (None, _) => hil::locate(),
        (Some(b @ "qemu-rt"), Some(elf)) => hil::locate_image(elf.into(), b),
        (Some(b), _) => hil::locate_image(hil::build_output(b), b),
    };
    match found {
        Ok(x) => Some(x),
        Err(e) if std::env::var_os("CI").is_some() => panic!("{test}: {e}"),
        Err(e) => {
            eprintln!("{test}: SKIPPED: {e}");
            None
        }
    }
}

fn load(name: &str) -> (Vec<Triangle>, JobSpec) {
    let path = strata_testkit::models::dir().join(name);
    let m = model::load(&path).unwrap_or_else(|e| panic!("{e}"));
    let tris = m.placed_sorted(&MachineConfig::default()).unwrap();
    let job = job_spec(&tris);
    (tris, job)
}

/// A job for the harness: a model (admitted as `strata print` admits it) or G-code text.
#[derive(Clone, Copy)]
enum Work<'a> {
    Model(&'a [Triangle], JobSpec),
    Gcode(&'a [u8]),
}

/// What one job over a port gave.
struct Run {
    /// What was sent: triangles of the admitted model, or bytes of G-code.
    sent: String,
    note: Option<String>,
    result: Result<Progress, String>,
    link: strata::protocol::LinkStats,
    elapsed: Duration,
    /// The device's clock at the end, ms.
    device_ms: u32,
}

/// Handshake, admission, then the print on the device's `clock`; `reference` (if given) is
/// simulated on a second thread meanwhile from the admitted triangles.
fn run_job<C: LinkClock>(
    label: &str,
    port: &mut Port<UnixStream>,
    mut clock: C,
    work: Work<'_>,
    budget_ms: u32,
    want_reference: bool,
) -> (Run, Option<Result<SimReport, String>>) {
    let t0 = Instant::now();
    port.get_mut().set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    port.get_mut().set_write_timeout(Some(Duration::from_millis(1))).unwrap();
    let mut conn = match hil::connect(port, &mut clock) {
        Ok(c) => c,
        Err(e) => {
            let run = Run {
                sent: String::new(),
                note: None,
                result: Err(format!("handshake: {e}")),
                link: Default::default(),
                elapsed: t0.elapsed(),
                device_ms: clock.now_ms().unwrap_or(0),
            };
            return (run, None);
        }
    };
    let machine = MachineConfig::default();
    let (tris, job, note, text) = match work {
        Work::Model(tris, job) => {
            let admitted = hil::admitted_on_link(port, &mut conn, &mut clock, tris, job, 0.02);
            let (tris, job, note) = admitted.unwrap_or_else(|e| {
                panic!(
                    "{label}: refused by admission control against the device's capacities \
                     {:?}: {e}",
                    conn.greeting.capacities
                )
            });
            assert_eq!(job.triangles as usize, tris.len());
            (tris, job, note, None)
        }
        Work::Gcode(text) => {
            let scan = gcode_file::scan(text, &machine).unwrap_or_else(|e| panic!("{label}: {e}"));
            (Vec::new(), job_spec(&[]), None, Some((text, scan.spec)))
        }
    };
    let source = match text {
        Some((text, spec)) => Source::Gcode(text, spec),
        None => Source::Model(&tris, job),
    };
    let sent = match source {
        Source::Model(t, _) => format!("{} triangles", t.len()),
        Source::Gcode(t, _) => format!("{} bytes of G-code", t.len()),
        Source::Card { name, .. } => format!("the card's {name}"),
    };
    // The simulated printer poses as the device: it offsets in bands where the device's
    // engine is too small for an island.
    let opts = SimOptions { capacities: conn.greeting.capacities, ..SimOptions::default() };
    std::thread::scope(|s| {
        let reference = want_reference
            .then(|| s.spawn(|| simulate_source(source, &machine, &opts).map_err(|(e, _)| e)));
        let mut next_report = Duration::from_secs(30);
        let result = hil::print_job(port, &mut conn, &mut clock, source, budget_ms, |p| {
            // A line every 30 s of a long job: where it stands.
            if t0.elapsed() > next_report {
                next_report += Duration::from_secs(30);
                eprintln!(
                    "  ... {:.0} s: {} triangles sent, {} layer reports, status {:?}",
                    t0.elapsed().as_secs_f64(),
                    p.triangles_sent,
                    p.layer_hashes.len(),
                    p.status
                );
            }
        });
        let run = Run {
            sent,
            note: note.clone(),
            result,
            link: *conn.ep.stats(),
            elapsed: t0.elapsed(),
            device_ms: clock.now_ms().unwrap_or(0),
        };
        (run, reference.map(|r| r.join().unwrap()))
    })
}

/// The device's results equal the reference: state, every layer hash, layer and triangle
/// counts, planned print time (protocol messages); with the firmware's `STEPS` and `COST`
/// lines also the steps per axis, the final positions and the executed print time.
fn assert_same(what: &str, reference: &SimReport, p: &Progress, fw: Option<&Costs>) {
    let st = p.status.expect("a final status");
    let rs = reference.status.expect("the reference's final status");
    assert_eq!(st.state, DeviceState::Done, "{what}: final state");
    assert_eq!(st.layers, reference.layers, "{what}: layers");
    assert_eq!(p.layer_hashes.len(), reference.layers as usize, "{what}: layer reports");
    if let Some(l) = (0..p.layer_hashes.len().min(reference.layer_hashes.len()))
        .find(|&l| p.layer_hashes[l] != reference.layer_hashes[l])
    {
        panic!(
            "{what}: layer {l} hash {:016x}, the simulation's {:016x} ({} of {} layers differ)",
            p.layer_hashes[l],
            reference.layer_hashes[l],
            p.layer_hashes.iter().zip(&reference.layer_hashes).filter(|(a, b)| a != b).count(),
            reference.layers
        );
    }
    assert_eq!(p.layer_hashes, reference.layer_hashes, "{what}: layer hashes");
    assert_eq!(st.triangles, rs.triangles, "{what}: triangles taken");
    assert_eq!(st.planned_ms, rs.planned_ms, "{what}: planned print time, ms");
    // Over the wire, as a real board would report them: steps, positions, motion time.
    let report = p.job_report.unwrap_or_else(|| panic!("{what}: no job report"));
    assert_eq!(Some(report), reference.job_report, "{what}: job report");
    assert_eq!(report.steps, reference.steps, "{what}: reported steps per axis");
    let Some(fw) = fw else { return };
    let steps = fw.steps().unwrap_or_else(|| panic!("{what}: the firmware printed no STEPS line"));
    assert_eq!(steps.steps, reference.steps, "{what}: steps per axis X, Y, Z, E");
    assert_eq!(steps.positions, reference.positions, "{what}: final positions X, Y, Z, E");
    if let Some(total) = fw.get("COST", &["steps"]) {
        assert_eq!(total, reference.steps.iter().sum::<u64>(), "{what}: COST steps");
    }
    assert_eq!(steps.print_ticks, Some(reference.print_ticks), "{what}: print time, ticks");
    // The generator leaves every reversal room for the edge's latency: none is later than
    // the allowance, so DIR's setup delays no step (the simulation's edges have none).
    let allowed = StepConfig::default().edge_latency_ticks() as u64;
    let latency = steps.edge_ticks_max.expect("the STEPS line gives the edge latency");
    assert!(latency <= allowed, "{what}: an edge {latency} ticks late, beyond {allowed}");
    assert_eq!(steps.late_dir_steps, Some(0), "{what}: steps delayed for DIR's setup");
    // Every step edge at the same tick relative to the first step.
    assert_eq!(steps.hash, Some(reference.board_hash), "{what}: step hash (axis, direction, tick)");
}

/// One model on QEMU: clean, then through the lossy relay; both equal the simulation.
fn qemu_model(name: &str) {
    let (tris, job) = load(name);
    qemu_job(name, &tris, job, true);
}

fn qemu_job(name: &str, tris: &[Triangle], job: JobSpec, lossy: bool) {
    qemu_job_on(None, name, tris, job, lossy);
}

/// [`qemu_job`] on the image of `board` (`None`: the 64 KB `qemu` build).
/// Returns the firmware's records of the clean run (`None`: skipped).
fn qemu_job_on(
    board: Option<&str>,
    name: &str,
    tris: &[Triangle],
    job: JobSpec,
    lossy: bool,
) -> Option<Costs> {
    qemu_work_on(board, name, Work::Model(tris, job), lossy)
}

/// [`qemu_job_on`] of a model or G-code.
fn qemu_work_on(board: Option<&str>, name: &str, work: Work<'_>, lossy: bool) -> Option<Costs> {
    let test = format!("hil_qemu {name}");
    let (qemu, elf) = qemu_or_skip(&test, board)?;
    let mut clean = None;
    let echo = std::env::var_os("STRATA_HIL_ECHO").is_some();
    let mut reference = None;
    let runs = if lossy { &[None, Some(Faults::uniform(LOSS, 7))][..] } else { &[None][..] };
    for &faults in runs {
        let label = format!("{name} {}", if faults.is_some() { "lossy" } else { "clean" });
        let (mut q, uart) =
            Qemu::start(&qemu, &elf, echo).unwrap_or_else(|e| panic!("{label}: {e}"));
        let mut clock = q.clock().unwrap_or_else(|e| panic!("{label}: {e}"));
        let (relay, port) = match faults {
            Some(f) => {
                let (r, p) = Relay::spawn(uart, f, BAUD, clock.clone()).unwrap();
                (Some(r), p)
            }
            None => (None, uart),
        };
        let mut port = Port::new(port);
        let budget = if board == Some("qemu-rt") { REALTIME_JOB_MS } else { QEMU_JOB_MS };
        let (run, r) = run_job(&label, &mut port, clock.clone(), work, budget, reference.is_none());
        if let Some(r) = r {
            reference = Some(r.unwrap_or_else(|e| panic!("{label}: reference simulation: {e}")));
        }
        let progress = run.result.unwrap_or_else(|e| {
            panic!(
                "{label}: {e}\n  qemu stderr: {}\n  qemu output (last lines): {:?}",
                q.stderr(),
                q.lines().iter().rev().take(12).rev().collect::<Vec<_>>()
            )
        });
        // The job's closing lines (COST, STEPS, MEM last) follow its last report.
        q.wait_for(&mut clock, CLOSING_LINES_MS, |l| l.iter().any(|l| l.starts_with("MEM ")))
            .unwrap_or_else(|e| panic!("{label}: waiting for the closing lines: {e}"));
        let lines = q.lines();
        let costs = Costs::parse(&lines);
        let (used, size) = (costs.get("MEM", &["stack_hwm"]), costs.get("MEM", &["stack_size"]));
        let (Some(used), Some(size)) = (used, size) else {
            panic!("{label}: no `MEM ... stack_hwm ... stack_size` line after the job")
        };
        assert!(
            used + RAM_HEADROOM <= size,
            "{label}: the stack used {used} of its {size} B, less than {RAM_HEADROOM} B from the \
             statics"
        );
        // The heaters (QEMU's simulated plant) reached the job's targets (a model's before
        // the first step; G-code moves where its own waits say), and nothing tripped.
        let heat = lines.iter().find(|l| l.starts_with("HEAT at_target")).unwrap_or_else(|| {
            panic!("{label}: no `HEAT at_target` line: the job never reached its heater targets")
        });
        assert!(
            heat.contains("motion_started=0") || matches!(work, Work::Gcode(_)),
            "{label}: the motion started before the heaters were at target: {heat}"
        );
        if let Some(fault) = lines.iter().find(|l| l.starts_with("HEAT FAULT")) {
            panic!("{label}: thermal fault during a normal job: {fault}");
        }
        drop(port);
        let relay_stats = relay.map(|r| r.finish());
        let rf = reference.as_ref().unwrap();
        eprintln!(
            "{label}: {}{}, {} layers, planned {:.1} s, executed {:.1} s (simulation \
             {:.1} s), firmware {:?} (simulation steps {:?} positions {:?} print ticks {} \
             board hash {:016x}), {:.1} s wall, {:.1} s of QEMU's clock, host link {:?}, relay {:?}",
            run.sent,
            run.note.map(|n| format!(" ({n})")).unwrap_or_default(),
            rf.layers,
            progress.status.map_or(0, |s| s.planned_ms) as f64 / 1000.0,
            progress.status.map_or(0, |s| s.done_ms) as f64 / 1000.0,
            rf.print_time_s,
            costs.steps(),
            rf.steps,
            rf.positions,
            rf.print_ticks,
            rf.board_hash,
            run.elapsed.as_secs_f64(),
            run.device_ms as f64 / 1000.0,
            run.link,
            relay_stats
        );
        assert_same(&label, rf, &progress, Some(&costs));
        if faults.is_some() {
            let l = run.link;
            assert!(
                l.retransmits + l.bad_frames + l.duplicates > 0,
                "{label}: the relay injected nothing: {l:?}"
            );
        } else {
            clean = Some(costs);
        }
    }
    clean
}

/// A small model every firmware build holds (64 triangles, 3 layers, 20 s of print).
#[test]
fn qemu_small_cylinder() {
    let tris = cylinder(4_000.0, 600, 16);
    qemu_job("cylinder r4 h0.6 16 sides", &tris, job_spec(&tris), true);
}

/// A 20 mm bridge: two 6 x 6 x 3 mm posts joined by a 1 mm plate, printed with bridge lines
/// across the gap (the printer's jobs bridge: `toolpath_bridges::the_printers_jobs_print_bridges`)
/// bit-exact with the host's simulation of the board.
#[test]
fn qemu_bridge_between_two_posts() {
    use strata_testkit::mesh::{cuboid, to_um};
    let mut mesh = cuboid([100.0, 100.0, 0.0], [106.0, 106.0, 3.0]);
    mesh.extend(cuboid([126.0, 100.0, 0.0], [132.0, 106.0, 3.0]));
    mesh.extend(cuboid([100.0, 100.0, 3.0], [132.0, 106.0, 4.0]));
    let mut tris = to_um(&mesh);
    tris.sort_by_key(Triangle::z_min);
    qemu_job("bridge 20 mm between two posts", &tris, job_spec(&tris), false);
}

/// A taller one in 0.2 mm bands (512 triangles, 15 layers: skins, infill, about a minute of
/// print).
#[test]
fn qemu_banded_cylinder() {
    let tris = banded_cylinder(4_000.0, 3_000, 16, 200);
    assert_eq!(tris.len(), 512);
    qemu_job("banded cylinder r4 h3 16 sides", &tris, job_spec(&tris), true);
}

/// A wider one (672 triangles, 20 layers): its last layers once overflowed the move buffer
/// depending on the link's timing (fixed by cutting one layer at a time).
#[test]
fn qemu_banded_cylinder_r5() {
    let tris = banded_cylinder(5_000.0, 4_000, 16, 200);
    assert_eq!(tris.len(), 672);
    qemu_job("banded cylinder r5 h4 16 sides", &tris, job_spec(&tris), true);
}

#[test]
fn qemu_embodier_asc() {
    qemu_model("embodier_asc.stl");
}

#[test]
fn qemu_xyz_20mm_cube() {
    qemu_model("xyz_20mm_cube.stl");
}

/// PrusaSlicer's G-code of the cube (`tests/data/gcode/`), streamed: the printer reads it with
/// its own G-code reader, heats as its `M190`/`M109` say, and its steps equal the host
/// simulation's of the same text. Clean only: the lossy relay carries its 436 KB at a
/// fifth of the clean run's pace in wall time (8 minutes), and the lossy link is the STL
/// runs' to prove.
#[test]
fn qemu_prusaslicer_cube_gcode() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../tests/data/gcode/xyz_20mm_cube_prusaslicer.gcode");
    let text = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    qemu_work_on(None, "xyz_20mm_cube_prusaslicer.gcode", Work::Gcode(&text), false);
}

#[test]
fn qemu_embodier_hotend_v2() {
    // The long prints take about 1.5 minutes of QEMU a run: with their lossy runs the whole
    // test stays near 8 minutes on 2 cores.
    qemu_model("embodier_hotend_v2.stl");
}

/// The M3 nut's layers are too small for the printer's 5 s minimum layer time even at the
/// 10 mm/s floor: a layer waits for the rest lifted 3 mm off the part, a dwell the firmware
/// must time exactly as the simulation does.
#[test]
fn qemu_prusashape_m3_hex_nut() {
    let name = "prusashape_M3_hex_nut.stl";
    let (tris, job) = load(name);
    let Some(costs) = qemu_job_on(None, name, &tris, job, true) else { return };
    let steps = costs.steps().expect("a STEPS line");
    // Z steps beyond the rise to the last layer: at least one lift of 3 mm up (400 steps/mm:
    // 1,200 steps) and down to the next layer, 0.2 mm higher (1,120), in place of the
    // 80-step rise between the two.
    let lift_steps = 1_200 + 1_120 - 80;
    assert!(
        steps.steps[2] >= steps.positions[2].unsigned_abs() + lift_steps,
        "no wait lifted the nozzle: Z steps {} for a rise of {}",
        steps.steps[2],
        steps.positions[2]
    );
}

// embodier_LM8UU on the 64 KB build: admission simplifies it for the slicer (742 active
// triangles to 388, measured deviation 0.0135 mm, under the default 0.02 mm), and the
// device offsets its fins in bands (710 edges for an island, the engine holds 271).

#[test]
fn qemu_embodier_lm8uu() {
    qemu_model("embodier_LM8UU_8p2pi.stl");
}

// 3DBenchy on the 64 KB build: admission simplifies it within 0.05 mm (225,135 triangles to
// about 4,400, with the quadric simplifier); CI prints its first layers up to and including
// the layer of each peak need ([`BENCHY_CI_LAYERS`]), the whole model is an ignored test.

const BENCHY: &str = "3DBenchy.stl";
/// The deviation 3DBenchy is admitted within, mm.
const BENCHY_DEVIATION_MM: f64 = 0.05;
/// 3DBenchy's layers in CI: its peak needs on the 64 KB board lie in layer 0 (active triangles,
/// contour points and loops, loop points, path points, the largest move unit), 43 (scanline
/// crossings) and 55 (the skin window's words) (`host/examples/layer_needs.rs`).
const BENCHY_CI_LAYERS: i32 = 56;

#[test]
fn qemu_3dbenchy_first_layers() {
    let (tris, job) = load(BENCHY);
    let (tris, job) = first_layers_within(&tris, job, BENCHY_CI_LAYERS, BENCHY_DEVIATION_MM);
    qemu_job(&format!("{BENCHY} (first {BENCHY_CI_LAYERS} layers)"), &tris, job, true);
}

#[test]
#[ignore = "the whole 3DBenchy (an hour and a quarter of print): run with --ignored"]
fn qemu_3dbenchy() {
    qemu_whole_within(BENCHY, BENCHY_DEVIATION_MM);
}

// Organic scaled models on the 64 KB build, admitted within 0.05 mm as 3DBenchy: the bunny
// (60 mm tall) and the genus-4 fertility statue (80 mm). CI prints each up to and including the
// layer of its last peak need; the whole models are ignored tests.

const BUNNY: &str = "scaled_mm/stanford_bunny_x60.stl";
/// The bunny's layers in CI: its peak toolpath needs on the 64 KB board lie in layers 103
/// (offset edges), 155 (scanline crossings), 165 (window spans), 267 (path points), 268 (loop
/// points) and 272 (the skin window's words) (`host/examples/layer_needs.rs`), near its ears.
const BUNNY_CI_LAYERS: i32 = 273;
const FERTILITY: &str = "scaled_mm/fertility_genus4_x80.stl";
/// Fertility's layers in CI: peaks in layers 54 (loop points, path points), 58 (the skin
/// window), 59 (scanline crossings) and 91 (window spans). A prefix's last layers are top
/// skins: ending at layers 60 to 96 they would cover the statue's widest part solid, 1,112 to
/// 1,243 path points in a layer, more than the board holds; ending at 100 they fit.
const FERTILITY_CI_LAYERS: i32 = 100;
/// The deviation the organic models are admitted within, mm.
const ORGANIC_DEVIATION_MM: f64 = 0.05;

/// Clean only: its layers print for 2.8 hours, about 10 minutes of QEMU on 2 cores (the
/// lossy relay, which doubles that, runs with fertility here and with the whole bunny).
#[test]
fn qemu_stanford_bunny_x60_to_its_ears() {
    let (tris, job) = load(BUNNY);
    let (tris, job) = first_layers_within(&tris, job, BUNNY_CI_LAYERS, ORGANIC_DEVIATION_MM);
    qemu_job(&format!("{BUNNY} (first {BUNNY_CI_LAYERS} layers)"), &tris, job, false);
}

#[test]
fn qemu_fertility_genus4_x80_first_layers() {
    let (tris, job) = load(FERTILITY);
    let (tris, job) = first_layers_within(&tris, job, FERTILITY_CI_LAYERS, ORGANIC_DEVIATION_MM);
    qemu_job(&format!("{FERTILITY} (first {FERTILITY_CI_LAYERS} layers)"), &tris, job, true);
}

#[test]
#[ignore = "the whole stanford_bunny_x60: run with --ignored"]
fn qemu_stanford_bunny_x60() {
    qemu_whole_within(BUNNY, ORGANIC_DEVIATION_MM);
}

#[test]
#[ignore = "the whole fertility_genus4_x80: run with --ignored"]
fn qemu_fertility_genus4_x80() {
    qemu_whole_within(FERTILITY, ORGANIC_DEVIATION_MM);
}

/// A whole model admitted within `max_deviation_mm` for the 64 KB board, clean and lossy.
fn qemu_whole_within(name: &str, max_deviation_mm: f64) {
    let (tris, job) = load(name);
    let caps = &strata::printer::BOARD_CAPACITIES;
    let (tris, job, _) = hil::admitted(&tris, job, caps, max_deviation_mm)
        .unwrap_or_else(|e| panic!("admission for the 64 KB board: {e}"));
    qemu_job(name, &tris, job, true);
}

// LM8UU also prints unsimplified, its offsets whole, on the same firmware built for QEMU's
// mps2-an385 (`scripts/build_firmware.sh qemu-mps2`: the same Cortex-M3 instruction set with
// 4 MB of RAM and capacities to match): the pipeline on the device's instruction set equals
// the host simulation for it too. Clean run only (about 1.5 minutes of QEMU;
// `STRATA_HIL_LOSSY_ALL=1` adds its lossy run).

#[test]
fn qemu_mps2_embodier_lm8uu() {
    let (tris, job) = load("embodier_LM8UU_8p2pi.stl");
    let lossy = std::env::var_os("STRATA_HIL_LOSSY_ALL").is_some();
    qemu_job_on(Some("qemu-mps2"), "embodier_LM8UU_8p2pi.stl on mps2-an385", &tris, job, lossy);
}

// Real time: the 64 KB build with its print clock at the chip's speed
// (`scripts/build_firmware.sh qemu-rt`: print ticks = instructions x 2.0 cycles, the
// executor's events at their wake times whatever thread mode does; `firmware/src/board/qemu.rs`).
// Every job must run without an underrun (no executor stall, no interrupt that fell behind),
// its queue slack never below zero, and equal the simulation bit for bit as above (which the
// accelerated board equals too). CI runs the first layers of each model
// ([`REALTIME_CI_LAYERS`]) and a heavy part; the whole models are ignored tests
// (`cargo test --release -p strata-host --test hil_qemu -- --ignored qemu_realtime_`).

/// Layers of each model the CI's real-time runs print (bottom skins, the first perimeters
/// and infill: the layers whose computation runs while the first moves print).
const REALTIME_CI_LAYERS: i32 = 4;

/// The first `layers` layers of a placed model as a job of its own: the triangles that start
/// below their top (of the model as admission streams it to the 64 KB board: a simplified
/// model stays the same one), the model's height there (the slicer cuts the same sections;
/// the last layers get top skins, as a part cut there would).
fn first_layers(tris: &[Triangle], job: JobSpec, layers: i32) -> (Vec<Triangle>, JobSpec) {
    first_layers_within(tris, job, layers, 0.02)
}

/// [`first_layers`] of the model as admitted within `max_deviation_mm`.
fn first_layers_within(
    tris: &[Triangle],
    job: JobSpec,
    layers: i32,
    max_deviation_mm: f64,
) -> (Vec<Triangle>, JobSpec) {
    let caps = &strata::printer::BOARD_CAPACITIES;
    let (tris, job, _) = hil::admitted(tris, job, caps, max_deviation_mm)
        .unwrap_or_else(|e| panic!("admission for the 64 KB board: {e}"));
    let s = &job.settings;
    let top = s.first_layer_height_um + (layers - 1) * s.layer_height_um;
    let tris: Vec<Triangle> = tris.iter().filter(|t| t.z_min() < top).copied().collect();
    let job = JobSpec { model_height_um: top, triangles: tris.len() as u32, ..job };
    (tris, job)
}

/// The real-time board's figures of one job (its `RT` line), checked: no underrun, no
/// interrupt behind, a slack above zero throughout.
fn qemu_realtime(name: &str, tris: &[Triangle], job: JobSpec) {
    let label = format!("{name} in real time");
    let Some(costs) = qemu_job_on(Some("qemu-rt"), &label, tris, job, false) else { return };
    let rt = |key: &str| -> i64 {
        costs
            .text("RT", &[key])
            .and_then(|v| v.parse().ok())
            .unwrap_or_else(|| panic!("{label}: no `RT ... {key}=N` line after the job"))
    };
    let ms = |ticks: i64| ticks as f64 / 72_000.0;
    eprintln!(
        "{label}: CPI {:.1}, {} underruns (stall {:.3} ms, longest {:.3} ms; the first at {:.1} \
         ms, thread phase {} layer {}), minimum queue slack {:.3} ms, {} overruns",
        rt("cpi_x10") as f64 / 10.0,
        rt("underruns"),
        ms(rt("stall_ticks")),
        ms(rt("stall_max_ticks")),
        ms(rt("first_underrun_tick")),
        rt("first_underrun_phase"),
        rt("first_underrun_layer"),
        ms(rt("min_slack_ticks")),
        rt("overruns")
    );
    assert_eq!(rt("underruns"), 0, "{label}: the step queue ran dry mid-move");
    assert_eq!(rt("overruns"), 0, "{label}: the step interrupt fell behind its events");
    assert_eq!(rt("slack_samples"), 1, "{label}: the motion never ran ahead of the clock");
    assert!(rt("min_slack_ticks") > 0, "{label}: the queue's slack reached zero");
}

#[test]
fn qemu_realtime_first_layers() {
    for name in MODELS {
        let (tris, job) = load(name);
        let (tris, job) = first_layers(&tris, job, REALTIME_CI_LAYERS);
        qemu_realtime(&format!("{name} (first {REALTIME_CI_LAYERS} layers)"), &tris, job);
    }
    // 3DBenchy's first layers hold the most active triangles and contour points of the whole
    // model (the walls of the lettering under its hull).
    let (tris, job) = load(BENCHY);
    let (tris, job) = first_layers_within(&tris, job, REALTIME_CI_LAYERS, BENCHY_DEVIATION_MM);
    qemu_realtime(&format!("{BENCHY} (first {REALTIME_CI_LAYERS} layers)"), &tris, job);
}

/// A gear prism with `teeth` teeth (outer radius 25 mm, 2 mm deep) at the bed's middle,
/// `height` mm tall: every layer a loop of `4 x teeth` short edges (two wall triangles
/// each), with narrow teeth whose perimeters and infill are all short segments.
fn gear(teeth: usize, height: f64) -> Vec<Triangle> {
    use std::f64::consts::TAU;
    let (r_out, r_in) = (25.0, 23.0);
    let ring: Vec<[f64; 2]> = (0..4 * teeth)
        .map(|j| {
            // Each tooth: two corners out, two in (a trapezoid wave).
            let r = if j % 4 < 2 { r_out } else { r_in };
            let a = TAU * j as f64 / (4 * teeth) as f64;
            [110.0 + r * a.cos(), 110.0 + r * a.sin()]
        })
        .collect();
    let mut tris = strata_testkit::mesh::to_um(&strata_testkit::mesh::prism(&ring, 0.0, height));
    tris.sort_by_key(Triangle::z_min);
    tris
}

/// The heaviest layers the 64 KB board takes print in real time without an underrun too: a
/// [`gear`] of 48 teeth, 192 edges a layer (384 active triangles: the slicer holds 388),
/// four layers.
#[test]
fn qemu_realtime_heavy_layers() {
    let tris = gear(48, 0.8);
    let job = job_spec(&tris);
    qemu_realtime("a 48-tooth gear (192 edges a layer)", &tris, job);
}

/// A whole sample model in real time (the ignored tests below: the print takes its print
/// time of the device's clock, 10 to 50 minutes, about as long in wall time).
fn qemu_realtime_model(name: &str) {
    let (tris, job) = load(name);
    qemu_realtime(name, &tris, job);
}

#[test]
#[ignore = "a whole model in real time: run with --ignored"]
fn qemu_realtime_embodier_asc() {
    qemu_realtime_model("embodier_asc.stl");
}

#[test]
#[ignore = "a whole model in real time: run with --ignored"]
fn qemu_realtime_xyz_20mm_cube() {
    qemu_realtime_model("xyz_20mm_cube.stl");
}

#[test]
#[ignore = "a whole model in real time: run with --ignored"]
fn qemu_realtime_embodier_hotend_v2() {
    qemu_realtime_model("embodier_hotend_v2.stl");
}

#[test]
#[ignore = "a whole model in real time: run with --ignored"]
fn qemu_realtime_embodier_lm8uu() {
    qemu_realtime_model("embodier_LM8UU_8p2pi.stl");
}

/// An abort in the middle of a job on the 64 KB firmware (thread mode resets the step queue
/// while the feed interrupt generates steps and the step interrupt executes them): the
/// printer confirms it, the job ends `Aborted`, no step comes with the drivers off, and the
/// motion stops short of the whole job's steps (the simulation's).
#[test]
fn qemu_abort_mid_job_stops_the_motion() {
    let Some((qemu, elf)) = qemu_or_skip("hil_qemu abort", None) else { return };
    let tris = banded_cylinder(8_000.0, 3_000, 32, 200);
    let job = job_spec(&tris);
    let whole = simulate(&tris, &MachineConfig::default(), job, &SimOptions::default())
        .unwrap_or_else(|(e, _)| panic!("simulation: {e}"));
    let (mut q, uart) = Qemu::start(&qemu, &elf, false).unwrap_or_else(|e| panic!("{e}"));
    let mut clock = q.clock().unwrap_or_else(|e| panic!("{e}"));
    let mut port = Port::new(uart);
    port.get_mut().set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    port.get_mut().set_write_timeout(Some(Duration::from_millis(1))).unwrap();
    let mut conn = hil::connect(&mut port, &mut clock).unwrap_or_else(|e| panic!("{e}"));
    let abort = std::sync::atomic::AtomicBool::new(false);
    let r = hil::print_job_or_abort(
        &mut port,
        &mut conn,
        clock.clone(),
        Source::Model(&tris, job),
        QEMU_JOB_MS,
        &abort,
        |p| {
            if p.layer_hashes.len() >= 3 {
                abort.store(true, std::sync::atomic::Ordering::Relaxed);
            }
        },
    );
    let e = r.expect_err("the job was aborted");
    assert!(e.contains("the printer confirmed"), "{e}");
    q.wait_for(&mut clock, CLOSING_LINES_MS, |l| l.iter().any(|l| l.starts_with("MEM ")))
        .unwrap_or_else(|e| panic!("waiting for the closing lines: {e}"));
    let lines = q.lines();
    let aborted = DeviceState::Aborted as u32;
    assert!(
        lines.iter().any(|l| l.starts_with(&format!("JOB end state={aborted} "))),
        "no `JOB end state={aborted}` line: {:?}",
        lines.iter().filter(|l| l.starts_with("JOB")).collect::<Vec<_>>()
    );
    let costs = Costs::parse(&lines);
    let steps = costs.steps().expect("a STEPS line");
    assert_eq!(costs.get("STEPS", &["steps_disabled"]), Some(0), "steps with the drivers off");
    let (done, all): (u64, u64) = (steps.steps.iter().sum(), whole.steps.iter().sum());
    assert!(done > 0 && done < all, "{done} steps of the whole job's {all}");
    eprintln!("aborted after {done} of {all} steps");
}

/// A closed cylinder of radius `r` and height `h` um with `n` sides at (100 mm, 100 mm),
/// zmin-sorted.
fn cylinder(r: f64, h: i32, n: usize) -> Vec<Triangle> {
    banded_cylinder(r, h, n, h)
}

/// Budget of a job on the in-process printer, ms of its clock (one millisecond a turn of
/// its loop; the cylinder takes about 20 s of it).
const SIM_JOB_MS: u32 = 600_000;

/// The harness without QEMU: the in-process simulated printer behind a unix socket, clean
/// and through the lossy relay, gives the simulation's hashes.
#[test]
fn harness_against_the_in_process_printer() {
    let tris = cylinder(6_000.0, 1_000, 96);
    let job = job_spec(&tris);
    let mut reference = None;
    for faults in [None, Some(Faults::uniform(LOSS, 3))] {
        let label = if faults.is_some() { "in-process lossy" } else { "in-process clean" };
        let (dev, uart) = SimDevice::start(ServeOptions::new(CREALITY_CAPACITIES, 200)).unwrap();
        let (relay, port) = match faults {
            Some(f) => {
                let (r, p) = Relay::spawn(uart, f, BAUD, dev.clock()).unwrap();
                (Some(r), p)
            }
            None => (None, uart),
        };
        let mut port = Port::new(port);
        let work = Work::Model(&tris, job);
        let (run, r) =
            run_job(label, &mut port, dev.clock(), work, SIM_JOB_MS, reference.is_none());
        if let Some(r) = r {
            reference = Some(r.unwrap());
        }
        drop(port);
        let relay_stats = relay.map(|r| r.finish());
        let state = dev.finish();
        let progress = run
            .result
            .unwrap_or_else(|e| panic!("{label}: {e}; device {state:?}; relay {relay_stats:?}"));
        let state = state.unwrap();
        eprintln!(
            "{label}: {} layers in {:.1} s, host link {:?}, relay {:?}",
            progress.layer_hashes.len(),
            run.elapsed.as_secs_f64(),
            run.link,
            relay_stats
        );
        assert_eq!(state, DeviceState::Done);
        assert!(run.note.is_none());
        assert_same(label, reference.as_ref().unwrap(), &progress, None);
        if faults.is_some() {
            assert!(run.link.retransmits > 0 && run.link.bad_frames > 0, "{:?}", run.link);
        }
    }
}

/// The four models through the harness into the in-process simulated printer (host-sized
/// toolpath stage, the Creality board's slicer capacities), clean: the harness's checks at
/// model scale without QEMU (about 6 minutes in a debug build).
#[test]
#[ignore = "slow (whole models in a debug build): the harness at model scale without QEMU"]
fn harness_in_process_models() {
    for name in MODELS {
        let (tris, job) = load(name);
        let (dev, port) = SimDevice::start(ServeOptions::new(CREALITY_CAPACITIES, 1000)).unwrap();
        let mut port = Port::new(port);
        let work = Work::Model(&tris, job);
        let (run, r) = run_job(name, &mut port, dev.clock(), work, SIM_JOB_MS, true);
        let progress = run.result.unwrap_or_else(|e| panic!("{name}: {e}"));
        drop(port);
        dev.finish().unwrap();
        let reference = r.unwrap().unwrap();
        eprintln!("{name}: {} layers in {:.1} s", reference.layers, run.elapsed.as_secs_f64());
        assert_same(name, &reference, &progress, None);
    }
}

/// A QEMU that cannot run the image is an error, never a hang (QEMU accepts the UART
/// connection before it loads the image, then exits: the clock says so).
#[test]
fn a_missing_image_is_an_error_not_a_hang() {
    let Some(qemu) = hil::find_qemu() else { return };
    let missing = std::env::temp_dir().join("strata-hil-no-such-image.elf");
    let t0 = Instant::now();
    let e = match Qemu::start(&qemu, &missing, false) {
        Err(e) => e,
        Ok((mut q, _port)) => {
            let e = q.clock().err().expect("no clock without an image");
            assert!(q.wait_exit(Duration::from_secs(60)), "qemu did not exit: {e}");
            format!("{e}; qemu: {}", q.stderr())
        }
    };
    eprintln!("{e} ({:.1} s)", t0.elapsed().as_secs_f64());
    assert!(e.contains("strata-hil-no-such-image"), "{e}");
}

/// A host's clock that stops for good once `killed` is set: the host never talks again, as
/// if its process had been killed.
struct Killable<'a, C> {
    clock: C,
    killed: &'a std::sync::atomic::AtomicBool,
}

impl<C: LinkClock> LinkClock for Killable<'_, C> {
    fn now_ms(&mut self) -> Result<u32, String> {
        if self.killed.load(std::sync::atomic::Ordering::Relaxed) {
            return Err("the host was killed".into());
        }
        self.clock.now_ms()
    }
}

/// A streamed print whose host is killed mid-job, resumed at once by a new host (`strata
/// print --resume`, a new link session): the firmware parks, reheats, brings the nozzle back
/// and prints on. Every layer hash either host heard equals the host simulation of the
/// uninterrupted job, the new host hears every layer after the one where the print stopped,
/// and the motors end where the uninterrupted job's did.
#[test]
fn qemu_killed_host_resumed() {
    let label = "hil_qemu killed host resumed";
    let Some((qemu, elf)) = qemu_or_skip(label, None) else { return };
    // 40 layers: the printer holds a few of them ahead of the motion, not the whole model.
    let tris = banded_cylinder(4_000.0, 8_000, 16, 200);
    let job = job_spec(&tris);
    let machine = MachineConfig::default();
    let echo = std::env::var_os("STRATA_HIL_ECHO").is_some();
    let (mut q, uart) = Qemu::start(&qemu, &elf, echo).unwrap_or_else(|e| panic!("{label}: {e}"));
    let mut clock = q.clock().unwrap_or_else(|e| panic!("{label}: {e}"));
    let mut port = Port::new(uart);
    port.get_mut().set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    port.get_mut().set_write_timeout(Some(Duration::from_millis(1))).unwrap();
    let killed = std::sync::atomic::AtomicBool::new(false);
    let mut first = {
        let mut host_clock = Killable { clock: clock.clone(), killed: &killed };
        let mut conn = hil::connect(&mut port, &mut host_clock).expect("handshake");
        let opts = SimOptions { capacities: conn.greeting.capacities, ..SimOptions::default() };
        let reference = simulate(&tris, &machine, job, &opts).expect("reference simulation");
        let mut last = Progress::default();
        let source = Source::Model(&tris, job);
        let r = hil::print_job(&mut port, &mut conn, &mut host_clock, source, QEMU_JOB_MS, |p| {
            // Killed once the printer has printed two layers.
            if p.status.is_some_and(|s| s.layer >= 2) {
                killed.store(true, std::sync::atomic::Ordering::Relaxed);
            }
            last = p.clone();
        });
        let e = r.expect_err("the first host was killed");
        assert!(e.contains("killed"), "{label}: {e}");
        assert!(last.triangles_sent < tris.len(), "{label}: killed after the whole model");
        (last, reference)
    };
    let reference = first.1;
    let first_heard = std::mem::take(&mut first.0.layer_hashes);
    // The new host, at once: it opens its own session and resumes.
    let mut conn = hil::connect(&mut port, &mut clock).expect("the new host's handshake");
    let source = Source::Model(&tris, job);
    let resumed = hil::resume_job(&mut port, &mut conn, &mut clock, source, QEMU_JOB_MS, |_| {})
        .unwrap_or_else(|e| {
            panic!(
                "{label}: resume: {e}\n  qemu output (last lines): {:?}",
                q.lines().iter().rev().take(12).rev().collect::<Vec<_>>()
            )
        });
    let parked = resumed.parked.expect("the printer said where it parked");
    let stop = parked.layer as usize;
    eprintln!(
        "{label}: killed with {} of {} triangles sent and {} layers heard; parked after layer \
         {stop} with {} triangles taken; the new host heard {} layers",
        first.0.triangles_sent,
        tris.len(),
        first_heard.iter().filter(|&&h| h != 0).count(),
        parked.taken,
        resumed.layer_hashes.iter().filter(|&&h| h != 0).count(),
    );
    assert!(stop + 1 < reference.layers as usize, "{label}: stopped after the last layer");
    for (layer, &want) in reference.layer_hashes.iter().enumerate() {
        for heard in [&first_heard, &resumed.layer_hashes] {
            let got = heard.get(layer).copied().unwrap_or(0);
            assert!(got == 0 || got == want, "{label}: layer {layer}: {got:x} vs {want:x}");
        }
        if layer > stop {
            assert_eq!(resumed.layer_hashes.get(layer), Some(&want), "{label}: layer {layer}");
        }
    }
    assert_eq!(resumed.status.map(|s| s.state), Some(DeviceState::Done));
    let report = resumed.job_report.expect("a job report");
    assert_eq!(report.positions, reference.positions, "{label}: final positions");
    q.wait_for(&mut clock, CLOSING_LINES_MS, |l| l.iter().any(|l| l.starts_with("MEM ")))
        .unwrap_or_else(|e| panic!("{label}: waiting for the closing lines: {e}"));
    let steps = Costs::parse(&q.lines()).steps().expect("a STEPS line");
    assert_eq!(steps.positions, reference.positions, "{label}: the motors' final positions");
}

/// The firmware reads the QEMU board's SD card (SSI0, SPI mode) at start-up and lists its
/// root directory as the image holds it (names long and short, sizes, a directory): FAT16
/// and FAT32, with and without a partition table; a blank card and an empty slot are said so.
#[test]
fn qemu_card_listing() {
    let label = "hil_qemu card listing";
    let Some((qemu, elf)) = qemu_or_skip(label, None) else { return };
    let models = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/models");
    let cube = std::fs::read(models.join("xyz_20mm_cube.stl")).expect("the cube model");
    let gcode = std::fs::read(
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/data/gcode/xyz_20mm_cube_prusaslicer.gcode"),
    )
    .expect("the G-code fixture");
    let files: [(&str, &[u8]); 3] = [
        ("xyz_20mm_cube.stl", &cube),
        ("xyz_20mm_cube_prusaslicer.gcode", &gcode),
        ("EMPTY.TXT", b""),
    ];
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "FAT16",
            Some(strata_testkit::card::image(fatfs::FatType::Fat16, 32, &files, false)),
            "fat=16",
        ),
        (
            "FAT32 partitioned",
            Some(strata_testkit::card::image(fatfs::FatType::Fat32, 64, &files, true)),
            "fat=32",
        ),
        ("blank", Some(vec![0u8; 32 << 20]), "not formatted"),
        ("empty slot", None, "no card in the slot"),
    ];
    for (what, image, want) in cases {
        let path = dir.path().join(format!("{what}.img"));
        if let Some(image) = &image {
            std::fs::write(&path, image).unwrap();
        }
        let card = image.as_ref().map(|_| path.as_path());
        let (mut q, _uart) = Qemu::start_with_card(&qemu, &elf, false, card)
            .unwrap_or_else(|e| panic!("{label} {what}: {e}"));
        let mut clock = q.clock().unwrap_or_else(|e| panic!("{label} {what}: {e}"));
        let done = |l: &[String]| {
            l.iter().any(|l| l.starts_with("CARD end") || l.starts_with("CARD none"))
        };
        q.wait_for(&mut clock, 10_000, done).unwrap_or_else(|e| panic!("{label} {what}: {e}"));
        let lines: Vec<String> = q.lines().into_iter().filter(|l| l.starts_with("CARD")).collect();
        eprintln!("{label} {what}: {lines:?}");
        let last = lines.last().unwrap();
        assert!(last.contains(want), "{what}: {last}");
        if image.is_none() || what == "blank" {
            continue;
        }
        let mut listed = lines[..lines.len() - 1].to_vec();
        listed.sort();
        let mut expected: Vec<String> =
            files.iter().map(|(name, data)| format!("CARD {} {name}", data.len())).collect();
        expected.push("CARD dir old prints".into());
        expected.sort();
        assert_eq!(listed, expected, "{what}");
        assert!(last.contains("files=3"), "{what}: {last}");
    }
}

/// Printing from the card with no host (issue 22's acceptance): a FAT32 card holding
/// `xyz_20mm_cube.stl` and PrusaSlicer's G-code of it. The host lists the card (every file,
/// its size), uploads a file and removes the STL (the card written over SSI0: `fatfs` reads
/// the image back once QEMU is gone), starts the G-code with one command and goes silent for
/// good (the cable pulled): the firmware reads the file from the card to its end, and every
/// step edge (axis, direction, tick), the steps per axis, the final positions and the print
/// time equal the host simulation of the same text streamed. (The STL's own print:
/// `qemu_stl_from_card_host_gone`.)
#[test]
fn qemu_gcode_from_card_host_gone() {
    let label = "hil_qemu G-code from the card, host gone";
    let Some((qemu, elf)) = qemu_or_skip(label, None) else { return };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let stl = std::fs::read(root.join("../../shared/models/xyz_20mm_cube.stl")).expect("the cube");
    let gcode_name = "xyz_20mm_cube_prusaslicer.gcode";
    let gcode = std::fs::read(root.join("../tests/data/gcode").join(gcode_name)).expect("G-code");
    let files: [(&str, &[u8]); 2] = [("xyz_20mm_cube.stl", &stl), (gcode_name, &gcode)];
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("card.img");
    std::fs::write(&image, strata_testkit::card::image(fatfs::FatType::Fat32, 64, &files, true))
        .unwrap();
    let machine = MachineConfig::default();
    let scan = gcode_file::scan(&gcode, &machine).unwrap();
    let reference =
        simulate_source(Source::Gcode(&gcode, scan.spec), &machine, &SimOptions::default())
            .unwrap_or_else(|(e, _)| panic!("{label}: reference: {e}"));
    let (mut q, mut clock, mut port, mut conn) = with_card(label, &qemu, &elf, &image);
    let listed = strata_host::serial::card_list(&mut port, &mut conn.ep, &mut clock)
        .unwrap_or_else(|e| panic!("{label}: card ls: {e}"));
    let mut got: Vec<(String, u32, bool)> =
        listed.into_iter().map(|e| (e.name, e.size, e.is_dir)).collect();
    got.sort();
    let mut want: Vec<(String, u32, bool)> =
        files.iter().map(|(n, d)| (n.to_string(), d.len() as u32, false)).collect();
    want.push(("old prints".into(), 0, true));
    want.sort();
    assert_eq!(got, want, "{label}: the card's listing");
    // A file uploaded (several clusters: SD block writes, the FAT writer), the STL removed.
    let uploaded: Vec<u8> =
        (0..3000).flat_map(|i| format!("G1 X{} Y10\n", i % 200).into_bytes()).collect();
    let write = CardWrite::upload("uploaded square.gcode", &uploaded);
    let n = strata_host::serial::card_write(&mut port, &mut conn.ep, &mut clock, write, |_| {})
        .unwrap_or_else(|e| panic!("{label}: upload: {e}"));
    assert_eq!(n as usize, uploaded.len());
    let remove = CardWrite::remove("xyz_20mm_cube.stl");
    strata_host::serial::card_write(&mut port, &mut conn.ep, &mut clock, remove, |_| {})
        .unwrap_or_else(|e| panic!("{label}: rm: {e}"));
    let listed = strata_host::serial::card_list(&mut port, &mut conn.ep, &mut clock)
        .unwrap_or_else(|e| panic!("{label}: card ls: {e}"));
    let mut got: Vec<(String, u32)> = listed.into_iter().map(|e| (e.name, e.size)).collect();
    got.sort();
    let mut want = vec![
        ("old prints".to_string(), 0),
        (gcode_name.to_string(), gcode.len() as u32),
        ("uploaded square.gcode".to_string(), uploaded.len() as u32),
    ];
    want.sort();
    assert_eq!(got, want, "{label}: the listing after the upload and the removal");
    let lines = print_detached(label, &mut q, &mut clock, &mut port, &mut conn, gcode_name);
    let steps = Costs::parse(&lines).steps().expect("a STEPS line");
    assert_eq!(steps.steps, reference.steps, "{label}: steps per axis X, Y, Z, E");
    assert_eq!(steps.positions, reference.positions, "{label}: final positions");
    assert_eq!(steps.print_ticks, Some(reference.print_ticks), "{label}: print time, ticks");
    assert_eq!(steps.hash, Some(reference.board_hash), "{label}: every step edge");
    // The card as `fatfs` reads it once QEMU is gone: the upload's bytes, no STL.
    drop(q);
    let back = card_file(&image, "uploaded square.gcode").expect("the uploaded file");
    assert!(back == uploaded, "{label}: the uploaded file reads back as sent");
    assert!(card_file(&image, "xyz_20mm_cube.stl").is_none(), "{label}: the STL is gone");
    eprintln!(
        "{label}: {} bytes read from the card, {:.1} s of print, {} steps, as streamed",
        gcode.len(),
        reference.print_time_s,
        steps.steps.iter().sum::<u64>()
    );
}

/// Starts the card's file `name` with one command and goes silent for good, as an unplugged
/// cable (what the printer sends is read and dropped: QEMU's UART would otherwise wait for
/// room in the socket) until the firmware's closing lines; checks that the job ended done and
/// that no step came before the board saw it. The firmware's lines.
fn print_detached(
    label: &str,
    q: &mut Qemu,
    clock: &mut hil::QemuClock,
    port: &mut Port<UnixStream>,
    conn: &mut hil::Connected,
    name: &str,
) -> Vec<String> {
    let start = Source::Card { name, detach: true };
    let started = hil::print_job(port, conn, &mut *clock, start, QEMU_JOB_MS, |_| {})
        .unwrap_or_else(|e| panic!("{label}: start: {e}"));
    assert!(started.card_file_bytes.is_some(), "{label}: started");
    let stop = std::sync::atomic::AtomicBool::new(false);
    let mut sink = port.get_mut().try_clone().unwrap();
    let ended = std::thread::scope(|s| {
        s.spawn(|| {
            let mut buf = [0u8; 4096];
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                let _ = std::io::Read::read(&mut sink, &mut buf);
            }
        });
        let ended = q.wait_for(clock, QEMU_JOB_MS, |l| l.iter().any(|l| l.starts_with("MEM ")));
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        ended
    })
    .unwrap_or_else(|e| panic!("{label}: waiting for the job's end: {e}"));
    let lines = q.lines();
    let jobs: Vec<&String> = lines.iter().filter(|l| l.starts_with("JOB")).collect();
    assert!(ended, "{label}: the job did not end: {jobs:?}");
    let done = DeviceState::Done as u32;
    assert!(jobs.iter().any(|l| l.starts_with(&format!("JOB end state={done} "))), "{jobs:?}");
    // No step came before the board saw the job (they would go with its queue's reset).
    assert!(
        jobs.iter().any(|l| l.starts_with("JOB start") && l.ends_with(" early_steps=0")),
        "{jobs:?}"
    );
    lines
}

/// An STL copied to the card (issue 22's acceptance, with `qemu_gcode_from_card_host_gone`):
/// `xyz_20mm_cube.stl` on a FAT32 card; one start command and the host goes silent for good.
/// The firmware places and sorts it on the card, writes its job and prints it: every step
/// edge, the steps per axis, the final positions and the print time equal the host
/// simulation of the same model placed and streamed (default settings), and the stack stays
/// clear of the statics.
#[test]
fn qemu_stl_from_card_host_gone() {
    let label = "hil_qemu STL from the card, host gone";
    let Some((qemu, elf)) = qemu_or_skip(label, None) else { return };
    let name = "xyz_20mm_cube.stl";
    let path = strata_testkit::models::dir().join(name);
    let stl = std::fs::read(&path).expect("the cube");
    // The card of `qemu_gcode_from_card_host_gone`: the cube and PrusaSlicer's G-code of it.
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let gcode_name = "xyz_20mm_cube_prusaslicer.gcode";
    let gcode = std::fs::read(root.join("../tests/data/gcode").join(gcode_name)).expect("G-code");
    let files: [(&str, &[u8]); 2] = [(name, &stl), (gcode_name, &gcode)];
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("card.img");
    std::fs::write(&image, strata_testkit::card::image(fatfs::FatType::Fat32, 64, &files, true))
        .unwrap();
    // The reference before QEMU starts (slow in a debug build): an emulator whose UART
    // nobody reads meanwhile stalls once the socket is full.
    let (tris, job) = load(name);
    let caps = strata::printer::BOARD_CAPACITIES;
    let opts = SimOptions { capacities: caps, ..SimOptions::default() };
    let reference = simulate_source(Source::Model(&tris, job), &MachineConfig::default(), &opts)
        .unwrap_or_else(|(e, _)| panic!("{label}: reference: {e}"));
    let (mut q, mut clock, mut port, mut conn) = with_card(label, &qemu, &elf, &image);
    let announced = Capacities { ram_bytes: caps.ram_bytes, ..conn.greeting.capacities };
    assert_eq!(announced, caps, "{label}: the board's capacities");
    let lines = print_detached(label, &mut q, &mut clock, &mut port, &mut conn, name);
    let costs = Costs::parse(&lines);
    let steps = costs.steps().expect("a STEPS line");
    assert_eq!(steps.steps, reference.steps, "{label}: steps per axis X, Y, Z, E");
    assert_eq!(steps.positions, reference.positions, "{label}: final positions");
    assert_eq!(steps.print_ticks, Some(reference.print_ticks), "{label}: print time, ticks");
    assert_eq!(steps.hash, Some(reference.board_hash), "{label}: every step edge");
    let (used, size) = (costs.get("MEM", &["stack_hwm"]), costs.get("MEM", &["stack_size"]));
    let (Some(used), Some(size)) = (used, size) else { panic!("{label}: no MEM line") };
    assert!(used + RAM_HEADROOM <= size, "{label}: the stack used {used} of its {size} B");
    // The card as `fatfs` reads it once QEMU is gone: the job the firmware wrote holds the
    // host's placed triangles in the host's order; the sort's runs file is gone.
    drop(q);
    let written = card_file(&image, strata::printer::STL_JOB_NAME).expect("the STL's job");
    assert_eq!(job_file_triangles(&written), tris, "{label}: the job's triangles");
    assert!(card_file(&image, strata::card::zsort::RUNS_NAME).is_none(), "{label}: runs");
    eprintln!(
        "{label}: {} triangles sorted on the card, {} layers, stack {used} of {size} B, as \
         streamed",
        tris.len(),
        reference.layers
    );
}

/// The file `name` of the partitioned card `image` as `fatfs` reads it (QEMU gone), if any.
fn card_file(image: &std::path::Path, name: &str) -> Option<Vec<u8>> {
    let bytes = std::fs::read(image).unwrap();
    let start = strata_testkit::card::PARTITION_START_BLOCK as usize * 512;
    let mut vol = std::io::Cursor::new(bytes[start..].to_vec());
    let fs = fatfs::FileSystem::new(&mut vol, fatfs::FsOptions::new()).unwrap();
    let mut f = fs.root_dir().open_file(name).ok()?;
    let mut back = Vec::new();
    std::io::Read::read_to_end(&mut f, &mut back).unwrap();
    Some(back)
}

/// The triangles of a job file's batches, in order.
fn job_file_triangles(file: &[u8]) -> Vec<Triangle> {
    use strata::protocol::{job_file, Message, MAX_PAYLOAD};
    job_file::check_magic(file).expect("a job file");
    let mut rest = &file[job_file::MAGIC.len()..];
    let mut tris = Vec::new();
    let mut payload = [0u8; MAX_PAYLOAD];
    while !rest.is_empty() {
        let read = |out: &mut [u8]| std::io::Read::read(&mut rest, out);
        let n = job_file::read_record(read, &mut payload).expect("a whole record");
        if let Ok(Message::Triangles(batch)) = Message::decode(&payload[..n]) {
            tris.extend(batch.iter());
        }
    }
    tris
}

/// QEMU with `image` as its SD card, its clock, and a link to its firmware (`label` names a
/// failure).
fn with_card(
    label: &str,
    qemu: &std::path::Path,
    elf: &std::path::Path,
    image: &std::path::Path,
) -> (Qemu, hil::QemuClock, Port<UnixStream>, hil::Connected) {
    let echo = std::env::var_os("STRATA_HIL_ECHO").is_some();
    let (mut q, uart) = Qemu::start_with_card(qemu, elf, echo, Some(image))
        .unwrap_or_else(|e| panic!("{label}: {e}"));
    let mut clock = q.clock().unwrap_or_else(|e| panic!("{label}: {e}"));
    let mut port = Port::new(uart);
    port.get_mut().set_read_timeout(Some(Duration::from_millis(1))).unwrap();
    port.get_mut().set_write_timeout(Some(Duration::from_millis(1))).unwrap();
    let conn = hil::connect(&mut port, &mut clock).unwrap_or_else(|e| panic!("{label}: {e}"));
    (q, clock, port, conn)
}

/// `strata upload MODEL` then `strata print --from-card`: `embodier_hotend_v2.stl`'s job,
/// admitted as `strata print` admits it, is written to an empty card over the link; printed
/// from the card (the host following its reports), it gives every layer hash, the job report,
/// the steps and every step edge of the streamed simulation, and its stack stays clear of
/// the statics.
#[test]
fn qemu_model_job_uploaded_prints_from_card_as_streamed() {
    let label = "hil_qemu model job uploaded, printed from the card";
    let Some((qemu, elf)) = qemu_or_skip(label, None) else { return };
    let dir = tempfile::tempdir().unwrap();
    let image = dir.path().join("card.img");
    std::fs::write(&image, strata_testkit::card::image(fatfs::FatType::Fat32, 64, &[], true))
        .unwrap();
    let machine = MachineConfig::default();
    // Admission and the reference before QEMU starts (slow in a debug build): an emulator
    // whose UART nobody reads meanwhile stalls once the socket is full.
    let (tris, job) = load("embodier_hotend_v2.stl");
    let caps = strata::printer::BOARD_CAPACITIES;
    let admitted = strata_host::admission::admit_job(&tris, &machine, &job, &caps, 0.02)
        .unwrap_or_else(|e| panic!("{label}: admission: {e}"));
    assert!(
        matches!(admitted, strata_host::admission::Admission::Unchanged(_)),
        "{label}: the model fits unchanged"
    );
    let opts = SimOptions { capacities: caps, ..SimOptions::default() };
    let reference = simulate_source(Source::Model(&tris, job), &machine, &opts)
        .unwrap_or_else(|(e, _)| panic!("{label}: reference: {e}"));
    let (mut q, mut clock, mut port, mut conn) = with_card(label, &qemu, &elf, &image);
    // The same capacities (the RAM they take differs between the host's layout and the
    // board's).
    let announced = Capacities { ram_bytes: caps.ram_bytes, ..conn.greeting.capacities };
    assert_eq!(announced, caps, "{label}: the board's capacities");
    let file = strata_host::job_file::encode(&job, &tris).unwrap();
    let name = "embodier_hotend_v2.sjob";
    let write = CardWrite::upload(name, &file);
    let n = strata_host::serial::card_write(&mut port, &mut conn.ep, &mut clock, write, |_| {})
        .unwrap_or_else(|e| panic!("{label}: upload: {e}"));
    assert_eq!(n as usize, file.len(), "{label}: bytes on the card");
    let source = Source::Card { name, detach: false };
    let progress = hil::print_job(&mut port, &mut conn, &mut clock, source, QEMU_JOB_MS, |_| {})
        .unwrap_or_else(|e| panic!("{label}: {e}"));
    assert_eq!(progress.card_file_bytes, Some(file.len() as u32));
    q.wait_for(&mut clock, CLOSING_LINES_MS, |l| l.iter().any(|l| l.starts_with("MEM ")))
        .unwrap_or_else(|e| panic!("{label}: waiting for the closing lines: {e}"));
    let lines = q.lines();
    let costs = Costs::parse(&lines);
    assert_same(label, &reference, &progress, Some(&costs));
    assert_eq!(costs.steps().and_then(|s| s.hash), Some(reference.board_hash), "{label}: edges");
    let jobs: Vec<&String> = lines.iter().filter(|l| l.starts_with("JOB")).collect();
    assert!(
        jobs.iter().any(|l| l.starts_with("JOB start") && l.ends_with(" early_steps=0")),
        "{jobs:?}"
    );
    let (used, size) = (costs.get("MEM", &["stack_hwm"]), costs.get("MEM", &["stack_size"]));
    let (Some(used), Some(size)) = (used, size) else { panic!("{label}: no MEM line") };
    assert!(used + RAM_HEADROOM <= size, "{label}: the stack used {used} of its {size} B");
    eprintln!(
        "{label}: {} triangles, {} bytes on the card, {} layers, stack {used} of {size} B, as \
         streamed",
        tris.len(),
        file.len(),
        reference.layers
    );
}

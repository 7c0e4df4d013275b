//! `strata print` against the simulated printer over a real pseudo-terminal pair
//! (`serialport::TTYPort::pair`): the device serves the master end in a thread of the test,
//! the `strata` binary opens the slave end by name through the `serialport` crate.

#![cfg(unix)]

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use assert_cmd::Command;
use serialport::{SerialPort, TTYPort};
use strata::machine::MachineConfig;
use strata::printer::CREALITY_CAPACITIES;
use strata::protocol::{Capacities, DeviceState};
use strata_host::card_image::ImageCard;
use strata_host::serial::{serve_device, DeviceClock, ServeOptions};
use strata_testkit::mesh::{holed_block, sphere};
use strata_testkit::stl::write_mesh;

/// The link timeout of both ends in these tests, s: the simulated printer serves in real
/// time on the test's own cores, so a machine busy elsewhere can hold either end for a
/// while; a real printer answers within the protocol's 3 s. Also the hang guard's unit.
const LINK_TIMEOUT_S: u32 = 60;

/// The device double's options: `caps`, motion `speedup` times real time, the tests' link
/// timeout.
fn device(caps: Capacities, speedup: u64) -> ServeOptions {
    let mut o = ServeOptions::new(caps, speedup);
    o.link.dead_ms = LINK_TIMEOUT_S * 1000;
    o
}

/// Runs `strata print` with `args` against a simulated printer announcing `caps`; returns the
/// command's output and the device's final state.
fn print_over_pty(args: &[&str], caps: Capacities) -> (std::process::Output, DeviceState) {
    print_over_pty_with(args, device(caps, 400))
}

/// [`print_over_pty`] with the device's options.
fn print_over_pty_with(args: &[&str], opts: ServeOptions) -> (std::process::Output, DeviceState) {
    let (out, state) = serve_on_pty(opts, None, |name, _| {
        let mut cmd = Command::cargo_bin("strata").unwrap();
        cmd.args(["print", "--port", name]).args(args);
        if !args.contains(&"--link-timeout") {
            cmd.args(["--link-timeout", &LINK_TIMEOUT_S.to_string()]);
        }
        cmd.timeout(hang_guard()).output().unwrap()
    });
    let state = state.unwrap_or_else(|e| {
        panic!("device: {e}; strata: {}", String::from_utf8_lossy(&out.stderr))
    });
    (out, state)
}

/// Serves a simulated printer with `opts` on the master end of a new pseudo-terminal pair
/// (on a thread with a big stack) while `host(slave name, stop)` runs, then stops it (a host
/// that panics sets `stop` first, or the device serves on); returns what `host` returned and
/// the device's final state.
fn serve_on_pty<R>(
    opts: ServeOptions,
    card: Option<ImageCard>,
    host: impl FnOnce(&str, &AtomicBool) -> R,
) -> (R, Result<DeviceState, String>) {
    let (mut master, slave) = TTYPort::pair().expect("pseudo-terminal pair");
    master.set_timeout(Duration::from_millis(1)).unwrap();
    let name = slave.name().expect("slave name");
    // The binary opens the slave end itself (exclusively).
    drop(slave);
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        let device = std::thread::Builder::new()
            .stack_size(512 << 20)
            .spawn_scoped(s, || {
                let machine = MachineConfig::default();
                serve_device(&mut master, &machine, opts, DeviceClock::Wall, &stop, card)
            })
            .unwrap();
        let got = host(&name, &stop);
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        (got, device.join().unwrap())
    })
}

#[test]
fn print_streams_a_model_to_the_simulated_printer_over_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let (out, state) =
        print_over_pty(&[model.to_str().unwrap(), "--skirt-loops", "0"], CREALITY_CAPACITIES);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout {stdout}\nstderr {stderr}");
    assert!(stdout.contains("printed 6 layers"), "{stdout}");
    assert!(stderr.contains("printer: 1024 active triangles"), "{stderr}");
    assert_eq!(state, DeviceState::Done);
}

#[test]
fn print_refuses_a_model_the_printer_cannot_hold() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    // A printer with room for 4 triangles: the 32-triangle block cannot be simplified that far.
    let tiny = Capacities { active_triangles: 4, contour_points: 4, ..CREALITY_CAPACITIES };
    let (out, _) = print_over_pty(&[model.to_str().unwrap()], tiny);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("does not fit the printer"), "{stderr}");
}

#[test]
fn print_fails_cleanly_when_nobody_answers() {
    let (_master, slave) = TTYPort::pair().expect("pseudo-terminal pair");
    let name = slave.name().unwrap();
    drop(slave);
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let out = Command::cargo_bin("strata")
        .unwrap()
        .args(["print", model.to_str().unwrap(), "--port", &name])
        .timeout(Duration::from_secs(30))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("no answer from the printer"), "{stderr}");
}

/// Ctrl-C mid-print: the real binary, a simulated printer printing in near real time (the
/// holed block takes about 10 s at 5x), SIGINT once the plain progress lines (stderr is a
/// pipe, not a terminal) show a layer and an ETA. The CLI sends Abort, gets the printer's
/// confirmation and exits non-zero saying so; the device ends Aborted; nothing hangs.
#[test]
fn ctrl_c_aborts_the_print_and_the_printer() {
    use std::io::{BufRead, BufReader};
    use std::process::{Command as Std, Stdio};
    use std::sync::atomic::Ordering;
    use std::time::Instant;

    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let ((status, lines, stdout, sent), state) =
        serve_on_pty(device(CREALITY_CAPACITIES, 5), None, |name, stop| {
            let timeout = LINK_TIMEOUT_S.to_string();
            let mut child = Std::new(env!("CARGO_BIN_EXE_strata"))
                .args(["print", model.to_str().unwrap(), "--port", name, "--skirt-loops", "0"])
                .args(["--link-timeout", &timeout])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap();
            let pid = child.id();
            let stderr = child.stderr.take().unwrap();
            let (tx, rx) = std::sync::mpsc::channel::<String>();
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
            let t0 = Instant::now();
            let mut lines: Vec<String> = Vec::new();
            let mut sent = false;
            let status = loop {
                while let Ok(l) = rx.try_recv() {
                    lines.push(l);
                }
                if !sent && lines.iter().any(|l| eta_known_line(l)) {
                    let ok = Std::new("kill").args(["-INT", &pid.to_string()]).status().unwrap();
                    assert!(ok.success());
                    sent = true;
                }
                if let Some(st) = child.try_wait().unwrap() {
                    break st;
                }
                if t0.elapsed() > hang_guard() {
                    let _ = child.kill();
                    stop.store(true, Ordering::Relaxed);
                    panic!("strata print hung (SIGINT sent: {sent}): {lines:#?}");
                }
                std::thread::sleep(Duration::from_millis(20));
            };
            // The rest of stderr.
            std::thread::sleep(Duration::from_millis(100));
            while let Ok(l) = rx.try_recv() {
                lines.push(l);
            }
            let mut stdout = String::new();
            std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut stdout).unwrap();
            (status, lines, stdout, sent)
        });
    assert!(sent, "no progress line with an ETA: {lines:#?}");
    let state = state.unwrap();
    let all = lines.join("\n");
    eprintln!("{all}");
    assert!(!status.success(), "{all}\n{stdout}");
    // The printer confirmed the abort (the CLI says so only on the printer's Aborted
    // status; without it, it says it was told).
    assert!(all.contains("aborted by the user (Ctrl-C): the printer confirmed"), "{all}");
    assert!(!stdout.contains("printed"), "{stdout}");
    assert_eq!(state, DeviceState::Aborted, "{all}");
    // The plain progress lines: triangles, bytes, layer, state and ETA.
    let p = lines.iter().find(|l| eta_known_line(l)).unwrap();
    for what in ["32/32 triangles (100%)", " B sent", "| layer ", "/6 |", "Printing", "ETA "] {
        assert!(p.contains(what), "{what}: {p}");
    }
}

/// How long a test may wait for `strata print` before it counts as hung, wall time: several
/// link timeouts.
/// `strata ARGS` on the printer at port `name` (the tests' link timeout, the hang guard).
fn strata(name: &str, args: &[&str]) -> std::process::Output {
    let mut cmd = Command::cargo_bin("strata").unwrap();
    cmd.args(args).args(["--port", name, "--link-timeout", &LINK_TIMEOUT_S.to_string()]);
    cmd.timeout(hang_guard()).output().unwrap()
}

/// What a command printed, out then err.
fn text(o: &std::process::Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn hang_guard() -> Duration {
    Duration::from_secs(5 * LINK_TIMEOUT_S as u64)
}

fn eta_known_line(l: &str) -> bool {
    l.starts_with("progress: ")
        && l.split("ETA ").nth(1).is_some_and(|t| t.starts_with(|c: char| c.is_ascii_digit()))
}

/// A UV sphere of radius 5 mm resting on z = 0, `lon` x `lat` ([`sphere`]).
fn sphere_on_the_bed(lon: usize, lat: usize) -> Vec<strata_testkit::mesh::TriMm> {
    sphere([0.0, 0.0, 5.0], 5.0, lon, lat)
}

/// Admission that takes longer than the link's dead time (a fine sphere simplified for a
/// small printer: seconds in a debug build) happens after the handshake: the link must stay
/// alive meanwhile, or the printer fails the job for a dead link.
#[test]
fn a_slow_admission_keeps_the_link_alive() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("sphere.stl");
    write_mesh(&model, &sphere_on_the_bed(96, 48));
    let small = Capacities { active_triangles: 150, contour_points: 150, ..CREALITY_CAPACITIES };
    let (out, state) = print_over_pty(
        &[model.to_str().unwrap(), "--skirt-loops", "0", "--max-deviation", "0.1"],
        small,
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout {stdout}\nstderr {stderr}");
    assert!(stderr.contains("simplified from 9024 to"), "{stderr}");
    assert_eq!(state, DeviceState::Done);
}

/// A printer that stops reading mid-job (busy elsewhere) for longer than the pseudo-terminal
/// takes to fill: the host's writes are refused (`TimedOut` after the port's 2 ms) again and
/// again, wait in its outbox while reads go on, and the print completes once the printer
/// reads again. (The test below shows that such a stall does fill the terminal.)
#[test]
fn a_printer_that_stops_reading_for_a_while_still_completes_the_print() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("sphere.stl");
    write_mesh(&model, &sphere_on_the_bed(48, 24));
    let mut opts = device(CREALITY_CAPACITIES, 400);
    opts.stall_reads_ms = STALL_FILLS_THE_TERMINAL_MS;
    let (out, state) = print_over_pty_with(&[model.to_str().unwrap(), "--skirt-loops", "0"], opts);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout {stdout}\nstderr {stderr}");
    assert!(stdout.contains("printed 50 layers"), "{stdout}");
    assert_eq!(state, DeviceState::Done);
}

/// A reader stall that the host resends into (its unacknowledged frames every 100 ms) fills a
/// Linux pseudo-terminal (4 KB line buffer and 64 KB of queued input) within a few seconds:
/// this long is well past that.
const STALL_FILLS_THE_TERMINAL_MS: u32 = 8_000;

/// The same stall for longer than the host's link timeout: the printer still answers (its
/// keepalives arrive), but takes no data, and the host ends with that error instead of
/// blocking: the writes above were indeed refused.
#[test]
fn a_printer_that_takes_no_data_past_the_link_timeout_ends_the_print_with_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("sphere.stl");
    write_mesh(&model, &sphere_on_the_bed(48, 24));
    let mut opts = device(CREALITY_CAPACITIES, 400);
    opts.stall_reads_ms = 2 * LINK_TIMEOUT_S * 1000;
    let (out, _) = print_over_pty_with(
        &[model.to_str().unwrap(), "--skirt-loops", "0", "--link-timeout", "2"],
        opts,
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("the printer took no data for 2."), "{stderr}");
}

/// A G-code file prints as it is: streamed in text messages, run by the printer's G-code
/// reader; the skipped command is named before the print starts.
#[test]
fn print_streams_a_gcode_file_to_the_simulated_printer_over_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("square.gcode");
    let square = "G28\nM201 X500\nG1 Z0.2 F600\n;LAYER_CHANGE\nG1 X10 Y10 F3000\n\
                  G1 X20 E1 F1200\nG1 Y20 E2\n;LAYER_CHANGE\nG1 Z0.4\nG1 X10 E3\nG1 Y10 E4\n";
    std::fs::write(&file, square).unwrap();
    let (out, state) = print_over_pty(&[file.to_str().unwrap()], CREALITY_CAPACITIES);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout {stdout}\nstderr {stderr}");
    assert!(stdout.contains("printed 2 layers"), "{stdout}");
    assert!(stdout.contains(&format!("{} bytes streamed", square.len())), "{stdout}");
    assert!(stderr.contains("skipped (not run by this printer): M201 x1"), "{stderr}");
    assert_eq!(state, DeviceState::Done);
}

/// `--resume` with a printer that parked no job: a clear error, and the printer stays idle
/// (nothing was sent to it but the hello).
#[test]
fn resume_with_no_parked_job_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let (out, state) = print_over_pty(&[model.to_str().unwrap(), "--resume"], CREALITY_CAPACITIES);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains("holds no parked job to resume (it is idle)"), "{stderr}");
    assert_eq!(state, DeviceState::Idle);
}

/// `strata upload`, `strata card ls`, `strata print --from-card` and `strata card rm`
/// against a simulated printer with a card (an image the `fatfs` crate wrote): the uploaded
/// file is listed at its size and prints to the end from the card; removed, it is gone from
/// the listing; a missing file and a model are refused in words.
#[test]
fn card_upload_ls_print_and_rm_over_a_pty() {
    // Two layers of a 20 mm square, Marlin style.
    let mut gcode = String::from("G28\nG90\nM83\n");
    for layer in 0..2 {
        let z = 0.2 * (layer + 1) as f64;
        gcode += &format!(";LAYER_CHANGE\nG1 Z{z:.1} F600\nG1 X90 Y90 F6000\n");
        for (x, y) in [(110, 90), (110, 110), (90, 110), (90, 90)] {
            gcode += &format!("G1 X{x} Y{y} E0.8 F1800\n");
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("square.gcode");
    std::fs::write(&file, &gcode).unwrap();
    let model = dir.path().join("block.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let image = strata_testkit::card::image(fatfs::FatType::Fat16, 32, &[], false);
    let opts = device(CREALITY_CAPACITIES, 50);
    let file = file.to_str().unwrap();
    let (outs, state) = serve_on_pty(opts, Some(ImageCard::new(image)), |name, _| {
        [
            strata(name, &["upload", file]),
            strata(name, &["upload", model.to_str().unwrap()]),
            strata(name, &["card", "ls"]),
            strata(name, &["print", "--from-card", "nothing.gcode"]),
            strata(name, &["card", "rm", "nothing.gcode"]),
            strata(name, &["print", "--from-card", "square.gcode"]),
            strata(name, &["card", "rm", "square.gcode"]),
            strata(name, &["card", "rm", "block.sjob"]),
            strata(name, &["card", "ls"]),
        ]
    });
    let [upload, upload_model, ls, missing, rm_missing, print, rm, rm_model, ls_after] = &outs;
    assert!(upload.status.success(), "{}", text(upload));
    assert!(text(upload).contains(&format!("{} bytes written", gcode.len())), "{}", text(upload));
    // A model uploads as its job, under its stem's name.
    assert!(upload_model.status.success(), "{}", text(upload_model));
    let job_line = String::from_utf8_lossy(&upload_model.stdout);
    assert!(
        job_line.starts_with("block.sjob: ") && job_line.contains("bytes written"),
        "{job_line}"
    );
    assert!(ls.status.success(), "{}", text(ls));
    let listing = String::from_utf8_lossy(&ls.stdout);
    let line = format!("{:>10}  square.gcode", gcode.len());
    assert!(listing.lines().any(|l| l == line), "{listing}");
    assert!(listing.lines().any(|l| l.ends_with("  block.sjob")), "{listing}");
    assert!(listing.lines().any(|l| l.ends_with("old prints/")), "{listing}");
    assert!(listing.contains("2 files"), "{listing}");
    for refused in [missing, rm_missing] {
        assert!(!refused.status.success());
        assert!(text(refused).contains("card: no such file on the SD card"), "{}", text(refused));
    }
    assert!(print.status.success(), "{}", text(print));
    assert!(text(print).contains("printed from the card"), "{}", text(print));
    assert!(rm.status.success(), "{}", text(rm));
    assert!(rm_model.status.success(), "{}", text(rm_model));
    let listing = String::from_utf8_lossy(&ls_after.stdout);
    assert!(!listing.contains("square.gcode") && listing.contains("0 files"), "{listing}");
    assert_eq!(state.unwrap(), DeviceState::Done);
}

/// `strata upload MODEL.stl` with settings, then `strata print --from-card`: the real binary
/// writes the model's job and the printer prints it from its card to the end (the device
/// double serves one job a session).
#[test]
fn a_models_job_uploads_and_prints_from_the_card_over_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("block.stl");
    write_mesh(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
    let image = strata_testkit::card::image(fatfs::FatType::Fat16, 32, &[], false);
    let opts = device(CREALITY_CAPACITIES, 50);
    let model = model.to_str().unwrap();
    let (outs, state) = serve_on_pty(opts, Some(ImageCard::new(image)), |name, _| {
        [
            strata(name, &["upload", model, "--name", "block job", "--layer-height", "0.3"]),
            strata(name, &["print", "--from-card", "block job"]),
        ]
    });
    let [upload, print] = &outs;
    assert!(upload.status.success(), "{}", text(upload));
    assert!(print.status.success(), "{}", text(print));
    // The block is 1.2 mm tall: its layers at 0.3 mm by the slicer's plane rule, not at the
    // default height: the upload's settings went with the job.
    let layers = |layer_height_um| {
        let mut settings = strata::machine::PrintSettings::default();
        settings.layer_height_um = layer_height_um;
        strata::slice::SliceConfig::new(&settings, 1_200).unwrap().layer_count()
    };
    let (want, default) =
        (layers(300), layers(strata::machine::PrintSettings::default().layer_height_um));
    assert_ne!(want, default, "the setting changes the layers");
    assert!(
        text(print).contains("printed from the card")
            && text(print).contains(&format!("{want} layers")),
        "{want} layers: {}",
        text(print)
    );
    assert_eq!(state.unwrap(), DeviceState::Done);
}

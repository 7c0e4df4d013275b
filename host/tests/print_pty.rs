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
use strata_host::serial::serve_device;

mod common;
use common::{holed_block, write_stl};

/// Runs `strata print` with `args` against a simulated printer announcing `caps`; returns the
/// command's output and the device's final state.
fn print_over_pty(args: &[&str], caps: Capacities) -> (std::process::Output, DeviceState) {
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
                serve_device(&mut master, &MachineConfig::default(), caps, 400, &stop)
            })
            .unwrap();
        let out = Command::cargo_bin("strata")
            .unwrap()
            .args(["print", "--port", &name])
            .args(args)
            .timeout(Duration::from_secs(60))
            .output()
            .unwrap();
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let state = device.join().unwrap().unwrap_or_else(|e| {
            panic!("device: {e}; strata: {}", String::from_utf8_lossy(&out.stderr))
        });
        (out, state)
    })
}

#[test]
fn print_streams_a_model_to_the_simulated_printer_over_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("holed.stl");
    write_stl(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
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
    write_stl(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
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
    write_stl(&model, &holed_block(-5.0, 5.0, -2.0, 2.0, 1.2));
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

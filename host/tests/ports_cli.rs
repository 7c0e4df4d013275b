//! `strata ports` through the built binary: it succeeds with or without serial ports, and
//! says so clearly when there is none (the empty case is also unit-tested in `print.rs`).

use std::process::Command;

#[test]
fn ports_lists_ports_or_says_there_are_none() {
    let out = Command::new(env!("CARGO_BIN_EXE_strata")).arg("ports").output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "stdout {stdout}\nstderr {stderr}");
    assert!(stderr.is_empty(), "{stderr}");
    let lines: Vec<&str> = stdout.lines().collect();
    assert!(!lines.is_empty(), "no output at all");
    if lines == ["no serial ports found"] {
        return;
    }
    // A machine with ports (a VM's 16550 at /dev/ttyS0, a USB adapter): `NAME<TAB>KIND`, one
    // per port, each a device that exists.
    for l in lines {
        let (name, kind) = l.split_once('\t').unwrap_or_else(|| panic!("not NAME<TAB>KIND: {l}"));
        assert!(!kind.is_empty(), "{l}");
        assert!(std::path::Path::new(name).exists(), "{name} does not exist");
    }
}

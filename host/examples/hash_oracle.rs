//! The behaviour oracle for changes that must not change behaviour: for each model, the
//! host simulation's per-layer step hashes, board step hash, print ticks and steps, once at
//! host capacities and once posing as the 64 KB board (`BOARD_CAPACITIES`) (admitted and simplified as
//! `strata print` would), plus a hash of the G-code `strata slice` writes. One line per
//! figure, so two runs compare with `diff` (`scripts/hash_oracle.sh` runs the six models).
//!
//! `cargo run --release -p strata-host --example hash_oracle -- MODEL...`

use std::hash::Hasher;

use strata::machine::MachineConfig;
use strata::printer::BOARD_CAPACITIES;
use strata::protocol::Capacities;
use strata_host::admission::{admit_job_paced, Admission};
use strata_host::model;
use strata_host::simjob::{simulate, SimOptions};
use strata_testkit::drive::job_spec;

/// FNV-1a over bytes (stable across runs and platforms, unlike `DefaultHasher`).
struct Fnv(u64);

impl Hasher for Fnv {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 ^ b as u64).wrapping_mul(0x100_0000_01b3);
        }
    }
}

fn run(name: &str, label: &str, caps: Option<Capacities>, path: &std::path::Path) {
    let machine = MachineConfig::default();
    let m = model::load(path).unwrap_or_else(|e| panic!("{e}"));
    let mut tris = m.placed_sorted(&machine).unwrap_or_else(|e| panic!("{e}"));
    let mut opts = SimOptions::default();
    if let Some(caps) = caps {
        let job = job_spec(&tris);
        match admit_job_paced(&tris, &machine, &job, &caps, 0.02, opts.baud).map(|p| p.admission) {
            Ok(Admission::Unchanged(_)) => {}
            Ok(Admission::Simplified(s)) => tris = s.triangles,
            Err(e) => {
                println!("{name} {label} refused: {e}");
                return;
            }
        }
        opts.capacities = caps;
    }
    let job = job_spec(&tris);
    match simulate(&tris, &machine, job, &opts) {
        Ok(r) => {
            println!(
                "{name} {label} layers={} triangles={} print_ticks={} board_hash={:016x} \
                 steps={:?} positions={:?} underruns={}",
                r.layers,
                tris.len(),
                r.print_ticks,
                r.board_hash,
                r.steps,
                r.positions,
                r.underruns
            );
            for (l, h) in r.layer_hashes.iter().enumerate() {
                println!("{name} {label} layer {l} {h:016x}");
            }
        }
        Err((e, _)) => println!("{name} {label} failed: {e}"),
    }
}

fn gcode_hash(name: &str, path: &std::path::Path) {
    let out = std::env::temp_dir().join(format!("strata-oracle-{}.gcode", std::process::id()));
    // target/<profile>/examples/hash_oracle -> target/<profile>/strata
    let exe = std::env::current_exe().expect("own path");
    let strata = exe.parent().and_then(|d| d.parent()).expect("target dir").join("strata");
    let status = std::process::Command::new(strata)
        .args(["slice"])
        .arg(path)
        .arg("-o")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status();
    match (status, std::fs::read(&out)) {
        (Ok(s), Ok(bytes)) if s.success() => {
            let mut h = Fnv(0xcbf2_9ce4_8422_2325);
            h.write(&bytes);
            println!("{name} gcode bytes={} fnv={:016x}", bytes.len(), h.finish());
        }
        (s, _) => println!("{name} gcode failed: {s:?}"),
    }
    let _ = std::fs::remove_file(&out);
}

fn main() {
    for arg in std::env::args().skip(1) {
        let path = std::path::PathBuf::from(&arg);
        let name = path.file_name().map_or(arg.clone(), |n| n.to_string_lossy().into_owned());
        gcode_hash(&name, &path);
        run(&name, "host", None, &path);
        run(&name, "board64k", Some(BOARD_CAPACITIES), &path);
    }
}

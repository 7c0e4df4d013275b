//! Fuzz target for `strata::gcode::read` (the line splitter and the reader).
//!
//! The first input byte picks a chunk size, the rest is the file. Checks: no panic; chunked
//! splitting gives the lines whole splitting gives; every line is within `LINE_BYTES`; every
//! move's target is inside the build volume on X, Y, Z; a refused line changes no position;
//! the counts add up.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::gcode::read::{Action, LineError, LineSplitter, Reader, LINE_BYTES};
use strata::machine::MachineConfig;

/// Every line of `file` split in chunks of `size` bytes.
fn lines(file: &[u8], size: usize) -> Vec<Result<Vec<u8>, LineError>> {
    let mut s = LineSplitter::new();
    let mut out = Vec::new();
    for chunk in file.chunks(size) {
        let mut rest = chunk;
        while !rest.is_empty() {
            let (taken, line) = s.take(rest);
            assert!(taken >= 1 && taken <= rest.len());
            rest = &rest[taken..];
            if let Some(l) = line {
                out.push(l.map(|()| s.line().to_vec()));
            }
        }
    }
    if let Some(l) = s.finish() {
        out.push(l.map(|()| s.line().to_vec()));
    }
    out
}

fuzz_target!(|data: &[u8]| {
    let Some((&selector, file)) = data.split_first() else { return };
    let size = usize::from(selector % 32) + 1;
    let whole = lines(file, file.len().max(1));
    assert_eq!(lines(file, size), whole);

    let machine = MachineConfig::ENDER3;
    let volume = machine.build_volume_um;
    let mut reader = Reader::new(&machine);
    let (mut moves, mut refused) = (0u32, 0u32);
    for line in &whole {
        let line = match line {
            Ok(l) => l,
            Err(e) => {
                reader.refuse(*e);
                refused += 1;
                continue;
            }
        };
        assert!(line.len() <= LINE_BYTES);
        let before = reader.machine_um();
        match reader.line(line) {
            Ok(Some(Action::Move(m))) => {
                moves += 1;
                for axis in 0..3 {
                    assert!((0..=volume[axis]).contains(&m.target_um[axis]), "{m:?}");
                }
            }
            Ok(Some(Action::Home { travel, .. })) => {
                assert!(travel.target_um[..3].iter().all(|&v| v >= 0));
            }
            Ok(_) => {}
            Err(_) => {
                refused += 1;
                assert_eq!(reader.machine_um(), before);
            }
        }
    }
    let stats = reader.stats();
    assert_eq!(stats.lines as usize, whole.len());
    assert_eq!((stats.moves, stats.refused), (moves, refused));
});

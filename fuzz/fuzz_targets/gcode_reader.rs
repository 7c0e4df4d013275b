//! Fuzz target for `strata::gcode::read` (the line splitter and the reader) and the printer's
//! G-code input stage (`strata::gcode::input`).
//!
//! The first input byte picks a chunk size, the rest is the file. Checks: no panic; chunked
//! splitting gives the lines whole splitting gives; every line is within `LINE_BYTES`; every
//! move's target is inside the build volume on X, Y, Z; a refused line changes no position;
//! the counts add up. Then the input stage takes the file in those chunks against a move
//! buffer that is full at times and a generator that finishes blocks in bursts: it reads to
//! the end (or, abandoned half way, to its last complete line), every move it gives is inside
//! the build volume, and it gives as many as it says.
#![no_main]

use libfuzzer_sys::fuzz_target;
use strata::gcode::input::{GcodeInput, GcodeSink};
use strata::gcode::read::{Action, LineError, LineSplitter, Reader, LINE_BYTES};
use strata::machine::MachineConfig;
use strata::move_ring::{PackedMove, RingFull};

/// A move buffer that refuses every `period`-th offer, and a generator that has finished
/// every block pushed.
struct Sink {
    moves: Vec<PackedMove>,
    offers: u32,
    period: u32,
    heaters: bool,
}

impl GcodeSink for Sink {
    fn push_move(&mut self, mv: &PackedMove) -> Result<(), RingFull> {
        self.offers += 1;
        if self.offers % self.period == 0 {
            return Err(RingFull);
        }
        self.moves.push(*mv);
        Ok(())
    }

    fn blocks_done(&mut self) -> u32 {
        self.moves.len() as u32
    }

    fn has_heaters(&self) -> bool {
        self.heaters
    }

    fn holding(&mut self, _holds: bool) {}
}

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
                // An arc's further segments: inside the bed too, and finite in number.
                let mut segments = 0;
                while let Some(m) = reader.continuation() {
                    moves += 1;
                    segments += 1;
                    assert!(segments < 4096, "an arc of too many segments");
                    for axis in 0..3 {
                        assert!((0..=volume[axis]).contains(&m.target_um[axis]), "{m:?}");
                    }
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

    // The input stage, chunk by chunk, offered again while it waits.
    let mut input = GcodeInput::new(&machine);
    let period = u32::from(selector % 5) + 2;
    let mut sink = Sink { moves: Vec::new(), offers: 0, period, heaters: selector & 0x80 != 0 };
    let chunks: Vec<&[u8]> = file.chunks(size).collect();
    let last = chunks.len();
    // With bit 6 of the selector the source goes away half way: the input ends at its last
    // complete line.
    let abandon_at = (selector & 0x40 != 0).then_some(last / 2);
    for (i, chunk) in chunks.iter().copied().chain([&[][..]]).enumerate() {
        if Some(i) == abandon_at {
            input.abandon();
            let mut tries = 0u32;
            while !input.take(&[], &mut 0, false, &mut sink) {
                tries += 1;
                input.apply_due(sink.blocks_done());
                assert!(tries < 10_000, "an abandoned input never drained");
            }
            input.apply_due(sink.blocks_done());
            assert!(input.finished());
            break;
        }
        let mut pos = 0;
        let mut tries = 0u32;
        while !input.take(chunk, &mut pos, i == last, &mut sink) {
            tries += 1;
            // The heaters come to their targets after a few offers; a full buffer drains.
            input.thermal(tries > 3);
            input.apply_due(sink.blocks_done());
            // Each refused offer is one try: a line's moves (an arc's up to 2,048 segments)
            // go in one by one against a buffer that refuses every other offer.
            assert!(tries < 10_000, "the input stage never finished a chunk");
        }
    }
    input.apply_due(sink.blocks_done());
    assert!(input.finished());
    assert_eq!(input.stats().moves as usize, sink.moves.len());
    if abandon_at.is_none() {
        assert_eq!(input.stats().lines as usize, whole.len());
    }
    for m in &sink.moves {
        for axis in 0..3 {
            assert!((0..=volume[axis]).contains(&m.target_um[axis]), "{m:?}");
        }
    }
});

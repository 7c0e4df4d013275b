//! A G-code file on the host, read before it is sent.
//!
//! The reader is the one the printer runs ([`strata::gcode::read`]): the job's spec (bytes,
//! layers), its moves, the commands the printer skips and the lines it refuses, with their
//! numbers, so the user hears of them before the print starts.

use std::collections::BTreeMap;

use strata::gcode::read::{Action, LineError, LineSplitter, Reader};
use strata::machine::MachineConfig;
use strata::protocol::GcodeSpec;

/// Refused lines kept with their numbers (all are counted).
const REFUSALS_KEPT: usize = 20;

/// What the printer's reader makes of a file.
#[derive(Debug, Clone, Default)]
pub struct GcodeScan {
    /// The job's spec for the printer.
    pub spec: GcodeSpec,
    /// Lines.
    pub lines: u32,
    /// Moves (`G0`/`G1`, `G4`, the travel of each `G28`).
    pub moves: u32,
    /// Commands the printer skips, by name (`M201`), with their counts.
    pub skipped: BTreeMap<String, u32>,
    /// Lines refused (the printer skips them too).
    pub refused: u32,
    /// The first refused lines: 1-based number and why.
    pub refusals: Vec<(u32, LineError)>,
    /// Moves clamped to the build volume.
    pub clamped: u32,
}

impl GcodeScan {
    /// The skipped commands and refused lines in words, one warning each (none when clean).
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        if !self.skipped.is_empty() {
            let list: Vec<String> = self.skipped.iter().map(|(c, n)| format!("{c} x{n}")).collect();
            out.push(format!("skipped (not run by this printer): {}", list.join(", ")));
        }
        if self.clamped > 0 {
            out.push(format!("{} moves go beyond the bed and stop at its edge", self.clamped));
        }
        if self.refused > 0 {
            let first: Vec<String> =
                self.refusals.iter().map(|(n, e)| format!("line {n}: {e}")).collect();
            out.push(format!("{} lines refused and skipped: {}", self.refused, first.join("; ")));
        }
        out
    }
}

/// Reads `text` as the printer on `machine` will.
pub fn scan(text: &[u8], machine: &MachineConfig) -> Result<GcodeScan, String> {
    let bytes =
        u32::try_from(text.len()).map_err(|_| "the file is larger than 4 GB".to_string())?;
    let mut reader = Reader::new(machine);
    let mut splitter = LineSplitter::new();
    let mut out = GcodeScan::default();
    let mut layers = 0u32;
    let mut rest = text;
    loop {
        let line = if rest.is_empty() {
            match splitter.finish() {
                Some(l) => l,
                None => break,
            }
        } else {
            let (taken, line) = splitter.take(rest);
            rest = &rest[taken..];
            match line {
                Some(l) => l,
                None => continue,
            }
        };
        let number = reader.stats().lines + 1;
        let action = match line {
            Ok(()) => reader.line(splitter.line()),
            Err(e) => Err(reader.refuse(e)),
        };
        match action {
            Ok(Some(Action::Layer(l))) => layers = layers.max(l.saturating_add(1)),
            Ok(Some(Action::Skipped { letter, code })) => {
                *out.skipped.entry(format!("{}{code}", letter as char)).or_default() += 1;
            }
            Ok(_) => {}
            Err(e) if out.refusals.len() < REFUSALS_KEPT => out.refusals.push((number, e)),
            Err(_) => {}
        }
        // An arc's segments are moves too.
        while reader.continuation().is_some() {}
    }
    let stats = reader.stats();
    out.lines = stats.lines;
    out.moves = stats.moves;
    out.refused = stats.refused;
    out.clamped = stats.clamped;
    out.spec = GcodeSpec { bytes, layers };
    Ok(out)
}

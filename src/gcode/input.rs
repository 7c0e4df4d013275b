//! A G-code job's input stage: text in, moves out, settings timed to the motion.
//!
//! The text comes in chunks, as it arrives from the link or the card; the planner's moves go
//! into the move buffer, and the printer settings the text sets (heater targets, the
//! part-cooling fan) take effect where the motion reaches them. Moves that go nowhere (their um target is the last one's; not a dwell) are dropped here, so
//! every move in the buffer makes exactly one planner block: a setting read after the `k`-th
//! move takes effect once the step generator has finished `k` blocks ([`GcodeInput::apply_due`]),
//! where the nozzle is (up to the step queue's lead), not when it was read (the move buffer
//! holds seconds of motion). A heater wait (`M109`/`M190`) and `M400` hold the reading until
//! every move before them is done (the planner is flushed meanwhile: the plan comes to rest
//! there on every board, whatever the heaters do, so the step hashes do not depend on them)
//! and, for a heater wait, until the heaters are at their targets.
//!
//! RAM: the line buffer ([`LINE_BYTES`](super::read::LINE_BYTES)), the reader's state and [`SETTINGS`] settings,
//! about 400 bytes, in the scratch the slicer and the toolpath stage use for a sliced job
//! ([`crate::scratch`]).

use heapless::Deque;

use super::read::{Action, Heater, LineError, LineSplitter, Reader};
use crate::machine::{MachineConfig, AXES};
use crate::move_ring::{PackedMove, RingFull};
use crate::plan::{Move, MoveKind};

/// Settings read ahead of the motion and waiting for it; a full queue holds the reading.
pub const SETTINGS: usize = 8;

/// A printer setting the G-code changes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Setting {
    /// Hotend target, degC.
    Hotend(i16),
    /// Bed target, degC.
    Bed(i16),
    /// Part-cooling fan duty, 0..=255.
    Fan(u8),
}

/// What the reading waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Hold {
    /// Nothing: it reads on.
    None,
    /// Every move before is done (`M400`).
    Motion,
    /// Every move before is done and the heaters are at their targets (`M109`, `M190`).
    Heat,
}

/// The printer side the input stage works with.
pub trait GcodeSink {
    /// The move into the move buffer; [`RingFull`] when it has no room now.
    fn push_move(&mut self, mv: &PackedMove) -> Result<(), RingFull>;
    /// Blocks the step generator has finished in this job.
    fn blocks_done(&mut self) -> u32;
    /// The board has heaters (a heater wait waits for them; without, it does not).
    fn has_heaters(&self) -> bool;
    /// The reading begins (`true`) or ends a hold: the planner flushes while it holds. Called
    /// before the next move goes in, so a feeder elsewhere (a board's feed interrupt) never
    /// flushes a plan that more moves will follow: the blocks stay the same on every board.
    fn holding(&mut self, holds: bool);
}

/// What the input stage has read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InputStats {
    /// Lines read (also the refused ones).
    pub lines: u32,
    /// Moves into the move buffer (each one block).
    pub moves: u32,
    /// Commands skipped.
    pub skipped: u32,
    /// Lines refused.
    pub refused: u32,
    /// The first refused line (1-based) and why.
    pub first_refused: Option<(u32, LineError)>,
    /// Moves clamped to the build volume.
    pub clamped: u32,
}

/// A G-code job's input state (see the [module docs](self)).
#[derive(Debug, Clone)]
pub struct GcodeInput {
    splitter: LineSplitter,
    reader: Reader,
    /// A move that waits for room in the move buffer.
    pending: Option<PackedMove>,
    /// The last move's target, um.
    last_target: [i32; AXES],
    /// The layer of the last marker.
    layer: u32,
    /// Settings and the number of moves before each.
    settings: Deque<(u32, Setting), SETTINGS>,
    hold: Hold,
    /// Heater targets in effect (hotend, bed), degC.
    targets: (i16, i16),
    /// Fan duty in effect.
    fan: u8,
    /// The heaters were at the targets in effect when last measured.
    at_target: bool,
    /// The text's end was read ([`GcodeInput::take`] with `end`).
    ended: bool,
    /// Bytes of text taken, and of them the current line's (not yet ended), wrapping.
    bytes: u32,
    line_bytes: u32,
    stats: InputStats,
}

impl GcodeInput {
    /// A new job's input on `machine`: at the origin, heaters and fan off.
    pub fn new(machine: &MachineConfig) -> Self {
        Self {
            splitter: LineSplitter::new(),
            reader: Reader::new(machine),
            pending: None,
            last_target: [0; AXES],
            layer: 0,
            settings: Deque::new(),
            hold: Hold::None,
            targets: (0, 0),
            fan: 0,
            at_target: false,
            ended: false,
            bytes: 0,
            line_bytes: 0,
            stats: InputStats::default(),
        }
    }

    /// What was read so far.
    pub fn stats(&self) -> InputStats {
        let read = self.reader.stats();
        InputStats {
            lines: read.lines,
            skipped: read.skipped,
            refused: read.refused,
            clamped: read.clamped,
            ..self.stats
        }
    }

    /// The heaters' measurement against the targets in effect (a board calls it after each
    /// update, with the targets it read from [`targets`](Self::targets) for it).
    pub fn thermal(&mut self, at_target: bool) {
        self.at_target = at_target;
    }

    /// The heater targets in effect (hotend, bed), degC.
    pub fn targets(&self) -> (i16, i16) {
        self.targets
    }

    /// The fan duty in effect.
    pub fn fan(&self) -> u8 {
        self.fan
    }

    /// What the reading waits for: the planner is flushed while it holds.
    pub fn hold(&self) -> Hold {
        self.hold
    }

    /// Every line is read, every move is in the buffer and every setting is in effect.
    pub fn finished(&self) -> bool {
        self.ended && self.pending.is_none() && self.settings.is_empty() && self.hold == Hold::None
    }

    /// The text ends here, where its source went away: a line cut short is dropped (never
    /// run), a hold is let go (nothing follows it); the move of the last complete line still
    /// goes in ([`take`](Self::take) with no text).
    pub fn abandon(&mut self) {
        self.splitter.clear();
        self.ended = true;
        self.hold = Hold::None;
    }

    /// Bytes of text in the lines read (a line not yet ended excluded): where a text that
    /// was [abandoned](Self::abandon) resumes.
    pub fn lines_bytes(&self) -> u32 {
        self.bytes.wrapping_sub(self.line_bytes)
    }

    /// The abandoned text goes on ([`lines_bytes`](Self::lines_bytes) on): the reader's
    /// state is as the last complete line left it.
    pub fn resume(&mut self) {
        self.bytes = self.lines_bytes();
        self.line_bytes = 0;
        self.splitter.clear();
        self.ended = false;
    }

    /// The settings whose moves are done take effect (`blocks_done`: blocks the generator
    /// has finished). A new heater target is not reached until measured so.
    pub fn apply_due(&mut self, blocks_done: u32) {
        while let Some(&(after, setting)) = self.settings.front() {
            // Wrapping: a job of more than 2^31 moves still compares correctly.
            if blocks_done.wrapping_sub(after) >= 1 << 31 {
                break;
            }
            self.settings.pop_front();
            match setting {
                Setting::Hotend(t) => (self.targets.0, self.at_target) = (t, false),
                Setting::Bed(t) => (self.targets.1, self.at_target) = (t, false),
                Setting::Fan(d) => self.fan = d,
            }
        }
    }

    /// Reads `text` from `*pos` (advanced past what was read) until all of it is read, or the
    /// reading must wait: a move with no room in the buffer, a full settings queue, a hold.
    /// `end`: the text is the last, its unterminated last line ends it. True when all was read.
    pub fn take(
        &mut self,
        text: &[u8],
        pos: &mut usize,
        end: bool,
        sink: &mut impl GcodeSink,
    ) -> bool {
        loop {
            if let Some(p) = self.pending {
                if sink.push_move(&p).is_err() {
                    return false;
                }
                self.pending = None;
                self.stats.moves = self.stats.moves.wrapping_add(1);
            }
            if self.hold != Hold::None {
                let done = sink.blocks_done();
                self.apply_due(done);
                let moved = done.wrapping_sub(self.stats.moves) < 1 << 31;
                let heated = self.at_target || !sink.has_heaters();
                if !moved || (self.hold == Hold::Heat && !heated) {
                    return false;
                }
                self.hold = Hold::None;
                sink.holding(false);
            }
            if self.settings.is_full() {
                self.apply_due(sink.blocks_done());
                if self.settings.is_full() {
                    return false;
                }
            }
            // An arc's segments, one at a time, before the next line.
            if let Some(m) = self.reader.continuation() {
                self.queue_move(&m);
                continue;
            }
            let rest = text.get(*pos..).unwrap_or(&[]);
            let line = if !rest.is_empty() {
                let (taken, line) = self.splitter.take(rest);
                *pos += taken;
                self.bytes = self.bytes.wrapping_add(taken as u32);
                self.line_bytes = match line {
                    Some(_) => 0,
                    None => self.line_bytes.wrapping_add(taken as u32),
                };
                line
            } else if end && !self.ended {
                self.ended = true;
                self.splitter.finish()
            } else {
                return true;
            };
            match line {
                Some(Ok(())) => {
                    self.read_line();
                    if self.hold != Hold::None {
                        sink.holding(true);
                    }
                }
                Some(Err(e)) => {
                    let e = self.reader.refuse(e);
                    self.note_refusal(e);
                }
                None => {}
            }
        }
    }

    /// The splitter's line through the reader, its action recorded.
    fn read_line(&mut self) {
        let line = self.splitter.line();
        let mut setting = None;
        match self.reader.line(line) {
            Ok(Some(Action::Move(m) | Action::Home { travel: m, .. })) => self.queue_move(&m),
            Ok(Some(Action::Layer(l))) => self.layer = l,
            Ok(Some(Action::Heat { heater, target_c, wait, .. })) => {
                setting = Some(match heater {
                    Heater::Hotend => Setting::Hotend(target_c),
                    Heater::Bed => Setting::Bed(target_c),
                });
                if wait {
                    self.hold = Hold::Heat;
                }
            }
            Ok(Some(Action::Fan(d))) => setting = Some(Setting::Fan(d)),
            Ok(Some(Action::Sync)) => self.hold = Hold::Motion,
            Ok(_) => {}
            Err(e) => self.note_refusal(e),
        }
        if let Some(s) = setting {
            // After the moves in the buffer (no move is pending when a line is read); the
            // queue had room (checked before the line was read).
            let _ = self.settings.push_back((self.stats.moves, s));
        }
    }

    /// `m` waits to go into the move buffer, unless it goes nowhere (not a dwell).
    fn queue_move(&mut self, m: &Move) {
        if m.kind == MoveKind::Dwell || m.target_um != self.last_target {
            self.last_target = m.target_um;
            self.pending = Some(PackedMove::pack(self.layer, m));
        }
    }

    /// The first refused line is kept (the reader counts them all).
    fn note_refusal(&mut self, e: LineError) {
        if self.stats.first_refused.is_none() {
            self.stats.first_refused = Some((self.reader.stats().lines, e));
        }
    }
}

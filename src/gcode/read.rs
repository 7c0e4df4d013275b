//! G-code reader: any slicer's Marlin-flavoured G-code in, planner [`Move`]s and printer
//! [`Action`]s out, in bounded memory and without floating point.
//!
//! Two parts, both `no_std` without allocation:
//! - [`LineSplitter`] cuts a byte stream (a file read in chunks, frames off the link) into lines
//!   of at most [`LINE_BYTES`] bytes (Marlin's `MAX_CMD_SIZE`); a longer line is reported as
//!   [`LineError::TooLong`] and skipped to its end, never truncated into a different command
//!   (a long `;` comment is cut instead: slicers write their settings in such comments);
//! - [`Reader`] interprets one line at a time with Marlin's modal state (absolute or relative
//!   axes and extruder, millimetres or inches, the feed rate, `G92` offsets, the `M220` speed
//!   and `M221` flow factors) and returns at most one [`Action`].
//!
//! # Numbers and positions
//! A number is read exactly as a decimal with 6 fraction digits (further digits round the
//! sixth, half away from zero): millimetres become nanometres, so relative extrusion summed
//! over a whole print does not drift. Numbers of 10^9 or more, and anything that is not a plain
//! decimal (`NaN`, `1e5`, `--1`), are a [`LineError::BadNumber`]. The reader keeps each axis'
//! logical position (what the G-code says, `G92` moves it) and its machine position (where the
//! motor is: `G92` does not move it, `M221` scales extrusion), both in nm. A move's target in
//! whole um is chosen so that the motor's nearest step is the step nearest the exact
//! nanometre position ([`target_um`]): the printed position is exact to the step, whatever the
//! rounding to um.
//!
//! # Commands
//! `G0`/`G1` (X Y Z E F), `G2`/`G3` (arcs in the XY plane around `I` `J` or of radius `R`, cut
//! into 1 mm segments as Marlin's `ARC_SUPPORT` does, each given by [`Reader::continuation`]),
//! `G4` (P ms, S s), `G17`, `G20`/`G21`, `G28` (home: the machine position goes
//! to 0), `G90`/`G91` (all axes, the extruder too, as Marlin 2), `G92`, `M82`/`M83`,
//! `M104`/`M109`, `M140`/`M190` (S, or R for `M109`/`M190`), `M106`/`M107`, `M84`/`M18`,
//! `M105`, `M114`, `M115`, `M117`, `M220`/`M221`, `M400`, `M73`, `M110`. Targets beyond the
//! build volume are clamped to it as Marlin's software endstops do, and counted. Anything else
//! is [`Action::Skipped`] and counted, never fatal. Comments are read for the layer markers of
//! PrusaSlicer (`;LAYER_CHANGE`), Cura (`;LAYER:n`, `;LAYER_COUNT:n`) and Strata's own writer
//! (both). Marlin's line numbers (`N`) and `*checksum` are honoured: a line number needs a
//! checksum, a checksum must match, and numbers must follow each other (`M110 N` sets the next).

use core::fmt;

use crate::machine::{MachineConfig, Rate, AXES};
use crate::math::isqrt_u128;
use crate::plan::{Move, MoveKind};
use crate::step::{nearest_step, step_position_q32};

/// Longest line the reader takes, bytes, without its end (Marlin's `MAX_CMD_SIZE`).
pub const LINE_BYTES: usize = 96;

/// Nanometres per millimetre: a number's 6 fraction digits.
const NM_PER_MM: i64 = 1_000_000;
/// Nanometres per micrometre.
const NM_PER_UM: i64 = 1_000;
/// Numbers must stay below 10^9 (mm, degC, mm/min, ...): in nm they fit an `i64` many times.
const MAX_INTEGER_DIGITS: u32 = 9;
/// Feed rate of a homing move, mm/s (Marlin's Ender-3 `HOMING_FEEDRATE_MM_M` for X and Y;
/// the planner lowers it to each axis' limit).
const HOMING_FEED_MM_S: u32 = 50;
/// Slowest feed rate of a move, mm/s x 100 (Marlin's `MINIMUM_PLANNER_SPEED`, 0.05 mm/s): a
/// file's `F0.001` neither stalls the print for days nor packs to a feed of zero.
const MIN_FEED_MM_S_X100: i128 = 5;
/// Length of an arc's segments, nm (Marlin's `MAX_ARC_SEGMENT_MM`, 1 mm).
const ARC_SEGMENT_NM: i64 = NM_PER_MM;
/// Segments of one arc at most (longer segments beyond: a whole circle across the bed is 700).
const MAX_ARC_SEGMENTS: i64 = 2_048;
/// How far an arc's end may lie off the bed before it is clamped, nm (10 m: its centre and
/// radius stay well inside the CORDIC's range).
const MAX_ARC_REACH_NM: i64 = 10_000 * NM_PER_MM;
/// Speed (`M220`) and flow (`M221`) factors accepted, percent (Marlin's range).
const FACTOR_PERCENT: core::ops::RangeInclusive<i64> = 10..=999;

/// Why a line was refused. The line did nothing; the reader's state is unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LineError {
    /// The line is longer than [`LINE_BYTES`].
    TooLong,
    /// A line number (`N`) without a checksum.
    MissingChecksum,
    /// The checksum after `*` is not the XOR of the bytes before it.
    Checksum {
        /// XOR of the bytes before `*`.
        computed: u8,
    },
    /// The line number is not the one expected (the last plus one, or the one `M110` set).
    LineNumber {
        /// The number expected.
        expected: u32,
    },
    /// The number after this letter is not a plain decimal below 10^9.
    BadNumber {
        /// The word's letter (upper case).
        letter: u8,
    },
    /// A byte that starts no word (not a letter).
    Unexpected {
        /// The byte.
        byte: u8,
    },
    /// This letter needs a number and has none (`G1 X`, `M104 S`).
    MissingValue {
        /// The word's letter.
        letter: u8,
    },
    /// The value of this letter is outside what the command accepts (a temperature above the
    /// machine's maximum, a feed rate of zero, a factor outside 10..=999 %, an extruder
    /// position beyond 2 km).
    OutOfRange {
        /// The word's letter.
        letter: u8,
    },
}

impl fmt::Display for LineError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::TooLong => write!(f, "line longer than {LINE_BYTES} bytes"),
            Self::MissingChecksum => write!(f, "line number without a checksum"),
            Self::Checksum { computed } => {
                write!(f, "checksum mismatch (the line's is {computed})")
            }
            Self::LineNumber { expected } => {
                write!(f, "line number out of sequence (expected {expected})")
            }
            Self::BadNumber { letter } => write!(f, "{} has a malformed number", letter as char),
            Self::Unexpected { byte } => write!(f, "unexpected byte 0x{byte:02x}"),
            Self::MissingValue { letter } => write!(f, "{} needs a number", letter as char),
            Self::OutOfRange { letter } => write!(f, "{} is out of range", letter as char),
        }
    }
}

/// A heater.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Heater {
    /// The hotend.
    Hotend,
    /// The bed.
    Bed,
}

/// What to report (`M105`, `M114`, `M115`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Report {
    /// Temperatures (`M105`).
    Temperatures,
    /// Position (`M114`).
    Position,
    /// Firmware name and capabilities (`M115`).
    Firmware,
}

/// What a line asks of the printer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Action<'l> {
    /// A move for the planner (`G0`/`G1`; `G4` as a [`MoveKind::Dwell`]).
    Move(Move),
    /// Home the axes of `axes` (bit 0 = X .. 2 = Z); their machine position is now 0.
    /// `travel` goes there from the last position at homing speed: what a machine whose
    /// position is trusted (a simulation) does instead of an endstop search.
    Home {
        /// Homed axes, bit per axis.
        axes: u8,
        /// The travel to the homed position.
        travel: Move,
    },
    /// Set a heater's target, degC (0: off); `wait`: wait until it is there (`M109`/`M190`;
    /// `cool`: also wait while it cools down to it, their `R` form).
    Heat {
        /// Which heater.
        heater: Heater,
        /// Target, degC.
        target_c: i16,
        /// Wait for the target.
        wait: bool,
        /// The wait also covers cooling down (`R`).
        cool: bool,
    },
    /// Part-cooling fan duty, 0..=255.
    Fan(u8),
    /// Steppers off.
    MotorsOff,
    /// Wait until every move so far has been made (`M400`).
    Sync,
    /// Send a report to the host.
    Report(Report),
    /// Show a message (`M117`): the text as in the line.
    Message(&'l [u8]),
    /// Print progress from the slicer (`M73`): percent done and minutes left, each when given.
    Progress {
        /// Percent done.
        percent: Option<u8>,
        /// Minutes left.
        minutes_left: Option<u32>,
    },
    /// A layer marker comment: the index of the layer that starts (Cura's raft layers are
    /// negative and count as 0).
    Layer(u32),
    /// The slicer's layer count (`;LAYER_COUNT:`).
    LayerCount(u32),
    /// A command this reader does not run (letter and number), counted.
    Skipped {
        /// `G`, `M` or `T`.
        letter: u8,
        /// Its number.
        code: u16,
    },
}

/// What the reader has seen.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReadStats {
    /// Lines read (also empty and comment lines, and refused ones).
    pub lines: u32,
    /// Moves returned (`G0`/`G1`, `G4`).
    pub moves: u32,
    /// Commands skipped.
    pub skipped: u32,
    /// Lines refused with a [`LineError`].
    pub refused: u32,
    /// Moves whose target was clamped to the build volume.
    pub clamped: u32,
}

/// Cuts a byte stream into lines of at most [`LINE_BYTES`] bytes (`\n`, `\r` or both end one).
#[derive(Debug, Clone)]
pub struct LineSplitter {
    buf: [u8; LINE_BYTES],
    len: usize,
    /// The current line ran past the buffer: its bytes are dropped until its end.
    overlong: bool,
    /// The current line's comment has begun (`;`): what does not fit is dropped, the line
    /// stays (Marlin ignores comments as it reads them).
    comment: bool,
    /// The last call ended a line: the next starts a new one.
    ended: bool,
}

impl Default for LineSplitter {
    fn default() -> Self {
        Self::new()
    }
}

impl LineSplitter {
    /// An empty splitter.
    pub const fn new() -> Self {
        Self { buf: [0; LINE_BYTES], len: 0, overlong: false, comment: false, ended: false }
    }

    /// Takes bytes of `input` up to and including the end of the next line. Returns how many it
    /// took and, when a line ended, the line ([`line`](Self::line) until the next call) or
    /// [`LineError::TooLong`].
    pub fn take(&mut self, input: &[u8]) -> (usize, Option<Result<(), LineError>>) {
        if self.ended {
            self.clear();
        }
        for (i, &b) in input.iter().enumerate() {
            if b == b'\n' || b == b'\r' {
                return (i + 1, Some(self.end()));
            }
            self.comment |= b == b';';
            match self.buf.get_mut(self.len) {
                Some(slot) if !self.overlong => {
                    *slot = b;
                    self.len += 1;
                }
                _ => self.overlong |= !self.comment,
            }
        }
        (input.len(), None)
    }

    /// Ends the stream: its last line if it had no line end.
    pub fn finish(&mut self) -> Option<Result<(), LineError>> {
        if self.ended {
            self.clear();
        }
        (self.len > 0 || self.overlong).then(|| self.end())
    }

    /// The line [`take`](Self::take) or [`finish`](Self::finish) ended, without its end.
    pub fn line(&self) -> &[u8] {
        self.buf.get(..self.len).unwrap_or(&[])
    }

    /// Drops a partial line (a new stream starts).
    pub fn clear(&mut self) {
        self.len = 0;
        self.overlong = false;
        self.comment = false;
        self.ended = false;
    }

    fn end(&mut self) -> Result<(), LineError> {
        self.ended = true;
        if self.overlong {
            self.len = 0;
            Err(LineError::TooLong)
        } else {
            Ok(())
        }
    }
}

/// Letters whose values a command reads, in [`Words`]' slots.
const LETTERS: &[u8; 10] = b"XYZEFSPRIJ";
const X: usize = 0;
const Y: usize = 1;
const E: usize = 3;
const F: usize = 4;
const S: usize = 5;
const P: usize = 6;
const R: usize = 7;
const I: usize = 8;
const J: usize = 9;

/// A word's value: absent, present without a number (`G28 X`), or a number in millionths.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
enum Value {
    #[default]
    Absent,
    Bare,
    Micro(i64),
}

/// The parameters of one command.
#[derive(Debug, Clone, Copy, Default)]
struct Words {
    values: [Value; LETTERS.len()],
}

impl Words {
    fn get(&self, slot: usize) -> Value {
        self.values.get(slot).copied().unwrap_or_default()
    }

    fn has(&self, slot: usize) -> bool {
        self.get(slot) != Value::Absent
    }

    /// The number of `slot`: `Ok(None)` when absent, an error when bare.
    fn num(&self, slot: usize) -> Result<Option<i64>, LineError> {
        match self.get(slot) {
            Value::Absent => Ok(None),
            Value::Bare => Err(LineError::MissingValue { letter: LETTERS[slot] }),
            Value::Micro(v) => Ok(Some(v)),
        }
    }

    /// The number of `slot` as a whole number in `range` (fraction dropped).
    fn whole(
        &self,
        slot: usize,
        range: core::ops::RangeInclusive<i64>,
    ) -> Result<Option<i64>, LineError> {
        match self.num(slot)? {
            None => Ok(None),
            Some(v) if range.contains(&(v / NM_PER_MM)) => Ok(Some(v / NM_PER_MM)),
            Some(_) => Err(LineError::OutOfRange { letter: LETTERS[slot] }),
        }
    }
}

/// A number of the line at `i` (after its letter): exact in millionths. Returns the value
/// (`None`: no number follows, a bare word) and the index after it.
fn parse_number(line: &[u8], mut i: usize, letter: u8) -> Result<(Option<i64>, usize), LineError> {
    let bad = LineError::BadNumber { letter };
    let start = i;
    let negative = line.get(i) == Some(&b'-');
    if matches!(line.get(i), Some(b'-' | b'+')) {
        i += 1;
    }
    let mut digits = 0u32;
    let mut int: i64 = 0;
    while let Some(d) = line.get(i).filter(|b| b.is_ascii_digit()) {
        digits += 1;
        if digits > MAX_INTEGER_DIGITS {
            return Err(bad);
        }
        int = int * 10 + i64::from(d - b'0');
        i += 1;
    }
    let mut frac: i64 = 0;
    if line.get(i) == Some(&b'.') {
        i += 1;
        // Weight of the next fraction digit in millionths (0 past the sixth).
        let mut weight = NM_PER_MM / 10;
        let mut seventh = true;
        while let Some(d) = line.get(i).filter(|b| b.is_ascii_digit()) {
            digits += 1;
            let d = i64::from(d - b'0');
            if weight > 0 {
                frac += d * weight;
                weight /= 10;
            } else if seventh {
                // The seventh digit rounds the sixth; later ones are read and dropped.
                frac += i64::from(d >= 5);
                seventh = false;
            }
            i += 1;
        }
    }
    if digits == 0 {
        // A sign or a point alone is malformed; nothing at all is a bare word.
        return if i > start { Err(bad) } else { Ok((None, i)) };
    }
    // A number runs into the next word or the end: `X1.5.2` or `X1e5` is malformed.
    if line
        .get(i)
        .is_some_and(|b| b.is_ascii_digit() || matches!(b, b'.' | b'e' | b'E' | b'-' | b'+'))
    {
        return Err(bad);
    }
    let v = int * NM_PER_MM + frac;
    Ok((Some(if negative { -v } else { v }), i))
}

/// A command word: its letter, number, whether the number had a fraction (`G29.1`: no command
/// this reader runs), and the index after it.
fn parse_command(code: &[u8]) -> Result<Option<(u8, u16, bool, usize)>, LineError> {
    let Some(i) = code.iter().position(|b| !b.is_ascii_whitespace()) else { return Ok(None) };
    let letter = code[i].to_ascii_uppercase();
    if !matches!(letter, b'G' | b'M' | b'T') {
        return Err(LineError::Unexpected { byte: code[i] });
    }
    let (v, end) = parse_number(code, i + 1, letter)?;
    let v = v.ok_or(LineError::MissingValue { letter })?;
    let number = u16::try_from(v / NM_PER_MM).map_err(|_| LineError::BadNumber { letter })?;
    Ok(Some((letter, number, v % NM_PER_MM != 0, end)))
}

/// The words after a command (spaces between them optional, letters in either case).
fn parse_words(rest: &[u8]) -> Result<Words, LineError> {
    let mut words = Words::default();
    let mut i = 0;
    while let Some(&b) = rest.get(i) {
        if b.is_ascii_whitespace() {
            i += 1;
            continue;
        }
        let letter = b.to_ascii_uppercase();
        if !letter.is_ascii_uppercase() {
            return Err(LineError::Unexpected { byte: b });
        }
        let (value, next) = parse_number(rest, i + 1, letter)?;
        // Words this reader never reads (`A`, `B`, `K`, ...) are passed over.
        if let Some(slot) = LETTERS.iter().position(|&l| l == letter) {
            words.values[slot] = value.map_or(Value::Bare, Value::Micro);
        }
        i = next;
    }
    Ok(words)
}

/// A line's parts.
struct LineParts<'l> {
    /// The command and its words.
    code: &'l [u8],
    /// After `;`.
    comment: &'l [u8],
    /// The line number (`N`), when the line has one.
    number: Option<u32>,
}

/// The code part of a line: the `;` comment split off, the `*checksum` checked and removed, the
/// line number taken (when the line has one).
fn split_line(line: &[u8]) -> Result<LineParts<'_>, LineError> {
    let (code, comment) = match line.iter().position(|&b| b == b';') {
        Some(c) => (&line[..c], &line[c + 1..]),
        None => (line, &[][..]),
    };
    let (code, checksum) = match code.iter().position(|&b| b == b'*') {
        Some(s) => (&code[..s], Some(code[s + 1..].trim_ascii())),
        None => (code, None),
    };
    if let Some(given) = checksum {
        let computed = code.iter().fold(0u8, |x, b| x ^ b);
        let ok = matches!(parse_number(given, 0, b'*'), Ok((Some(v), end))
            if end == given.len() && v == i64::from(computed) * NM_PER_MM);
        if !ok {
            return Err(LineError::Checksum { computed });
        }
    }
    let trimmed = code.trim_ascii_start();
    if !matches!(trimmed.first(), Some(b'N' | b'n')) {
        return Ok(LineParts { code, comment, number: None });
    }
    if checksum.is_none() {
        return Err(LineError::MissingChecksum);
    }
    let bad = LineError::BadNumber { letter: b'N' };
    let (v, end) = parse_number(trimmed, 1, b'N')?;
    let n = v.filter(|v| v % NM_PER_MM == 0).ok_or(bad)? / NM_PER_MM;
    let n = u32::try_from(n).map_err(|_| bad)?;
    Ok(LineParts { code: &trimmed[end..], comment, number: Some(n) })
}

/// The layer marker of a comment (without its `;`), if it is one.
fn marker(comment: &[u8], layer: Option<u32>) -> Option<Action<'static>> {
    let number = |rest: &[u8]| -> Option<i64> {
        let (v, end) = parse_number(rest.trim_ascii(), 0, b';').ok()?;
        (end == rest.trim_ascii().len()).then_some(v? / NM_PER_MM)
    };
    if comment.starts_with(b"LAYER_CHANGE") {
        return Some(Action::Layer(layer.map_or(0, |l| l.saturating_add(1))));
    }
    if let Some(rest) = comment.strip_prefix(b"LAYER_COUNT:") {
        return Some(Action::LayerCount(u32::try_from(number(rest)?).ok()?));
    }
    if let Some(rest) = comment.strip_prefix(b"LAYER:") {
        return Some(Action::Layer(u32::try_from(number(rest)?.max(0)).ok()?));
    }
    None
}

/// The machine's limits the reader needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Limits {
    steps_per_mm: [Rate; AXES],
    /// Build volume X, Y, Z, nm.
    volume_nm: [i64; 3],
    max_hotend_c: i16,
    max_bed_c: i16,
}

/// The interpreter: Marlin's modal state and both positions of each axis.
#[derive(Debug, Clone)]
pub struct Reader {
    limits: Limits,
    /// Position as the G-code sees it (`G92` sets it), nm.
    logical_nm: [i64; AXES],
    /// Position of the motor (the planner's), nm.
    machine_nm: [i64; AXES],
    /// Absolute XYZ (`G90`).
    absolute: bool,
    /// Absolute extruder (`M82`).
    absolute_e: bool,
    /// Numbers are inches (`G20`).
    inches: bool,
    /// Feed rate, mm/min in millionths (0: none given yet).
    feed: i64,
    speed_percent: i64,
    flow_percent: i64,
    /// The line number the next numbered line must have.
    next_line: u32,
    /// The layer of the last marker.
    layer: Option<u32>,
    /// The arc being cut into segments.
    arc: Option<ArcCut>,
    stats: ReadStats,
}

/// An arc (`G2`/`G3`) cut into straight segments of about [`ARC_SEGMENT_NM`].
#[derive(Debug, Clone, Copy)]
struct ArcCut {
    /// Centre X, Y, machine nm.
    centre: [i64; 2],
    radius: i64,
    /// Angle of the start, q30 rad.
    start: i64,
    /// Angle turned, q30 rad (negative clockwise).
    travel: i64,
    /// Machine position at the start and at the end, nm.
    from: [i64; AXES],
    to: [i64; AXES],
    segments: u32,
    /// Segments given.
    done: u32,
    /// The last segment's end (at first the start), nm.
    last: [i64; AXES],
    feed: Rate,
}

impl Reader {
    /// A reader for `machine` at its origin: absolute, millimetres, relative nothing.
    pub fn new(machine: &MachineConfig) -> Self {
        let v = machine.build_volume_um;
        Self {
            limits: Limits {
                steps_per_mm: machine.steps_per_mm,
                volume_nm: [v[0], v[1], v[2]].map(|um| i64::from(um) * NM_PER_UM),
                max_hotend_c: machine.max_hotend_temp_c,
                max_bed_c: machine.max_bed_temp_c,
            },
            logical_nm: [0; AXES],
            machine_nm: [0; AXES],
            absolute: true,
            absolute_e: true,
            inches: false,
            feed: 0,
            speed_percent: 100,
            flow_percent: 100,
            next_line: 1,
            layer: None,
            arc: None,
            stats: ReadStats::default(),
        }
    }

    /// What the reader has seen.
    pub fn stats(&self) -> &ReadStats {
        &self.stats
    }

    /// The motors' position, um (the last move's target).
    pub fn machine_um(&self) -> [i32; AXES] {
        self.machine_nm.map(|nm| clamp_i32(nm.div_euclid(NM_PER_UM)))
    }

    /// A line ([`LineSplitter::line`]) refused by the splitter: counted.
    pub fn refuse(&mut self, e: LineError) -> LineError {
        self.stats.lines += 1;
        self.stats.refused += 1;
        e
    }

    /// Reads one line (without its end). `Ok(None)`: nothing to do (a blank or comment line,
    /// a modal change, a move that goes nowhere is still returned).
    pub fn line<'l>(&mut self, line: &'l [u8]) -> Result<Option<Action<'l>>, LineError> {
        self.stats.lines += 1;
        self.arc = None;
        let saved = (self.logical_nm, self.machine_nm, self.feed);
        let r = self.read(line);
        match r {
            Ok(Some(Action::Move(_))) => self.stats.moves += 1,
            Ok(Some(Action::Skipped { .. })) => self.stats.skipped += 1,
            Err(_) => {
                self.stats.refused += 1;
                (self.logical_nm, self.machine_nm, self.feed) = saved;
            }
            _ => {}
        }
        r
    }

    fn read<'l>(&mut self, line: &'l [u8]) -> Result<Option<Action<'l>>, LineError> {
        let LineParts { code, comment, number } = split_line(line)?;
        let Some((letter, code_number, sub, end)) = parse_command(code)? else {
            // A numbered empty line still counts in the sequence.
            self.check_number(number, false)?;
            let m = marker(comment.trim_ascii_start(), self.layer);
            if let Some(Action::Layer(l)) = m {
                self.layer = Some(l);
            }
            return Ok(m);
        };
        self.check_number(number, (letter, code_number) == (b'M', 110))?;
        let rest = code.get(end..).unwrap_or(&[]);
        let skipped = Action::Skipped { letter, code: code_number };
        if sub {
            return Ok(Some(skipped));
        }
        // Only commands this reader runs have their words read: others may carry anything.
        let words = || parse_words(rest);
        let action = match (letter, code_number) {
            (b'G', 0 | 1) => self.linear(&words()?)?,
            (b'G', 2 | 3) => self.arc(&words()?, code_number == 2)?,
            // The XY plane only: arcs in another plane are not run.
            (b'G', 17) => None,
            (b'G', 4) => self.dwell(&words()?)?,
            (b'G', 20) => self.set(|r| r.inches = true),
            (b'G', 21) => self.set(|r| r.inches = false),
            (b'G', 28) => Some(self.home(&words()?)),
            (b'G', 90) => self.set(|r| (r.absolute, r.absolute_e) = (true, true)),
            (b'G', 91) => self.set(|r| (r.absolute, r.absolute_e) = (false, false)),
            (b'G', 92) => self.set_position(&words()?)?,
            (b'M', 82) => self.set(|r| r.absolute_e = true),
            (b'M', 83) => self.set(|r| r.absolute_e = false),
            (b'M', 104 | 109) => Some(self.heat(&words()?, Heater::Hotend, code_number == 109)?),
            (b'M', 140 | 190) => Some(self.heat(&words()?, Heater::Bed, code_number == 190)?),
            (b'M', 106 | 107) => {
                let w = words()?;
                if w.whole(P, 0..=0).is_err() {
                    // Another fan than the part-cooling fan.
                    Some(skipped)
                } else if code_number == 107 {
                    Some(Action::Fan(0))
                } else {
                    Some(Action::Fan(w.whole(S, 0..=255)?.unwrap_or(255) as u8))
                }
            }
            (b'M', 18 | 84) => {
                // With S, only the idle timeout is set.
                if words()?.has(S) {
                    Some(skipped)
                } else {
                    Some(Action::MotorsOff)
                }
            }
            (b'M', 105) => Some(Action::Report(Report::Temperatures)),
            (b'M', 114) => Some(Action::Report(Report::Position)),
            (b'M', 115) => Some(Action::Report(Report::Firmware)),
            (b'M', 117) => Some(Action::Message(rest.trim_ascii())),
            (b'M', 220) => self.factor(&words()?, |r, v| r.speed_percent = v)?,
            (b'M', 221) => self.factor(&words()?, |r, v| r.flow_percent = v)?,
            (b'M', 400) => Some(Action::Sync),
            (b'M', 73) => {
                let w = words()?;
                Some(Action::Progress {
                    percent: w.whole(P, 0..=100)?.map(|p| p as u8),
                    minutes_left: w.whole(R, 0..=i64::from(u32::MAX))?.map(|m| m as u32),
                })
            }
            // M110 only sets the sequence (checked above); T0 is the only extruder.
            (b'M', 110) | (b'T', 0) => None,
            _ => Some(skipped),
        };
        Ok(action)
    }

    fn set<'l>(&mut self, f: impl FnOnce(&mut Self)) -> Option<Action<'l>> {
        f(self);
        None
    }

    /// Honours `N`: a numbered line must carry the expected number (`M110 N` sets it).
    fn check_number(&mut self, number: Option<u32>, sets_it: bool) -> Result<(), LineError> {
        let Some(n) = number else { return Ok(()) };
        if !sets_it && n != self.next_line {
            return Err(LineError::LineNumber { expected: self.next_line });
        }
        self.next_line = n.wrapping_add(1);
        Ok(())
    }

    /// A number of millimetres (or inches after `G20`) in nm.
    fn length_nm(&self, micro: i64) -> i64 {
        if self.inches {
            // 25.4 mm per inch: millionths of an inch times 25.4 is nm.
            micro.saturating_mul(254) / 10
        } else {
            micro
        }
    }

    /// `G0`/`G1`: the new positions and the move to them.
    fn linear<'l>(&mut self, w: &Words) -> Result<Option<Action<'l>>, LineError> {
        self.set_feed(w)?;
        let before = self.machine_nm;
        if !self.advance(w, true)? {
            return Ok(None);
        }
        if self.feed == 0 {
            return Err(LineError::MissingValue { letter: b'F' });
        }
        let kind = kind_between(&before, &self.machine_nm);
        Ok(Some(Action::Move(Move::new(self.target(), self.feed_rate(), kind))))
    }

    /// The modal feed rate from `F`, when given.
    fn set_feed(&mut self, w: &Words) -> Result<(), LineError> {
        if let Some(f) = w.num(F)? {
            if f <= 0 {
                return Err(LineError::OutOfRange { letter: b'F' });
            }
            self.feed = self.length_nm(f);
        }
        Ok(())
    }

    /// The feed rate of a move: mm/min in millionths times the speed factor, to mm/s in 32.32,
    /// at least Marlin's slowest planned speed.
    fn feed_rate(&self) -> Rate {
        let bits = (self.feed as i128 * self.speed_percent as i128) << 32;
        let slowest = (MIN_FEED_MM_S_X100 << 32) / 100;
        Rate::from_bits(
            (bits / (60 * NM_PER_MM as i128 * 100)).clamp(slowest, u64::MAX as i128) as u64
        )
    }

    /// The logical and machine positions of the axes `w` names (X, Y, Z and Z clamped to the
    /// build volume, X and Y only with `clamp_xy`); whether it named any.
    fn advance(&mut self, w: &Words, clamp_xy: bool) -> Result<bool, LineError> {
        let mut any = false;
        let mut clamped = false;
        for axis in 0..AXES {
            let Some(v) = w.num(X + axis)? else { continue };
            any = true;
            let v = self.length_nm(v);
            let relative = if axis == E { !self.absolute_e } else { !self.absolute };
            let logical = if relative { self.logical_nm[axis].saturating_add(v) } else { v };
            let mut delta = logical.saturating_sub(self.logical_nm[axis]);
            if axis == E {
                delta = delta.saturating_mul(self.flow_percent) / 100;
            }
            let mut machine = self.machine_nm[axis].saturating_add(delta);
            match self.limits.volume_nm.get(axis) {
                Some(&max) if (clamp_xy || axis == 2) && !(0..=max).contains(&machine) => {
                    machine = machine.clamp(0, max);
                    clamped = true;
                }
                Some(_) if clamp_xy || axis == 2 => {}
                // An arc's end is clamped segment by segment; never beyond the numbers' range.
                Some(_) => machine = machine.clamp(-MAX_ARC_REACH_NM, MAX_ARC_REACH_NM),
                None if machine.unsigned_abs() > i32::MAX as u64 * NM_PER_UM as u64 => {
                    return Err(LineError::OutOfRange { letter: b'E' });
                }
                None => {}
            }
            self.logical_nm[axis] = logical;
            self.machine_nm[axis] = machine;
        }
        if clamped {
            self.stats.clamped += 1;
        }
        Ok(any)
    }

    /// `G2` (clockwise) / `G3`: an arc in the XY plane around the centre `I` `J` from the start
    /// (or of radius `R`), Z and E in proportion; its first segment (the others:
    /// [`continuation`](Self::continuation)).
    fn arc<'l>(&mut self, w: &Words, clockwise: bool) -> Result<Option<Action<'l>>, LineError> {
        let (i, j, r) = (w.num(I)?, w.num(J)?, w.num(R)?);
        self.set_feed(w)?;
        let from = self.machine_nm;
        self.advance(w, false)?;
        if self.feed == 0 {
            return Err(LineError::MissingValue { letter: b'F' });
        }
        let to = self.machine_nm;
        let (dx, dy) = (to[X] - from[X], to[Y] - from[Y]);
        let centre = match (i, j, r) {
            (None, None, Some(r)) => {
                let r = self.length_nm(r);
                centre_of(from, dx, dy, r, clockwise)
                    .ok_or(LineError::OutOfRange { letter: b'R' })?
            }
            (None, None, None) => return Err(LineError::MissingValue { letter: b'I' }),
            _ => {
                let (i, j) = (self.length_nm(i.unwrap_or(0)), self.length_nm(j.unwrap_or(0)));
                [from[X] + i, from[Y] + j]
            }
        };
        let (sx, sy) = (from[X] - centre[0], from[Y] - centre[1]);
        let radius = isqrt_u128((sx as i128 * sx as i128 + sy as i128 * sy as i128) as u128) as i64;
        if radius == 0 {
            return Err(LineError::OutOfRange { letter: b'I' });
        }
        let start = cordic::atan2(sy, sx);
        let end = cordic::atan2(to[Y] - centre[1], to[X] - centre[0]);
        // Clockwise turns negative; the same start and end make a whole circle.
        let mut travel = end - start;
        if clockwise && travel >= 0 {
            travel -= cordic::TAU;
        } else if !clockwise && travel <= 0 {
            travel += cordic::TAU;
        }
        let flat = ((travel.unsigned_abs() as u128 * radius as u128) >> cordic::ONE_BITS) as i128;
        let rise = (to[2] - from[2]) as i128;
        let length = isqrt_u128((flat * flat + rise * rise) as u128) as i64;
        let segments = (length / ARC_SEGMENT_NM).clamp(1, MAX_ARC_SEGMENTS);
        // Where the arc leaves the machine: its end, clamped as its last segment is.
        for (axis, max) in self.limits.volume_nm.iter().enumerate().take(2) {
            self.machine_nm[axis] = self.machine_nm[axis].clamp(0, *max);
        }
        let arc = ArcCut {
            centre,
            radius,
            start,
            travel,
            from,
            to,
            segments: segments as u32,
            done: 0,
            last: from,
            feed: self.feed_rate(),
        };
        self.arc = Some(arc);
        Ok(self.next_segment().map(Action::Move))
    }

    /// The next segment of the arc being cut, counted as a move; `None` once it is whole
    /// (call until then before the next [`line`](Self::line), which drops what is left).
    pub fn continuation(&mut self) -> Option<Move> {
        let m = self.next_segment()?;
        self.stats.moves += 1;
        Some(m)
    }

    fn next_segment(&mut self) -> Option<Move> {
        let arc = self.arc.as_mut()?;
        arc.done += 1;
        let (k, n) = (i64::from(arc.done), i64::from(arc.segments));
        let mut at = arc.to;
        if k < n {
            let angle = arc.start + (arc.travel as i128 * k as i128 / n as i128) as i64;
            let (sin, cos) = cordic::sin_cos(angle);
            at[X] = arc.centre[0] + ((arc.radius as i128 * cos as i128) >> cordic::ONE_BITS) as i64;
            at[Y] = arc.centre[1] + ((arc.radius as i128 * sin as i128) >> cordic::ONE_BITS) as i64;
            for ((a, from), to) in at.iter_mut().zip(arc.from).zip(arc.to).skip(2) {
                *a = from + ((to - from) as i128 * k as i128 / n as i128) as i64;
            }
        }
        let (before, feed) = (arc.last, arc.feed);
        let mut clamped = false;
        for (axis, max) in self.limits.volume_nm.iter().enumerate().take(2) {
            clamped |= !(0..=*max).contains(&at[axis]);
            at[axis] = at[axis].clamp(0, *max);
        }
        arc.last = at;
        if k >= n {
            self.arc = None;
        }
        self.stats.clamped += u32::from(clamped);
        let target = core::array::from_fn(|a| target_um(at[a], self.limits.steps_per_mm[a]));
        Some(Move::new(target, feed, kind_between(&before, &at)))
    }

    /// The planner target of the machine position: each axis in um on the step nearest the
    /// exact position.
    fn target(&self) -> [i32; AXES] {
        core::array::from_fn(|a| target_um(self.machine_nm[a], self.limits.steps_per_mm[a]))
    }

    /// `G4`: a dwell of P ms or S s at the current position.
    fn dwell<'l>(&mut self, w: &Words) -> Result<Option<Action<'l>>, LineError> {
        // Millionths of a ms (P) or of a second (S), as us.
        let us = match (w.num(P)?, w.num(S)?) {
            (Some(p), _) => p / 1000,
            (None, Some(s)) => s,
            (None, None) => 0,
        };
        if us <= 0 {
            return Ok(None);
        }
        let seconds = Rate::from_bits((((us as u128) << 32) / 1_000_000) as u64);
        Ok(Some(Action::Move(Move::dwell(self.target(), seconds))))
    }

    /// `G28`: the named axes (all without names) go to machine 0.
    fn home<'l>(&mut self, w: &Words) -> Action<'l> {
        let named = (0..3).fold(0u8, |m, a| m | (u8::from(w.has(X + a)) << a));
        let axes = if named == 0 { 0b111 } else { named };
        for a in (0..3).filter(|a| axes & (1 << a) != 0) {
            self.logical_nm[a] = 0;
            self.machine_nm[a] = 0;
        }
        let travel = Move::new(self.target(), Rate::from_num(HOMING_FEED_MM_S), MoveKind::Travel);
        Action::Home { axes, travel }
    }

    /// `G92`: the logical position of the named axes; the motors stay.
    fn set_position<'l>(&mut self, w: &Words) -> Result<Option<Action<'l>>, LineError> {
        let mut values = [None; AXES];
        for (a, v) in values.iter_mut().enumerate() {
            *v = w.num(X + a)?;
        }
        for (a, v) in values.into_iter().enumerate() {
            if let Some(v) = v {
                self.logical_nm[a] = self.length_nm(v);
            }
        }
        Ok(None)
    }

    /// `M104`/`M109`/`M140`/`M190`: S sets (and waits to heat), R sets and waits either way.
    fn heat<'l>(&mut self, w: &Words, heater: Heater, wait: bool) -> Result<Action<'l>, LineError> {
        let max = match heater {
            Heater::Hotend => self.limits.max_hotend_c,
            Heater::Bed => self.limits.max_bed_c,
        };
        let range = 0..=i64::from(max);
        let (target, cool) = match (w.whole(S, range.clone())?, wait) {
            (Some(s), _) => (s, false),
            (None, true) => {
                (w.whole(R, range)?.ok_or(LineError::MissingValue { letter: b'S' })?, true)
            }
            (None, false) => return Err(LineError::MissingValue { letter: b'S' }),
        };
        Ok(Action::Heat { heater, target_c: target as i16, wait, cool })
    }

    /// `M220`/`M221 S`: a factor in percent.
    fn factor<'l>(
        &mut self,
        w: &Words,
        set: impl FnOnce(&mut Self, i64),
    ) -> Result<Option<Action<'l>>, LineError> {
        if let Some(v) = w.whole(S, FACTOR_PERCENT)? {
            set(self, v);
        }
        Ok(None)
    }
}

/// Print when the extruder moves with XYZ, retract when it moves alone, travel otherwise.
fn kind_between(before: &[i64; AXES], after: &[i64; AXES]) -> MoveKind {
    let moved = |a: usize| after[a] != before[a];
    match ((0..E).any(moved), moved(E)) {
        (true, true) => MoveKind::Print,
        (false, true) => MoveKind::Retract,
        _ => MoveKind::Travel,
    }
}

/// The centre of the arc of radius `r` (nm; negative: the longer way round) from `from` by
/// (`dx`, `dy`), turning clockwise or not; `None` when the ends are further apart than the
/// diameter or the same (Marlin's `R` form).
fn centre_of(from: [i64; AXES], dx: i64, dy: i64, r: i64, clockwise: bool) -> Option<[i64; 2]> {
    let d2 = dx as i128 * dx as i128 + dy as i128 * dy as i128;
    let r2 = r as i128 * r as i128;
    if d2 == 0 || 4 * r2 < d2 {
        return None;
    }
    let d = isqrt_u128(d2 as u128) as i128;
    // Distance of the centre from the chord's middle, on its left (anticlockwise) for a
    // clockwise arc shorter than a half circle.
    let h = isqrt_u128((4 * r2 - d2) as u128) as i128 / 2;
    let left = clockwise != (r > 0);
    let sign: i128 = if left { 1 } else { -1 };
    let cx = from[X] as i128 + dx as i128 / 2 - sign * h * dy as i128 / d;
    let cy = from[Y] as i128 + dy as i128 / 2 + sign * h * dx as i128 / d;
    Some([cx as i64, cy as i64])
}

/// Fixed-point trigonometry for arcs (CORDIC, no floating point): angles in q30 radians.
mod cordic {
    /// Fraction bits of angles and of sine and cosine.
    pub const ONE_BITS: u32 = 30;
    /// pi in q30.
    pub const PI: i64 = 3_373_259_426;
    /// 2 pi in q30.
    pub const TAU: i64 = 2 * PI;
    /// atan(2^-i) in q30.
    const ATAN: [i64; 31] = [
        843_314_857,
        497_837_829,
        263_043_837,
        133_525_159,
        67_021_687,
        33_543_516,
        16_775_851,
        8_388_437,
        4_194_283,
        2_097_149,
        1_048_576,
        524_288,
        262_144,
        131_072,
        65_536,
        32_768,
        16_384,
        8_192,
        4_096,
        2_048,
        1_024,
        512,
        256,
        128,
        64,
        32,
        16,
        8,
        4,
        2,
        1,
    ];
    /// The rotations' gain 1 / prod sqrt(1 + 2^-2i) in q30.
    const GAIN: i64 = 652_032_874;

    /// The angle of (`x`, `y`) in (-pi, pi], q30; 0 for the origin. |x|, |y| < 2^62.
    pub fn atan2(y: i64, x: i64) -> i64 {
        if x == 0 && y == 0 {
            return 0;
        }
        // Into the right half plane, then rotate onto the X axis.
        let (mut x, mut y, mut z) = if x < 0 {
            if y >= 0 {
                (y, -x, PI / 2)
            } else {
                (-y, x, -PI / 2)
            }
        } else {
            (x, y, 0)
        };
        // Room for the gain's growth: the vector at 2^52 or below.
        while x.abs() > 1 << 52 || y.abs() > 1 << 52 {
            (x, y) = (x >> 1, y >> 1);
        }
        for (i, a) in ATAN.iter().enumerate() {
            let (dx, dy) = (y >> i, x >> i);
            if y > 0 {
                (x, y, z) = (x + dx, y - dy, z + a);
            } else {
                (x, y, z) = (x - dx, y + dy, z - a);
            }
        }
        z
    }

    /// Sine and cosine of `angle` (q30 rad, any), q30.
    pub fn sin_cos(angle: i64) -> (i64, i64) {
        // Into [-pi, pi], then into [-pi/2, pi/2] (a half turn flips both signs).
        let mut a = angle.rem_euclid(TAU);
        if a > PI {
            a -= TAU;
        }
        let flip = !(-PI / 2..=PI / 2).contains(&a);
        if a > PI / 2 {
            a -= PI;
        } else if a < -PI / 2 {
            a += PI;
        }
        let (mut x, mut y, mut z) = (GAIN, 0i64, a);
        for (i, t) in ATAN.iter().enumerate() {
            let (dx, dy) = (y >> i, x >> i);
            if z >= 0 {
                (x, y, z) = (x - dx, y + dy, z - t);
            } else {
                (x, y, z) = (x + dx, y - dy, z + t);
            }
        }
        if flip {
            (-y, -x)
        } else {
            (y, x)
        }
    }
}

fn clamp_i32(v: i64) -> i32 {
    v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

/// A position of `nm` nanometres as whole um whose nearest motor step (on an axis of
/// `steps_per_mm`) is the step nearest `nm` itself.
///
/// It is the um nearest `nm`, moved by one or two um where rounding to um would cross a
/// half-step boundary (a step is 2.5 um or more on every axis of a machine with up to 400
/// steps/mm; finer axes keep the nearest um).
pub fn target_um(nm: i64, steps_per_mm: Rate) -> i32 {
    let spm = i128::from(steps_per_mm.to_bits());
    // Exact position in steps, q32 (floor), and its nearest step.
    let exact_q32 = (i128::from(nm) * spm).div_euclid(NM_PER_MM as i128);
    let want =
        nearest_step(exact_q32.clamp(i128::from(i64::MIN / 2), i128::from(i64::MAX / 2)) as i64);
    let half = 1i64 << 31;
    let nearest = clamp_i32((nm + NM_PER_UM / 2).div_euclid(NM_PER_UM));
    let mut um = nearest;
    // Up to two um either way (a step of 2.5 um holds two whole um strictly inside).
    for _ in 0..4 {
        let p = step_position_q32(um, steps_per_mm);
        let centre = want.saturating_mul(1 << 32);
        if p <= centre - half {
            um = um.saturating_add(1);
        } else if p >= centre + half {
            um = um.saturating_sub(1);
        } else {
            return um;
        }
    }
    nearest
}

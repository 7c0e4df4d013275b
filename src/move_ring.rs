//! The move buffer: toolpath moves waiting for the planner, delta-coded into a byte ring.
//!
//! [`MoveStream`] turns the toolpath stage's moves (relative E) into [`PackedMove`]s (absolute
//! E, the feed as U16F16 bits, the layer). [`MoveRing`] stores each as one variable-length
//! record relative to the move before it, so a move takes a few bytes instead of 24 (5.0 to
//! 6.3 on average over the sample models, at most [`MAX_RECORD`]):
//!
//! - a header byte: bits 0-1 the kind (0 print, 1 travel, 2 retract, 3 dwell), bit 2 the layer
//!   or the fan changed, bit 3 the feed changed, bits 4-7 which of the X, Y, Z, E deltas
//!   follow;
//! - the non-zero deltas of X, Y, Z, E (um, in that order), each a zigzag LEB128 varint
//!   (deltas taken in `i64`: no overflow at the `i32` extremes), then, when the layer or the
//!   fan changed, the layer delta's zigzag shifted left by 8 with the fan duty in the low
//!   byte, as an LEB128 varint (a layer's first move: 2 bytes);
//! - the feed bits when the feed changed, halves swapped (whole mm/s, the usual case, then
//!   fit one or two bytes), as an LEB128 varint.
//!
//! The producer side ([`MoveEncoder`]) codes each move against the last one pushed, the
//! consumer side against the last one popped; both start at the origin (all zero) after
//! [`MoveRing::clear`]. The coding is lossless: every `PackedMove` comes out bit for bit as
//! it went in.
//!
//! Flow control ([`crate::printer`]): the toolpath stage emits a layer unit by unit (a path
//! with the travel before it, [`Toolpath::emit_next`](crate::toolpath::Toolpath::emit_next))
//! into the ring's [`RingRoom`] ([`MoveRing::room`]), each unit generated once: its moves are
//! pushed as they come; when one does not fit, the rest are only coded to count the unit's
//! bytes, and at the unit's end the ring (bytes in use, coder) and the [`MoveStream`] go back
//! to where the unit began and the stage undoes it too. The unit waits, and is offered again
//! once its exact bytes are free ([`RoomMemory`]). A unit's bytes depend on the move before
//! it only, not on what waits in the ring: a unit refused by an empty ring never fits
//! ([`RingRoom::never_fits`]). The host's admission control codes a job's moves with a
//! [`MoveMeter`] to find its largest unit in bytes.
//!
//! Every move of a layer is in one of its units (the height change, retraction and priming
//! with the travel they belong to, a layer without extrusion closed by a unit of its own), so
//! the rooms count every byte the ring takes. The other events are outside the units and
//! take no bytes: a layer's `LayerStart` goes out when the layer is built, before its first
//! unit is offered (it sets the stream's layer), and its `LayerEnd` after its last unit.

use crate::machine::{Rate, AXES};
use crate::plan::{Move, MoveKind};
use crate::toolpath::{Feature, Room, ToolEvent, ToolMove};

/// A toolpath move waiting for the planner.
///
/// The planner's [`Move`] with its feed as U16F16 bits (the toolpath's feeds are whole or simple
/// fractions of mm/s; the same packing runs on the host simulation and the board) and the layer it
/// belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PackedMove {
    /// Target X, Y, Z, E, um.
    pub target_um: [i32; AXES],
    /// Feed, mm/s as U16F16 bits.
    pub feed_bits: u32,
    /// Layer (saturated at `u16::MAX`).
    pub layer: u16,
    /// The part-cooling fan's duty from this move on, 0..=255 ([`ToolMove::fan`]; 0 for a
    /// G-code job's moves, whose fan is a setting timed to the motion).
    pub fan: u8,
    /// Print, travel or retract.
    pub kind: MoveKind,
}

impl PackedMove {
    /// Where both coder states start: the origin, feed 0, layer 0.
    pub const ORIGIN: Self =
        Self { target_um: [0; AXES], feed_bits: 0, layer: 0, fan: 0, kind: MoveKind::Print };

    /// `mv` of `layer`, fan off; the feed keeps 16 fractional bits (saturating at 65,536
    /// mm/s).
    pub fn pack(layer: u32, mv: &Move) -> Self {
        let feed_bits = (mv.feed_mm_s.to_bits() >> 16).min(u32::MAX as u64) as u32;
        let layer = layer.min(u16::MAX as u32) as u16;
        Self { target_um: mv.target_um, feed_bits, layer, fan: 0, kind: mv.kind }
    }

    /// The move for the planner.
    pub fn unpack(&self) -> Move {
        Move::new(self.target_um, Rate::from_bits(u64::from(self.feed_bits) << 16), self.kind)
    }
}

/// Where the toolpath stream stands.
///
/// Its layer, absolute E and position. Turns the toolpath stage's moves into planner moves (the
/// printer and the host's admission control both use it, so both see the same moves).
#[derive(Debug, Clone, Copy, Default)]
pub struct MoveStream {
    layer: u32,
    e_um: i32,
    xyz: [i32; 3],
}

impl MoveStream {
    /// Layer 0 at the origin, E 0 (where a job starts).
    pub const fn new() -> Self {
        Self { layer: 0, e_um: 0, xyz: [0; 3] }
    }

    /// The layer the next moves belong to (the toolpath stage's `LayerStart`).
    pub fn start_layer(&mut self, index: u32) {
        self.layer = index;
    }

    /// The current layer.
    pub fn layer(&self) -> u32 {
        self.layer
    }

    /// `m` as a planner move with absolute E: a retraction when the head stays in place, a
    /// print move when it extrudes, a travel otherwise; a dwell where the head is.
    pub fn next(&mut self, m: &ToolMove) -> PackedMove {
        if m.feature == Feature::Dwell {
            let at = [self.xyz[0], self.xyz[1], self.xyz[2], self.e_um];
            let dwell = Move::dwell(at, m.feed_mm_s);
            return PackedMove { fan: m.fan, ..PackedMove::pack(self.layer, &dwell) };
        }
        self.e_um = self.e_um.wrapping_add(m.e_um);
        let xyz = [m.to.x, m.to.y, m.z_um];
        let kind = if xyz == self.xyz {
            MoveKind::Retract
        } else if m.e_um > 0 {
            MoveKind::Print
        } else {
            MoveKind::Travel
        };
        self.xyz = xyz;
        let mv = Move::new([xyz[0], xyz[1], xyz[2], self.e_um], m.feed_mm_s, kind);
        PackedMove { fan: m.fan, ..PackedMove::pack(self.layer, &mv) }
    }
}

/// The longest record: the header, four axis deltas of up to 33 zigzag bits (5 bytes each),
/// a layer delta of up to 17 zigzag bits with the fan's 8 (4 bytes) and the feed's 32 bits
/// (5 bytes).
pub const MAX_RECORD: usize = 1 + 4 * 5 + 4 + 5;

/// Header bit: the layer or the fan changed (the layer delta and the fan follow the axis
/// deltas).
const NEW_LAYER: u8 = 1 << 2;
/// Header bit: the feed changed (its bits end the record).
const NEW_FEED: u8 = 1 << 3;
/// Header bit of the first axis delta (X; Y, Z, E follow).
const AXIS_DELTA: u8 = 1 << 4;

/// The producer side of the coding: the last move coded.
#[derive(Debug, Clone, Copy)]
pub struct MoveEncoder {
    prev: PackedMove,
}

impl Default for MoveEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl MoveEncoder {
    /// At the origin ([`PackedMove::ORIGIN`]).
    pub const fn new() -> Self {
        Self { prev: PackedMove::ORIGIN }
    }

    /// Writes `mv`'s record (relative to the last move coded) into `out` and returns its
    /// length; `mv` becomes the last move coded.
    pub fn encode(&mut self, mv: &PackedMove, out: &mut [u8; MAX_RECORD]) -> usize {
        let mut w = Writer { out, len: 1 };
        let mut header = match mv.kind {
            MoveKind::Print => 0,
            MoveKind::Travel => 1,
            MoveKind::Retract => 2,
            MoveKind::Dwell => 3,
        };
        for (axis, (&to, &from)) in mv.target_um.iter().zip(&self.prev.target_um).enumerate() {
            let delta = i64::from(to) - i64::from(from);
            if delta != 0 {
                header |= AXIS_DELTA << axis;
                w.varint(zigzag(delta));
            }
        }
        if mv.layer != self.prev.layer || mv.fan != self.prev.fan {
            header |= NEW_LAYER;
            let delta = zigzag(i64::from(mv.layer) - i64::from(self.prev.layer));
            w.varint(delta << 8 | u64::from(mv.fan));
        }
        if mv.feed_bits != self.prev.feed_bits {
            header |= NEW_FEED;
            w.varint(u64::from(mv.feed_bits.rotate_left(16)));
        }
        if let Some(first) = w.out.first_mut() {
            *first = header;
        }
        self.prev = *mv;
        w.len
    }
}

/// Appends bytes to a record buffer (never past its end: [`MAX_RECORD`] holds every record).
struct Writer<'a> {
    out: &'a mut [u8; MAX_RECORD],
    len: usize,
}

impl Writer<'_> {
    /// `v` as LEB128: 7 bits a byte, low first, the top bit set on all but the last.
    fn varint(&mut self, mut v: u64) {
        loop {
            let low = (v & 0x7f) as u8;
            v >>= 7;
            let byte = if v == 0 { low } else { low | 0x80 };
            if let Some(slot) = self.out.get_mut(self.len) {
                *slot = byte;
            }
            self.len += 1;
            if v == 0 {
                break;
            }
        }
    }
}

/// Signed to unsigned with the small magnitudes small: 0, -1, 1, -2, ... -> 0, 1, 2, 3, ...
fn zigzag(v: i64) -> u64 {
    ((v << 1) ^ (v >> 63)) as u64
}

fn unzigzag(v: u64) -> i64 {
    (v >> 1) as i64 ^ -((v & 1) as i64)
}

/// Reads one LEB128 varint from `bytes`; `None` when they end first or it exceeds 64 bits.
fn read_varint(bytes: &mut impl Iterator<Item = u8>) -> Option<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let b = bytes.next()?;
        let bits = u64::from(b & 0x7f);
        if shift == 63 && bits > 1 {
            return None;
        }
        v |= bits << shift;
        if b & 0x80 == 0 {
            return Some(v);
        }
    }
    None
}

/// Decodes the record at the front of `bytes` relative to `prev`; `None` when it is not a
/// record [`MoveEncoder::encode`] writes (a malformed header or varint, a value out of range).
fn decode(prev: &PackedMove, bytes: &mut impl Iterator<Item = u8>) -> Option<PackedMove> {
    let header = bytes.next()?;
    let kind = match header & 3 {
        0 => MoveKind::Print,
        1 => MoveKind::Travel,
        2 => MoveKind::Retract,
        _ => MoveKind::Dwell,
    };
    let mut mv = PackedMove { kind, ..*prev };
    for (axis, target) in mv.target_um.iter_mut().enumerate() {
        if header & (AXIS_DELTA << axis) != 0 {
            let delta = unzigzag(read_varint(bytes)?);
            *target = i32::try_from(i64::from(*target).checked_add(delta)?).ok()?;
        }
    }
    if header & NEW_LAYER != 0 {
        let v = read_varint(bytes)?;
        mv.fan = v as u8;
        let delta = unzigzag(v >> 8);
        mv.layer = u16::try_from(i64::from(mv.layer).checked_add(delta)?).ok()?;
    }
    if header & NEW_FEED != 0 {
        mv.feed_bits = u32::try_from(read_varint(bytes)?).ok()?.rotate_right(16);
    }
    Some(mv)
}

/// Bytes of toolpath events as a move buffer codes them: a [`MoveStream`] and a
/// [`MoveEncoder`] run on (copies of the ones the moves will go through).
#[derive(Debug, Clone, Copy, Default)]
pub struct MoveMeter {
    stream: MoveStream,
    encoder: MoveEncoder,
}

impl MoveMeter {
    /// From `stream` and `encoder`'s state.
    pub const fn new(stream: MoveStream, encoder: MoveEncoder) -> Self {
        Self { stream, encoder }
    }

    /// Takes `e`: a move's record length, bytes (0 for the other events; a layer start
    /// sets the layer of the next moves, as the printer's stream does).
    pub fn event(&mut self, e: &ToolEvent<'_>) -> usize {
        match e {
            ToolEvent::Move(m) => {
                let mut record = [0u8; MAX_RECORD];
                self.encoder.encode(&self.stream.next(m), &mut record)
            }
            ToolEvent::LayerStart { index, .. } => {
                self.stream.start_layer(*index);
                0
            }
            ToolEvent::LayerEnd(_) | ToolEvent::Progress => 0,
        }
    }
}

/// What an owner's rooms learn from one call to the next ([`MoveRing::room`]).
///
/// The bytes the waiting unit needs (exact when it was coded, an estimate otherwise), and the bytes
/// and moves of the units taken so far, whose ratio with a quarter added is the estimate that
/// spares coding a unit that cannot fit.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RoomMemory {
    /// Bytes to wait for before offering again (0: none waits).
    wait: usize,
    /// `wait` is the waiting unit's exact bytes.
    exact: bool,
    /// Bytes and moves of the units taken.
    coded: (u64, u64),
    /// Bytes of the largest unit taken.
    largest: usize,
}

impl RoomMemory {
    /// Nothing learnt yet (a new job).
    pub const EMPTY: Self = Self { wait: 0, exact: false, coded: (0, 0), largest: 0 };

    /// Free bytes below which offering the waiting unit is no use.
    pub fn waits_for(&self) -> usize {
        self.wait
    }

    /// Bytes of the largest unit taken.
    pub fn largest(&self) -> usize {
        self.largest
    }

    /// Bytes and moves of the units taken.
    pub fn coded(&self) -> (u64, u64) {
        self.coded
    }

    /// Expected bytes of a unit of `moves` moves: the bytes per move so far plus a quarter
    /// (0 before any unit was taken).
    fn expected(&self, moves: u32) -> usize {
        let (bytes, taken) = self.coded;
        let per_move_q4 = (bytes * 20).checked_div(taken).unwrap_or(0) as usize;
        (moves as usize).saturating_mul(per_move_q4) >> 4
    }
}

/// The move ring as the toolpath stage's [`Room`] (see the [module docs](self)).
///
/// Each move of a unit is coded into the ring as it comes (through the [`MoveStream`]); when one
/// does not fit, the unit's other moves are only counted, and at its close the ring and the stream
/// go back to where the unit began and its exact bytes are remembered. A unit whose expected bytes
/// ([`RoomMemory`]) exceed the free ones is refused before it runs while the ring holds moves; the
/// waiting unit's exact bytes, once known, spare that estimate.
#[derive(Debug)]
pub struct RingRoom<'a, const BYTES: usize> {
    ring: &'a mut MoveRing<BYTES>,
    stream: &'a mut MoveStream,
    memory: &'a mut RoomMemory,
    /// Where the open unit began: the ring's bytes in use and coder, and the stream.
    mark: (usize, MoveEncoder, MoveStream),
    /// Moves of the open unit (as opened) and its bytes coded so far.
    unit: (u32, usize),
    /// The coder counting the open unit's moves once one did not fit (nothing written).
    over: Option<MoveEncoder>,
    /// The first unit offered is the waiting one, of these exact bytes.
    known: Option<usize>,
    /// Bytes of the unit refused last, when known exactly.
    refused: Option<usize>,
}

impl<const BYTES: usize> RingRoom<'_, BYTES> {
    /// Bytes of the unit refused last, if they are known exactly: it fits once that many are
    /// free, and never when more than the capacity.
    pub fn refused(&self) -> Option<usize> {
        self.refused
    }

    /// The last unit refused can never go in: its bytes exceed the ring's capacity.
    pub fn never_fits(&self) -> bool {
        self.refused.is_some_and(|b| b > self.ring.capacity())
    }

    /// Refuses the unit: `bytes` to wait for, `exact` or an estimate.
    fn refuse(&mut self, bytes: usize, exact: bool) -> bool {
        self.refused = exact.then_some(bytes);
        self.memory.wait = bytes;
        self.memory.exact = exact;
        false
    }
}

impl<const BYTES: usize> Room for RingRoom<'_, BYTES> {
    fn open(&mut self, moves: u32) -> bool {
        let free = self.ring.free_bytes();
        match self.known.take() {
            Some(bytes) if bytes > free => return self.refuse(bytes, true),
            Some(_) => {}
            None => {
                let expected = self.memory.expected(moves);
                let capacity = self.ring.capacity();
                if expected > free && free < capacity {
                    return self.refuse(expected.min(capacity), false);
                }
            }
        }
        self.mark = (self.ring.len, self.ring.encoder, *self.stream);
        self.unit = (moves, 0);
        self.over = None;
        true
    }

    fn event(&mut self, e: &ToolEvent<'_>) {
        let ToolEvent::Move(m) = e else { return };
        let mv = self.stream.next(m);
        let bytes = match &mut self.over {
            None => match self.ring.code(&mv) {
                Ok(n) => n,
                Err(RingFull) => {
                    let mut counting = self.ring.encoder;
                    let n = counting.encode(&mv, &mut [0; MAX_RECORD]);
                    self.over = Some(counting);
                    n
                }
            },
            Some(counting) => counting.encode(&mv, &mut [0; MAX_RECORD]),
        };
        self.unit.1 += bytes;
    }

    fn close(&mut self) -> bool {
        let (moves, bytes) = self.unit;
        if self.over.is_some() {
            (self.ring.len, self.ring.encoder, *self.stream) = self.mark;
            return self.refuse(bytes, true);
        }
        self.refused = None;
        let m = &mut *self.memory;
        m.wait = 0;
        m.exact = false;
        m.coded = (m.coded.0 + bytes as u64, m.coded.1 + u64::from(moves));
        m.largest = m.largest.max(bytes);
        true
    }
}

/// The move buffer refused a move: its record does not fit the free bytes (nothing changed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RingFull;

/// Moves waiting for the planner as delta-coded records in a ring of `BYTES` bytes (first in,
/// first out).
#[derive(Debug, Clone)]
pub struct MoveRing<const BYTES: usize> {
    buf: [u8; BYTES],
    /// Offset of the first record's header.
    head: usize,
    /// Bytes in use.
    len: usize,
    /// Bytes of `BYTES` it may not use (0 unless [`limit`](Self::limit)ed): stored rather
    /// than the limit itself so that a new ring is all zero bytes.
    withheld: usize,
    encoder: MoveEncoder,
    /// The last move popped: the next record is coded relative to it.
    popped: PackedMove,
}

impl<const BYTES: usize> Default for MoveRing<BYTES> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const BYTES: usize> MoveRing<BYTES> {
    /// Empty, both coder states at the origin.
    pub const fn new() -> Self {
        Self {
            buf: [0; BYTES],
            head: 0,
            len: 0,
            withheld: 0,
            encoder: MoveEncoder::new(),
            popped: PackedMove::ORIGIN,
        }
    }

    /// Holds at most `bytes` from now on (at most `BYTES`): a buffer posing as a smaller one
    /// (a host simulation of a board, tests). The moves already in stay.
    pub fn limit(&mut self, bytes: usize) {
        self.withheld = BYTES - bytes.min(BYTES);
    }

    /// Drops every move; both coder states go back to the origin.
    pub fn clear(&mut self) {
        self.head = 0;
        self.len = 0;
        self.encoder = MoveEncoder::new();
        self.popped = PackedMove::ORIGIN;
    }

    /// Capacity, bytes (`BYTES`, or less when [`limit`](Self::limit)ed).
    pub const fn capacity(&self) -> usize {
        BYTES - self.withheld
    }

    /// Bytes in use.
    pub fn used_bytes(&self) -> usize {
        self.len
    }

    /// No move waits.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes free.
    pub fn free_bytes(&self) -> usize {
        self.capacity().saturating_sub(self.len)
    }

    /// The ring as the room for the toolpath stage's next units ([`RingRoom`]): their moves
    /// go through `stream` into the ring; `memory` is what earlier rooms learnt, and learns
    /// what this one does.
    pub fn room<'a>(
        &'a mut self,
        stream: &'a mut MoveStream,
        memory: &'a mut RoomMemory,
    ) -> RingRoom<'a, BYTES> {
        let known = memory.exact.then_some(memory.wait);
        let mark = (self.len, self.encoder, *stream);
        RingRoom {
            ring: self,
            stream,
            memory,
            mark,
            unit: (0, 0),
            over: None,
            known,
            refused: None,
        }
    }

    /// Appends `mv`; [`RingFull`] (and the ring unchanged) when its record does not fit.
    pub fn push(&mut self, mv: &PackedMove) -> Result<(), RingFull> {
        self.code(mv).map(|_| ())
    }

    /// [`push`](Self::push), giving the record's bytes.
    fn code(&mut self, mv: &PackedMove) -> Result<usize, RingFull> {
        let mut record = [0u8; MAX_RECORD];
        let mut encoder = self.encoder;
        let n = encoder.encode(mv, &mut record);
        if n > self.free_bytes() {
            return Err(RingFull);
        }
        for (k, &b) in record.iter().take(n).enumerate() {
            let at = self.wrap(self.len + k);
            if let Some(slot) = self.buf.get_mut(at) {
                *slot = b;
            }
        }
        self.len += n;
        self.encoder = encoder;
        Ok(n)
    }

    /// The first move (`None` when empty).
    pub fn front(&self) -> Option<PackedMove> {
        self.decode_front().map(|(mv, _)| mv)
    }

    /// Removes and returns the first move (`None` when empty).
    pub fn pop_front(&mut self) -> Option<PackedMove> {
        let (mv, read) = self.decode_front()?;
        self.head = self.wrap(read);
        self.len -= read;
        self.popped = mv;
        Some(mv)
    }

    /// The first move and its record's length, bytes. A record ends within [`MAX_RECORD`]
    /// bytes: when those do not wrap, they are read as one slice (fewer checks a byte).
    fn decode_front(&self) -> Option<(PackedMove, usize)> {
        let end = self.head + self.len.min(MAX_RECORD);
        if let Some(run) = self.buf.get(self.head..end) {
            let mut bytes = run.iter().copied();
            let mv = decode(&self.popped, &mut bytes)?;
            return Some((mv, run.len() - bytes.len()));
        }
        let mut bytes = self.bytes();
        let mv = decode(&self.popped, &mut bytes)?;
        Some((mv, self.len - bytes.len()))
    }

    /// The bytes in use, oldest first.
    fn bytes(&self) -> Bytes<'_> {
        let (wrapped, tail) = self.buf.split_at(self.head.min(BYTES));
        Bytes { tail, wrapped, left: self.len }
    }

    /// The buffer index `offset` bytes after the head (`offset < BYTES`).
    fn wrap(&self, offset: usize) -> usize {
        let at = self.head + offset;
        if at >= BYTES {
            at - BYTES
        } else {
            at
        }
    }
}

/// The ring's bytes in use: the tail of the buffer from the head on, then its start.
struct Bytes<'a> {
    tail: &'a [u8],
    wrapped: &'a [u8],
    left: usize,
}

impl Iterator for Bytes<'_> {
    type Item = u8;

    fn next(&mut self) -> Option<u8> {
        if self.left == 0 {
            return None;
        }
        if self.tail.is_empty() {
            self.tail = core::mem::take(&mut self.wrapped);
        }
        let (&b, rest) = self.tail.split_first()?;
        self.tail = rest;
        self.left -= 1;
        Some(b)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left, Some(self.left))
    }
}

impl ExactSizeIterator for Bytes<'_> {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geom::Point2;
    use crate::test_rng::xorshift;
    use crate::toolpath::Feature;
    use std::collections::VecDeque;

    const KINDS: [MoveKind; 4] =
        [MoveKind::Print, MoveKind::Travel, MoveKind::Retract, MoveKind::Dwell];

    fn record(prev: &PackedMove, mv: &PackedMove) -> Vec<u8> {
        let mut enc = MoveEncoder { prev: *prev };
        let mut out = [0u8; MAX_RECORD];
        let n = enc.encode(mv, &mut out);
        out[..n].to_vec()
    }

    fn decoded(prev: &PackedMove, bytes: &[u8]) -> Option<PackedMove> {
        decode(prev, &mut bytes.iter().copied())
    }

    /// A move after `prev`: mostly toolpath-like (small steps, the same feed and layer), with
    /// zero deltas, full-range and extreme coordinates, feeds and layer jumps mixed in.
    fn random_move(next: &mut impl FnMut() -> u64, prev: &PackedMove) -> PackedMove {
        let mut mv = *prev;
        for t in &mut mv.target_um {
            *t = match next() % 8 {
                0 | 1 => *t,
                2 => i32::MIN,
                3 => i32::MAX,
                4 => next() as i32,
                _ => t.wrapping_add((next() % 20_001) as i32 - 10_000),
            };
        }
        mv.feed_bits = match next() % 6 {
            0 => 0,
            1 => u32::MAX,
            2 => next() as u32,
            3 => ((next() % 300) as u32) << 16,
            _ => prev.feed_bits,
        };
        mv.layer = match next() % 8 {
            0 => 0,
            1 => u16::MAX,
            2 => next() as u16,
            3 => prev.layer.wrapping_add(1),
            _ => prev.layer,
        };
        mv.fan = match next() % 4 {
            0 => next() as u8,
            _ => prev.fan,
        };
        mv.kind = KINDS[(next() % 4) as usize];
        mv
    }

    #[test]
    fn zigzag_maps_small_magnitudes_to_small_codes() {
        let pairs = [(0i64, 0u64), (-1, 1), (1, 2), (-2, 3), (2, 4)];
        for (v, z) in pairs {
            assert_eq!(zigzag(v), z);
            assert_eq!(unzigzag(z), v);
        }
        // The widest delta of two i32 coordinates, both ways.
        let span = i64::from(i32::MAX) - i64::from(i32::MIN);
        for v in [span, -span, i64::MIN, i64::MAX] {
            assert_eq!(unzigzag(zigzag(v)), v);
        }
        assert_eq!(zigzag(span), (1 << 33) - 2);
    }

    #[test]
    fn records_have_the_documented_layout() {
        let o = PackedMove::ORIGIN;
        // X +100 um: header X bit, zigzag 200 = 0b1_1001000 -> 0xc8 0x01.
        let x = PackedMove { target_um: [100, 0, 0, 0], ..o };
        assert_eq!(record(&o, &x), [0x10, 0xc8, 0x01]);
        // A travel at 40 mm/s (U16F16 40 << 16; halves swapped: 40).
        let f = PackedMove { feed_bits: 40 << 16, kind: MoveKind::Travel, ..o };
        assert_eq!(record(&o, &f), [0x01 | 0x08, 40]);
        // A retraction of E -1 um into layer 3: E delta zigzag 1, layer delta zigzag 6 with
        // the fan (0) in its low byte: 6 << 8 = 1536 = 0b1100_0000000 -> 0x80 0x0c.
        let r = PackedMove { target_um: [0, 0, 0, -1], layer: 3, kind: MoveKind::Retract, ..o };
        assert_eq!(record(&o, &r), [0x02 | 0x04 | 0x80, 1, 0x80, 0x0c]);
        // The fan to 255 on the same layer: layer delta 0, 255 -> 0xff 0x01.
        let fan = PackedMove { fan: 255, ..o };
        assert_eq!(record(&o, &fan), [0x04, 0xff, 0x01]);
        // The same move again: the header alone.
        assert_eq!(record(&x, &x), [0x00]);
    }

    #[test]
    fn the_widest_record_is_max_record_and_round_trips() {
        let low = PackedMove {
            target_um: [i32::MIN; AXES],
            feed_bits: 0,
            layer: 0,
            fan: 0,
            kind: MoveKind::Print,
        };
        let high = PackedMove {
            target_um: [i32::MAX; AXES],
            feed_bits: u32::MAX,
            layer: u16::MAX,
            fan: u8::MAX,
            kind: MoveKind::Retract,
        };
        for (a, b) in [(low, high), (high, low)] {
            let r = record(&a, &b);
            // 1 header + 4 x 5 (33 bits) + 4 (17 + 8 bits) + feed (5 bytes for u32::MAX, 1
            // for 0).
            let feed = if b.feed_bits == 0 { 1 } else { 5 };
            assert_eq!(r.len(), 1 + 20 + 4 + feed);
            assert_eq!(decoded(&a, &r), Some(b));
        }
        assert_eq!(MAX_RECORD, 30);
    }

    #[test]
    fn random_moves_round_trip_through_a_wrapping_ring() {
        let mut next = xorshift(0x5eed_1234_abcd_0001);
        let mut ring: MoveRing<97> = MoveRing::new();
        let mut model: VecDeque<PackedMove> = VecDeque::new();
        let (mut last, mut pushed_bytes, mut refused) = (PackedMove::ORIGIN, 0, 0);
        for _ in 0..200_000 {
            if next() % 2 == 0 {
                let mv = random_move(&mut next, &last);
                let before = (ring.used_bytes(), ring.front());
                let used = ring.used_bytes();
                match ring.push(&mv) {
                    Ok(()) => {
                        pushed_bytes += ring.used_bytes() - used;
                        model.push_back(mv);
                        last = mv;
                    }
                    Err(RingFull) => {
                        refused += 1;
                        assert!(used + record(&last, &mv).len() > 97);
                        assert_eq!((ring.used_bytes(), ring.front()), before);
                    }
                }
            } else {
                assert_eq!(ring.front(), model.front().copied());
                assert_eq!(ring.pop_front(), model.pop_front());
            }
            assert_eq!(ring.is_empty(), model.is_empty());
            assert!(ring.used_bytes() <= 97);
        }
        while let Some(mv) = model.pop_front() {
            assert_eq!(ring.pop_front(), Some(mv));
        }
        assert_eq!(ring.pop_front(), None);
        assert!(ring.is_empty());
        // The ring wrapped many times and was full at times.
        assert!(pushed_bytes > 100 * 97, "{pushed_bytes}");
        assert!(refused > 100, "{refused}");
    }

    #[test]
    fn a_refused_push_leaves_the_ring_and_its_coding_unchanged() {
        let o = PackedMove::ORIGIN;
        let a = PackedMove { target_um: [1_000_000, 0, 0, 0], ..o };
        let b = PackedMove { target_um: [-5, 7, 200, -300], feed_bits: 33 << 16, ..o };
        // `a` takes 4 bytes (zigzag 2,000,000 needs 21 bits), `b` after it 10 (X 3, Y 1, Z 2,
        // E 2, feed 1): 12 bytes hold either, not both.
        assert_eq!(record(&a, &b).len(), 10);
        let mut ring: MoveRing<12> = MoveRing::new();
        assert_eq!(ring.push(&a), Ok(()));
        assert_eq!(ring.used_bytes(), 4);
        assert_eq!(ring.push(&b), Err(RingFull));
        assert_eq!(ring.used_bytes(), 4);
        assert_eq!(ring.pop_front(), Some(a));
        // `b` is coded against `a` (the last accepted), not against the refused attempt.
        assert_eq!(ring.push(&b), Ok(()));
        assert_eq!(ring.pop_front(), Some(b));
        assert_eq!(ring.pop_front(), None);
        // No capacity at all: refused, never a panic.
        let mut none: MoveRing<0> = MoveRing::new();
        assert_eq!(none.push(&a), Err(RingFull));
        assert_eq!(none.front(), None);
    }

    /// Offers `unit` to `room` as the toolpath stage does: true when it was kept.
    fn offer(room: &mut impl Room, unit: &[ToolMove]) -> bool {
        room.open(unit.len() as u32) && {
            for m in unit {
                room.event(&ToolEvent::Move(*m));
            }
            room.close()
        }
    }

    /// `unit`'s moves packed from `stream` and their bytes coded from `coder`.
    fn coded(
        mut stream: MoveStream,
        mut coder: MoveEncoder,
        unit: &[ToolMove],
    ) -> (Vec<PackedMove>, usize) {
        let mut bytes = 0;
        let moves = unit
            .iter()
            .map(|m| {
                let mv = stream.next(m);
                bytes += coder.encode(&mv, &mut [0; MAX_RECORD]);
                mv
            })
            .collect();
        (moves, bytes)
    }

    #[test]
    fn a_ring_room_keeps_a_unit_that_fits_and_undoes_one_that_does_not() {
        let unit = three_move_unit();
        let first = PackedMove { target_um: [5_000, 0, 0, 0], ..PackedMove::ORIGIN };
        let mut ring: MoveRing<64> = MoveRing::new();
        ring.push(&first).unwrap();
        let used = ring.used_bytes();
        let mut stream = stream_at(1);
        // The unit after `first`, coded independently of the ring.
        let (moves, bytes) = coded(stream, MoveEncoder { prev: first }, &unit);
        assert!(bytes > 3 && used + bytes <= 64);
        // One byte short: the unit runs out of bytes, is undone (the ring, its coder and the
        // stream as before) and its exact bytes are known, all of them.
        ring.limit(used + bytes - 1);
        let mut memory = RoomMemory::EMPTY;
        let mut room = ring.room(&mut stream, &mut memory);
        assert!(!offer(&mut room, &unit));
        assert_eq!((room.refused(), room.never_fits()), (Some(bytes), false));
        assert_eq!((ring.used_bytes(), ring.front()), (used, Some(first)));
        assert_eq!(memory.waits_for(), bytes);
        assert_eq!(coded(stream, MoveEncoder { prev: first }, &unit), (moves.clone(), bytes));
        // Refused on its known bytes while they do not fit, then kept when they do.
        assert!(!offer(&mut ring.room(&mut stream, &mut memory), &unit));
        assert_eq!((ring.used_bytes(), memory.waits_for()), (used, bytes));
        ring.limit(used + bytes);
        let mut room = ring.room(&mut stream, &mut memory);
        assert!(offer(&mut room, &unit));
        assert_eq!(room.refused(), None);
        assert_eq!(ring.used_bytes(), used + bytes);
        assert_eq!(
            (memory.waits_for(), memory.largest(), memory.coded()),
            (0, bytes, (bytes as u64, 3))
        );
        // The ring holds `first` and the unit's moves, coded after it (not after the undone
        // attempt).
        assert_eq!(ring.pop_front(), Some(first));
        for mv in moves {
            assert_eq!(ring.pop_front(), Some(mv));
        }
        assert_eq!(ring.pop_front(), None);
        // An empty ring below the unit's bytes can never take it.
        let mut small: MoveRing<64> = MoveRing::new();
        let (_, alone) = coded(stream_at(1), MoveEncoder::new(), &unit);
        small.limit(alone - 1);
        let (mut s, mut m) = (stream_at(1), RoomMemory::EMPTY);
        let mut never = small.room(&mut s, &mut m);
        assert!(!offer(&mut never, &unit));
        assert!(never.never_fits());
        assert!(small.is_empty());
    }

    #[test]
    fn the_estimate_refuses_a_unit_before_it_runs_while_moves_wait() {
        let unit = three_move_unit();
        let (_, bytes) = coded(stream_at(1), MoveEncoder::new(), &unit);
        // A room that learnt `bytes` for 3 moves expects (bytes / 3 + a quarter) a move.
        let mut ring: MoveRing<64> = MoveRing::new();
        let (mut stream, mut memory) = (stream_at(1), RoomMemory::EMPTY);
        assert!(offer(&mut ring.room(&mut stream, &mut memory), &unit));
        let expected = 3 * (bytes * 20 / 3) / 16;
        assert!(expected > bytes);
        // Free bytes below the estimate with moves waiting: refused before it runs, the
        // estimate (at most the capacity) to wait for.
        let used = ring.used_bytes();
        ring.limit(used + expected - 1);
        let mut room = ring.room(&mut stream, &mut memory);
        assert!(!room.open(3));
        assert_eq!(room.refused(), None);
        assert_eq!(memory.waits_for(), expected.min(used + expected - 1));
        assert_eq!(ring.used_bytes(), used);
        // An empty ring runs the unit whatever the estimate.
        while ring.pop_front().is_some() {}
        ring.limit(bytes + 1);
        assert!(offer(&mut ring.room(&mut stream, &mut memory), &unit));
    }

    #[test]
    fn counted_and_unbounded_rooms_take_units_by_moves() {
        let unit = three_move_unit();
        let mut sent = 0;
        let mut moves = crate::toolpath::Moves { left: 5, sink: |_: &ToolEvent<'_>| sent += 1 };
        assert!(offer(&mut moves, &unit) && moves.left == 2);
        assert!(!offer(&mut moves, &unit) && moves.left == 2);
        let mut all = |_: &ToolEvent<'_>| sent += 1;
        assert!(offer(&mut all, &unit));
        assert_eq!(sent, 6);
    }

    /// A travel, a print and a retraction along X at z 0.2 mm, 40 mm/s.
    fn three_move_unit() -> [ToolMove; 3] {
        let at = |x: i32, e_um| ToolMove {
            to: Point2::new(x, 0),
            z_um: 200,
            e_um,
            feed_mm_s: Rate::from_num(40),
            feature: Feature::InternalInfill,
            fan: 0,
        };
        [at(1_000, 0), at(2_000, 30), at(2_000, -500)]
    }

    fn stream_at(layer: u32) -> MoveStream {
        let mut s = MoveStream::new();
        s.start_layer(layer);
        s
    }

    #[test]
    fn malformed_records_decode_to_none() {
        let o = PackedMove::ORIGIN;
        // A delta announced but missing, a varint cut short.
        assert_eq!(decoded(&o, &[0x10]), None);
        assert_eq!(decoded(&o, &[0x10, 0x80]), None);
        // A varint over 64 bits.
        assert_eq!(
            decoded(&o, &[0x10, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 2]),
            None
        );
        // Past the i32 range, the u16 layer range and the u32 feed.
        let top = PackedMove { target_um: [i32::MAX, 0, 0, 0], layer: u16::MAX, ..o };
        assert_eq!(decoded(&top, &[0x10, 2]), None);
        // Layer +1 (zigzag 2, shifted past the fan's byte: 512 -> 0x80 0x04).
        assert_eq!(decoded(&top, &[0x04, 0x80, 0x04]), None);
        assert_eq!(decoded(&o, &[0x08, 0x80, 0x80, 0x80, 0x80, 0x10]), None);
        // Random bytes never panic.
        let mut next = xorshift(77);
        for _ in 0..20_000 {
            let bytes: Vec<u8> = (0..(next() % 32)).map(|_| next() as u8).collect();
            let _ = decoded(&random_move(&mut next, &o), &bytes);
        }
    }

    #[test]
    fn the_stream_makes_absolute_moves_of_each_kind() {
        let mut s = MoveStream::new();
        let feed = Rate::from_num(40);
        let at = |x, y, e_um| ToolMove {
            to: Point2::new(x, y),
            z_um: 200,
            e_um,
            feed_mm_s: feed,
            feature: Feature::InternalInfill,
            fan: 0,
        };
        s.start_layer(2);
        let travel = s.next(&at(1_000, 0, 0));
        let print = s.next(&at(2_000, 0, 50));
        let retract = s.next(&at(2_000, 0, -800));
        assert_eq!(travel.target_um, [1_000, 0, 200, 0]);
        assert_eq!(travel.kind, MoveKind::Travel);
        assert_eq!(print.target_um, [2_000, 0, 200, 50]);
        assert_eq!(print.kind, MoveKind::Print);
        assert_eq!(retract.target_um, [2_000, 0, 200, -750]);
        assert_eq!(retract.kind, MoveKind::Retract);
        assert_eq!((print.layer, print.feed_bits), (2, 40 << 16));
        assert_eq!(print.unpack().feed_mm_s, feed);
    }

    #[test]
    fn packing_keeps_16_fractional_bits_and_saturates() {
        let mv = |feed: Rate| Move::new([1, 2, 3, 4], feed, MoveKind::Travel);
        let half = PackedMove::pack(7, &mv(Rate::from_num(1.5)));
        assert_eq!((half.feed_bits, half.layer, half.target_um), (0x1_8000, 7, [1, 2, 3, 4]));
        assert_eq!(half.unpack(), mv(Rate::from_num(1.5)));
        // Below 2^-16 mm/s truncates to 0; from 65,536 mm/s on saturates; layers saturate.
        assert_eq!(PackedMove::pack(0, &mv(Rate::from_bits(0xffff))).feed_bits, 0);
        assert_eq!(PackedMove::pack(0, &mv(Rate::from_num(70_000))).feed_bits, u32::MAX);
        assert_eq!(PackedMove::pack(1 << 20, &mv(Rate::ZERO)).layer, u16::MAX);
    }
}

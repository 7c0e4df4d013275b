//! The move buffer: toolpath moves waiting for the planner, delta-coded into a byte ring.
//!
//! [`MoveStream`] turns the toolpath stage's moves (relative E) into [`PackedMove`]s (absolute
//! E, the feed as U16F16 bits, the layer). [`MoveRing`] stores each as one variable-length
//! record relative to the move before it, so a move takes a few bytes instead of 24 (5.0 to
//! 6.3 on average over the sample models, at most [`MAX_RECORD`]):
//!
//! - a header byte: bits 0-1 the kind (0 print, 1 travel, 2 retract), bit 2 the layer
//!   changed, bit 3 the feed changed, bits 4-7 which of the X, Y, Z, E deltas follow;
//! - the non-zero deltas of X, Y, Z, E (um, in that order), the layer delta when the layer
//!   changed, each a zigzag LEB128 varint (deltas taken in `i64`: no overflow at the `i32`
//!   extremes);
//! - the feed bits when the feed changed, halves swapped (whole mm/s, the usual case, then
//!   fit one or two bytes), as an LEB128 varint.
//!
//! The producer side ([`MoveEncoder`]) codes each move against the last one pushed, the
//! consumer side against the last one popped; both start at the origin (all zero) after
//! [`MoveRing::clear`]. The coding is lossless: every `PackedMove` comes out bit for bit as
//! it went in.
//!
//! Flow control ([`crate::printer`]): the toolpath stage emits a layer unit by unit (a path
//! with the travel before it, [`Toolpath::emit_next`](crate::toolpath::Toolpath::emit_next)),
//! each only once the ring's [`ByteRoom`] ([`MoveRing::room`]) takes it: the room codes the
//! unit's moves on copies of the [`MoveStream`] and of the ring's [`MoveEncoder`] (a
//! [`MoveMeter`]), so it knows the unit's bytes exactly before the first of them is pushed,
//! and takes it only when they fit the free bytes. A unit's bytes depend on the move before
//! it only, not on what waits in the ring: a unit refused by an empty ring never fits
//! ([`ByteRoom::refused`] above the capacity). The host's admission control runs the same
//! meter and room over a job to find its largest unit in bytes.
//!
//! Every move of a layer is in one of its units (the height change, retraction and priming
//! with the travel they belong to, a layer without extrusion closed by a unit of its own), so
//! the rooms count every byte the ring takes. The other events are outside the units and
//! take no bytes: a layer's `LayerStart` goes out when the layer is built, before its first
//! unit is offered (it sets the stream's layer, which the room's copy then starts from), and
//! its `LayerEnd` after its last unit.

use crate::machine::{Rate, AXES};
use crate::plan::{Move, MoveKind};
use crate::toolpath::{Replay, Room, ToolEvent, ToolMove};

/// A toolpath move waiting for the planner: the planner's [`Move`] with its feed as U16F16
/// bits (the toolpath's feeds are whole or simple fractions of mm/s; the same packing runs on
/// the host simulation and the board) and the layer it belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PackedMove {
    /// Target X, Y, Z, E, um.
    pub target_um: [i32; AXES],
    /// Feed, mm/s as U16F16 bits.
    pub feed_bits: u32,
    /// Layer (saturated at `u16::MAX`).
    pub layer: u16,
    /// Print, travel or retract.
    pub kind: MoveKind,
}

impl PackedMove {
    /// Where both coder states start: the origin, feed 0, layer 0.
    pub const ORIGIN: Self =
        Self { target_um: [0; AXES], feed_bits: 0, layer: 0, kind: MoveKind::Print };

    /// `mv` of `layer`; the feed keeps 16 fractional bits (saturating at 65,536 mm/s).
    pub fn pack(layer: u32, mv: &Move) -> Self {
        let feed_bits = (mv.feed_mm_s.to_bits() >> 16).min(u32::MAX as u64) as u32;
        let layer = layer.min(u16::MAX as u32) as u16;
        Self { target_um: mv.target_um, feed_bits, layer, kind: mv.kind }
    }

    /// The move for the planner.
    pub fn unpack(&self) -> Move {
        Move::new(self.target_um, Rate::from_bits(u64::from(self.feed_bits) << 16), self.kind)
    }
}

/// Where the toolpath stream stands: its layer, absolute E and position. Turns the
/// toolpath stage's moves into planner moves (the printer and the host's admission control
/// both use it, so both see the same moves).
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
    /// print move when it extrudes, a travel otherwise.
    pub fn next(&mut self, m: &ToolMove) -> PackedMove {
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
        PackedMove::pack(self.layer, &mv)
    }
}

/// The longest record: the header, four axis deltas of up to 33 zigzag bits (5 bytes each),
/// a layer delta of up to 17 zigzag bits (3 bytes) and the feed's 32 bits (5 bytes).
pub const MAX_RECORD: usize = 1 + 4 * 5 + 3 + 5;

/// Header bit: the layer changed (its delta follows the axis deltas).
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
        };
        for (axis, (&to, &from)) in mv.target_um.iter().zip(&self.prev.target_um).enumerate() {
            let delta = i64::from(to) - i64::from(from);
            if delta != 0 {
                header |= AXIS_DELTA << axis;
                w.varint(zigzag(delta));
            }
        }
        if mv.layer != self.prev.layer {
            header |= NEW_LAYER;
            w.varint(zigzag(i64::from(mv.layer) - i64::from(self.prev.layer)));
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
        _ => return None,
    };
    let mut mv = PackedMove { kind, ..*prev };
    for (axis, target) in mv.target_um.iter_mut().enumerate() {
        if header & (AXIS_DELTA << axis) != 0 {
            let delta = unzigzag(read_varint(bytes)?);
            *target = i32::try_from(i64::from(*target).checked_add(delta)?).ok()?;
        }
    }
    if header & NEW_LAYER != 0 {
        let delta = unzigzag(read_varint(bytes)?);
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

/// What an owner's rooms learn from one call to the next ([`ByteRoom::remembering`],
/// [`ByteRoom::memory`]): the bytes the waiting unit needs (exact when it was replayed, an
/// estimate otherwise), and the bytes and moves of the units taken so far, whose ratio with a
/// quarter added is the estimate that spares the replay of a unit that cannot fit.
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
    pub const NEW: Self = Self { wait: 0, exact: false, coded: (0, 0), largest: 0 };

    /// Free bytes below which offering the waiting unit is no use.
    pub fn waits_for(&self) -> usize {
        self.wait
    }

    /// Bytes of the largest unit taken.
    pub fn largest(&self) -> usize {
        self.largest
    }
}

/// Room in a move buffer for the toolpath stage's units, in exact bytes (see the
/// [module docs](self)): a unit offered is replayed through a copy of the [`MoveMeter`] and
/// taken when its bytes fit the bytes left; then the meter and the bytes left move on with it,
/// so several units in one call are counted as exactly as one.
#[derive(Debug, Clone, Copy)]
pub struct ByteRoom {
    meter: MoveMeter,
    free: usize,
    capacity: usize,
    /// Bytes of the unit refused last.
    refused: Option<usize>,
    /// Bytes of the largest unit taken.
    largest: usize,
    /// Bytes of all units taken.
    taken: u64,
    /// Moves of all units taken.
    taken_moves: u64,
    /// The exact bytes of the first unit offered, known from an earlier refusal (the coding
    /// state has not moved since): taken without a replay.
    known_first: Option<usize>,
    /// The meter is behind the units taken (one went in on its known bytes): no more units
    /// in this call.
    stale: bool,
    /// Expected bytes per move, 1/16 B (0: none): a unit whose expected bytes exceed the
    /// free ones is refused without a replay while the buffer is not empty.
    per_move_q4: usize,
    /// The bytes to wait for after such a refusal (an estimate, at most the capacity).
    hint: Option<usize>,
}

impl ByteRoom {
    /// `free` bytes of a buffer of `capacity`, the moves coded by `meter` from its state.
    pub const fn new(meter: MoveMeter, free: usize, capacity: usize) -> Self {
        Self {
            meter,
            free,
            capacity,
            refused: None,
            largest: 0,
            taken: 0,
            taken_moves: 0,
            known_first: None,
            stale: false,
            per_move_q4: 0,
            hint: None,
        }
    }

    /// The first unit offered has `bytes` (exact: it was refused with them and the coding
    /// state has not moved since), so it is taken or refused without a replay.
    const fn with_known_first(mut self, bytes: Option<usize>) -> Self {
        self.known_first = bytes;
        self
    }

    /// Units are expected to take `per_move_q4` / 16 bytes a move: one whose expected bytes
    /// exceed the free ones is refused without a replay (unless the buffer is empty), and
    /// [`wait_hint`](Self::wait_hint) says how many to wait for.
    const fn with_estimate(mut self, per_move_q4: usize) -> Self {
        self.per_move_q4 = per_move_q4;
        self
    }

    /// This room with what earlier rooms learnt: the waiting unit's exact bytes, if known,
    /// and the job's bytes per move so far plus a quarter as the estimate.
    pub fn remembering(self, memory: &RoomMemory) -> Self {
        let (bytes, moves) = memory.coded;
        let per_move_q4 = (bytes * 20).checked_div(moves).unwrap_or(0) as usize;
        self.with_known_first(memory.exact.then_some(memory.wait)).with_estimate(per_move_q4)
    }

    /// `before` with what this room learnt.
    pub fn memory(&self, before: &RoomMemory) -> RoomMemory {
        let (bytes, moves) = before.coded;
        RoomMemory {
            wait: self.wait_hint().unwrap_or(0),
            exact: self.refused.is_some(),
            coded: (bytes + self.taken, moves + self.taken_moves),
            largest: before.largest.max(self.largest),
        }
    }

    /// Bytes to wait for before offering again: the exact bytes of the unit refused last,
    /// or the estimate of one refused without a replay.
    fn wait_hint(&self) -> Option<usize> {
        self.refused.or(self.hint)
    }

    /// Room without bound, to measure units (the host's admission control).
    pub const fn unbounded(meter: MoveMeter) -> Self {
        Self::new(meter, usize::MAX, usize::MAX)
    }

    /// Bytes of the unit refused last, if one was: it fits once that many are free, and
    /// never when more than the capacity.
    pub fn refused(&self) -> Option<usize> {
        self.refused
    }

    /// The last unit refused can never go in: its bytes exceed the buffer's capacity.
    pub fn never_fits(&self) -> bool {
        self.refused.is_some_and(|b| b > self.capacity)
    }

    /// Bytes of the largest unit taken.
    pub fn largest(&self) -> usize {
        self.largest
    }

    /// Bytes of all units taken.
    pub fn taken(&self) -> u64 {
        self.taken
    }

    /// Bytes left.
    pub fn free(&self) -> usize {
        self.free
    }

    /// The meter, at the end of the units taken.
    pub fn meter(&self) -> MoveMeter {
        self.meter
    }
}

impl Room for ByteRoom {
    fn take(&mut self, moves: u32, replay: &mut Replay<'_>) -> bool {
        if self.stale {
            return false;
        }
        if let Some(bytes) = self.known_first.take() {
            if bytes > self.free {
                self.refused = Some(bytes);
                return false;
            }
            // The meter cannot follow without the replay: this call takes no more units.
            self.stale = true;
            self.commit(bytes, moves);
            return true;
        }
        let expected = (moves as usize).saturating_mul(self.per_move_q4) >> 4;
        if expected > self.free && self.free < self.capacity {
            self.hint = Some(expected.min(self.capacity));
            return false;
        }
        let mut meter = self.meter;
        let (mut bytes, mut seen) = (0usize, 0u32);
        replay(&mut |e: &ToolEvent<'_>| {
            bytes += meter.event(e);
            seen += u32::from(matches!(e, ToolEvent::Move(_)));
        });
        debug_assert_eq!(seen, moves, "a unit replays the moves it was planned with");
        if bytes > self.free {
            self.refused = Some(bytes);
            return false;
        }
        self.meter = meter;
        self.commit(bytes, moves);
        true
    }
}

impl ByteRoom {
    /// A unit of `bytes` and `moves` went in.
    fn commit(&mut self, bytes: usize, moves: u32) {
        self.refused = None;
        self.hint = None;
        self.free -= bytes;
        self.largest = self.largest.max(bytes);
        self.taken += bytes as u64;
        self.taken_moves += u64::from(moves);
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

    /// The room for the next toolpath units: the free bytes, measured with the moves coded
    /// as [`push`](Self::push) will code them after the ones already in (`stream`: the
    /// stream the moves come from, where it stands now).
    pub fn room(&self, stream: &MoveStream) -> ByteRoom {
        ByteRoom::new(MoveMeter::new(*stream, self.encoder), self.free_bytes(), self.capacity())
    }

    /// Appends `mv`; [`RingFull`] (and the ring unchanged) when its record does not fit.
    pub fn push(&mut self, mv: &PackedMove) -> Result<(), RingFull> {
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
        Ok(())
    }

    /// The first move (`None` when empty).
    pub fn front(&self) -> Option<PackedMove> {
        decode(&self.popped, &mut self.bytes())
    }

    /// Removes and returns the first move (`None` when empty).
    pub fn pop_front(&mut self) -> Option<PackedMove> {
        let mut bytes = self.bytes();
        let mv = decode(&self.popped, &mut bytes)?;
        let read = self.len - bytes.len();
        self.head = self.wrap(read);
        self.len -= read;
        self.popped = mv;
        Some(mv)
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

    const KINDS: [MoveKind; 3] = [MoveKind::Print, MoveKind::Travel, MoveKind::Retract];

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
        mv.kind = KINDS[(next() % 3) as usize];
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
        // A retraction of E -1 um into layer 3: E delta zigzag 1, layer delta zigzag 6.
        let r = PackedMove { target_um: [0, 0, 0, -1], layer: 3, kind: MoveKind::Retract, ..o };
        assert_eq!(record(&o, &r), [0x02 | 0x04 | 0x80, 1, 6]);
        // The same move again: the header alone.
        assert_eq!(record(&x, &x), [0x00]);
    }

    #[test]
    fn the_widest_record_is_max_record_and_round_trips() {
        let low = PackedMove {
            target_um: [i32::MIN; AXES],
            feed_bits: 0,
            layer: 0,
            kind: MoveKind::Print,
        };
        let high = PackedMove {
            target_um: [i32::MAX; AXES],
            feed_bits: u32::MAX,
            layer: u16::MAX,
            kind: MoveKind::Retract,
        };
        for (a, b) in [(low, high), (high, low)] {
            let r = record(&a, &b);
            // 1 header + 4 x 5 (33 bits) + 3 (17 bits) + feed (5 bytes for u32::MAX, 1 for 0).
            let feed = if b.feed_bits == 0 { 1 } else { 5 };
            assert_eq!(r.len(), 1 + 20 + 3 + feed);
            assert_eq!(decoded(&a, &r), Some(b));
        }
        assert_eq!(MAX_RECORD, 29);
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

    #[test]
    fn a_byte_room_takes_units_by_their_coded_bytes() {
        // A unit of three moves of layer 1 (travel, print, retract), and its bytes from the
        // origin by the encoder (whose records are checked above).
        let unit = three_move_unit();
        let mut stream = stream_at(1);
        let (mut enc, mut out, mut bytes) = (MoveEncoder::new(), [0u8; MAX_RECORD], 0);
        for m in &unit {
            bytes += enc.encode(&stream.next(m), &mut out);
        }
        let mut s = stream_at(1);
        let mut ring: MoveRing<64> = MoveRing::new();
        let replay = &mut |out: &mut dyn FnMut(&ToolEvent<'_>)| {
            for m in &unit {
                out(&ToolEvent::Move(*m));
            }
        };
        // Free bytes one short: refused, nothing moves on; then taken twice in one room, the
        // second time coded after the first (fewer bytes: only the deltas change).
        let mut short = ByteRoom::new(MoveMeter::new(s, MoveEncoder::new()), bytes - 1, 64);
        assert!(!short.take(3, replay));
        assert_eq!((short.refused(), short.never_fits(), short.taken()), (Some(bytes), false, 0));
        let mut room = ring.room(&s);
        assert_eq!(room.free(), 64);
        assert!(room.take(3, replay));
        assert_eq!((room.largest(), room.taken(), room.free()), (bytes, bytes as u64, 64 - bytes));
        assert!(room.take(3, replay));
        let second = room.taken() as usize - bytes;
        assert!(second < bytes, "{second} {bytes}");
        // The ring takes the same bytes.
        for _ in 0..2 {
            for m in &unit {
                ring.push(&s.next(m)).unwrap();
            }
        }
        assert_eq!(ring.used_bytes(), bytes + second);
        // A ring limited below the unit's bytes can never take it.
        let mut small: MoveRing<64> = MoveRing::new();
        small.limit(bytes - 1);
        let mut never = small.room(&stream_at(1));
        assert!(!never.take(3, replay));
        assert!(never.never_fits());
        // A `usize` room counts moves.
        let mut moves = 5usize;
        assert!(moves.take(3, replay) && moves == 2);
        assert!(!moves.take(3, replay) && moves == 2);
    }

    #[test]
    fn known_bytes_and_the_estimate_spare_replays_without_changing_what_is_taken() {
        let unit = three_move_unit();
        let replays = core::cell::Cell::new(0);
        let replay = &mut |out: &mut dyn FnMut(&ToolEvent<'_>)| {
            replays.set(replays.get() + 1);
            for m in &unit {
                out(&ToolEvent::Move(*m));
            }
        };
        let meter = MoveMeter::new(stream_at(1), MoveEncoder::new());
        // The exact bytes, from a refusal.
        let mut first = ByteRoom::new(meter, 0, 64);
        assert!(!first.take(3, replay));
        let bytes = first.refused().unwrap();
        assert_eq!((first.wait_hint(), replays.get()), (Some(bytes), 1));
        // What the next call's room is told: wait for those bytes, then take the unit on
        // them (no replay), and remember it as taken.
        let memory = first.memory(&RoomMemory::NEW);
        assert_eq!((memory.waits_for(), memory.largest()), (bytes, 0));
        let mut next = ByteRoom::new(meter, bytes, 64).remembering(&memory);
        assert!(next.take(3, replay));
        assert_eq!(replays.get(), 1);
        let after = next.memory(&memory);
        assert_eq!((after.waits_for(), after.largest()), (0, bytes));
        // Known bytes: refused below them and taken at them, neither time replayed; after a
        // unit taken on its bytes the room takes no other (its meter did not follow).
        let mut below = ByteRoom::new(meter, bytes - 1, 64).with_known_first(Some(bytes));
        assert!(!below.take(3, replay));
        assert_eq!((below.refused(), replays.get()), (Some(bytes), 1));
        let mut exact = ByteRoom::new(meter, 64, 64).with_known_first(Some(bytes));
        assert!(exact.take(3, replay));
        assert_eq!((exact.taken(), exact.taken_moves, exact.free()), (bytes as u64, 3, 64 - bytes));
        assert!(!exact.take(3, replay));
        assert_eq!((exact.refused(), exact.wait_hint(), replays.get()), (None, None, 1));
        // An estimate above the free bytes refuses without a replay and says what to wait
        // for (at most the capacity), unless the buffer is empty: then the unit is replayed
        // and taken on its real bytes.
        let per_move_q4 = 16 * 20;
        let mut busy = ByteRoom::new(meter, 59, 64).with_estimate(per_move_q4);
        assert!(!busy.take(3, replay));
        assert_eq!((busy.refused(), busy.wait_hint(), replays.get()), (None, Some(60), 1));
        let mut capped = ByteRoom::new(meter, 10, 32).with_estimate(per_move_q4);
        assert!(!capped.take(3, replay));
        assert_eq!(capped.wait_hint(), Some(32));
        let mut empty = ByteRoom::new(meter, 32, 32).with_estimate(per_move_q4);
        assert!(empty.take(3, replay));
        assert_eq!((empty.taken(), replays.get()), (bytes as u64, 2));
    }

    /// A travel, a print and a retraction along X at z 0.2 mm, 40 mm/s.
    fn three_move_unit() -> [ToolMove; 3] {
        let at = |x: i32, e_um| ToolMove {
            to: Point2::new(x, 0),
            z_um: 200,
            e_um,
            feed_mm_s: Rate::from_num(40),
            feature: Feature::InternalInfill,
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
        // Kind 3 does not exist.
        assert_eq!(decoded(&o, &[0x03]), None);
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
        assert_eq!(decoded(&top, &[0x04, 2]), None);
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

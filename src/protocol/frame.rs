//! Frames on the wire: a header, the payload and a CRC-32, COBS-encoded and ended by `0x00`.
//!
//! Before COBS a frame is `[version << 4 | type, seq, ack, credits, payload.., crc32 LE]`; the
//! CRC (CRC-32/ISO-HDLC, the Ethernet/zip polynomial) covers header and payload. COBS removes
//! every zero byte from the frame, so a `0x00` always ends a frame and the [`Decoder`]
//! resynchronises on the next one after any corruption or loss.

use crc::{Crc, CRC_32_ISO_HDLC};

/// Protocol version carried in every frame (high nibble of the first byte).
///
/// 2: the capabilities carry the toolpath stage's capacities. 3: status carries the temperatures.
/// 4: the capabilities' move buffer is in bytes of delta-coded moves, filled a path (with the
/// travel before it) at a time: it must hold the job's largest such unit, not a layer.
/// 5: G-code jobs (`GcodeStart`, `Gcode`). 6: link sessions and parked jobs. 7: the printer's
/// SD card (files, G-code printed from it). 8: the job's options carry the brim width.
pub const VERSION: u8 = 8;
/// Header bytes before the payload.
pub const HEADER_LEN: usize = 4;
/// CRC bytes after the payload.
pub const CRC_LEN: usize = 4;
/// Largest payload of one frame, bytes (16 long-form triangles and the batch header fit).
pub const MAX_PAYLOAD: usize = 400;
/// Largest unencoded frame: header, payload, CRC.
pub const MAX_RAW: usize = HEADER_LEN + MAX_PAYLOAD + CRC_LEN;
/// Largest encoded frame on the wire: COBS adds one byte per 254 and the leading code byte;
/// plus the `0x00` delimiter.
pub const MAX_WIRE: usize = MAX_RAW + MAX_RAW / 254 + 2;
/// An encoded frame with no payload (an ack, a probe): 8 bytes, COBS' code byte and the
/// delimiter (no zero run can need a second code byte in 8 bytes).
pub const MIN_WIRE: usize = HEADER_LEN + CRC_LEN + 2;

const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// What a frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameType {
    /// A sequenced message payload (delivered once, in order).
    Data = 0,
    /// Acknowledgement and credits only (no sequence number consumed, no payload).
    Ack = 1,
    /// A session opens (no payload; the sequence and ack fields carry the session's 16-bit
    /// nonce, low byte first): sent
    /// by a host that starts talking to a device, echoed by the device once it started the
    /// session afresh (see [`super::link`]).
    Open = 2,
}

/// One decoded, checked frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame<'a> {
    /// Data or ack.
    pub kind: FrameType,
    /// Sequence number of a data frame (0 for an ack).
    pub seq: u8,
    /// Cumulative acknowledgement: every data frame before this sequence number arrived.
    pub ack: u8,
    /// Free receive slots of the sender: it accepts sequence numbers `ack..ack + credits`.
    pub credits: u8,
    /// Message bytes (empty for an ack).
    pub payload: &'a [u8],
}

/// Why a received frame was discarded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FrameError {
    /// Longer than [`MAX_WIRE`] before its delimiter.
    TooLong,
    /// Invalid COBS code bytes.
    Cobs,
    /// Shorter than header and CRC.
    TooShort,
    /// The CRC does not match.
    Crc,
    /// Another protocol version.
    Version(u8),
    /// Unknown frame type, or an ack with a payload.
    Type(u8),
}

impl core::fmt::Display for FrameError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooLong => write!(f, "frame longer than {MAX_WIRE} bytes"),
            Self::Cobs => write!(f, "invalid COBS encoding"),
            Self::TooShort => write!(f, "frame shorter than its header and CRC"),
            Self::Crc => write!(f, "CRC mismatch"),
            Self::Version(v) => write!(f, "protocol version {v} (expected {VERSION})"),
            Self::Type(t) => write!(f, "unknown frame type {t}"),
        }
    }
}

/// COBS-encodes `src` into `dst` (no delimiter); returns the length, or `None` if too small.
pub fn cobs_encode(src: &[u8], dst: &mut [u8]) -> Option<usize> {
    let mut code_at = 0usize;
    let mut out = 1usize;
    let mut code = 1u8;
    *dst.get_mut(0)? = 0;
    for &b in src {
        if b == 0 {
            *dst.get_mut(code_at)? = code;
            code_at = out;
            *dst.get_mut(out)? = 0;
            out += 1;
            code = 1;
        } else {
            *dst.get_mut(out)? = b;
            out += 1;
            code += 1;
            if code == 0xFF {
                *dst.get_mut(code_at)? = code;
                code_at = out;
                *dst.get_mut(out)? = 0;
                out += 1;
                code = 1;
            }
        }
    }
    *dst.get_mut(code_at)? = code;
    Some(out)
}

/// Decodes a COBS block (no delimiter) in place; returns the decoded length.
pub fn cobs_decode_in_place(buf: &mut [u8]) -> Option<usize> {
    let (mut read, mut write) = (0usize, 0usize);
    while read < buf.len() {
        let code = buf[read] as usize;
        if code == 0 || read + code > buf.len() {
            return None;
        }
        read += 1;
        for _ in 1..code {
            buf[write] = buf[read];
            write += 1;
            read += 1;
        }
        if code != 0xFF && read < buf.len() {
            buf[write] = 0;
            write += 1;
        }
    }
    Some(write)
}

/// Builds a frame into `out` (COBS-encoded, `0x00`-terminated); returns the wire length, or
/// `None` when the payload exceeds [`MAX_PAYLOAD`] or `out` is too small.
pub fn encode(
    kind: FrameType,
    seq: u8,
    ack: u8,
    credits: u8,
    payload: &[u8],
    out: &mut [u8],
) -> Option<usize> {
    if payload.len() > MAX_PAYLOAD {
        return None;
    }
    let mut raw = [0u8; MAX_RAW];
    raw[0] = VERSION << 4 | kind as u8;
    raw[1] = seq;
    raw[2] = ack;
    raw[3] = credits;
    let end = HEADER_LEN + payload.len();
    raw[HEADER_LEN..end].copy_from_slice(payload);
    let crc = CRC32.checksum(&raw[..end]);
    raw[end..end + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let n = cobs_encode(&raw[..end + CRC_LEN], out)?;
    *out.get_mut(n)? = 0;
    Some(n + 1)
}

/// Wire length of a data frame carrying `payload` (COBS overhead and delimiter included).
pub fn wire_len(payload: &[u8]) -> usize {
    let mut out = [0u8; MAX_WIRE];
    encode(FrameType::Data, 0, 0, 0, payload, &mut out).unwrap_or(0)
}

/// Checks a decoded (un-COBSed) frame.
pub fn parse(raw: &[u8]) -> Result<Frame<'_>, FrameError> {
    if raw.len() < HEADER_LEN + CRC_LEN {
        return Err(FrameError::TooShort);
    }
    let (body, crc) = raw.split_at(raw.len() - CRC_LEN);
    let want = u32::from_le_bytes([crc[0], crc[1], crc[2], crc[3]]);
    if CRC32.checksum(body) != want {
        return Err(FrameError::Crc);
    }
    if body[0] >> 4 != VERSION {
        return Err(FrameError::Version(body[0] >> 4));
    }
    let payload = &body[HEADER_LEN..];
    let kind = match body[0] & 0x0F {
        0 => FrameType::Data,
        1 if payload.is_empty() => FrameType::Ack,
        2 if payload.is_empty() => FrameType::Open,
        t => return Err(FrameError::Type(t)),
    };
    Ok(Frame { kind, seq: body[1], ack: body[2], credits: body[3], payload })
}

/// Incremental frame decoder: feed bytes, get checked frames. Never panics; a corrupted or
/// truncated frame is reported as an error and skipped, decoding resumes after the next `0x00`.
#[derive(Debug, Clone)]
pub struct Decoder {
    buf: [u8; MAX_WIRE],
    len: usize,
    overflow: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    /// An empty decoder.
    pub const fn new() -> Self {
        Self { buf: [0; MAX_WIRE], len: 0, overflow: false }
    }

    /// Takes one byte: `None` while a frame is incomplete (or between frames), then the
    /// frame's check result when its delimiter arrives.
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame<'_>, FrameError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let (len, overflow) = (self.len, self.overflow);
        self.len = 0;
        self.overflow = false;
        if overflow {
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        let Some(n) = cobs_decode_in_place(&mut self.buf[..len]) else {
            return Some(Err(FrameError::Cobs));
        };
        Some(parse(&self.buf[..n]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cobs_round_trips_zeros_and_long_runs() {
        let mut cases: [[u8; 600]; 3] = [[0; 600], [1; 600], [0; 600]];
        for (i, b) in cases[2].iter_mut().enumerate() {
            *b = (i % 7) as u8;
        }
        for src in &cases {
            for len in [0, 1, 253, 254, 255, 508, 600] {
                let mut enc = [0u8; 700];
                let n = cobs_encode(&src[..len], &mut enc).unwrap();
                assert!(!enc[..n].contains(&0));
                let d = cobs_decode_in_place(&mut enc[..n]).unwrap();
                assert_eq!(&enc[..d], &src[..len]);
            }
        }
    }

    #[test]
    fn an_empty_frame_takes_min_wire_bytes() {
        // Every header and CRC value, zeros included: 8 bytes need one COBS code byte.
        for (kind, v) in [(FrameType::Ack, 0u8), (FrameType::Data, 0xFF), (FrameType::Data, 0)] {
            let mut out = [0u8; MAX_WIRE];
            let n = encode(kind, v, v, v, &[], &mut out).unwrap();
            assert_eq!(n, MIN_WIRE, "{kind:?} {v}");
        }
    }
}

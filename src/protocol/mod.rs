//! The host-device protocol: framed, checksummed, sequenced, flow-controlled messages.
//!
//! Three layers, each usable alone:
//! - [`frame`]: a frame is `[version/type, seq, ack, credits, payload.., CRC-32]`,
//!   COBS-encoded and ended by `0x00`; the [`Decoder`] takes bytes in any chunking and
//!   yields only frames whose length, CRC, version and type check (never panics);
//! - [`link`]: an [`Endpoint`] per side turns frames into a reliable, in-order message
//!   stream: sequence numbers, cumulative acks, credit-based flow control (the receiver
//!   announces its free slots in every frame; the sender never exceeds them), go-back-N
//!   retransmission on a timeout, duplicate suppression, keepalives and dead-link detection,
//!   and sessions (a new host opens its own: a device whose host died talks to the next);
//! - [`msg`]: the messages (hello/capabilities, job start, triangle batches, end of model,
//!   pause/resume/abort/emergency stop, status, per-layer hashes, a parked job's news) in
//!   little-endian fields,
//!   every field checked on decode, and the compact triangle encoding (20 bytes for a
//!   triangle whose edges are within 32 mm on every axis, else 24).
//!
//! Both ends are `no_std` state machines that take time as an argument (`now_ms`), so the
//! firmware runs the device side unchanged and the host wraps the other side around a serial
//! port or an in-memory link.
//!
//! Wire cost of a triangle (short form): 20 bytes, plus one batch's framing (2 message
//! header bytes, 4 frame header, 4 CRC, 2 COBS, 1 delimiter = 13 bytes over 19 triangles):
//! about 20.7 bytes per triangle.

pub mod frame;
pub mod job_file;
pub mod link;
pub mod msg;

pub use frame::{Decoder, Frame, FrameError, FrameType, MAX_PAYLOAD, MAX_WIRE, VERSION};
pub use link::{Endpoint, LinkConfig, LinkError, LinkStats, SendError};
pub use msg::{
    job_fingerprint, BatchBuilder, Capacities, CardEntry, CardFault, DecodeError, DeviceState,
    EncodeError, ErrorCode, GcodeSpec, JobOptions, JobReport, JobSpec, Message, ParkedJob, Status,
    TriangleBatch,
};

//! Messages: a type byte and little-endian fields, and the compact triangle encoding.
//!
//! A triangle is bit-packed (LSB first): a form bit, the first corner as three unsigned
//! 20-bit coordinates (um, 0..=1048.575 mm), then the other two corners as signed deltas from
//! the first: 16 bits each in the short form (every edge within +-32.767 mm on every axis,
//! 157 bits = **20 bytes**), 21 bits each in the long form (187 bits = **24 bytes**).

use crate::geom::{Point3, Triangle};
use crate::machine::{InfillPattern, PrintSettings, Rate};

use super::frame::MAX_PAYLOAD;

/// Largest coordinate (um) a triangle on the wire may have: 20 bits.
pub const MAX_WIRE_COORD_UM: i32 = (1 << 20) - 1;
/// Bytes of a short-form triangle.
pub const SHORT_TRIANGLE_BYTES: usize = 20;
/// Bytes of a long-form triangle.
pub const LONG_TRIANGLE_BYTES: usize = 24;
/// Bytes before the triangles of a batch (type, count).
pub const BATCH_HEADER: usize = 2;
/// Triangles a batch always holds (all in the long form; more short ones fit).
pub const MAX_BATCH: usize = (MAX_PAYLOAD - BATCH_HEADER) / LONG_TRIANGLE_BYTES;

/// Message type bytes: the first byte of every payload ([`Message::type_byte`]).
pub mod ty {
    #![allow(missing_docs)]
    pub const HELLO: u8 = 0x01;
    pub const CAPABILITIES: u8 = 0x02;
    pub const JOB_START: u8 = 0x10;
    pub const TRIANGLES: u8 = 0x11;
    pub const END_OF_MODEL: u8 = 0x12;
    pub const GCODE_START: u8 = 0x13;
    pub const GCODE: u8 = 0x14;
    pub const PAUSE: u8 = 0x20;
    pub const RESUME: u8 = 0x21;
    pub const ABORT: u8 = 0x22;
    pub const EMERGENCY_STOP: u8 = 0x23;
    pub const STATUS: u8 = 0x30;
    pub const LAYER_DONE: u8 = 0x31;
    pub const JOB_REPORT: u8 = 0x32;
    pub const FAILURE: u8 = 0x33;
    pub const PARKED: u8 = 0x34;
    pub const CARD_LIST: u8 = 0x40;
    pub const CARD_ENTRY: u8 = 0x41;
    pub const CARD_LISTED: u8 = 0x42;
    pub const CARD_PRINT: u8 = 0x43;
    pub const CARD_REFUSED: u8 = 0x44;
    pub const CARD_STARTED: u8 = 0x45;
    pub const CARD_REMOVE: u8 = 0x46;
    pub const CARD_CREATE: u8 = 0x47;
    pub const CARD_DATA: u8 = 0x48;
    pub const CARD_CLOSE: u8 = 0x49;
    pub const CARD_DONE: u8 = 0x4A;
}

/// What a device holds: announced in [`Message::Capabilities`], used for admission control.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Capacities {
    /// Active triangle set (`Slicer` `ACTIVE`).
    pub active_triangles: u32,
    /// Cut segments, and contour points, of one layer (`Slicer` `SEGMENTS`).
    pub contour_points: u32,
    /// Loops of one layer (`Slicer` `LOOPS`).
    pub contour_loops: u32,
    /// Bytes of the move buffer between the toolpath stage and the planner (delta-coded
    /// records, `strata::move_ring`): the toolpath stage fills it a path (with the travel
    /// before it) at a time, so the job's largest such unit, coded, must fit it whole.
    pub move_buffer_bytes: u32,
    /// Layers the skin window holds (top solid layers the toolpath stage can wait for).
    pub layer_window: u16,
    /// RAM the pipeline's buffers take on the device, bytes.
    pub ram_bytes: u32,
    /// Toolpath: simplified loop points of one layer, and offset edges (splits, pieces) of
    /// one island (`Toolpath` `PTS`; needs `max(layer_points, offset_edges)`).
    pub toolpath_points: u32,
    /// Toolpath: loops of one layer (`Toolpath` `LOOPS`; needs `layer_loops`).
    pub toolpath_loops: u32,
    /// Toolpath: scanline crossings of one infill pass, and its segments and pieces in
    /// 12-byte units (`Toolpath` `CROSS`; needs `crossings`).
    pub scan_crossings: u32,
    /// Toolpath: path points of one layer, two per path record (`Toolpath` `PATH`; needs
    /// `path_points`).
    pub path_points: u32,
    /// Toolpath: words of the contours stored in the skin window (`Toolpath` `RING`; needs
    /// `ring_points`).
    pub window_ring_words: u32,
    /// Toolpath: crossings (then spans) of the skin window's layers with one scanline
    /// (`Toolpath` `SPANS`; needs `spans`).
    pub window_spans: u32,
}

/// Toolpath choices that are not part of [`PrintSettings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JobOptions {
    /// Print the external perimeter after the inner ones.
    pub outer_perimeter_last: bool,
    /// Seam: 0 rear, 1 nearest.
    pub seam: u8,
    /// Skirt loops.
    pub skirt_loops: u8,
    /// Gap between skirt and first layer (or its brim), um.
    pub skirt_distance_um: i32,
    /// Brim loops (0: none): the host's width over the line width, rounded down. One byte in
    /// memory (the job message keeps its size on the board's stack), an `i32` on the wire
    /// (0..=255).
    pub brim_loops: u8,
}

impl Default for JobOptions {
    fn default() -> Self {
        Self {
            outer_perimeter_last: true,
            seam: 0,
            skirt_loops: 1,
            skirt_distance_um: 3000,
            brim_loops: 0,
        }
    }
}

/// A job: settings, options and what the model is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct JobSpec {
    /// Print settings.
    pub settings: PrintSettings,
    /// Toolpath options.
    pub options: JobOptions,
    /// Highest z of the placed model, um.
    pub model_height_um: i32,
    /// Triangles that will be streamed.
    pub triangles: u32,
}

/// What the device is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DeviceState {
    /// Waiting for a job.
    #[default]
    Idle = 0,
    /// Receiving triangles and printing.
    Printing = 1,
    /// Paused (motion stops after the queued moves).
    Paused = 2,
    /// Every step executed.
    Done = 3,
    /// Stopped by an error (see the status' error).
    Failed = 4,
    /// Aborted by the host.
    Aborted = 5,
    /// Emergency stop: drivers disabled at once.
    Stopped = 6,
}

/// Why a job failed (status error code; the detail is a number explained per code).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ErrorCode {
    /// No error.
    #[default]
    None = 0,
    /// Settings or model refused (detail: 0).
    BadJob = 1,
    /// The slicer failed (detail: layer).
    Slice = 2,
    /// The toolpath stage failed (detail: layer).
    Toolpath = 3,
    /// The planner refused a move (detail: layer).
    Plan = 4,
    /// A message that does not fit the state (detail: message type).
    Unexpected = 5,
    /// A message that does not decode (detail: message type).
    BadMessage = 6,
    /// A path (with the travel before it) needs more bytes of coded moves than the whole move
    /// buffer holds, or the buffer overflowed (detail: layer).
    Moves = 7,
    /// The link went silent (detail: ms): the job printed what it had, parked and paused.
    LinkDead = 8,
    /// A heater fault (detail: the fault's code, `strata::thermal::ThermalFault`): heaters
    /// off, motion stopped.
    Thermal = 9,
    /// The card failed the job (detail: the [`CardFault`]'s code): removed or unreadable
    /// mid-print.
    Card = 10,
}

impl ErrorCode {
    fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::None,
            1 => Self::BadJob,
            2 => Self::Slice,
            3 => Self::Toolpath,
            4 => Self::Plan,
            5 => Self::Unexpected,
            6 => Self::BadMessage,
            7 => Self::Moves,
            8 => Self::LinkDead,
            9 => Self::Thermal,
            10 => Self::Card,
            _ => return None,
        })
    }
}

impl DeviceState {
    fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Self::Idle,
            1 => Self::Printing,
            2 => Self::Paused,
            3 => Self::Done,
            4 => Self::Failed,
            5 => Self::Aborted,
            6 => Self::Stopped,
            _ => return None,
        })
    }
}

/// A status report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Status {
    /// State.
    pub state: DeviceState,
    /// Layers whose moves are planned.
    pub layer: u32,
    /// Layers of the job.
    pub layers: u32,
    /// Print time of the blocks planned so far, ms.
    pub planned_ms: u32,
    /// Print time executed so far, ms.
    pub done_ms: u32,
    /// Triangles received.
    pub triangles: u32,
    /// Move buffer fill (bytes in use), percent.
    pub queue_fill_pct: u8,
    /// Error, if failed.
    pub error: ErrorCode,
    /// Error detail (see [`ErrorCode`]).
    pub detail: u32,
    /// Hotend temperature, 0.1 degC.
    pub hotend_c_x10: i16,
    /// Bed temperature, 0.1 degC.
    pub bed_c_x10: i16,
    /// Motion waits for the heaters to reach their targets (before the first layer).
    pub heating: bool,
}

/// A batch of encoded triangles (checked when decoded: iterate with [`TriangleBatch::iter`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TriangleBatch<'a> {
    count: u8,
    bytes: &'a [u8],
}

impl<'a> TriangleBatch<'a> {
    /// Number of triangles.
    pub fn len(&self) -> usize {
        self.count as usize
    }
    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
    /// The triangles, in order.
    pub fn iter(&self) -> impl Iterator<Item = Triangle> + 'a {
        let mut bytes = self.bytes;
        (0..self.count).map_while(move |_| {
            let (t, n) = decode_triangle(bytes)?;
            bytes = &bytes[n..];
            Some(t)
        })
    }
}

/// One message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Message<'a> {
    /// Host greets the device (protocol version).
    Hello {
        /// Protocol version.
        version: u8,
    },
    /// Device answers with its capacities.
    Capabilities {
        /// Protocol version.
        version: u8,
        /// Capacities.
        capacities: Capacities,
    },
    /// A job begins.
    JobStart(JobSpec),
    /// Triangles, in zmin order.
    Triangles(TriangleBatch<'a>),
    /// Every triangle (or the whole G-code text) was sent.
    EndOfModel,
    /// A G-code job begins: the printer runs the text that follows ([`Message::Gcode`]) as
    /// it is, no slicing.
    GcodeStart(GcodeSpec),
    /// The next bytes of a G-code job's text (lines may run on into the next message).
    Gcode(&'a [u8]),
    /// Pause after the queued motion.
    Pause,
    /// Resume.
    Resume,
    /// End the job (motion stops at rest, drivers off).
    Abort,
    /// Stop at once: drivers disabled immediately.
    EmergencyStop,
    /// Device status.
    Status(Status),
    /// A layer's moves are planned: its motion hash.
    LayerDone {
        /// Layer index.
        layer: u32,
        /// Hash of the layer's step commands (see `StepProducer::take_hash`).
        hash: u64,
    },
    /// The job's totals, sent once when it is done (before the status saying so).
    JobReport(JobReport),
    /// Why the job failed, in the failing stage's own words (UTF-8, e.g. "slicer: too many
    /// active triangles in layer 37 (capacity 388)"), sent once before the status saying
    /// so; the status keeps its code and detail.
    Failure(&'a str),
    /// The device holds a job whose host went silent, parked and paused: sent after the
    /// capabilities to a new host, which may resume it ([`Message::Resume`]) by sending the
    /// rest of the same job.
    Parked(ParkedJob),
    /// List the card's root directory from its `from`-th entry: the device answers with the
    /// entries that fit its send queue ([`Message::CardEntry`]), then [`Message::CardListed`]
    /// (or [`Message::CardRefused`]).
    CardList {
        /// Entries to skip.
        from: u16,
    },
    /// An entry of the card's root directory.
    CardEntry(CardEntry<'a>),
    /// The end of a listing's answer.
    CardListed {
        /// Entries listed so far (the `from` of the next [`Message::CardList`]).
        next: u16,
        /// The directory has no more entries.
        done: bool,
    },
    /// Print the card's file of this name (in the root directory): the device starts a job
    /// that needs no host, or answers [`Message::CardRefused`].
    CardPrint(&'a str),
    /// A card request could not be done.
    CardRefused(CardFault),
    /// The card's file began printing (the answer to [`Message::CardPrint`]; the statuses
    /// after it are this job's).
    CardStarted {
        /// Bytes of the file.
        bytes: u32,
    },
    /// Remove the card's file of this name (answered with [`Message::CardDone`] or
    /// [`Message::CardRefused`]).
    CardRemove(&'a str),
    /// Create (or replace) the card's file of this name, empty; [`Message::CardData`] follows,
    /// then [`Message::CardClose`] (answered with [`Message::CardDone`], or
    /// [`Message::CardRefused`] at the first failure).
    CardCreate(&'a str),
    /// The next bytes of the file being written.
    CardData(&'a [u8]),
    /// The file being written is complete.
    CardClose,
    /// A card write is done: the bytes of the file written (0 for a removal).
    CardDone {
        /// Bytes of the file.
        bytes: u32,
    },
}

/// An entry of the card's root directory ([`Message::CardEntry`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CardEntry<'a> {
    /// Bytes of the file (0 for a directory).
    pub size: u32,
    /// A directory.
    pub is_dir: bool,
    /// Its name (the long name; a name longer than the card reader keeps is cut).
    pub name: &'a str,
}

/// Why the card could not do what was asked (a request refused, or a card job failed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CardFault {
    /// No card in the slot (or it does not answer).
    Absent = 1,
    /// The card answered, then a read failed.
    Unreadable = 2,
    /// No FAT16 or FAT32 volume on the card.
    Unformatted = 3,
    /// A FAT the reader does not support (FAT12, sectors other than 512 bytes).
    Unsupported = 4,
    /// The file system is damaged.
    Damaged = 5,
    /// No file of that name.
    NotFound = 6,
    /// The name is a directory's.
    IsDirectory = 7,
    /// The file is neither G-code nor STL.
    NotPrintable = 8,
    /// The file is an STL (no longer refused: an STL on the card is placed, sorted and
    /// printed; the code stays reserved).
    Stl = 9,
    /// A job is running or paused.
    Busy = 10,
    /// The card went away (or a read failed) in the middle of a print.
    Removed = 11,
    /// The card (or its root directory) has no room left.
    Full = 12,
    /// A file name the card cannot hold.
    BadName = 13,
    /// No file is being written (none was created, or a job started meanwhile).
    NoUpload = 14,
    /// A job file whose records are damaged, or written for another protocol version.
    BadJob = 15,
    /// An STL file that cannot be read (damaged, or no triangles).
    BadStl = 16,
    /// A model larger than the bed.
    TooLarge = 17,
    /// A model of more triangles than the printer sorts on its card.
    TooManyTriangles = 18,
    /// An ASCII STL (the printer reads binary STL from its card).
    AsciiStl = 19,
    /// A model whose layers cross more triangles than the printer's slicer holds (its active
    /// triangles).
    TooComplex = 20,
}

impl CardFault {
    /// The fault of code `v` (its `as u8`).
    pub fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            1 => Self::Absent,
            2 => Self::Unreadable,
            3 => Self::Unformatted,
            4 => Self::Unsupported,
            5 => Self::Damaged,
            6 => Self::NotFound,
            7 => Self::IsDirectory,
            8 => Self::NotPrintable,
            9 => Self::Stl,
            10 => Self::Busy,
            11 => Self::Removed,
            12 => Self::Full,
            13 => Self::BadName,
            14 => Self::NoUpload,
            15 => Self::BadJob,
            16 => Self::BadStl,
            17 => Self::TooLarge,
            18 => Self::TooManyTriangles,
            19 => Self::AsciiStl,
            20 => Self::TooComplex,
            _ => return None,
        })
    }
}

impl core::fmt::Display for CardFault {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            Self::Absent => "no SD card in the printer",
            Self::Unreadable => "the SD card could not be read",
            Self::Unformatted => "the SD card is not formatted (FAT16 or FAT32 expected)",
            Self::Unsupported => "the SD card's FAT is not supported (FAT16 or FAT32 expected)",
            Self::Damaged => "the SD card's file system is damaged",
            Self::NotFound => "no such file on the SD card",
            Self::IsDirectory => "that name is a directory on the SD card",
            Self::NotPrintable => "the file is neither G-code nor STL",
            Self::Stl => {
                "the file is an STL: the printer prints G-code and model jobs from the card; \
                 write the model's job with `strata upload FILE.stl`, or print it with \
                 `strata print FILE.stl` (it slices on board as it streams)"
            }
            Self::Busy => "the printer is busy with a job",
            Self::Removed => "the SD card was removed or failed during the print",
            Self::Full => "the SD card is full",
            Self::BadJob => {
                "the job file is damaged or from another version of strata: upload the model \
                 again with `strata upload`"
            }
            Self::BadStl => "the STL file cannot be read (damaged, or it holds no triangles)",
            Self::TooLarge => "the model is larger than the bed",
            Self::AsciiStl => {
                "the STL is ASCII: the printer reads binary STL from its card (save it as binary \
                 STL, or write its job with `strata upload FILE.stl`)"
            }
            Self::TooComplex => {
                "the model crosses more triangles in a layer than the printer's slicer holds \
                 (its active triangles): write its job with `strata upload FILE.stl`, which \
                 simplifies it to fit"
            }
            Self::TooManyTriangles => {
                "the model has more triangles than the printer sorts on its card: print it with \
                 `strata print FILE.stl` or write its job with `strata upload FILE.stl` (both \
                 simplify it to fit)"
            }
            Self::NoUpload => "no file is being written to the SD card (a job started meanwhile?)",
            Self::BadName => {
                "a name the SD card cannot hold (printable ASCII without \"*/:<>?\\| and at \
                 most 64 characters)"
            }
        })
    }
}

/// A job parked when its host went silent: where a new host resumes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ParkedJob {
    /// The layer of the last move printed.
    pub layer: u32,
    /// Triangles the device took, or bytes of G-code text in the lines it read (the
    /// resuming host sends what follows).
    pub taken: u32,
    /// The job's fingerprint ([`job_fingerprint`] of its start message): a host resumes
    /// only the same job.
    pub fingerprint: u32,
}

/// A job's fingerprint: the CRC-32 (ISO-HDLC) of its start message's payload.
///
/// The payload is the type byte, then the settings, height and triangle count of
/// [`Message::JobStart`], or the bytes and layers of [`Message::GcodeStart`].
pub fn job_fingerprint(start_payload: &[u8]) -> u32 {
    FINGERPRINT_CRC.checksum(start_payload)
}

/// The fingerprint's CRC, its table built at compile time (in flash: built at run time it
/// would take 1 KB of the stack).
const FINGERPRINT_CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// A G-code job, as the host measured its text.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GcodeSpec {
    /// Bytes of text that will be sent.
    pub bytes: u32,
    /// Layers the text marks (`;LAYER_CHANGE`, `;LAYER:n`); 0 when it marks none.
    pub layers: u32,
}

/// What a finished job did: every step sent to the motors, where they ended and how long
/// the motion lasted, comparable bit for bit with the host simulation of the same job.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct JobReport {
    /// Steps per axis X, Y, Z, E.
    pub steps: [u64; 4],
    /// Final motor positions X, Y, Z, E, steps from the job's origin.
    pub positions: [i64; 4],
    /// Duration of the planned motion, step timer ticks.
    pub print_ticks: u64,
}

/// Why a message does not encode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The output buffer is too small.
    BufferFull,
    /// A triangle coordinate outside `0..=MAX_WIRE_COORD_UM`.
    OutOfRange,
}

/// Why a payload does not decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// Empty payload.
    Empty,
    /// Unknown message type.
    UnknownType(u8),
    /// Wrong length for the type.
    Length(u8),
    /// A field has an invalid value.
    Field(u8),
}

impl core::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => write!(f, "empty message"),
            Self::UnknownType(t) => write!(f, "unknown message type 0x{t:02x}"),
            Self::Length(t) => write!(f, "message 0x{t:02x} has a wrong length"),
            Self::Field(t) => write!(f, "message 0x{t:02x} has an invalid field"),
        }
    }
}

struct Writer<'b> {
    buf: &'b mut [u8],
    len: usize,
}

impl Writer<'_> {
    fn put(&mut self, bytes: &[u8]) -> Result<(), EncodeError> {
        let end = self.len + bytes.len();
        self.buf.get_mut(self.len..end).ok_or(EncodeError::BufferFull)?.copy_from_slice(bytes);
        self.len = end;
        Ok(())
    }
    fn u8(&mut self, v: u8) -> Result<(), EncodeError> {
        self.put(&[v])
    }
    fn u16(&mut self, v: u16) -> Result<(), EncodeError> {
        self.put(&v.to_le_bytes())
    }
    fn u32(&mut self, v: u32) -> Result<(), EncodeError> {
        self.put(&v.to_le_bytes())
    }
    fn i32(&mut self, v: i32) -> Result<(), EncodeError> {
        self.put(&v.to_le_bytes())
    }
    fn u64(&mut self, v: u64) -> Result<(), EncodeError> {
        self.put(&v.to_le_bytes())
    }
    fn rate(&mut self, v: Rate) -> Result<(), EncodeError> {
        self.u64(v.to_bits())
    }
}

struct Reader<'a> {
    bytes: &'a [u8],
    ty: u8,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], DecodeError> {
        if self.bytes.len() < n {
            return Err(DecodeError::Length(self.ty));
        }
        let (a, b) = self.bytes.split_at(n);
        self.bytes = b;
        Ok(a)
    }
    fn u8(&mut self) -> Result<u8, DecodeError> {
        Ok(self.take(1)?[0])
    }
    fn u16(&mut self) -> Result<u16, DecodeError> {
        let b = self.take(2)?;
        Ok(u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Result<u32, DecodeError> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }
    fn i32(&mut self) -> Result<i32, DecodeError> {
        Ok(self.u32()? as i32)
    }
    fn u64(&mut self) -> Result<u64, DecodeError> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }
    fn rate(&mut self) -> Result<Rate, DecodeError> {
        Ok(Rate::from_bits(self.u64()?))
    }
    fn bool(&mut self) -> Result<bool, DecodeError> {
        match self.u8()? {
            0 => Ok(false),
            1 => Ok(true),
            _ => Err(DecodeError::Field(self.ty)),
        }
    }
    fn end(&self) -> Result<(), DecodeError> {
        if self.bytes.is_empty() {
            Ok(())
        } else {
            Err(DecodeError::Length(self.ty))
        }
    }
}

impl<'a> Message<'a> {
    /// Writes the message into `buf`; returns its length.
    pub fn encode(&self, buf: &mut [u8]) -> Result<usize, EncodeError> {
        let mut w = Writer { buf, len: 0 };
        match self {
            Self::Hello { version } => {
                w.u8(ty::HELLO)?;
                w.u8(*version)?;
            }
            Self::Capabilities { version, capacities: c } => {
                w.u8(ty::CAPABILITIES)?;
                w.u8(*version)?;
                w.u32(c.active_triangles)?;
                w.u32(c.contour_points)?;
                w.u32(c.contour_loops)?;
                w.u32(c.move_buffer_bytes)?;
                w.u16(c.layer_window)?;
                w.u32(c.ram_bytes)?;
                w.u32(c.toolpath_points)?;
                w.u32(c.toolpath_loops)?;
                w.u32(c.scan_crossings)?;
                w.u32(c.path_points)?;
                w.u32(c.window_ring_words)?;
                w.u32(c.window_spans)?;
            }
            Self::JobStart(j) => {
                let s = &j.settings;
                w.u8(ty::JOB_START)?;
                w.i32(s.layer_height_um)?;
                w.i32(s.first_layer_height_um)?;
                w.i32(s.line_width_um)?;
                w.u8(s.perimeters)?;
                w.u8(s.infill_percent)?;
                w.u8(match s.infill_pattern {
                    InfillPattern::Lines => 0,
                    InfillPattern::Zigzag => 1,
                    InfillPattern::Grid => 2,
                })?;
                w.u8(s.top_layers)?;
                w.u8(s.bottom_layers)?;
                w.u16(s.hotend_temp_c as u16)?;
                w.u16(s.bed_temp_c as u16)?;
                w.rate(s.perimeter_speed_mm_s)?;
                w.rate(s.infill_speed_mm_s)?;
                w.rate(s.travel_speed_mm_s)?;
                w.rate(s.first_layer_speed_mm_s)?;
                w.i32(s.retract_length_um)?;
                w.rate(s.retract_speed_mm_s)?;
                w.u64(s.min_loop_area_um2 as u64)?;
                w.u8(j.options.outer_perimeter_last as u8)?;
                w.u8(j.options.seam)?;
                w.u8(j.options.skirt_loops)?;
                w.i32(j.options.skirt_distance_um)?;
                w.i32(i32::from(j.options.brim_loops))?;
                w.i32(j.model_height_um)?;
                w.u32(j.triangles)?;
            }
            Self::Triangles(b) => {
                w.u8(ty::TRIANGLES)?;
                w.u8(b.count)?;
                w.put(b.bytes)?;
            }
            Self::EndOfModel => w.u8(ty::END_OF_MODEL)?,
            Self::Pause => w.u8(ty::PAUSE)?,
            Self::Resume => w.u8(ty::RESUME)?,
            Self::Abort => w.u8(ty::ABORT)?,
            Self::EmergencyStop => w.u8(ty::EMERGENCY_STOP)?,
            Self::Status(s) => {
                w.u8(ty::STATUS)?;
                w.u8(s.state as u8)?;
                w.u32(s.layer)?;
                w.u32(s.layers)?;
                w.u32(s.planned_ms)?;
                w.u32(s.done_ms)?;
                w.u32(s.triangles)?;
                w.u8(s.queue_fill_pct)?;
                w.u8(s.error as u8)?;
                w.u32(s.detail)?;
                w.u16(s.hotend_c_x10 as u16)?;
                w.u16(s.bed_c_x10 as u16)?;
                w.u8(s.heating as u8)?;
            }
            Self::LayerDone { layer, hash } => {
                w.u8(ty::LAYER_DONE)?;
                w.u32(*layer)?;
                w.u64(*hash)?;
            }
            Self::JobReport(j) => {
                w.u8(ty::JOB_REPORT)?;
                for v in j.steps {
                    w.u64(v)?;
                }
                for v in j.positions {
                    w.u64(v as u64)?;
                }
                w.u64(j.print_ticks)?;
            }
            Self::Failure(text) => {
                w.u8(ty::FAILURE)?;
                w.put(text.as_bytes())?;
            }
            Self::Parked(p) => {
                w.u8(ty::PARKED)?;
                w.u32(p.layer)?;
                w.u32(p.taken)?;
                w.u32(p.fingerprint)?;
            }
            Self::CardList { from } => {
                w.u8(ty::CARD_LIST)?;
                w.u16(*from)?;
            }
            Self::CardEntry(e) => {
                w.u8(ty::CARD_ENTRY)?;
                w.u32(e.size)?;
                w.u8(e.is_dir as u8)?;
                w.put(e.name.as_bytes())?;
            }
            Self::CardListed { next, done } => {
                w.u8(ty::CARD_LISTED)?;
                w.u16(*next)?;
                w.u8(*done as u8)?;
            }
            Self::CardPrint(name) => {
                if name.is_empty() {
                    return Err(EncodeError::OutOfRange);
                }
                w.u8(ty::CARD_PRINT)?;
                w.put(name.as_bytes())?;
            }
            Self::CardRefused(fault) => {
                w.u8(ty::CARD_REFUSED)?;
                w.u8(*fault as u8)?;
            }
            Self::CardStarted { bytes } => {
                w.u8(ty::CARD_STARTED)?;
                w.u32(*bytes)?;
            }
            Self::CardRemove(name) | Self::CardCreate(name) => {
                if name.is_empty() {
                    return Err(EncodeError::OutOfRange);
                }
                w.u8(self.type_byte())?;
                w.put(name.as_bytes())?;
            }
            Self::CardData(bytes) => {
                if bytes.is_empty() {
                    return Err(EncodeError::OutOfRange);
                }
                w.u8(ty::CARD_DATA)?;
                w.put(bytes)?;
            }
            Self::CardClose => w.u8(ty::CARD_CLOSE)?,
            Self::CardDone { bytes } => {
                w.u8(ty::CARD_DONE)?;
                w.u32(*bytes)?;
            }
            Self::GcodeStart(g) => {
                w.u8(ty::GCODE_START)?;
                w.u32(g.bytes)?;
                w.u32(g.layers)?;
            }
            Self::Gcode(text) => {
                if text.is_empty() {
                    return Err(EncodeError::OutOfRange);
                }
                w.u8(ty::GCODE)?;
                w.put(text)?;
            }
        }
        Ok(w.len)
    }

    /// The message's type byte (the first byte of its payload, [`ty`]).
    pub fn type_byte(&self) -> u8 {
        match self {
            Self::Hello { .. } => ty::HELLO,
            Self::Capabilities { .. } => ty::CAPABILITIES,
            Self::JobStart(_) => ty::JOB_START,
            Self::Triangles(_) => ty::TRIANGLES,
            Self::EndOfModel => ty::END_OF_MODEL,
            Self::Pause => ty::PAUSE,
            Self::Resume => ty::RESUME,
            Self::Abort => ty::ABORT,
            Self::EmergencyStop => ty::EMERGENCY_STOP,
            Self::Status(_) => ty::STATUS,
            Self::LayerDone { .. } => ty::LAYER_DONE,
            Self::JobReport(_) => ty::JOB_REPORT,
            Self::Failure(_) => ty::FAILURE,
            Self::Parked(_) => ty::PARKED,
            Self::GcodeStart(_) => ty::GCODE_START,
            Self::Gcode(_) => ty::GCODE,
            Self::CardList { .. } => ty::CARD_LIST,
            Self::CardEntry(_) => ty::CARD_ENTRY,
            Self::CardListed { .. } => ty::CARD_LISTED,
            Self::CardPrint(_) => ty::CARD_PRINT,
            Self::CardRefused(_) => ty::CARD_REFUSED,
            Self::CardStarted { .. } => ty::CARD_STARTED,
            Self::CardRemove(_) => ty::CARD_REMOVE,
            Self::CardCreate(_) => ty::CARD_CREATE,
            Self::CardData(_) => ty::CARD_DATA,
            Self::CardClose => ty::CARD_CLOSE,
            Self::CardDone { .. } => ty::CARD_DONE,
        }
    }

    /// Reads and checks a message; every field is validated, a triangle batch completely.
    pub fn decode(bytes: &'a [u8]) -> Result<Self, DecodeError> {
        let (&t, rest) = bytes.split_first().ok_or(DecodeError::Empty)?;
        let mut r = Reader { bytes: rest, ty: t };
        let bad = DecodeError::Field(t);
        let m = match t {
            ty::HELLO => Self::Hello { version: r.u8()? },
            ty::CAPABILITIES => Self::Capabilities {
                version: r.u8()?,
                capacities: Capacities {
                    active_triangles: r.u32()?,
                    contour_points: r.u32()?,
                    contour_loops: r.u32()?,
                    move_buffer_bytes: r.u32()?,
                    layer_window: r.u16()?,
                    ram_bytes: r.u32()?,
                    toolpath_points: r.u32()?,
                    toolpath_loops: r.u32()?,
                    scan_crossings: r.u32()?,
                    path_points: r.u32()?,
                    window_ring_words: r.u32()?,
                    window_spans: r.u32()?,
                },
            },
            ty::JOB_START => {
                let s = PrintSettings {
                    layer_height_um: r.i32()?,
                    first_layer_height_um: r.i32()?,
                    line_width_um: r.i32()?,
                    perimeters: r.u8()?,
                    infill_percent: r.u8()?,
                    infill_pattern: match r.u8()? {
                        0 => InfillPattern::Lines,
                        1 => InfillPattern::Zigzag,
                        2 => InfillPattern::Grid,
                        _ => return Err(bad),
                    },
                    top_layers: r.u8()?,
                    bottom_layers: r.u8()?,
                    hotend_temp_c: r.u16()? as i16,
                    bed_temp_c: r.u16()? as i16,
                    perimeter_speed_mm_s: r.rate()?,
                    infill_speed_mm_s: r.rate()?,
                    travel_speed_mm_s: r.rate()?,
                    first_layer_speed_mm_s: r.rate()?,
                    retract_length_um: r.i32()?,
                    retract_speed_mm_s: r.rate()?,
                    min_loop_area_um2: r.u64()? as i64,
                };
                let options = JobOptions {
                    outer_perimeter_last: r.bool()?,
                    seam: r.u8()?,
                    skirt_loops: r.u8()?,
                    skirt_distance_um: r.i32()?,
                    brim_loops: u8::try_from(r.i32()?).map_err(|_| bad)?,
                };
                if options.seam > 1 {
                    return Err(bad);
                }
                Self::JobStart(JobSpec {
                    settings: s,
                    options,
                    model_height_um: r.i32()?,
                    triangles: r.u32()?,
                })
            }
            ty::TRIANGLES => {
                let count = r.u8()?;
                let body = r.bytes;
                let mut at = 0usize;
                for _ in 0..count {
                    let (_, n) = decode_triangle(&body[at..]).ok_or(bad)?;
                    at += n;
                }
                if at != body.len() || count == 0 {
                    return Err(DecodeError::Length(t));
                }
                r.bytes = &[];
                Self::Triangles(TriangleBatch { count, bytes: body })
            }
            ty::END_OF_MODEL => Self::EndOfModel,
            ty::PAUSE => Self::Pause,
            ty::RESUME => Self::Resume,
            ty::ABORT => Self::Abort,
            ty::EMERGENCY_STOP => Self::EmergencyStop,
            ty::STATUS => Self::Status(Status {
                state: DeviceState::from_u8(r.u8()?).ok_or(bad)?,
                layer: r.u32()?,
                layers: r.u32()?,
                planned_ms: r.u32()?,
                done_ms: r.u32()?,
                triangles: r.u32()?,
                queue_fill_pct: r.u8()?,
                error: ErrorCode::from_u8(r.u8()?).ok_or(bad)?,
                detail: r.u32()?,
                hotend_c_x10: r.u16()? as i16,
                bed_c_x10: r.u16()? as i16,
                heating: match r.u8()? {
                    0 => false,
                    1 => true,
                    _ => return Err(bad),
                },
            }),
            ty::LAYER_DONE => Self::LayerDone { layer: r.u32()?, hash: r.u64()? },
            ty::PARKED => {
                Self::Parked(ParkedJob { layer: r.u32()?, taken: r.u32()?, fingerprint: r.u32()? })
            }
            ty::JOB_REPORT => {
                let mut j = JobReport::default();
                for v in &mut j.steps {
                    *v = r.u64()?;
                }
                for v in &mut j.positions {
                    *v = r.u64()? as i64;
                }
                j.print_ticks = r.u64()?;
                Self::JobReport(j)
            }
            ty::FAILURE => {
                let text = r.take(r.bytes.len())?;
                Self::Failure(core::str::from_utf8(text).map_err(|_| bad)?)
            }
            ty::GCODE_START => Self::GcodeStart(GcodeSpec { bytes: r.u32()?, layers: r.u32()? }),
            ty::GCODE => {
                let text = r.take(r.bytes.len())?;
                if text.is_empty() {
                    return Err(DecodeError::Length(t));
                }
                Self::Gcode(text)
            }
            ty::CARD_LIST => Self::CardList { from: r.u16()? },
            ty::CARD_ENTRY => {
                let (size, is_dir) = (r.u32()?, r.bool()?);
                let name = r.take(r.bytes.len())?;
                let name = core::str::from_utf8(name).map_err(|_| bad)?;
                Self::CardEntry(CardEntry { size, is_dir, name })
            }
            ty::CARD_LISTED => Self::CardListed { next: r.u16()?, done: r.bool()? },
            ty::CARD_PRINT | ty::CARD_REMOVE | ty::CARD_CREATE => {
                let name = r.take(r.bytes.len())?;
                if name.is_empty() {
                    return Err(DecodeError::Length(t));
                }
                let name = core::str::from_utf8(name).map_err(|_| bad)?;
                match t {
                    ty::CARD_PRINT => Self::CardPrint(name),
                    ty::CARD_REMOVE => Self::CardRemove(name),
                    _ => Self::CardCreate(name),
                }
            }
            ty::CARD_DATA => {
                let bytes = r.take(r.bytes.len())?;
                if bytes.is_empty() {
                    return Err(DecodeError::Length(t));
                }
                Self::CardData(bytes)
            }
            ty::CARD_CLOSE => Self::CardClose,
            ty::CARD_DONE => Self::CardDone { bytes: r.u32()? },
            ty::CARD_REFUSED => Self::CardRefused(CardFault::from_u8(r.u8()?).ok_or(bad)?),
            ty::CARD_STARTED => Self::CardStarted { bytes: r.u32()? },
            other => return Err(DecodeError::UnknownType(other)),
        };
        r.end()?;
        Ok(m)
    }
}

/// Bytes `t` takes on the wire (20 or 24), or `None` when a coordinate is out of range.
pub fn triangle_len(t: &Triangle) -> Option<usize> {
    let ok = |c: i32| (0..=MAX_WIRE_COORD_UM).contains(&c);
    if !t.v.iter().all(|p| ok(p.x) && ok(p.y) && ok(p.z)) {
        return None;
    }
    let short = t.v[1..].iter().all(|p| {
        let d = [p.x - t.v[0].x, p.y - t.v[0].y, p.z - t.v[0].z];
        d.iter().all(|&c| i16::try_from(c).is_ok())
    });
    Some(if short { SHORT_TRIANGLE_BYTES } else { LONG_TRIANGLE_BYTES })
}

struct Bits<'b> {
    buf: &'b mut [u8],
    bit: usize,
}

impl Bits<'_> {
    fn put(&mut self, value: u32, bits: usize) {
        for i in 0..bits {
            if value >> i & 1 == 1 {
                self.buf[(self.bit + i) / 8] |= 1 << ((self.bit + i) % 8);
            }
        }
        self.bit += bits;
    }
}

/// The `bits` (at most 25) bits of `buf` from bit `*bit` on, least significant first: one
/// little-endian load of the four bytes that hold them (bytes past the end read as 0).
fn get_bits(buf: &[u8], bit: &mut usize, bits: usize) -> u32 {
    debug_assert!(bits <= 25);
    let first = *bit / 8;
    let mut word = [0u8; 4];
    match buf.get(first..first + 4) {
        Some(four) => word.copy_from_slice(four),
        None => {
            for (w, b) in word.iter_mut().zip(buf.iter().skip(first)) {
                *w = *b;
            }
        }
    }
    let v = (u32::from_le_bytes(word) >> (*bit % 8)) & ((1u32 << bits) - 1);
    *bit += bits;
    v
}

fn sign_extend(v: u32, bits: usize) -> i32 {
    ((v << (32 - bits)) as i32) >> (32 - bits)
}

/// Encodes one triangle into `out`; returns its length (20 or 24).
pub fn encode_triangle(t: &Triangle, out: &mut [u8]) -> Result<usize, EncodeError> {
    let n = triangle_len(t).ok_or(EncodeError::OutOfRange)?;
    let out = out.get_mut(..n).ok_or(EncodeError::BufferFull)?;
    out.fill(0);
    let mut w = Bits { buf: out, bit: 0 };
    let long = n == LONG_TRIANGLE_BYTES;
    let db = if long { 21 } else { 16 };
    w.put(long as u32, 1);
    for c in [t.v[0].x, t.v[0].y, t.v[0].z] {
        w.put(c as u32, 20);
    }
    for p in &t.v[1..] {
        for d in [p.x - t.v[0].x, p.y - t.v[0].y, p.z - t.v[0].z] {
            w.put((d as u32) & ((1 << db) - 1), db);
        }
    }
    Ok(n)
}

/// Decodes one triangle from the front of `bytes`: the triangle and its length, or `None`
/// when truncated or a corner lies outside `0..=MAX_WIRE_COORD_UM`.
pub fn decode_triangle(bytes: &[u8]) -> Option<(Triangle, usize)> {
    let first = *bytes.first()?;
    let long = first & 1 == 1;
    let (n, db) = if long { (LONG_TRIANGLE_BYTES, 21) } else { (SHORT_TRIANGLE_BYTES, 16) };
    let b = bytes.get(..n)?;
    let mut bit = 1usize;
    let v0 = [0; 3].map(|_: i32| get_bits(b, &mut bit, 20) as i32);
    let mut v = [Point3::new(v0[0], v0[1], v0[2]); 3];
    for p in &mut v[1..] {
        let d = [0; 3].map(|_: i32| sign_extend(get_bits(b, &mut bit, db), db));
        *p = Point3::new(v0[0] + d[0], v0[1] + d[1], v0[2] + d[2]);
    }
    let t = Triangle { v };
    // Canonical form only: a long triangle that fits the short form, or stray padding bits,
    // are refused (every triangle has exactly one encoding).
    if triangle_len(&t)? != n || (long && b[23] >> 3 != 0) || (!long && b[19] >> 5 != 0) {
        return None;
    }
    Some((t, n))
}

/// Builds a triangle batch payload in a buffer of [`MAX_PAYLOAD`] bytes.
#[derive(Debug, Clone)]
pub struct BatchBuilder {
    buf: [u8; MAX_PAYLOAD],
    len: usize,
    count: u8,
}

impl Default for BatchBuilder {
    fn default() -> Self {
        Self::new()
    }
}

impl BatchBuilder {
    /// An empty batch.
    pub const fn new() -> Self {
        Self { buf: [0; MAX_PAYLOAD], len: BATCH_HEADER, count: 0 }
    }
    /// Adds a triangle; `Err(BufferFull)` when it does not fit (send the batch first).
    pub fn push(&mut self, t: &Triangle) -> Result<(), EncodeError> {
        if self.count == u8::MAX {
            return Err(EncodeError::BufferFull);
        }
        let n = encode_triangle(t, &mut self.buf[self.len..])?;
        self.len += n;
        self.count += 1;
        Ok(())
    }
    /// Adds the leading triangles of `tris` that fit: how many. An empty batch takes none
    /// only when the first is outside the wire's range.
    pub fn fill(&mut self, tris: &[Triangle]) -> usize {
        tris.iter().take_while(|t| self.push(t).is_ok()).count()
    }
    /// Triangles in the batch.
    pub fn len(&self) -> usize {
        self.count as usize
    }
    /// True when empty.
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }
    /// The finished payload (a [`Message::Triangles`]).
    pub fn payload(&mut self) -> &[u8] {
        self.buf[0] = ty::TRIANGLES;
        self.buf[1] = self.count;
        &self.buf[..self.len]
    }
    /// Empties the batch.
    pub fn clear(&mut self) {
        self.len = BATCH_HEADER;
        self.count = 0;
    }
}

//! Why a job failed: the failing stage's own error, its code and detail on the wire, and its
//! words for the host.

use core::fmt;

use crate::machine::ConfigError;
use crate::protocol::{CardFault, ErrorCode};
use crate::slice::SliceError;
use crate::thermal::ThermalFault;
use crate::toolpath::ToolpathError;

/// Why a job was refused at its start: the stage that refused its settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refusal {
    /// The print settings, against the machine.
    Settings(ConfigError),
    /// The slicer's settings.
    Slice(SliceError),
    /// The toolpath stage's settings.
    Toolpath(ToolpathError),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Settings(e) => write!(f, "settings: {e}"),
            Self::Slice(e) => write!(f, "slicer: {e}"),
            Self::Toolpath(e) => write!(f, "toolpaths: {e}"),
        }
    }
}

/// Why a job failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Failure {
    /// The job was refused at its start.
    Refused(Refusal),
    /// The slicer failed.
    Slice(SliceError),
    /// The toolpath stage failed.
    Toolpath(ToolpathError),
    /// A path (with the travel before it) of this layer needs more bytes of coded moves than
    /// the whole move buffer holds, or the buffer overflowed.
    Moves {
        /// The layer.
        layer: u32,
    },
    /// The planner refused a move of this layer.
    Plan {
        /// The layer.
        layer: u32,
    },
    /// A message that does not fit the job's state.
    Unexpected {
        /// Its type byte ([`crate::protocol::msg::ty`]).
        message: u8,
    },
    /// A message that does not decode.
    BadMessage {
        /// Its first byte.
        first_byte: u8,
    },
    /// A heater fault (heaters off, motion stopped).
    Thermal {
        /// The fault's code ([`ThermalFault::code`]).
        code: u8,
    },
    /// The card a job printed from failed (removed, unreadable).
    Card(CardFault),
}

impl Failure {
    /// The status report's error code and detail; `layers_cut`: the layers the slicer had
    /// cut (the detail of a slicer or toolpath failure).
    pub fn code(&self, layers_cut: u32) -> (ErrorCode, u32) {
        match *self {
            Self::Refused(_) => (ErrorCode::BadJob, 0),
            Self::Slice(_) => (ErrorCode::Slice, layers_cut),
            Self::Toolpath(_) => (ErrorCode::Toolpath, layers_cut),
            Self::Moves { layer } => (ErrorCode::Moves, layer),
            Self::Plan { layer } => (ErrorCode::Plan, layer),
            Self::Unexpected { message } => (ErrorCode::Unexpected, u32::from(message)),
            Self::BadMessage { first_byte } => (ErrorCode::BadMessage, u32::from(first_byte)),
            Self::Thermal { code } => (ErrorCode::Thermal, u32::from(code)),
            Self::Card(fault) => (ErrorCode::Card, fault as u32),
        }
    }
}

impl fmt::Display for Failure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Refused(r) => write!(f, "job refused: {r}"),
            Self::Slice(error) => write!(f, "slicer: {error}"),
            Self::Toolpath(error) => write!(f, "toolpaths: {error}"),
            Self::Moves { layer } => write!(
                f,
                "move buffer: a path of layer {layer} (with the travel before it) needs more \
                 bytes of moves than the buffer holds"
            ),
            Self::Plan { layer } => write!(f, "planner: refused a move of layer {layer}"),
            Self::Unexpected { message } => {
                write!(f, "job: message 0x{message:02x} does not fit the job's state")
            }
            Self::BadMessage { first_byte } => {
                write!(f, "link: a message of type 0x{first_byte:02x} did not decode")
            }
            Self::Thermal { code } => match ThermalFault::from_code(*code) {
                Some(fault) => write!(f, "heaters: {fault}"),
                None => write!(f, "heaters: fault code {code}"),
            },
            Self::Card(fault) => write!(f, "card: {fault}"),
        }
    }
}

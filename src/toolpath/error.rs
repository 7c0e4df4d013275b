//! What can stop the toolpath stage: its bounded buffers and its errors.

#[cfg(doc)]
#[allow(unused_imports)]
use super::*;
use core::fmt;

/// A bounded buffer of the toolpath stage.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Buffer {
    /// Points of one layer's loops (`PTS`).
    LayerPoints,
    /// Loops of one layer (`LOOPS`).
    LayerLoops,
    /// Raw offset edges of one island (`PTS`).
    OffsetEdges,
    /// Intersection points of one island's offset curves (`PTS`).
    OffsetSplits,
    /// Arrangement pieces of one island's offset curves (`PTS`).
    OffsetPieces,
    /// Scanline crossings of one layer (`CROSS`).
    Crossings,
    /// Infill line segments and their feature pieces of one layer (`CROSS` x 12 bytes).
    LineSegments,
    /// Infill intervals on one scanline (64).
    LineIntervals,
    /// Points of one layer's paths (`PATH`).
    PathPoints,
    /// Paths of one layer (2 `PATH` entries each).
    Paths,
    /// Path points beyond the packed range (x or y outside +-2^21 um, see [`paths`]).
    PathRange,
    /// Stored contours of the skin window's layers, in words (`RING`).
    RingPoints,
    /// Crossings of the skin window's layers with one scanline (`SPANS`).
    WindowSpans,
    /// Layers in the window (top + bottom + 2).
    WindowLayers,
}

impl fmt::Display for Buffer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::LayerPoints => "loop points per layer",
            Self::LayerLoops => "loops per layer",
            Self::OffsetEdges => "offset edges per island",
            Self::OffsetSplits => "offset intersections per island",
            Self::OffsetPieces => "offset pieces per island",
            Self::Crossings => "scanline crossings per layer",
            Self::LineSegments => "infill line segments per layer",
            Self::LineIntervals => "infill intervals per scanline",
            Self::PathPoints => "path points per layer",
            Self::PathRange => "path points beyond the packed range (um)",
            Self::Paths => "paths per layer",
            Self::RingPoints => "stored contour words of the skin window",
            Self::WindowSpans => "skin window crossings on one scanline",
            Self::WindowLayers => "layers in the skin window",
        })
    }
}

/// Why the toolpath stage stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ToolpathError {
    /// `push_layer` or `finish` after `finish`, or on a [`Toolpath::empty`] stage never
    /// [`reset`](Toolpath::reset) (call `reset`). First, so that it is the zero tag and an
    /// empty stage's `Some(Finished)` is zero bytes.
    Finished,
    /// A [`ToolpathConfig`] field is out of range.
    InvalidConfig {
        /// The field.
        field: &'static str,
    },
    /// A buffer is full.
    Capacity {
        /// Which buffer.
        what: Buffer,
        /// Its capacity.
        capacity: u32,
        /// The layer being built (or stored).
        layer: u32,
    },
    /// Layers must arrive in order from 0.
    OutOfOrder {
        /// The index expected.
        expected: u32,
        /// The index received.
        got: u32,
    },
    /// [`Toolpath::accept_layer`] or [`Toolpath::build_next`] while a layer is still being
    /// emitted ([`Toolpath::emit_next`] first).
    Emitting {
        /// The layer being emitted.
        layer: u32,
    },
}

impl fmt::Display for ToolpathError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::InvalidConfig { field } => {
                write!(f, "toolpath setting `{field}` is out of range")
            }
            Self::Capacity { what, capacity, layer } => {
                write!(f, "too many {what} in layer {layer} (capacity {capacity})")
            }
            Self::OutOfOrder { expected, got } => {
                write!(f, "layer {got} arrived, layer {expected} expected")
            }
            Self::Emitting { layer } => {
                write!(f, "layer {layer} is still being emitted; emit it before the next layer")
            }
            Self::Finished => {
                f.write_str("the toolpath stage has finished; reset it to start again")
            }
        }
    }
}

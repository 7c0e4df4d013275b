//! What the toolpath stage emits: moves and events, and the room an owner gives them.

use crate::geom::Point2;
use crate::machine::Rate;

use super::LayerStats;
#[cfg(doc)]
#[allow(unused_imports)]
use super::*;

/// What an extrusion or move is, named as PrusaSlicer's G-code viewer names its `;TYPE:`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Feature {
    /// The outermost perimeter.
    ExternalPerimeter,
    /// An inner perimeter.
    Perimeter,
    /// Sparse infill.
    InternalInfill,
    /// Solid infill (near a top or bottom surface).
    SolidInfill,
    /// Solid infill on a top surface.
    TopSolidInfill,
    /// The skirt around the first layer.
    Skirt,
    /// A move without extrusion.
    #[default]
    Travel,
    /// Filament pulled back.
    Retract,
    /// Filament pushed forward again after a retraction.
    Unretract,
    /// The head waits in place (`G4`), its move's feed the wait in seconds.
    Dwell,
    /// Skin over no material of the layer below, in straight lines across the gap.
    BridgeInfill,
    /// A perimeter over no material of the layer below.
    OverhangPerimeter,
    /// A brim loop around the first layer's islands.
    Brim,
}

impl Feature {
    /// Every feature, at the index of its code (`as u8`).
    pub const ALL: [Feature; 13] = [
        Feature::ExternalPerimeter,
        Feature::Perimeter,
        Feature::InternalInfill,
        Feature::SolidInfill,
        Feature::TopSolidInfill,
        Feature::Skirt,
        Feature::Travel,
        Feature::Retract,
        Feature::Unretract,
        Feature::Dwell,
        Feature::BridgeInfill,
        Feature::OverhangPerimeter,
        Feature::Brim,
    ];
}

// Each feature sits at its code.
const _: () = {
    let mut i = 0;
    while i < Feature::ALL.len() {
        assert!(Feature::ALL[i] as usize == i);
        i += 1;
    }
};

/// What [`Toolpath::emit_next`] left.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Emitted {
    /// No layer is being emitted: the last one is complete (its `LayerEnd` went out).
    Complete,
    /// The next unit of layer `layer` needs room for `moves` moves.
    NeedsRoom {
        /// Moves of the unit, exactly.
        moves: u32,
        /// The layer being emitted.
        layer: u32,
    },
}

/// Where a layer's emission units go ([`Toolpath::emit_next`]), each whole or not at all.
///
/// A unit is opened with its exact move count, its moves are sent, and it is closed, kept or undone
/// by the room (then the stage undoes it too and the unit waits).
///
/// A closure is a room without bound; [`Moves`] counts moves; the printer's move ring
/// ([`crate::move_ring::RingRoom`]) codes each move into its bytes as it comes and undoes a
/// unit that runs out of them (its exact bytes counted to its end).
pub trait Room {
    /// The next unit has `moves` moves: false refuses it before any goes out (it waits;
    /// the emission stops with [`Emitted::NeedsRoom`]).
    fn open(&mut self, moves: u32) -> bool;
    /// An event: a [`ToolEvent::Move`] of the open unit, or a layer's
    /// [`ToolEvent::LayerEnd`] (between units).
    fn event(&mut self, e: &ToolEvent<'_>);
    /// The open unit's last move was sent: true when the room keeps the unit, false when it
    /// undid it (it waits, as if refused by [`open`](Self::open)).
    fn close(&mut self) -> bool;
}

impl<F: FnMut(&ToolEvent<'_>) + ?Sized> Room for F {
    fn open(&mut self, _: u32) -> bool {
        true
    }

    fn event(&mut self, e: &ToolEvent<'_>) {
        self(e)
    }

    fn close(&mut self) -> bool {
        true
    }
}

/// A room of `left` moves (counted down as units go in) sending the events to `sink`.
#[derive(Debug)]
pub struct Moves<F> {
    /// Moves left.
    pub left: usize,
    /// Where the events go.
    pub sink: F,
}

impl<F: FnMut(&ToolEvent<'_>)> Room for Moves<F> {
    fn open(&mut self, moves: u32) -> bool {
        let Some(left) = self.left.checked_sub(moves as usize) else { return false };
        self.left = left;
        true
    }

    fn event(&mut self, e: &ToolEvent<'_>) {
        (self.sink)(e)
    }

    fn close(&mut self) -> bool {
        true
    }
}

/// One move of the print head.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ToolMove {
    /// Target XY, um (for a retraction: the current position).
    pub to: Point2,
    /// Target Z, um.
    pub z_um: i32,
    /// Filament fed during the move, um (negative for a retraction).
    pub e_um: i32,
    /// Feed rate, mm/s (filament speed for retractions; the wait in seconds for a
    /// [`Feature::Dwell`]).
    pub feed_mm_s: Rate,
    /// What the move is.
    pub feature: Feature,
    /// The part-cooling fan's duty from this move on, 0..=255 (it changes on a layer's first
    /// move and on extrusions only: the travels between a bridge's lines keep its fan).
    pub fan: u8,
}

/// What the toolpath stage emits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ToolEvent<'a> {
    /// A layer begins (its first move goes to `z_um`).
    LayerStart {
        /// Layer index.
        index: u32,
        /// Nozzle height, um.
        z_um: i32,
        /// Layer thickness, um.
        height_um: i32,
    },
    /// A move.
    Move(ToolMove),
    /// The layer is complete.
    LayerEnd(&'a LayerStats),
    /// A point inside a layer's computation (between perimeters, every few infill
    /// intervals): nothing to record; an owner that must keep other work going while a
    /// layer is computed (the firmware generates steps) may do a bounded piece of it here.
    Progress,
}

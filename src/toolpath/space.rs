//! The working memory the toolpath stage computes a layer in.
//!
//! Per layer the stage needs its offset engine (with the points of the loops it returns) and
//! then its infill scratch, never both at once ([`ToolpathSpace`]). A stage used alone keeps
//! them in a [`ToolpathScratch`]; an owner of several stages lends memory in which these take
//! turns with other tenants (the printer's shared scratch, where the slicer's cut takes the
//! place between layers).

use crate::geom::Point2;

use super::offset::Offsetter;
use super::FillScratch;

/// What the toolpath stage computes a layer in: its offset engine or its infill scratch, one
/// at a time. Each accessor that switches starts its turn from a cleared value.
pub trait ToolpathSpace<const PTS: usize, const CROSS: usize> {
    /// The offset engine and the loop points kept beside it (a new engine and cleared points
    /// if another tenant had the place).
    fn engine_and_points(&mut self) -> (&mut Offsetter<PTS>, &mut [Point2; PTS]);
    /// The engine if it has the place (its counters not yet collected), without a switch.
    fn live_engine(&mut self) -> Option<&mut Offsetter<PTS>>;
    /// The infill scratch (a cleared one if another tenant had the place).
    fn fill(&mut self) -> &mut FillScratch<CROSS>;
    /// The infill scratch if it has the place, without a switch: where the stage keeps the
    /// nearest-path grid of the layer it is emitting.
    fn live_fill(&mut self) -> Option<&mut FillScratch<CROSS>>;

    /// The offset engine (a new one if another tenant had the place).
    fn engine(&mut self) -> &mut Offsetter<PTS> {
        self.engine_and_points().0
    }
}

/// The offset engine's tenant.
///
/// The engine and the points of the loops that the stage takes from it and gives back to it (its
/// `tmp` loops, used only while the engine has the place: 8 B per `P` here instead of in the
/// stage).
pub struct Engine<const P: usize> {
    engine: Offsetter<P>,
    points: [Point2; P],
}

impl<const P: usize> Engine<P> {
    /// A new engine, its points cleared (all zero bytes).
    pub const EMPTY: Self = Self { engine: Offsetter::new(), points: [Point2::new(0, 0); P] };

    /// The engine and its points.
    pub fn parts(&mut self) -> (&mut Offsetter<P>, &mut [Point2; P]) {
        (&mut self.engine, &mut self.points)
    }
}

/// The working memory of a toolpath stage used alone (no other stage shares it).
pub struct ToolpathScratch<const PTS: usize, const CROSS: usize> {
    tenant: Tenant<PTS, CROSS>,
}

/// Who has the place (no `repr`: switching writes the cleared value in place).
enum Tenant<const P: usize, const C: usize> {
    Offset(Engine<P>),
    Fill(FillScratch<C>),
}

impl<const PTS: usize, const CROSS: usize> Default for ToolpathScratch<PTS, CROSS> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const PTS: usize, const CROSS: usize> ToolpathScratch<PTS, CROSS> {
    /// An empty one (the offset engine has the place).
    pub const fn new() -> Self {
        Self { tenant: Tenant::Offset(Engine::EMPTY) }
    }
}

impl<const PTS: usize, const CROSS: usize> ToolpathSpace<PTS, CROSS>
    for ToolpathScratch<PTS, CROSS>
{
    fn engine_and_points(&mut self) -> (&mut Offsetter<PTS>, &mut [Point2; PTS]) {
        match self.tenant {
            Tenant::Offset(ref mut e) => e.parts(),
            _ => {
                self.tenant = Tenant::Offset(Engine::EMPTY);
                self.engine_and_points()
            }
        }
    }

    fn live_engine(&mut self) -> Option<&mut Offsetter<PTS>> {
        match self.tenant {
            Tenant::Offset(ref mut e) => Some(e.parts().0),
            _ => None,
        }
    }

    fn fill(&mut self) -> &mut FillScratch<CROSS> {
        match self.tenant {
            Tenant::Fill(ref mut f) => f,
            _ => {
                self.tenant = Tenant::Fill(FillScratch::EMPTY);
                self.fill()
            }
        }
    }

    fn live_fill(&mut self) -> Option<&mut FillScratch<CROSS>> {
        match self.tenant {
            Tenant::Fill(ref mut f) => Some(f),
            _ => None,
        }
    }
}

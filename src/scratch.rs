//! The per-layer working memory that the slicer and the toolpath stage take turns in.
//!
//! Three tenants of a sliced job never work at once:
//! - the slicer's cut of a layer (its segments, their links and flags, the endpoint hash:
//!   [`CUT_BYTES`] per `SEGMENTS`) and, in the place of the hash once the segments are
//!   linked, the layer's loop points: the slicer's output, handed on in the scratch
//!   ([`SlicedLayer`](crate::slice::SlicedLayer); the loop records stay in the slicer). The
//!   toolpath stage copies the layer before it takes the place;
//! - the toolpath stage's offset engine and the points of the loops it returns
//!   ([`ToolpathNeeds::ENGINE_BYTES`] per `PTS`), then
//!   its infill scratch ([`ToolpathNeeds::CROSS_BYTES`] per `CROSS`, reused by the ordering:
//!   the nearest-path grid stays in its pool while the layer's paths are emitted unit by
//!   unit, so an owner cuts the next layer only once the stage is no longer
//!   [`emitting`](crate::toolpath::Toolpath::emitting); a grid lost anyway is replaced by
//!   scans, in the same order).
//!
//! A G-code job ([`GcodeInput`]) has the place to itself: it neither slices nor builds
//! toolpaths.
//!
//! A [`Scratch`] holds whichever works now, so an owner of both stages (the
//! [`Printer`](crate::printer::Printer)) pays for the largest one only. Each stage states what
//! it needs as a trait ([`CutSpace`] for the slicer, [`ToolpathSpace`] for the toolpath stage;
//! neither stage knows the other) and the scratch, above both, provides both. It is lent with
//! `&mut` to [`Slicer::push`](crate::slice::Slicer::push) (and its other cutting calls), which
//! hands it on to its layer sink with the layer in it, where the toolpath stage takes both
//! ([`Toolpath::push_sliced`](crate::toolpath::Toolpath::push_sliced)). A turn starts from a
//! cleared value written in place (in the optimised build: a memset, no stack temporary, no
//! constant in flash); nothing is kept from one turn to the next, so a stage works the same
//! whoever had the place before. Each tenant keeps its own capacity: overflowing one is the
//! same typed error as with a scratch of its own.

use core::mem::size_of;

use crate::card::fat::{File, Volume};
use crate::card::zsort::StlSort;
use crate::card::{OpenFile, WritingFile};
use crate::gcode::input::GcodeInput;
use crate::geom::Point2;
use crate::machine::MachineConfig;
use crate::slice::{CutScratch, CutSpace};
use crate::toolpath::offset::Offsetter;
use crate::toolpath::{Engine, FillScratch, ToolpathNeeds, ToolpathSpace};

/// Bytes per `SEGMENTS` of the slicer's cut: segment 16, link 4, flags 1, and 8 for two hash
/// slots, then an output point.
pub const CUT_BYTES: usize = CutScratch::<0>::BYTES_PER_SEGMENT;

/// A [`Scratch`] type with the capacities of its tenants named at the point of use (the names
/// of [`Capacities`](crate::protocol::Capacities)):
///
/// ```
/// strata::scratch_type! {
///     /// A bench scratch.
///     pub type BenchScratch = { contour_points: 8192, toolpath_points: 8192, scan_crossings: 16384 };
/// }
/// ```
#[macro_export]
macro_rules! scratch_type {
    (
        $(#[$meta:meta])*
        $vis:vis type $name:ident = {
            contour_points: $s:expr,
            toolpath_points: $pts:expr,
            scan_crossings: $cross:expr $(,)?
        };
    ) => {
        $(#[$meta])*
        $vis type $name = $crate::scratch::Scratch<{ $s }, { $pts }, { $cross }>;
    };
}

/// The working memory of a slicer with `SEGMENTS` segments per layer and a toolpath stage with
/// `PTS` offset edges and `CROSS` infill crossings (see the [module docs](self)).
///
/// A slicer alone uses a [`SliceScratch`](crate::slice::SliceScratch) (`PTS = CROSS = 0`), a
/// toolpath stage alone a [`ToolpathScratch`](crate::toolpath::ToolpathScratch) (`SEGMENTS = 0`).
///
/// Large capacities make a large value: on the host, build it where the stack is big enough
/// (or in a `static`/boxed slot).
pub struct Scratch<const SEGMENTS: usize, const PTS: usize, const CROSS: usize> {
    tenant: Tenant<SEGMENTS, PTS, CROSS>,
}

/// Who has the place. No `repr`: the largest tenant is stored without a tag (a niche in it
/// tells the others apart), and switching tenants writes the cleared value in place (with
/// `repr(u8)` the optimised build copies it through a stack temporary of several KB).
// The tenants differ in size by design: they overlay one another (no allocator to box one).
#[allow(clippy::large_enum_variant)]
enum Tenant<const S: usize, const P: usize, const C: usize> {
    Cut(CutScratch<S>),
    Offset(Engine<P>),
    Fill(FillScratch<C>),
    /// A G-code job's input, and the card file it reads (a job from the card).
    Gcode(GcodeInput, Option<OpenFile>),
    /// A file being written to the card (no job runs).
    Upload(WritingFile),
    /// An STL on the card being placed and sorted (no job runs). The sort is 8-aligned: the
    /// word after the 4-byte tag would be padding, whose undefined bytes keep the optimised
    /// build from clearing the place in place (it clears an 11 KB stack temporary and copies
    /// it, which overflows the board's stack); a defined zero word there (written, never
    /// read) lets it. `scripts/build_firmware.sh` fails a build with such a frame.
    Stl(#[allow(dead_code)] u32, StlSort),
}

impl<const S: usize, const P: usize, const C: usize> Default for Scratch<S, P, C> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const S: usize, const P: usize, const C: usize> Scratch<S, P, C> {
    /// An empty scratch, all zero bytes (a `static` of it goes to `.bss`): the largest
    /// tenant, cleared, has the place, as it is the one stored without a tag (the others
    /// would be a non-zero niche value); when the tenants are too close in size for a niche
    /// and the enum has a tag, the first tenant (tag zero) has it. Whoever has the place
    /// first, every accessor starts its turn from a cleared value, so which one it is does
    /// not matter. (`scripts/build_firmware.sh` checks that the device's is in `.bss`.)
    pub const fn new() -> Self {
        let cut = size_of::<CutScratch<S>>();
        let engine = size_of::<Engine<P>>();
        let fill = size_of::<FillScratch<C>>();
        let largest = if cut > engine { cut } else { engine };
        let largest = if fill > largest { fill } else { largest };
        let tenant = if size_of::<Tenant<S, P, C>>() > largest {
            Tenant::Cut(CutScratch::EMPTY)
        } else if fill >= cut && fill >= engine {
            Tenant::Fill(FillScratch::EMPTY)
        } else if engine >= cut {
            Tenant::Offset(Engine::EMPTY)
        } else {
            Tenant::Cut(CutScratch::EMPTY)
        };
        Self { tenant }
    }
}

impl<const S: usize, const P: usize, const C: usize> Scratch<S, P, C> {
    /// A G-code job's input takes the place, new for `machine` (a G-code job neither slices
    /// nor builds toolpaths), with the card file it reads, if any.
    pub fn start_gcode(&mut self, machine: &MachineConfig, card: Option<OpenFile>) {
        self.tenant = Tenant::Gcode(GcodeInput::new(machine), card);
    }

    /// The G-code job's input, while it has the place.
    pub fn gcode(&mut self) -> Option<&mut GcodeInput> {
        match self.tenant {
            Tenant::Gcode(ref mut g, _) => Some(g),
            _ => None,
        }
    }

    /// The G-code job's input, while it has the place.
    pub fn gcode_ref(&self) -> Option<&GcodeInput> {
        match self.tenant {
            Tenant::Gcode(ref g, _) => Some(g),
            _ => None,
        }
    }

    /// A file being written to the card takes the place.
    pub fn start_upload(&mut self, file: WritingFile) {
        self.tenant = Tenant::Upload(file);
    }

    /// The file being written to the card, while it has the place.
    pub fn upload(&mut self) -> Option<&mut WritingFile> {
        match self.tenant {
            Tenant::Upload(ref mut w) => Some(w),
            _ => None,
        }
    }

    /// The STL file `stl` on `volume` takes the place to be sorted (written in place, then
    /// begun: no temporary of its size).
    pub fn start_stl(&mut self, volume: Volume, stl: File) {
        self.tenant = Tenant::Stl(0, StlSort::EMPTY);
        if let Tenant::Stl(_, ref mut s) = self.tenant {
            s.begin(volume, stl);
        }
    }

    /// The STL being sorted, while it has the place.
    pub fn stl(&mut self) -> Option<&mut StlSort> {
        match self.tenant {
            Tenant::Stl(_, ref mut s) => Some(s),
            _ => None,
        }
    }

    /// The card file a G-code job reads, while its input has the place.
    pub fn card_file(&mut self) -> Option<&mut OpenFile> {
        match self.tenant {
            Tenant::Gcode(_, Some(ref mut f)) => Some(f),
            _ => None,
        }
    }
}

impl<const S: usize, const P: usize, const C: usize> CutSpace<S> for Scratch<S, P, C> {
    fn cut(&mut self) -> &mut CutScratch<S> {
        match self.tenant {
            Tenant::Cut(ref mut c) => c,
            _ => {
                self.tenant = Tenant::Cut(CutScratch::EMPTY);
                self.cut()
            }
        }
    }

    fn contour_points(&self) -> &[Point2] {
        match self.tenant {
            Tenant::Cut(ref c) => c.points(),
            _ => &[],
        }
    }
}

impl<const S: usize, const P: usize, const C: usize> ToolpathSpace<P, C> for Scratch<S, P, C> {
    fn engine_and_points(&mut self) -> (&mut Offsetter<P>, &mut [Point2; P]) {
        match self.tenant {
            Tenant::Offset(ref mut e) => e.parts(),
            _ => {
                self.tenant = Tenant::Offset(Engine::EMPTY);
                self.engine_and_points()
            }
        }
    }

    fn live_engine(&mut self) -> Option<&mut Offsetter<P>> {
        match self.tenant {
            Tenant::Offset(ref mut e) => Some(e.parts().0),
            _ => None,
        }
    }

    fn fill(&mut self) -> &mut FillScratch<C> {
        match self.tenant {
            Tenant::Fill(ref mut f) => f,
            _ => {
                self.tenant = Tenant::Fill(FillScratch::EMPTY);
                self.fill()
            }
        }
    }

    fn live_fill(&mut self) -> Option<&mut FillScratch<C>> {
        match self.tenant {
            Tenant::Fill(ref mut f) => Some(f),
            _ => None,
        }
    }
}

/// RAM of a [`Scratch`] whose tenants have these capacities (`segments` cut segments and loop
/// points, `pts` offset edges, `cross` infill crossings).
///
/// The largest tenant, bytes (the value adds at most a tag and alignment padding); a G-code
/// job's input with its card file, a file being written to the card and an STL on the card
/// being sorted, at least.
pub fn bytes(segments: usize, pts: usize, cross: usize) -> usize {
    let cut = size_of::<CutScratch<0>>() + segments * CUT_BYTES;
    let card = size_of::<(GcodeInput, Option<OpenFile>)>()
        .max(size_of::<WritingFile>())
        .max(size_of::<StlSort>());
    cut.max(ToolpathNeeds::work_bytes_of(pts, cross)).max(card)
}

// The documented bytes per capacity unit hold on every target (the thumbv7m-none-eabi build
// checks them for the device).
const _: () = assert!(CUT_BYTES == 29);

#[cfg(test)]
mod tests {
    use super::*;

    /// `bytes` of these capacities against the value's size.
    fn check<const S: usize, const P: usize, const C: usize>() {
        let (exact, want) = (size_of::<Scratch<S, P, C>>(), bytes(S, P, C));
        // A tag and alignment padding only.
        assert!(exact >= want && exact <= want + 16, "{S} {P} {C}: {exact} vs {want}");
    }

    #[test]
    fn the_largest_tenant_takes_the_place() {
        assert_eq!(CUT_BYTES, 29);
        check::<192, 128, 224>();
        check::<388, 128, 512>();
        check::<600, 16, 16>();
        check::<0, 0, 900>();
        check::<0, 0, 0>();
        // The 64 KB board: the cut fits in the engine's place.
        assert_eq!(bytes(192, 128, 224), bytes(0, 128, 224));
    }
}

//! The thin-area measurement: a report, not part of printing.
//!
//! For `strata slice`'s report the stage measures each island's area thinner than a line
//! ([`LayerStats::thin_area_um2`]): the island minus its morphological opening by half a line
//! width (its contours offset inwards by half a line, then grown back with miter joins). The
//! measurement borrows the offset engine between a layer's perimeters and its infill; its use
//! of the engine is kept out of the printing needs ([`ToolpathStats::thin_pts`]) and a buffer
//! it overflows counts the island as unmeasured ([`LayerStats::thin_unmeasured`]) instead of
//! failing: the toolpaths never depend on it. A printer turns it off
//! ([`ToolpathConfig::measure_thin_area`]).

use super::offset::Join;
use super::poly::Loops;
use super::{island_curves, Buffer, LayerStats, Toolpath, ToolpathSpace};

#[cfg(doc)]
use super::{ToolpathConfig, ToolpathStats};

impl<
        const PTS: usize,
        const LOOPS: usize,
        const CROSS: usize,
        const PATH: usize,
        const RING: usize,
        const SPANS: usize,
    > Toolpath<PTS, LOOPS, CROSS, PATH, RING, SPANS>
{
    /// Adds `island`'s thin area to `layer` (or counts it unmeasured); `opened2`: the doubled
    /// area of its opening if the external perimeter already measured it (`Some(None)`: it
    /// did not fit), `None` when the island had no perimeters.
    pub(super) fn measure_thin_area<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        island: u16,
        opened2: Option<Option<i64>>,
        layer: &mut LayerStats,
    ) {
        let w = self.cfg.line_width_um;
        let min_width = i64::from(w / 8);
        let limit = self.offset_limit();
        let opened2 = match opened2 {
            Some(a) => a,
            // No perimeters: the centre lines of an external perimeter all the same.
            None => self.measure(work, |t, work| {
                let (engine, points) = work.engine_and_points();
                let mut tmp = Loops::new(points, &mut t.tmp);
                tmp.clear();
                let curves = island_curves(&t.contour, island, w / 2);
                engine.union_into(&mut tmp, island, 0, min_width, limit, curves)?;
                t.grow_tmp_area2(work, island)
            }),
        };
        match opened2 {
            Some(opened2) => {
                let region2: i64 = self
                    .contour
                    .rings()
                    .iter()
                    .filter(|r| r.island == island)
                    .map(|r| r.area2)
                    .sum();
                layer.thin_area_um2 += ((region2 - opened2).max(0) / 2) as u64;
            }
            None => layer.thin_unmeasured += 1,
        }
    }

    /// The doubled area of the opening of the external perimeter's centre lines in `tmp`
    /// (`None`: it did not fit); clears `tmp`.
    pub(super) fn opening_of_tmp<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        island: u16,
    ) -> Option<i64> {
        self.measure(work, |t, work| t.grow_tmp_area2(work, island))
    }

    /// Runs a thin-area measurement: its use of the offset engine and of `tmp` is kept out
    /// of the printing needs (recorded in [`ToolpathStats::thin_pts`]), and a buffer it
    /// overflows gives `None` instead of an error (the toolpaths do not depend on it).
    fn measure<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        f: impl FnOnce(&mut Self, &mut W) -> Result<i64, Buffer>,
    ) -> Option<i64> {
        let (peaks, points, rings) =
            (work.engine().peaks, self.tmp.peak_points, self.tmp.peak_rings);
        let r = f(self, work);
        let p = work.engine().peaks;
        let used = p.edges.max(p.splits).max(p.pieces).max(self.tmp.peak_points);
        self.stats.thin_pts = self.stats.thin_pts.max(used as u32);
        (work.engine().peaks, self.tmp.peak_points, self.tmp.peak_rings) = (peaks, points, rings);
        self.tmp.clear();
        r.ok()
    }

    /// Grows the loops in `tmp` (the island's contours offset inwards by half a line) back
    /// outwards by half a line with miter joins and returns the doubled area of the result,
    /// the island's morphological opening by half a line width: the island minus its parts
    /// thinner than a line (with square corners: a rectangle comes back whole). Clears `tmp`.
    fn grow_tmp_area2<W: ToolpathSpace<PTS, CROSS>>(
        &mut self,
        work: &mut W,
        island: u16,
    ) -> Result<i64, Buffer> {
        let half = self.cfg.line_width_um / 2;
        if self.tmp.rings().is_empty() {
            return Ok(0);
        }
        let limit = self.offset_limit();
        let (engine, points) = work.engine_and_points();
        let mut tmp = Loops::new(points, &mut self.tmp);
        engine.collect(limit, |engine| {
            for r in tmp.rings() {
                engine.add_loop(tmp.ring_points(r), -half, Join::Miter)?;
            }
            Ok(())
        })?;
        tmp.clear();
        engine.trace_into(&mut tmp, island, 0, 1)?;
        let area2 = tmp.rings().iter().map(|r| r.area2).sum();
        tmp.clear();
        Ok(area2)
    }
}

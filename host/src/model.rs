//! Loading a model file: parse, place on the bed, sort by lowest z.

use std::path::Path;

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::place::{Bounds, Placement};
use strata::stl::{self, RawTriangle, StlSummary};

/// A parsed model, in file coordinates.
pub struct Model {
    /// What the parser saw.
    pub summary: StlSummary,
    /// The non-degenerate facets in file order.
    pub triangles: Vec<RawTriangle>,
    /// Bounds of `triangles` in file units.
    pub bounds: Bounds,
}

/// Reads and parses an STL file; errors carry the path and, for parse errors, the byte offset.
pub fn load(path: &Path) -> Result<Model, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    load_bytes(&bytes).map_err(|e| format!("{}: {e}", path.display()))
}

/// Parses an STL file's bytes.
pub fn load_bytes(bytes: &[u8]) -> Result<Model, String> {
    let mut triangles = Vec::new();
    let mut bounds = Bounds::EMPTY;
    let summary = stl::read_all(bytes, &mut |t| {
        bounds.include(&t);
        triangles.push(t);
    })
    .map_err(|e| e.to_string())?;
    Ok(Model { summary, triangles, bounds })
}

impl Model {
    /// The model on the bed in micrometres, sorted by lowest z (the order the slicer needs).
    pub fn placed_sorted(&self, machine: &MachineConfig) -> Result<Vec<Triangle>, String> {
        let placement = Placement::on_bed(&self.bounds, machine).map_err(|e| e.to_string())?;
        let mut placed: Vec<Triangle> = self.triangles.iter().map(|t| placement.apply(t)).collect();
        placed.sort_by_key(Triangle::z_min);
        Ok(placed)
    }
}

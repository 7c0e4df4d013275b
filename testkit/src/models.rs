//! The shared test models.
//!
//! `../shared/models` beside the checkout (described by its `README.md`, whose table gives every
//! file's triangle count, format, bounding box, watertightness and layer count at 0.2 mm), found,
//! listed, read and placed as the host places a model.

use std::path::{Path, PathBuf};

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::place::{Bounds, Placement};

/// Where the shared models are (whether or not the folder exists).
pub fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/models")
}

/// The shared models' folder, or `None` when it is absent (so tests can skip, with a message);
/// with the environment variable `CI` set the models are required and their absence panics.
pub fn shared_models() -> Option<PathBuf> {
    let dir = dir();
    if dir.is_dir() {
        return Some(dir);
    }
    if std::env::var_os("CI").is_some() {
        panic!("CI is set but the shared test models are missing at {}", dir.display());
    }
    eprintln!("skipping: shared test models not found at {}", dir.display());
    None
}

fn is_stl(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("stl"))
}

fn sorted_entries(dir: &Path) -> Vec<PathBuf> {
    let read = std::fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let mut entries: Vec<PathBuf> = read.map(|e| e.expect("a folder entry").path()).collect();
    entries.sort();
    entries
}

/// The `.stl` files (any case) directly in `dir`, sorted.
pub fn stl_files(dir: &Path) -> Vec<PathBuf> {
    sorted_entries(dir).into_iter().filter(|p| p.is_file() && is_stl(p)).collect()
}

/// The `.stl` files (any case) in `dir` and every folder below it, sorted by path.
pub fn stl_files_below(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for p in sorted_entries(dir) {
        if p.is_dir() {
            out.extend(stl_files_below(&p));
        } else if is_stl(&p) {
            out.push(p);
        }
    }
    out
}

/// The rows of every markdown table in `dir/README.md` whose first cell names an `.stl` file.
///
/// The cells, trimmed (`| file | bytes | format | triangles | size | bbox | watertight | bodies |
/// layers @0.2 | sha |`: cell 0 is the file, `/`-separated below `dir`).
pub fn readme_table(dir: &Path) -> Vec<Vec<String>> {
    let path = dir.join("README.md");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .filter_map(|line| {
            let line = line.trim().strip_prefix('|')?;
            let line = line.strip_suffix('|').unwrap_or(line);
            let cells: Vec<String> = line.split('|').map(|c| c.trim().to_string()).collect();
            cells[0].ends_with(".stl").then_some(cells)
        })
        .collect()
}

/// A README row with a layer count.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LayerRow {
    /// Path below the models' folder, `/`-separated.
    pub file: String,
    /// The README says the mesh is watertight.
    pub watertight: bool,
    /// Layers at 0.2 mm.
    pub layers: u32,
}

/// Every README row that has a layer count (cell 8, "layers @0.2").
pub fn readme_layers(dir: &Path) -> Vec<LayerRow> {
    readme_table(dir)
        .into_iter()
        .filter(|cells| cells.len() >= 9)
        .filter_map(|cells| {
            let layers = cells[8].parse().ok()?;
            Some(LayerRow { file: cells[0].clone(), watertight: cells[6] == "yes", layers })
        })
        .collect()
}

/// The default machine with a bed large enough for every shared model (plate_holes is
/// 203 x 305 mm): 400 x 400 x 250 mm.
pub fn big_machine() -> MachineConfig {
    let mut m = MachineConfig::default();
    m.build_volume_um = [400_000, 400_000, 250_000];
    m
}

/// Parses STL `bytes` and places the model as the host does (centred on the bed, dropped to
/// z = 0), sorted by lowest z; the error in words.
pub fn placed_sorted(bytes: &[u8], machine: &MachineConfig) -> Result<Vec<Triangle>, String> {
    let mut raw = Vec::new();
    let mut bounds = Bounds::EMPTY;
    strata::stl::read_all(bytes, &mut |t| {
        bounds.include(&t);
        raw.push(t);
    })
    .map_err(|e| e.to_string())?;
    let placement = Placement::on_bed(&bounds, machine).map_err(|e| e.to_string())?;
    let mut tris: Vec<Triangle> = raw.iter().map(|t| placement.apply(t)).collect();
    tris.sort_by_key(Triangle::z_min);
    Ok(tris)
}

/// [`placed_sorted`] of the file at `path`; panics naming the file on any error.
pub fn load_placed(path: &Path, machine: &MachineConfig) -> Vec<Triangle> {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    placed_sorted(&bytes, machine).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

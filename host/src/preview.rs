//! Preview of what the simulated printer did.
//!
//! The nozzle path reconstructed from the step pulses of the simulated board (not from the planned
//! moves), one SVG per layer and an HTML page that steps through them.

use std::fmt::Write as _;
use std::path::Path;

use strata::machine::AXES;
use strata::sim::EdgeObserver;

/// Steps per mm X, Y, Z, E of the Ender-3 (the simulated printer's machine).
const STEPS_PER_MM: [f64; AXES] = [80.0, 80.0, 400.0, 93.0];
/// A path point every this many mm of XY motion (and at every extrusion change).
const RESOLUTION_MM: f64 = 0.25;

/// One straight piece of the nozzle path, mm.
#[derive(Debug, Clone, Copy)]
pub struct Piece {
    /// Start.
    pub from: [f64; 2],
    /// End.
    pub to: [f64; 2],
    /// Filament was fed along it.
    pub extruding: bool,
}

/// Records the nozzle path per layer (a new layer whenever the head moves in XY at a new
/// height).
#[derive(Debug, Default)]
pub struct PathRecorder {
    /// Off: records nothing.
    pub enabled: bool,
    pos: [i64; AXES],
    last: [i64; AXES],
    /// Layers: height (mm) and pieces.
    pub layers: Vec<(f64, Vec<Piece>)>,
}

impl PathRecorder {
    /// A recorder (`enabled` false records nothing).
    pub fn new(enabled: bool) -> Self {
        Self { enabled, ..Self::default() }
    }

    fn mm(&self, p: &[i64; AXES], axis: usize) -> f64 {
        p[axis] as f64 / STEPS_PER_MM[axis]
    }

    fn flush(&mut self) {
        let (from, to) = (
            [self.mm(&self.last, 0), self.mm(&self.last, 1)],
            [self.mm(&self.pos, 0), self.mm(&self.pos, 1)],
        );
        let extruding = self.pos[3] > self.last[3];
        if from != to {
            let z = self.mm(&self.pos, 2);
            if !matches!(self.layers.last(), Some(l) if (l.0 - z).abs() <= 1e-9) {
                self.layers.push((z, Vec::new()));
            }
            if let Some(l) = self.layers.last_mut() {
                l.1.push(Piece { from, to, extruding });
            }
        }
        self.last = self.pos;
    }
}

impl EdgeObserver for PathRecorder {
    fn on_step(&mut self, axis: usize, _positive: bool, _tick: u64, position: i64) {
        if !self.enabled {
            return;
        }
        if axis == 2 {
            self.flush();
            self.pos[2] = position;
            self.last = self.pos;
            return;
        }
        let was_extruding = self.pos[3] > self.last[3];
        self.pos[axis] = position;
        let extruding = self.pos[3] > self.last[3];
        let d = (self.mm(&self.pos, 0) - self.mm(&self.last, 0))
            .hypot(self.mm(&self.pos, 1) - self.mm(&self.last, 1));
        if d >= RESOLUTION_MM || (axis == 3 && extruding != was_extruding) {
            self.flush();
        }
    }
}

/// Writes `layer_NNNN.svg` per layer and `index.html` into `dir`.
pub fn write(dir: &Path, rec: &PathRecorder, title: &str) -> Result<usize, String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    // The view frames what was printed (travels from and to the home position may leave it).
    let pieces = rec.layers.iter().flat_map(|l| &l.1).filter(|p| p.extruding);
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in pieces {
        for q in [p.from, p.to] {
            for k in 0..2 {
                lo[k] = lo[k].min(q[k]);
                hi[k] = hi[k].max(q[k]);
            }
        }
    }
    if lo[0] > hi[0] {
        return Err("nothing was printed".into());
    }
    let (x0, y0, w, h) = (lo[0] - 2.0, lo[1] - 2.0, hi[0] - lo[0] + 4.0, hi[1] - lo[1] + 4.0);
    let mut names = Vec::new();
    for (i, (z, pieces)) in rec.layers.iter().enumerate() {
        let (mut ext, mut trav) = (String::new(), String::new());
        for p in pieces {
            let d = if p.extruding { &mut ext } else { &mut trav };
            let _ = write!(d, "M{:.3} {:.3}L{:.3} {:.3}", p.from[0], p.from[1], p.to[0], p.to[1]);
        }
        let svg = format!(
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w:.2}mm\" height=\"{h:.2}mm\" \
             viewBox=\"{x0:.3} {ny:.3} {w:.3} {h:.3}\">\n<title>layer {i} z={z:.3} mm</title>\n\
             <rect x=\"{x0:.3}\" y=\"{ny:.3}\" width=\"{w:.3}\" height=\"{h:.3}\" fill=\"white\"/>\n\
             <g transform=\"scale(1,-1)\" fill=\"none\" stroke-linecap=\"round\">\n\
             <path d=\"{trav}\" stroke=\"#c8c8c8\" stroke-width=\"0.08\"/>\n\
             <path d=\"{ext}\" stroke=\"#1f5fbf\" stroke-width=\"0.4\" stroke-opacity=\"0.8\"/>\n\
             </g>\n</svg>\n",
            ny = -(y0 + h),
        );
        let name = format!("layer_{i:04}.svg");
        std::fs::write(dir.join(&name), svg).map_err(|e| format!("{}: {e}", dir.display()))?;
        names.push((name, *z));
    }
    let list: Vec<String> = names.iter().map(|(n, z)| format!("[\"{n}\",{z:.3}]")).collect();
    let html = format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{title}</title>\n\
         <style>body{{font-family:sans-serif}} img{{width:80vmin;height:80vmin;\
         object-fit:contain;border:1px solid #ccc}}</style></head>\n<body>\n\
         <h1>{title}</h1>\n<p>Nozzle path reconstructed from the simulated step pulses: \
         extrusion blue, travel grey. Arrow keys or the slider step through the layers.</p>\n\
         <input id=\"s\" type=\"range\" min=\"0\" max=\"{max}\" value=\"0\" style=\"width:80vmin\">\n\
         <p id=\"t\"></p>\n<img id=\"i\" alt=\"layer\">\n<script>\n\
         const L=[{list}];const s=document.getElementById('s');\n\
         function show(){{const k=+s.value;document.getElementById('i').src=L[k][0];\
         document.getElementById('t').textContent='layer '+k+' of '+L.length+', z = '+L[k][1]+' mm';}}\n\
         s.oninput=show;document.onkeydown=e=>{{if(e.key=='ArrowRight'||e.key=='ArrowUp')s.value=+s.value+1;\
         if(e.key=='ArrowLeft'||e.key=='ArrowDown')s.value=+s.value-1;show();}};show();\n\
         </script>\n</body></html>\n",
        max = names.len().saturating_sub(1),
        list = list.join(",")
    );
    std::fs::write(dir.join("index.html"), html).map_err(|e| format!("{}: {e}", dir.display()))?;
    Ok(names.len())
}

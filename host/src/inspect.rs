//! `strata inspect`: format, counts, bounding box and closedness of a model.
//!
//! Closed means every edge of the non-degenerate facets is shared by exactly two facets, with
//! corners compared by their exact f32 values (bit patterns, -0.0 taken as 0.0). Open edges
//! (one facet) and non-manifold edges (more than two) are counted in the findings.

use std::collections::HashMap;
use std::path::Path;

use serde_json::{json, Value};
use strata::stl::{RawTriangle, StlFormat};

use strata_host::model::{self, Model};

/// Runs `strata inspect MODEL [--json]`.
pub fn run(path: &Path, json: bool) -> Result<(), String> {
    let model = model::load(path)?;
    let edges = EdgeUse::of(&model.triangles);
    if json {
        let text = serde_json::to_string_pretty(&report_json(&model, &edges))
            .map_err(|e| format!("json: {e}"))?;
        println!("{text}");
    } else {
        print!("{}", report_text(path, &model, &edges));
    }
    Ok(())
}

/// How often the edges of a mesh are used by its facets.
#[derive(Debug, Default, PartialEq, Eq)]
struct EdgeUse {
    /// Distinct edges.
    edges: usize,
    /// Edges of exactly one facet (holes, cracks).
    open: usize,
    /// Edges of more than two facets.
    non_manifold: usize,
}

/// A corner as a hash key: the f32 bit patterns, with -0.0 turned into 0.0 (`x + 0.0`).
type Corner = [u32; 3];

impl EdgeUse {
    fn of(triangles: &[RawTriangle]) -> Self {
        let mut uses: HashMap<(Corner, Corner), u32> = HashMap::with_capacity(triangles.len() * 2);
        for t in triangles {
            let c = t.vertices.map(|v| v.map(|x| (x + 0.0).to_bits()));
            for (a, b) in [(c[0], c[1]), (c[1], c[2]), (c[2], c[0])] {
                *uses.entry(if a <= b { (a, b) } else { (b, a) }).or_default() += 1;
            }
        }
        let open = uses.values().filter(|&&n| n == 1).count();
        let non_manifold = uses.values().filter(|&&n| n > 2).count();
        Self { edges: uses.len(), open, non_manifold }
    }

    /// Every edge shared by exactly two facets (and there are facets).
    fn closed(&self) -> bool {
        self.edges > 0 && self.open == 0 && self.non_manifold == 0
    }
}

fn format_name(format: StlFormat) -> &'static str {
    match format {
        StlFormat::Binary => "binary",
        StlFormat::Ascii => "ascii",
    }
}

/// A file coordinate for JSON: the shortest decimal that reads back as the same f32.
fn json_mm(v: f32) -> Value {
    json!(v.to_string().parse::<f64>().unwrap_or(f64::from(v)))
}

fn report_json(model: &Model, edges: &EdgeUse) -> Value {
    let s = &model.summary;
    let corner = |c: [f32; 3]| {
        if model.bounds.is_empty() {
            Value::Null
        } else {
            Value::Array(c.iter().map(|&v| json_mm(v)).collect())
        }
    };
    json!({
        "format": format_name(s.format),
        "triangles": s.triangles,
        "degenerate": s.degenerate,
        "bbox_min": corner(model.bounds.min),
        "bbox_max": corner(model.bounds.max),
        "closed": edges.closed(),
        "findings": {
            "count_mismatch": s.count_mismatch.map(|m| json!({
                "declared": m.declared,
                "found": m.found,
            })),
            "trailing_bytes": s.trailing_bytes,
            "bad_normals": s.bad_normals,
            "ignored_words": s.ignored_words,
            "missing_endsolid": s.missing_endsolid,
            "open_edges": edges.open,
            "non_manifold_edges": edges.non_manifold,
        },
    })
}

fn report_text(path: &Path, model: &Model, edges: &EdgeUse) -> String {
    let s = &model.summary;
    let b = &model.bounds;
    let mut lines = vec![
        ("model", path.display().to_string()),
        ("format", format_name(s.format).to_string()),
        ("triangles", format!("{} ({} degenerate)", s.triangles, s.degenerate)),
    ];
    if b.is_empty() {
        lines.push(("bbox", "none (no facet with area)".to_string()));
    } else {
        let [x0, y0, z0] = b.min;
        let [x1, y1, z1] = b.max;
        lines.push((
            "bbox",
            format!("({x0:.3}, {y0:.3}, {z0:.3}) .. ({x1:.3}, {y1:.3}, {z1:.3}) mm"),
        ));
        lines.push(("size", format!("{:.3} x {:.3} x {:.3} mm", x1 - x0, y1 - y0, z1 - z0)));
    }
    let closed = if edges.closed() { "yes" } else { "no" };
    lines.push(("closed", closed.to_string()));

    let mut findings = Vec::new();
    if let Some(m) = s.count_mismatch {
        findings.push(format!("header declares {} facets, file holds {}", m.declared, m.found));
    }
    if s.bad_normals > 0 {
        findings.push(format!(
            "{} facets with a normal that is not a number (not used)",
            s.bad_normals
        ));
    }
    if s.ignored_words > 0 {
        findings.push(format!("{} words after statements skipped", s.ignored_words));
    }
    if s.trailing_bytes > 0 {
        findings.push(format!("{} bytes after the last facet", s.trailing_bytes));
    }
    if s.missing_endsolid {
        findings.push("no closing endsolid".to_string());
    }
    if edges.open > 0 {
        findings.push(format!("{} open edges (used by one facet)", edges.open));
    }
    if edges.non_manifold > 0 {
        findings.push(format!("{} edges shared by more than two facets", edges.non_manifold));
    }
    if findings.is_empty() {
        findings.push("none".to_string());
    }
    lines.extend(findings.into_iter().map(|f| ("finding", f)));

    lines.iter().map(|(label, value)| format!("{label:<10} {value}\n")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [f32; 3], b: [f32; 3], c: [f32; 3]) -> RawTriangle {
        RawTriangle { normal: [0.0; 3], vertices: [a, b, c] }
    }

    /// A tetrahedron: 4 facets, 6 edges, closed.
    fn tetra() -> Vec<RawTriangle> {
        let (o, x, y, z) = ([0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]);
        vec![tri(o, y, x), tri(o, x, z), tri(o, z, y), tri(x, y, z)]
    }

    #[test]
    fn tetrahedron_is_closed_until_a_facet_goes() {
        let t = tetra();
        assert_eq!(EdgeUse::of(&t), EdgeUse { edges: 6, open: 0, non_manifold: 0 });
        assert!(EdgeUse::of(&t).closed());
        assert_eq!(EdgeUse::of(&t[..3]), EdgeUse { edges: 6, open: 3, non_manifold: 0 });
        assert!(!EdgeUse::of(&[]).closed());
    }

    #[test]
    fn negative_zero_is_the_same_corner_and_extra_facets_are_non_manifold() {
        let mut t = tetra();
        t[0].vertices[0] = [-0.0, 0.0, -0.0];
        assert!(EdgeUse::of(&t).closed());
        t.push(t[3]);
        let e = EdgeUse::of(&t);
        assert_eq!((e.open, e.non_manifold, e.closed()), (0, 3, false));
    }
}

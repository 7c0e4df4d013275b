//! Toolpaths of analytic parts against independent f64 models.

mod slice_support;
mod toolpath_support;

use slice_support::{cuboid, to_um};
use strata::machine::PrintSettings;
use toolpath_support::run;

#[test]
fn smoke_cube() {
    let tris = to_um(&cuboid([100.0, 100.0, 0.0], [120.0, 120.0, 20.0]));
    let r = run(&tris, &PrintSettings::default());
    eprintln!("{:?}", r.stats);
    for l in r.layers.iter().take(6) {
        eprintln!("{:?}", l.stats);
    }
    assert_eq!(r.layers.len(), 100);
}

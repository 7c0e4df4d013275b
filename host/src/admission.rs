//! Admission control: does the model fit the device's capacities at these settings?
//! (Simplification comes in a later step.)

use strata::geom::Triangle;
use strata::protocol::Capacities;
use strata::slice::{peak_needs, PeakNeeds, SliceConfig};

/// What a model needs against what the device has.
#[derive(Debug, Clone, Copy)]
pub struct Fit {
    /// The model's peaks.
    pub needs: PeakNeeds,
    /// True when every peak fits.
    pub fits: bool,
}

/// Checks the model's peak active set and contour points against `caps`.
pub fn check(tris: &[Triangle], config: &SliceConfig, caps: &Capacities) -> Result<Fit, String> {
    let needs = peak_needs(tris, config).map_err(|e| e.to_string())?;
    let fits = needs.active_triangles <= caps.active_triangles
        && needs.contour_points <= caps.contour_points;
    Ok(Fit { needs, fits })
}

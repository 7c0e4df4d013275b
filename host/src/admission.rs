//! Admission control: does the model fit the device's capacities at these settings, and if
//! not, a simplified mesh that does, within a stated maximum deviation.
//!
//! The model's peak needs come from `strata::slice::peak_needs` (the largest active set and
//! the most contour points of any layer) and are compared with the capacities the device
//! announced. A model that does not fit is simplified two ways, and the deviation is measured,
//! not assumed: a two-sided Hausdorff estimate between the original and the simplified surface
//! (original vertices to the simplified mesh, and points sampled on the simplified triangles
//! to the original, exact point-triangle distances through an R-tree).
//! - The quadric simplifier ([`crate::simplify`]: edge collapses held within a distance bound,
//!   vertices placed where the surface's planes meet) at growing bounds up to just under the
//!   allowed deviation, each run going on from the last; the first that fits is taken.
//! - `meshopt` (edge collapses onto existing vertices) towards a triangle count: its error
//!   parameter is a quadric estimate that can be several times below the real distance, so the
//!   simplification keeping the most triangles that fits is searched (bisection on the count).
//!
//! The fit that deviates less is taken if its measured deviation is within the stated bound,
//! else the model is refused with that deviation in the message (so the user can allow it
//! knowingly; the quadric simplifier then goes on past the bound up to meshopt's deviation).
//!
//! [`admit_job`] checks the whole pipeline: after the slicer, the model (as it will be
//! streamed) runs through a host-sized toolpath stage with the job's settings, exactly as the
//! device will run it ([`toolpath_peaks`]), and every toolpath need is compared with the
//! device's toolpath capacities (`PTS`, `LOOPS`, `CROSS`, `PATH`, `RING`, `SPANS`) and the
//! largest emission unit's bytes (a path with the travel before it: the device's toolpath
//! stage emits a layer unit by unit, each once its move buffer has room for the unit's coded
//! moves; measured with the device's own `strata::move_ring` room and coder) with the move
//! buffer. Simplifying
//! the mesh only reduces the slicer's needs, so a toolpath need that does not fit refuses the
//! model, naming the resource, the layer where it peaks, the need and the capacity.

use std::cell::Cell;

use meshopt::{simplify_decoder, SimplifyOptions};
use rstar::{PointDistance, RTree, RTreeObject, AABB};
use strata::geom::{Point2, Point3, Triangle};
use strata::machine::MachineConfig;
use strata::move_ring::MoveMeter;
use strata::protocol::{Capacities, JobSpec};
use strata::slice::{peak_needs, PeakNeeds, SliceConfig, SlicedLayer};
use strata::toolpath::{Room, ToolEvent, ToolpathConfig, ToolpathError, ToolpathNeeds};

use crate::pace::{self, LayerClock, Pace};
use crate::simplify::{self, dist2_point_triangle, mm, Simplifier, BARY, V};
use crate::stages::{HostScratch, HostSlicer, HostToolpath};

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

/// A simplification that fits.
#[derive(Debug, Clone)]
pub struct Simplified {
    /// The simplified triangles, placed, sorted by lowest z.
    pub triangles: Vec<Triangle>,
    /// Triangles before.
    pub triangles_in: usize,
    /// The allowed deviation, mm.
    pub error_bound_mm: f64,
    /// Measured deviation (two-sided Hausdorff estimate), mm.
    pub max_deviation_mm: f64,
    /// Needs of the simplified model.
    pub needs: PeakNeeds,
}

impl Simplified {
    /// `out` (sorted by lowest z), simplified from `original` within `bound_mm`, measured
    /// `dev_mm`, with its slicer `needs`.
    fn of(
        original: &[Triangle],
        out: Vec<Triangle>,
        bound_mm: f64,
        dev_mm: f64,
        needs: PeakNeeds,
    ) -> Self {
        Self {
            triangles_in: original.len(),
            error_bound_mm: bound_mm,
            max_deviation_mm: dev_mm,
            needs,
            triangles: out,
        }
    }
}

/// The admission decision.
#[derive(Debug, Clone)]
pub enum Admission {
    /// Fits unchanged.
    Unchanged(PeakNeeds),
    /// Fits after simplification.
    Simplified(Simplified),
}

impl Admission {
    /// The triangles to stream: `original` unchanged, or the simplification.
    pub fn triangles<'a>(&'a self, original: &'a [Triangle]) -> &'a [Triangle] {
        match self {
            Self::Unchanged(_) => original,
            Self::Simplified(s) => &s.triangles,
        }
    }
}

/// Admits `tris` (placed, sorted by lowest z) for `job` on a device with `caps` and `machine`.
///
/// The slicer's needs as [`admit`] (simplified within `max_deviation_mm` if need be), then the
/// toolpath stage's needs of the model as it will be streamed ([`toolpath_peaks`] against
/// [`toolpath_shortfalls`]): refused with a message naming every resource that does not fit.
pub fn admit_job(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<Admission, String> {
    admit_job_peaks(tris, machine, job, caps, max_deviation_mm).map(|(a, _)| a)
}

/// [`admit_job`], and the toolpath needs of the admitted model.
pub fn admit_job_peaks(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<(Admission, ToolpathPeaks), String> {
    admit_job_timed(tris, machine, job, caps, max_deviation_mm).map(|(a, p, _)| (a, p))
}

/// [`admit_job_peaks`], and the print time of every layer.
pub fn admit_job_timed(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<(Admission, ToolpathPeaks, LayerTimes), String> {
    let config = SliceConfig::new(&job.settings, job.model_height_um).map_err(|e| e.to_string())?;
    let admission = admit(tris, &config, caps, max_deviation_mm)?;
    match toolpath_fit(admission.triangles(tris), machine, job, caps)? {
        Ok((peaks, times)) => Ok((admission, peaks, times)),
        Err(short) => {
            // Fewer contour points mean fewer loop points, path points and stored contours:
            // the quadric simplifier's bounds, the first whose slicer and toolpath needs both
            // fit.
            let mesh = Indexed::weld(tris);
            let mut s = Simplifier::new(&mesh.points, &mesh.indices, simplify::Options::default());
            for bound in QEM_STAGES.iter().map(|k| k * max_deviation_mm * QEM_SHARE) {
                s.run(bound);
                let mut out = s.triangles();
                out.sort_by_key(Triangle::z_min);
                let fit = check(&out, &config, caps)?;
                if !fit.fits {
                    continue;
                }
                if let Ok((peaks, times)) = toolpath_fit(&out, machine, job, caps)? {
                    let dev = deviation(&mesh, tris, &out);
                    if dev <= max_deviation_mm {
                        let s = Simplified::of(tris, out, max_deviation_mm, dev, fit.needs);
                        return Ok((Admission::Simplified(s), peaks, times));
                    }
                }
            }
            let simplified = match &admission {
                Admission::Unchanged(_) => String::new(),
                Admission::Simplified(s) => {
                    format!(" (simplified to {} triangles for the slicer)", s.triangles.len())
                }
            };
            Err(format!(
                "the model does not fit the printer's toolpath memory{simplified}:\n  - {}",
                short.join("\n  - ")
            ))
        }
    }
}

/// The toolpath needs of `streamed` on a device with `caps` and the layers' print times, or
/// what does not fit (`Ok(Err(shortfalls))`).
fn toolpath_fit(
    streamed: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    caps: &Capacities,
) -> Result<Result<(ToolpathPeaks, LayerTimes), Vec<String>>, String> {
    // Offsets as the device does them: in bands where its engine holds less than one needs.
    // If even that fails, the needs of offsets done whole say what does not fit.
    Ok(match toolpath_pass(streamed, machine, job, Some(caps)) {
        Ok((peaks, times)) => {
            let short = toolpath_shortfalls(&peaks, caps);
            if short.is_empty() {
                Ok((peaks, times))
            } else {
                Err(short)
            }
        }
        Err(banded) => {
            let peaks = toolpath_peaks(streamed, machine, job)?;
            let mut short = toolpath_shortfalls(&peaks, caps);
            if short.is_empty() {
                short.push(banded);
            }
            Err(short)
        }
    })
}

/// A job admitted for the device's memory and for the link's speed.
#[derive(Debug, Clone)]
pub struct Paced {
    /// The model as it will be streamed.
    pub admission: Admission,
    /// Its toolpath needs.
    pub peaks: ToolpathPeaks,
    /// Its layers' print times.
    pub times: LayerTimes,
    /// How the link keeps up with its print ([`Pace::keeps_ahead`] false: the printer will
    /// wait for the link that long; no simplification within the bound avoids it).
    pub pace: Pace,
}

/// Simplifications tried for the link's sake (each cuts the triangles by the ratio the worst
/// layer's lag asks for).
const PACE_STEPS: usize = 6;
/// Share of the ratio a pacing step asks for that it takes: a margin for the print times and
/// the frames, which change a little with the mesh.
const PACE_MARGIN: f64 = 0.8;

/// [`admit_job_timed`], and a model the link at `baud` streams ahead of the print.
///
/// A model whose triangles the link cannot deliver as fast as the printer prints them
/// ([`crate::pace`]) is simplified (within `max_deviation_mm`, measured, as for the device's
/// memory) until it can: fewer triangles in the ratio of the time the link has to the time it
/// needs at the worst layer. If no simplification within the bound keeps ahead, the one that
/// lags least is taken and its [`Pace`] says by how much (the caller warns).
pub fn admit_job_paced(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    caps: &Capacities,
    max_deviation_mm: f64,
    baud: u32,
) -> Result<Paced, String> {
    let config = SliceConfig::new(&job.settings, job.model_height_um).map_err(|e| e.to_string())?;
    let (admission, peaks, times) = admit_job_timed(tris, machine, job, caps, max_deviation_mm)?;
    let pace_of = |streamed: &[Triangle], times: &LayerTimes| {
        pace::pace(&pace::stream_bytes(streamed, &config), &times.starts_s, times.total_s, baud)
    };
    let pace = pace_of(admission.triangles(tris), &times);
    let mut best = Paced { admission, peaks, times, pace };
    if best.pace.keeps_ahead() {
        return Ok(best);
    }
    let mesh = Indexed::weld(tris);
    for _ in 0..PACE_STEPS {
        let streamed = best.admission.triangles(tris);
        let layer = best.pace.layer as usize;
        let has = best.times.starts_s.get(layer).copied().unwrap_or(0.0).max(0.0);
        let needs = best.pace.worst_lag_s + has;
        let ratio = (has / needs * PACE_MARGIN).clamp(0.0, PACE_MARGIN);
        let target = (streamed.len() as f64 * ratio) as usize;
        if target < 4 {
            break;
        }
        let mut out = mesh.simplify(target);
        out.sort_by_key(Triangle::z_min);
        let fit = check(&out, &config, caps)?;
        let dev = deviation(&mesh, tris, &out);
        if !fit.fits || dev > max_deviation_mm || out.len() >= streamed.len() {
            break;
        }
        let Ok((peaks, times)) = toolpath_fit(&out, machine, job, caps)? else {
            break;
        };
        let pace = pace_of(&out, &times);
        let admission =
            Admission::Simplified(Simplified::of(tris, out, max_deviation_mm, dev, fit.needs));
        best = Paced { admission, peaks, times, pace };
        if pace.keeps_ahead() {
            break;
        }
    }
    Ok(best)
}

/// Admits `tris` (placed, sorted by lowest z) on a device with `caps`.
///
/// Unchanged, simplified with a *measured* deviation of at most `max_deviation_mm`, or refused with
/// a message saying what does not fit and what deviation a fitting simplification would have.
pub fn admit(
    tris: &[Triangle],
    config: &SliceConfig,
    caps: &Capacities,
    max_deviation_mm: f64,
) -> Result<Admission, String> {
    let fit = check(tris, config, caps)?;
    if fit.fits {
        return Ok(Admission::Unchanged(fit.needs));
    }
    let mesh = Indexed::weld(tris);
    // meshopt's largest fit, then the quadric simplifier's smallest bound that fits: the one
    // with the smaller measured deviation.
    let meshopt = match largest_fit(&mesh, tris, config, caps)? {
        Some((out, needs)) => {
            let dev = deviation(&mesh, tris, &out);
            Some(Candidate { triangles: out, needs, dev })
        }
        None => None,
    };
    let limit = meshopt.as_ref().map_or(max_deviation_mm * QEM_REACH, |m| m.dev);
    let qem = qem_fit(&mesh, tris, config, caps, max_deviation_mm, limit)?;
    let best = [meshopt, qem].into_iter().flatten().min_by(|a, b| a.dev.total_cmp(&b.dev));
    let Some(Candidate { triangles: out, needs, dev }) = best else {
        return Err(format!(
            "the model does not fit the printer even simplified to a few triangles: it needs \
             {} active triangles and {} contour points per layer, the printer holds {} and {}",
            fit.needs.active_triangles,
            fit.needs.contour_points,
            caps.active_triangles,
            caps.contour_points
        ));
    };
    if dev > max_deviation_mm {
        return Err(format!(
            "the model does not fit the printer: it needs {} active triangles and {} contour \
             points per layer, the printer holds {} and {}; simplified until it fits ({} of {} \
             triangles) its surface moves by {dev:.3} mm, more than the allowed \
             {max_deviation_mm} mm (allow it with --max-deviation {:.3})",
            fit.needs.active_triangles,
            fit.needs.contour_points,
            caps.active_triangles,
            caps.contour_points,
            out.len(),
            tris.len(),
            (dev * 1000.0).ceil() / 1000.0
        ));
    }
    Ok(Admission::Simplified(Simplified::of(tris, out, max_deviation_mm, dev, needs)))
}

/// A simplification that fits, with its measured deviation (mm).
struct Candidate {
    triangles: Vec<Triangle>,
    needs: PeakNeeds,
    dev: f64,
}

/// The quadric simplifier's bound as a share of the allowed deviation (the rest is slack for
/// the float arithmetic; the deviation is measured anyway).
const QEM_SHARE: f64 = 0.98;
/// Bounds the quadric simplifier runs through, as shares of its bound at the allowed
/// deviation, smallest first: the first that fits deviates least.
const QEM_STAGES: [f64; 6] = [0.2, 0.35, 0.5, 0.65, 0.8, 1.0];
/// Beyond the allowed deviation (for the refusal's figure): each bound this much larger...
const QEM_GROWTH: f64 = 1.25;
/// ... up to this many times the allowed deviation when meshopt found nothing that fits.
const QEM_REACH: f64 = 16.0;

/// The quadric simplifier's fit with the smallest bound among [`QEM_STAGES`] (each stage goes
/// on from the last), measured; if none fits within `max_deviation_mm`, larger bounds up to
/// `limit_mm` (only a fit deviating less than `limit_mm` is of use); `None` when nothing fits.
fn qem_fit(
    mesh: &Indexed,
    tris: &[Triangle],
    config: &SliceConfig,
    caps: &Capacities,
    max_deviation_mm: f64,
    limit_mm: f64,
) -> Result<Option<Candidate>, String> {
    let top = max_deviation_mm * QEM_SHARE;
    let beyond = std::iter::successors(Some(top * QEM_GROWTH), |b| Some(b * QEM_GROWTH))
        .take_while(|b| *b < limit_mm * QEM_SHARE);
    let bounds = QEM_STAGES.iter().map(|s| s * top).chain(beyond);
    // Collapses that lower the most crowded of the job's planes go first.
    let layers = simplify::Layers {
        first_um: config.first_layer_height_um,
        height_um: config.layer_height_um,
    };
    let opts = simplify::Options { layers: Some(layers), ..simplify::Options::default() };
    let mut s = Simplifier::new(&mesh.points, &mesh.indices, opts);
    for bound in bounds {
        s.run(bound);
        let mut out = s.triangles();
        out.sort_by_key(Triangle::z_min);
        let fit = check(&out, config, caps)?;
        if fit.fits {
            let dev = deviation(mesh, tris, &out);
            return Ok(Some(Candidate { triangles: out, needs: fit.needs, dev }));
        }
    }
    Ok(None)
}

/// Bisection steps between a fitting and a non-fitting triangle count.
const SEARCH_STEPS: usize = 7;

/// The simplification with the most triangles that fits `caps` (meshopt towards a triangle
/// count, no error limit: halving from the original until one fits, then bisecting between
/// the last fitting and the first non-fitting count), with its needs; `None` when nothing
/// down to 4 triangles fits.
fn largest_fit(
    mesh: &Indexed,
    tris: &[Triangle],
    config: &SliceConfig,
    caps: &Capacities,
) -> Result<Option<(Vec<Triangle>, PeakNeeds)>, String> {
    let try_count = |target: usize| -> Result<(Vec<Triangle>, Fit), String> {
        let mut out = mesh.simplify(target);
        out.sort_by_key(Triangle::z_min);
        let fit = check(&out, config, caps)?;
        Ok((out, fit))
    };
    let (mut hi, mut target) = (tris.len(), tris.len() / 2);
    let mut best = loop {
        if target < 4 {
            return Ok(None);
        }
        let (out, fit) = try_count(target)?;
        if fit.fits {
            break (out, fit.needs);
        }
        hi = target;
        target /= 2;
    };
    let mut lo = target;
    for _ in 0..SEARCH_STEPS {
        let mid = lo + (hi - lo) / 2;
        if mid <= lo {
            break;
        }
        let (out, fit) = try_count(mid)?;
        if fit.fits {
            lo = mid;
            if out.len() > best.0.len() {
                best = (out, fit.needs);
            }
        } else {
            hi = mid;
        }
    }
    Ok(Some(best))
}

/// A need of the toolpath stage and the layer where it peaks (the first layer with that
/// value).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Peak {
    /// The largest use.
    pub value: u32,
    /// Layer index.
    pub layer: u32,
    /// Layer height (top of the layer), um.
    pub z_um: i32,
}

impl Peak {
    fn raise(&mut self, value: u32, layer: (u32, i32)) {
        if value > self.value {
            *self = Self { value, layer: layer.0, z_um: layer.1 };
        }
    }
}

/// What the toolpath stage needs for a model, with the layers where the needs peak.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ToolpathPeaks {
    /// The stage's needs (`ToolpathStats::needs` of the whole run).
    pub needs: ToolpathNeeds,
    /// `PTS`: loop points of a layer, or offset edges of an island (the larger).
    pub points: Peak,
    /// `LOOPS`: loops of a layer.
    pub loops: Peak,
    /// The slicer's `L` (`contour_loops`): loops the slicer keeps of a layer.
    pub contour_loops: Peak,
    /// `CROSS`: scanline crossings (segments and pieces in 12-byte units) of a pass.
    pub crossings: Peak,
    /// `PATH`: path points of a layer.
    pub path_points: Peak,
    /// `RING`: words of the skin window's stored contours.
    pub ring_words: Peak,
    /// `SPANS`: the skin window's crossings with one scanline.
    pub spans: Peak,
    /// Bytes of the largest emission unit (a path with the travel, retraction and priming
    /// before it) in the move buffer, coded as the device codes them (`strata::move_ring`'s
    /// `MoveMeter`, the coding's state running on across units and layers): the device's
    /// toolpath stage emits a layer unit by unit, each once its move buffer has that many
    /// bytes free, so the buffer must hold it.
    pub unit_bytes: Peak,
    /// Bytes of all the job's moves, coded (what the move buffer would hold if nothing were
    /// planned).
    pub move_bytes: u64,
    /// Layers.
    pub layers: u32,
}

/// The toolpath stage's needs for `tris`, the layers where they peak and the largest emission
/// unit's bytes.
///
/// `tris` (placed, sorted by lowest z, as they will be streamed) run through a host-sized slicer
/// and toolpath stage with the settings the device derives from `job`.
///
/// The stage is driven as the device drives it: each layer taken (`accept_layer`) builds at most
/// one, whose units are then emitted (`emit_next`) into the device's byte room, without bound here,
/// which measures each unit's coded bytes; after the last layer the waiting ones are built and
/// emitted one at a time (`build_next`). A need found growing while the stage takes a layer is
/// attributed to that layer (the window's stored contours) or to the layer it builds meanwhile (the
/// others: a layer is built once the layers its top skins wait for have arrived). Runs on a thread
/// with a large stack (the stages are large values).
pub fn toolpath_peaks(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
) -> Result<ToolpathPeaks, String> {
    toolpath_peaks_limited(tris, machine, job, None)
}

/// [`toolpath_peaks`] as a device with `device`'s capacities builds the layers.
///
/// Its offset engine's edges (`PTS`): offsets that need more are done in bands, which may
/// change them within the output's tolerance; its path points and scanline crossings: a layer
/// whose bridges need more is built without them.
///
/// An offset that does not fit even in the thinnest bands is the error.
pub fn toolpath_peaks_limited(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    device: Option<&Capacities>,
) -> Result<ToolpathPeaks, String> {
    toolpath_pass(tris, machine, job, device).map(|(peaks, _)| peaks)
}

/// Print time of each layer's start and of the whole job, s (a [`LayerClock`]'s).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LayerTimes {
    /// Print time before each layer's first move (index = layer), s.
    pub starts_s: Vec<f64>,
    /// Print time of the whole job, s.
    pub total_s: f64,
    /// Whether each layer extrudes (index = layer).
    pub extrudes: Vec<bool>,
}

/// [`toolpath_peaks_limited`] and the print time of every layer (the moves through the device's
/// planner: [`LayerClock`]).
pub fn toolpath_pass(
    tris: &[Triangle],
    machine: &MachineConfig,
    job: &JobSpec,
    device: Option<&Capacities>,
) -> Result<(ToolpathPeaks, LayerTimes), String> {
    let slice_cfg =
        SliceConfig::new(&job.settings, job.model_height_um).map_err(|e| e.to_string())?;
    let cfg = strata::printer::job_toolpath_config(machine, job);
    std::thread::scope(|scope| {
        std::thread::Builder::new()
            .name("admission".into())
            .stack_size(256 << 20)
            .spawn_scoped(scope, || measure(tris, slice_cfg, cfg, device, machine))
            .map_err(|e| format!("cannot start the admission thread: {e}"))?
            .join()
            .map_err(|_| "the admission thread panicked".to_string())?
    })
}

fn measure(
    tris: &[Triangle],
    slice_cfg: SliceConfig,
    cfg: ToolpathConfig,
    device: Option<&Capacities>,
    machine: &MachineConfig,
) -> Result<(ToolpathPeaks, LayerTimes), String> {
    let clock = std::cell::RefCell::new(LayerClock::new(machine));
    let mut slicer = Box::new(HostSlicer::new(slice_cfg).map_err(|e| e.to_string())?);
    let mut tp = Box::new(HostToolpath::new(cfg).map_err(|e| e.to_string())?);
    if let Some(caps) = device {
        tp.set_offset_limit(caps.toolpath_points as usize);
        tp.set_bridge_limits(caps.path_points as usize, caps.scan_crossings as usize);
    }
    let mut work = Box::new(HostScratch::new());
    tp.set_position(Point2::new(0, 0), 0);
    let peaks = Cell::new(ToolpathPeaks::default());
    // The layer being built or emitted, and the moves coded as the device's move buffer
    // codes them (from the origin, as after the device's `JobStart`).
    let emitting = Cell::new((0u32, 0i32));
    let meter = Cell::new(MoveMeter::default());
    let coded = Cell::new(0u64);
    let events = &mut |e: &ToolEvent<'_>| {
        clock.borrow_mut().event(e);
        let mut m = meter.get();
        coded.set(coded.get() + m.event(e) as u64);
        meter.set(m);
        match e {
            ToolEvent::LayerStart { index, z_um, .. } => emitting.set((*index, *z_um)),
            ToolEvent::LayerEnd(_) => {
                let mut p = peaks.get();
                p.layers += 1;
                peaks.set(p);
            }
            ToolEvent::Move(_) | ToolEvent::Progress => {}
        }
    };
    // Needs that grew while the stage took or built a layer (`pushed`: the layer taken).
    let raise = |before: ToolpathNeeds, n: ToolpathNeeds, pushed: (u32, i32)| {
        let emitted = emitting.get();
        let mut p = peaks.get();
        if n != before {
            p.points.raise(n.layer_points.max(n.offset_edges), emitted);
            p.loops.raise(n.layer_loops, emitted);
            p.ring_words.raise(n.ring_points, pushed);
            p.crossings.raise(n.crossings, emitted);
            p.path_points.raise(n.path_points, emitted);
            p.spans.raise(n.spans, emitted);
        }
        peaks.set(p);
    };
    // The built layer's units into a room without bound, each unit's bytes those the
    // events' meter (the device's coding) counts from its open to its close.
    let emit = |tp: &mut HostToolpath,
                work: &mut HostScratch,
                events: &mut dyn FnMut(&ToolEvent<'_>)|
     -> Result<(), ToolpathError> {
        while tp.emitting() {
            let mut room =
                UnitBytes { events: &mut *events, coded: &coded, opened: 0, units: (0, 0) };
            tp.emit_next(work, &mut room)?;
            let (largest, total) = room.units;
            let mut p = peaks.get();
            p.unit_bytes.raise(largest as u32, emitting.get());
            p.move_bytes += total;
            peaks.set(p);
        }
        Ok(())
    };
    let mut failed = None;
    let mut sink = |l: SlicedLayer<'_, _, _>| {
        if failed.is_some() {
            return;
        }
        let before = tp.stats().needs;
        // Heights as the nozzle's (the top of the layer), as `LayerStart` gives them.
        let index = l.layer().index;
        let pushed = (index, cfg.layer_z_um(index));
        emitting.set(pushed);
        let mut p = peaks.get();
        p.contour_loops.raise(l.layer().loops.len() as u32, pushed);
        peaks.set(p);
        let taken = tp.accept_sliced(l, &mut *events);
        raise(before, tp.stats().needs, pushed);
        if let Err(e) = taken.and_then(|work| emit(&mut tp, work, &mut *events)) {
            failed = Some(e);
        }
    };
    for t in tris {
        slicer.push(t, &mut *work, &mut sink).map_err(|e| e.to_string())?;
    }
    slicer.finish(&mut *work, &mut sink).map_err(|e| e.to_string())?;
    if let Some(e) = failed {
        return Err(format!("the toolpath stage cannot measure this model: {e}"));
    }
    // The layers the last ones' top skins waited for, one at a time as the device builds them.
    let flushed = (|| loop {
        let before = tp.stats().needs;
        let pushed = emitting.get();
        if !tp.build_next(&mut *work, &mut *events)? {
            return Ok(());
        }
        raise(before, tp.stats().needs, pushed);
        emit(&mut tp, &mut work, &mut *events)?;
    })();
    flushed.map_err(|e: ToolpathError| e.to_string())?;
    let stats = tp.finish(&mut *work, events).map_err(|e| e.to_string())?;
    let mut p = peaks.get();
    p.needs = stats.needs;
    // Every move is in a unit: the rooms counted every byte the moves take.
    if p.move_bytes != coded.get() {
        return Err(format!(
            "the move buffer's room counted {} bytes of units, the moves take {}",
            p.move_bytes,
            coded.get()
        ));
    }
    let (starts_s, total_s, extrudes) = clock.into_inner().finish();
    Ok((p, LayerTimes { starts_s, total_s, extrudes }))
}

/// A room without bound that passes the events on to `events` and measures each unit by
/// `coded` (the bytes `events` counted so far).
struct UnitBytes<'a, 'e> {
    events: &'a mut (dyn FnMut(&ToolEvent<'_>) + 'e),
    coded: &'a Cell<u64>,
    /// `coded` when the open unit began.
    opened: u64,
    /// Bytes of the largest unit and of all units.
    units: (u64, u64),
}

impl Room for UnitBytes<'_, '_> {
    fn open(&mut self, _: u32) -> bool {
        self.opened = self.coded.get();
        true
    }

    fn event(&mut self, e: &ToolEvent<'_>) {
        (self.events)(e)
    }

    fn close(&mut self) -> bool {
        let bytes = self.coded.get() - self.opened;
        self.units = (self.units.0.max(bytes), self.units.1 + bytes);
        true
    }
}

/// Every toolpath need of `peaks` that `caps` does not hold, as a sentence for the user (empty when
/// everything fits).
///
/// `PTS >= max(layer_points, offset_edges)`, `LOOPS >= layer_loops`, `CROSS >= crossings`, `PATH >=
/// path_points`, `RING >= ring_points`, `SPANS >= spans` (the `ToolpathNeeds` docs), the slicer's
/// `contour_loops >=` the loops it keeps of a layer, and the move buffer's bytes `>=` the largest
/// emission unit's ([`ToolpathPeaks::unit_bytes`]). Paths are not compared with `CROSS`: a layer
/// with more paths than the nearest-path grid holds is ordered by a scan instead (same order, no
/// error).
pub fn toolpath_shortfalls(peaks: &ToolpathPeaks, caps: &Capacities) -> Vec<String> {
    const AREA: &str = "the part's cross-section is too large for this printer's memory";
    const WINDOW: &str = "the layers the top and bottom skins wait for are too large for this \
                          printer's memory (fewer --top-layers/--bottom-layers need less)";
    let mm = |z: i32| z as f64 / 1000.0;
    let mut out = Vec::new();
    let mut need = |p: &Peak, what: &str, cap: u32, why: &str| {
        if p.value > cap {
            let at = if why == WINDOW { "the skin window at" } else { "layer at" };
            out.push(format!(
                "{at} {:.2} mm needs {} {what}; the printer holds {cap}: {why}",
                mm(p.z_um),
                p.value
            ));
        }
    };
    need(&peaks.points, "toolpath loop points and offset edges", caps.toolpath_points, AREA);
    need(&peaks.loops, "toolpath loops", caps.toolpath_loops, AREA);
    need(&peaks.contour_loops, "contour loops", caps.contour_loops, AREA);
    need(&peaks.crossings, "scanline crossings", caps.scan_crossings, AREA);
    need(&peaks.path_points, "toolpath path points", caps.path_points, AREA);
    need(&peaks.ring_words, "contour words", caps.window_ring_words, WINDOW);
    need(&peaks.spans, "scanline spans", caps.window_spans, WINDOW);
    let m = &peaks.unit_bytes;
    if m.value > caps.move_buffer_bytes {
        out.push(format!(
            "layer at {:.2} mm needs {} bytes of buffered toolpath moves for one path (with the \
             travel before it); the printer's move buffer holds {} bytes: a path too long for \
             this printer's memory",
            mm(m.z_um),
            m.value,
            caps.move_buffer_bytes
        ));
    }
    out
}

/// The deviation between the original `a` (indexed as `mesh`) and the simplification `b`,
/// mm: a two-sided estimate (every original vertex against `b`, 13 samples of every
/// triangle of `b` against `a`).
fn deviation(mesh: &Indexed, a: &[Triangle], b: &[Triangle]) -> f64 {
    let (sa, sb) = (Surface::new(a), Surface::new(b));
    let there = mesh.points.iter().map(|p| sb.distance(mm(*p))).fold(0.0, f64::max);
    let back = b
        .iter()
        .flat_map(|t| {
            let v = t.v.map(mm);
            BARY.map(|w| [0, 1, 2].map(|k| w[0] * v[0][k] + w[1] * v[1][k] + w[2] * v[2][k]))
        })
        .map(|p| sa.distance(p))
        .fold(0.0, f64::max);
    there.max(back)
}

/// An indexed mesh with welded (bit-identical) vertices, positions in mm.
struct Indexed {
    points: Vec<Point3>,
    positions: Vec<[f32; 3]>,
    indices: Vec<u32>,
}

impl Indexed {
    fn weld(tris: &[Triangle]) -> Self {
        let (points, indices) = simplify::weld(tris);
        let positions =
            points.iter().map(|p| [p.x as f32 / 1e3, p.y as f32 / 1e3, p.z as f32 / 1e3]).collect();
        Self { points, positions, indices }
    }

    /// meshopt towards `target` triangles, no error limit; the triangles keep original
    /// vertices (exact um).
    fn simplify(&self, target: usize) -> Vec<Triangle> {
        let idx = simplify_decoder(
            &self.indices,
            &self.positions,
            target * 3,
            f32::MAX,
            SimplifyOptions::ErrorAbsolute,
            None,
        );
        self.triangles(&idx)
    }

    /// Triangles of an index list (original vertices, exact um).
    fn triangles(&self, idx: &[u32]) -> Vec<Triangle> {
        idx.chunks_exact(3)
            .map(|c| Triangle { v: [0, 1, 2].map(|k| self.points[c[k] as usize]) })
            .collect()
    }
}

/// A triangle in mm for the R-tree.
struct TriMm([V; 3]);

impl RTreeObject for TriMm {
    type Envelope = AABB<V>;

    fn envelope(&self) -> AABB<V> {
        let [a, b, c] = self.0;
        AABB::from_corners(
            [0, 1, 2].map(|k| a[k].min(b[k]).min(c[k])),
            [0, 1, 2].map(|k| a[k].max(b[k]).max(c[k])),
        )
    }
}

impl PointDistance for TriMm {
    fn distance_2(&self, p: &V) -> f64 {
        dist2_point_triangle(*p, self.0[0], self.0[1], self.0[2])
    }
}

/// A surface for exact nearest-distance queries (an R-tree of its triangles).
struct Surface(RTree<TriMm>);

impl Surface {
    fn new(tris: &[Triangle]) -> Self {
        Self(RTree::bulk_load(tris.iter().map(|t| TriMm(t.v.map(mm))).collect()))
    }

    /// Distance from `p` to the surface, mm (infinite for an empty surface).
    fn distance(&self, p: V) -> f64 {
        self.0.nearest_neighbor(&p).map_or(f64::INFINITY, |t| t.distance_2(&p).sqrt())
    }
}

/// Two-sided Hausdorff estimate between two surfaces, mm: every vertex of `a` against `b`,
/// and 13 sample points of every triangle of `b` (corners, edge midpoints, centroid, 6
/// interior) against `a`.
pub fn hausdorff_mm(a: &[Triangle], b: &[Triangle]) -> f64 {
    let mesh = Indexed::weld(a);
    deviation(&mesh, a, b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tri(a: [i32; 3], b: [i32; 3], c: [i32; 3]) -> Triangle {
        let p = |v: [i32; 3]| Point3::new(v[0], v[1], v[2]);
        Triangle { v: [p(a), p(b), p(c)] }
    }

    #[test]
    fn point_triangle_distance() {
        let (a, b, c) = ([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
        let d = |p: V| dist2_point_triangle(p, a, b, c).sqrt();
        assert!((d([0.2, 0.2, 0.5]) - 0.5).abs() < 1e-12);
        assert!((d([2.0, 0.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((d([-1.0, -1.0, 0.0]) - 2f64.sqrt()).abs() < 1e-12);
        assert!((d([1.0, 1.0, 0.0]) - 0.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn hausdorff_of_a_plane_and_a_bump() {
        let mut fine = Vec::new();
        for i in 0..10 {
            for j in 0..10 {
                let (x, y) = (i * 1000, j * 1000);
                fine.push(tri([x, y, 0], [x + 1000, y, 0], [x + 1000, y + 1000, 0]));
                fine.push(tri([x, y, 0], [x + 1000, y + 1000, 0], [x, y + 1000, 0]));
            }
        }
        let coarse = vec![
            tri([0, 0, 0], [10_000, 0, 0], [10_000, 10_000, 0]),
            tri([0, 0, 0], [10_000, 10_000, 0], [0, 10_000, 0]),
        ];
        assert!(hausdorff_mm(&fine, &coarse) < 1e-9);
        // Raise one inner vertex by 50 um.
        for t in &mut fine {
            for p in &mut t.v {
                if p.x == 5000 && p.y == 5000 {
                    p.z = 50;
                }
            }
        }
        let h = hausdorff_mm(&fine, &coarse);
        assert!((h - 0.05).abs() < 1e-9, "{h}");
    }
}

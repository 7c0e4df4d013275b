//! Measurements on recorded steps: timing error against the reference, speeds and
//! accelerations with error bounds derived from the step-time tolerance.

use strata::machine::AXES;

use super::reference::{self, RefMove};
use super::{JobConfig, JobResult, StepRec};

/// Largest allowed error of an executed step against its ideal time, s.
pub const STEP_TOL_S: f64 = 1e-6;

/// Timing of the recorded steps against the reference.
#[derive(Debug, Clone, Copy, Default)]
pub struct TimingReport {
    /// Largest |recorded - ideal|, s.
    pub max_err_s: f64,
    /// Where: axis and step index.
    pub worst: (usize, usize),
    /// Steps compared.
    pub steps: usize,
}

/// Compares every recorded step with the reference: same count and directions per axis,
/// and the time error of each.
pub fn compare_steps(r: &JobResult, plan: &[RefMove], cfg: &JobConfig) -> TimingReport {
    let ideal = reference::ideal_steps(plan, cfg);
    let hz = cfg.step.timer_hz as f64;
    let mut rep = TimingReport::default();
    for a in 0..AXES {
        let rec = &r.rec.steps[a];
        assert_eq!(rec.len(), ideal[a].len(), "axis {a}: step count vs reference");
        for (i, (s, &(t, up))) in rec.iter().zip(&ideal[a]).enumerate() {
            assert_eq!(s.positive, up, "axis {a} step {i}: direction");
            let err = (s.tick as f64 - r.gen0_tick as f64) / hz - t;
            if err.abs() > rep.max_err_s {
                rep.max_err_s = err.abs();
                rep.worst = (a, i);
            }
        }
        rep.steps += rec.len();
    }
    rep
}

/// Speed and acceleration limits seen in the recorded steps.
#[derive(Debug, Clone, Copy, Default)]
pub struct LimitReport {
    /// Largest measured axis speed / axis maximum (tolerance already removed: <= 1 passes).
    pub axis_speed_ratio: f64,
    /// Largest measured path speed / feed rate of its move (likewise).
    pub feed_ratio: f64,
    /// Largest measured axis acceleration / axis maximum (likewise).
    pub axis_accel_ratio: f64,
    /// Largest measured path acceleration / the move's acceleration limit (likewise).
    pub path_accel_ratio: f64,
    /// Largest |measured - reference| acceleration over its error bound.
    pub accel_vs_reference: f64,
    /// Velocity windows and acceleration phases checked.
    pub windows: usize,
    pub phases: usize,
}

fn tick_s(r: &JobResult, cfg: &JobConfig, t: u64) -> f64 {
    (t as f64 - r.gen0_tick as f64) / cfg.step.timer_hz as f64
}

/// Average speed over the steps `i..=j` (same direction), steps/s, and the factor by which
/// a step-time error of [`STEP_TOL_S`] can inflate it.
fn window_speed(s: &[StepRec], i: usize, j: usize, hz: f64) -> (f64, f64) {
    let dt = (s[j].tick - s[i].tick) as f64 / hz;
    let v = (j - i) as f64 / dt;
    (v, dt / (dt - 2.0 * STEP_TOL_S))
}

/// Checks speeds and accelerations against the limits of `cfg` and the reference plan:
/// - per axis, every window of steps in one direction spanning >= `window_s`: speed <= axis
///   maximum x the window's error factor;
/// - per kinematic move, windows of its dominant axis inside the move: path speed <= feed
///   rate x error factor;
/// - per acceleration or deceleration phase with enough steps: the acceleration from three
///   equally spaced steps (exact for constant acceleration) within its worst-case error
///   (every time off by [`STEP_TOL_S`]) of the reference, and below the axis and path
///   limits.
pub fn check_limits(
    r: &JobResult,
    plan: &[RefMove],
    cfg: &JobConfig,
    window_s: f64,
) -> LimitReport {
    let hz = cfg.step.timer_hz as f64;
    let spm = cfg.step.steps_per_mm.map(|x| x.to_num::<f64>());
    let vmax = cfg.plan.max_feed_mm_s.map(|x| x.to_num::<f64>());
    let amax = cfg.plan.max_accel_mm_s2.map(|x| x.to_num::<f64>());
    let mut rep = LimitReport::default();
    for a in 0..AXES {
        let s = &r.rec.steps[a];
        let mut i = 0;
        while i < s.len() {
            let mut j = i + 1;
            while j < s.len()
                && s[j].positive == s[i].positive
                && ((s[j].tick - s[i].tick) as f64) < window_s * hz
            {
                j += 1;
            }
            if j >= s.len() || s[j].positive != s[i].positive {
                i = j.max(i + 1);
                continue;
            }
            let (v, k) = window_speed(s, i, j, hz);
            let ratio = v / spm[a] / (vmax[a] * k);
            rep.axis_speed_ratio = rep.axis_speed_ratio.max(ratio);
            assert!(ratio <= 1.0, "axis {a} at {v} steps/s over its maximum (window {i}..{j})");
            rep.windows += 1;
            i += ((j - i) / 4).max(1);
        }
    }
    for m in plan {
        let (t0, t1) = (m.t0, m.t0 + m.duration());
        // Dominant axis (in steps).
        let a = (0..AXES)
            .max_by(|&x, &y| (m.d[x].abs() * spm[x]).total_cmp(&(m.d[y].abs() * spm[y])))
            .unwrap();
        let s = &r.rec.steps[a];
        let lo = s.partition_point(|x| tick_s(r, cfg, x.tick) < t0);
        let hi = s.partition_point(|x| tick_s(r, cfg, x.tick) <= t1);
        if hi < lo + 3 {
            continue;
        }
        let steps = &s[lo..hi];
        let ratio = m.ratio(a).abs();
        // Path speed over windows.
        let mut i = 0;
        while i + 1 < steps.len() {
            let mut j = i + 1;
            while j + 1 < steps.len() && ((steps[j].tick - steps[i].tick) as f64) < window_s * hz {
                j += 1;
            }
            let (v, k) = window_speed(steps, i, j, hz);
            let path = v / spm[a] / ratio;
            let fr = path / (m.feed * k);
            rep.feed_ratio = rep.feed_ratio.max(fr);
            assert!(fr <= 1.0, "move {}: path speed {path} mm/s over feed {}", m.index, m.feed);
            i = j;
        }
        // Accelerations per phase.
        for (p0, p1, sign) in [(t0, t0 + m.ta, 1.0), (t0 + m.ta + m.tc, t1, -1.0)] {
            if p1 - p0 < 5e-3 {
                continue;
            }
            let lo = steps.partition_point(|x| tick_s(r, cfg, x.tick) < p0);
            let hi = steps.partition_point(|x| tick_s(r, cfg, x.tick) <= p1);
            if hi < lo + 7 {
                continue;
            }
            let k = (hi - lo - 1) / 2;
            let t = [lo, lo + k, lo + 2 * k].map(|i| tick_s(r, cfg, steps[i].tick));
            let acc = |t: [f64; 3]| {
                let v1 = k as f64 / (t[1] - t[0]);
                let v2 = k as f64 / (t[2] - t[1]);
                (v2 - v1) / ((t[2] - t[0]) / 2.0) / spm[a]
            };
            let est = acc(t);
            let mut err: f64 = 0.0;
            for signs in 0..8 {
                let mut tt = t;
                for (b, x) in tt.iter_mut().enumerate() {
                    *x += if signs >> b & 1 == 1 { STEP_TOL_S } else { -STEP_TOL_S };
                }
                err = err.max((acc(tt) - est).abs());
            }
            // The reference axis acceleration in this phase (speed magnitude of the axis).
            let want = sign * m.accel * ratio;
            rep.accel_vs_reference =
                rep.accel_vs_reference.max((est.abs() - want.abs()).abs() / err);
            let axis_ratio = (est.abs() - err) / amax[a];
            let path_limit = match m.kind {
                strata::plan::MoveKind::Print => cfg.plan.print_accel_mm_s2,
                _ => cfg.plan.travel_accel_mm_s2,
            }
            .to_num::<f64>();
            let path_ratio = ((est.abs() - err) / ratio) / path_limit;
            rep.axis_accel_ratio = rep.axis_accel_ratio.max(axis_ratio);
            rep.path_accel_ratio = rep.path_accel_ratio.max(path_ratio);
            assert!(axis_ratio <= 1.0, "move {}: axis {a} accel {est} over {}", m.index, amax[a]);
            assert!(
                path_ratio <= 1.0,
                "move {}: path accel {} over {path_limit}",
                m.index,
                est / ratio
            );
            rep.phases += 1;
        }
    }
    rep
}

/// Axis position (steps) at board tick `t` from the recorded crossings, linear between them.
/// Crossing `k` of an axis happens at position `start + k +- 1/2`.
pub fn position_at(steps: &[StepRec], start: i64, t: f64) -> f64 {
    let i = steps.partition_point(|s| (s.tick as f64) <= t);
    let cross = |s: &StepRec| s.position as f64 - if s.positive { 0.5 } else { -0.5 };
    if i == 0 {
        return steps.first().map_or(start as f64, |s| {
            if (s.tick as f64) > t {
                start as f64
            } else {
                cross(s)
            }
        });
    }
    if i == steps.len() {
        return steps[i - 1].position as f64;
    }
    let (a, b) = (&steps[i - 1], &steps[i]);
    let (ca, cb) = (cross(a), cross(b));
    ca + (cb - ca) * (t - a.tick as f64) / (b.tick - a.tick) as f64
}

/// Fits `p = c0 + c1 t + c2 t^2` (least squares) to crossings and returns the speed
/// (steps/s) where the fitted path reaches position `at`.
pub fn speed_at_position(points: &[(f64, f64)], at: f64) -> (f64, f64) {
    // points: (t, p); normal equations for a quadratic.
    let t0 = points[0].0;
    let mut m = [[0.0f64; 4]; 3];
    for &(t, p) in points {
        let x = t - t0;
        let row = [1.0, x, x * x];
        for i in 0..3 {
            for j in 0..3 {
                m[i][j] += row[i] * row[j];
            }
            m[i][3] += row[i] * p;
        }
    }
    for c in 0..3 {
        let piv = m[c][c];
        for j in c..4 {
            m[c][j] /= piv;
        }
        for r in 0..3 {
            if r != c {
                let fct = m[r][c];
                for j in c..4 {
                    m[r][j] -= fct * m[c][j];
                }
            }
        }
    }
    let (c0, c1, c2) = (m[0][3], m[1][3], m[2][3]);
    // Solve c2 x^2 + c1 x + c0 - at = 0 near the data.
    let (a, b, c) = (c2, c1, c0 - at);
    let disc = (b * b - 4.0 * a * c).max(0.0).sqrt();
    let roots = if a.abs() < 1e-18 {
        vec![-c / b]
    } else {
        vec![(-b + disc) / (2.0 * a), (-b - disc) / (2.0 * a)]
    };
    let span = points.last().unwrap().0 - t0;
    let x = roots
        .into_iter()
        .min_by(|p, q| (p - span / 2.0).abs().total_cmp(&(q - span / 2.0).abs()))
        .unwrap();
    (c1 + 2.0 * c2 * x, x + t0)
}

//! An independent `f64` reference: full-knowledge planner over the whole move list (same
//! limits and junction formula as Klipper's toolhead, written from the formulas, with complete
//! backward and forward passes) and the ideal time of every step.

use strata::machine::AXES;
use strata::plan::{Move, MoveKind};

use super::JobConfig;

/// One planned move of the reference.
#[derive(Debug, Clone, Copy)]
pub struct RefMove {
    pub index: usize,
    pub start_um: [i32; AXES],
    pub end_um: [i32; AXES],
    pub kind: MoveKind,
    /// Axis distances, mm.
    pub d: [f64; AXES],
    /// Path length (XYZ, or E for extruder-only), mm.
    pub len: f64,
    pub kinematic: bool,
    pub feed: f64,
    pub accel: f64,
    pub max_cruise_v2: f64,
    pub max_start_v2: f64,
    pub v0: f64,
    pub vc: f64,
    pub v1: f64,
    /// Start time, s.
    pub t0: f64,
    pub ta: f64,
    pub tc: f64,
    pub td: f64,
    pub sa: f64,
    pub sc: f64,
    pub sd: f64,
    /// A dwell's wait, s (0 for a move).
    pub wait: f64,
}

impl RefMove {
    /// Move `index` of `kind` standing at `at`, nothing planned yet (every figure 0; an
    /// acceleration of 1 so that no ramp divides by 0).
    fn still(index: usize, at: [i32; AXES], kind: MoveKind) -> Self {
        Self {
            index,
            start_um: at,
            end_um: at,
            kind,
            d: [0.0; AXES],
            len: 0.0,
            kinematic: false,
            feed: 0.0,
            accel: 1.0,
            max_cruise_v2: 0.0,
            max_start_v2: 0.0,
            v0: 0.0,
            vc: 0.0,
            v1: 0.0,
            t0: 0.0,
            ta: 0.0,
            tc: 0.0,
            td: 0.0,
            sa: 0.0,
            sc: 0.0,
            sd: 0.0,
            wait: 0.0,
        }
    }

    pub fn duration(&self) -> f64 {
        self.ta + self.tc + self.td + self.wait
    }

    /// Path distance per axis distance.
    pub fn ratio(&self, axis: usize) -> f64 {
        self.d[axis] / self.len
    }

    /// Time from the move start at path distance `s` (mm).
    pub fn time_at(&self, s: f64) -> f64 {
        let a = self.accel;
        if s <= self.sa {
            if s <= 0.0 {
                return 0.0;
            }
            2.0 * s / (self.v0 + (self.v0 * self.v0 + 2.0 * a * s).sqrt())
        } else if s <= self.sa + self.sc {
            self.ta + (s - self.sa) / self.vc
        } else {
            let r = (self.len - s).max(0.0);
            if r == 0.0 {
                return self.duration();
            }
            self.duration() - 2.0 * r / (self.v1 + (self.v1 * self.v1 + 2.0 * a * r).sqrt())
        }
    }

    /// Path speed at time `t` from the move start.
    pub fn speed_at(&self, t: f64) -> f64 {
        if t <= self.ta {
            self.v0 + self.accel * t
        } else if t <= self.ta + self.tc {
            self.vc
        } else {
            self.vc - self.accel * (t - self.ta - self.tc)
        }
    }
}

fn f(r: strata::machine::Rate) -> f64 {
    r.to_num::<f64>()
}

/// The full-knowledge plan of `moves` (moves that go nowhere are skipped).
pub fn plan(moves: &[Move], cfg: &JobConfig) -> Vec<RefMove> {
    let pc = &cfg.plan;
    let vmax = pc.max_feed_mm_s.map(f);
    let amax = pc.max_accel_mm_s2.map(f);
    let scv = f(pc.square_corner_velocity_mm_s);
    let ecv = f(pc.extruder_corner_velocity_mm_s);
    let mut out: Vec<RefMove> = Vec::new();
    let mut pos = cfg.start_um;
    for (index, m) in moves.iter().enumerate() {
        if m.kind == MoveKind::Dwell {
            // At rest where the head is, for the wait (its target is not read).
            out.push(RefMove { wait: f(m.feed_mm_s), ..RefMove::still(index, pos, m.kind) });
            continue;
        }
        let d: [f64; AXES] = std::array::from_fn(|i| (m.target_um[i] - pos[i]) as f64 / 1000.0);
        if d.iter().all(|&x| x == 0.0) {
            continue;
        }
        let xyz = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let kinematic = xyz > 0.0;
        let len = if kinematic { xyz } else { d[3].abs() };
        let feed = f(m.feed_mm_s);
        let mut cruise = feed;
        let mut accel = match m.kind {
            MoveKind::Print => f(pc.print_accel_mm_s2),
            _ => f(pc.travel_accel_mm_s2),
        };
        for i in 0..AXES {
            if d[i] != 0.0 {
                cruise = cruise.min(vmax[i] * len / d[i].abs());
                accel = accel.min(amax[i] * len / d[i].abs());
            }
        }
        let max_cruise_v2 = cruise * cruise;
        let mut max_start_v2 = 0.0;
        if let Some(p) = out.last() {
            if p.kinematic && kinematic {
                max_start_v2 = junction_v2(p, &d, len, accel, max_cruise_v2, scv, ecv);
            }
        }
        out.push(RefMove {
            end_um: m.target_um,
            d,
            len,
            kinematic,
            feed,
            accel,
            max_cruise_v2,
            max_start_v2,
            ..RefMove::still(index, pos, m.kind)
        });
        pos = m.target_um;
    }
    // Backward: the largest start speed from which everything after can stop at the end.
    let n = out.len();
    let mut back = vec![0.0; n + 1];
    for i in (0..n).rev() {
        let m = &out[i];
        back[i] = m.max_start_v2.min(back[i + 1] + 2.0 * m.accel * m.len);
    }
    // Forward from rest.
    let mut start = vec![0.0; n + 1];
    for i in 1..n {
        let p = &out[i - 1];
        start[i] = back[i].min(start[i - 1] + 2.0 * p.accel * p.len);
        if p.kind == MoveKind::Dwell {
            start[i] = 0.0;
        }
    }
    start[0] = 0.0;
    let mut t = 0.0;
    for i in 0..n {
        let (s2, e2) = (start[i], if i + 1 < n { start[i + 1] } else { 0.0 });
        let m = &mut out[i];
        let dv2 = 2.0 * m.accel * m.len;
        let c2 = m.max_cruise_v2.min((s2 + e2 + dv2) / 2.0).max(s2).max(e2);
        m.v0 = s2.sqrt();
        m.vc = c2.sqrt();
        m.v1 = e2.sqrt();
        m.sa = (c2 - s2) / (2.0 * m.accel);
        m.sd = ((c2 - e2) / (2.0 * m.accel)).min(m.len - m.sa);
        m.sc = (m.len - m.sa - m.sd).max(0.0);
        m.ta = if m.sa > 0.0 { 2.0 * m.sa / (m.v0 + m.vc) } else { 0.0 };
        m.tc = if m.sc > 0.0 { m.sc / m.vc } else { 0.0 };
        m.td = if m.sd > 0.0 { 2.0 * m.sd / (m.vc + m.v1) } else { 0.0 };
        m.t0 = t;
        t += m.duration();
    }
    out
}

/// Klipper's junction: junction deviation from the square-corner velocity (per move accel),
/// the centripetal cap of both moves, the extruder's velocity jump and both cruise limits.
fn junction_v2(
    p: &RefMove,
    d: &[f64; AXES],
    len: f64,
    accel: f64,
    max_cruise_v2: f64,
    scv: f64,
    ecv: f64,
) -> f64 {
    let dot = p.d[0] * d[0] + p.d[1] * d[1] + p.d[2] * d[2];
    let jcos = -dot / (p.len * len);
    if jcos > 0.999999 {
        // Klipper: (nearly) a reversal stops.
        return 0.0;
    }
    let mut v2 = max_cruise_v2.min(p.max_cruise_v2);
    let sin_half = (0.5 * (1.0 - jcos)).max(0.0).sqrt();
    let cos_half = (0.5 * (1.0 + jcos)).max(0.0).sqrt();
    if cos_half > 1e-9 {
        let jd = |a: f64| scv * scv * (2f64.sqrt() - 1.0) / a;
        let r = |a: f64| jd(a) * sin_half / (1.0 - sin_half);
        let tan_half = sin_half / cos_half;
        v2 = v2
            .min(r(accel) * accel)
            .min(r(p.accel) * p.accel)
            .min(0.5 * len * tan_half * accel)
            .min(0.5 * p.len * tan_half * p.accel);
    }
    let dr = d[3] / len - p.d[3] / p.len;
    if dr != 0.0 {
        v2 = v2.min((ecv / dr.abs()).powi(2));
    }
    v2
}

/// Integer steps/mm of each axis (the reference needs exact ties).
fn spm(cfg: &JobConfig) -> [i64; AXES] {
    cfg.step.steps_per_mm.map(|r| {
        assert_eq!(r.frac(), 0, "reference supports integer steps/mm only");
        r.to_num::<i64>()
    })
}

/// Motor position of a fresh start at `um`: nearest step, half up.
fn nearest(um: i32, spm: i64) -> i64 {
    (um as i64 * spm + 500).div_euclid(1000)
}

/// Motor positions at the start.
pub fn start_steps(cfg: &JobConfig) -> [i64; AXES] {
    let s = spm(cfg);
    std::array::from_fn(|a| nearest(cfg.start_um[a], s[a]))
}

/// Motor positions after `moves`: a step whenever the ideal position (`um * spm / 1000`,
/// exact rational) moves strictly past a half-step boundary.
pub fn expected_positions(moves: &[Move], cfg: &JobConfig) -> [i64; AXES] {
    let s = spm(cfg);
    let mut m = start_steps(cfg);
    for mv in moves.iter().filter(|m| m.kind != MoveKind::Dwell) {
        for a in 0..AXES {
            let n1 = mv.target_um[a] as i64 * s[a];
            while n1 > 1000 * m[a] + 500 {
                m[a] += 1;
            }
            while n1 < 1000 * m[a] - 500 {
                m[a] -= 1;
            }
        }
    }
    m
}

/// Ideal step (time in s from the start of the plan, positive direction) per axis.
pub fn ideal_steps(plan: &[RefMove], cfg: &JobConfig) -> [Vec<(f64, bool)>; AXES] {
    let s = spm(cfg);
    let mut out: [Vec<(f64, bool)>; AXES] = Default::default();
    let mut m = start_steps(cfg);
    for mv in plan {
        for a in 0..AXES {
            let n0 = mv.start_um[a] as i64 * s[a];
            let n1 = mv.end_um[a] as i64 * s[a];
            if n1 == n0 {
                continue;
            }
            let span = (n1 - n0) as f64;
            loop {
                let (b, up) =
                    if n1 > n0 { (1000 * m[a] + 500, true) } else { (1000 * m[a] - 500, false) };
                let crosses = if up { n1 > b } else { n1 < b };
                if !crosses {
                    break;
                }
                let frac = (b - n0) as f64 / span;
                let t = mv.t0 + mv.time_at(frac * mv.len);
                out[a].push((t, up));
                m[a] += if up { 1 } else { -1 };
            }
        }
    }
    out
}

/// Total duration of the reference plan, s.
pub fn total_time(plan: &[RefMove]) -> f64 {
    plan.last().map_or(0.0, |m| m.t0 + m.duration())
}

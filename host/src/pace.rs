//! Whether the link keeps ahead of the print.
//!
//! The device cuts layer `L` once every triangle below its plane has arrived (the stream is
//! sorted by lowest z), and the motion needs layer `L`'s first moves when the layers before it
//! have printed. Printing starts once layer 0 is cut, so with `B(L)` the wire bytes of the
//! frames that carry the triangles up to the one that completes plane `L` and `T(L)` the print
//! time of the layers before `L`, the link keeps ahead when, for every layer,
//! `B(L) / rate - B(0) / rate <= T(L)`. A model whose triangles are dense for its size (a 2 mm
//! scan of 80,000 triangles prints in seconds and takes tens of seconds to stream) falls behind:
//! the printer pauses, waiting for the link, and the nozzle oozes where it stands.
//!
//! [`LayerClock`] gives `T(L)`: the toolpath stage's moves through the device's planner (the
//! machine's limits, its lookahead), whose block times are the print time. [`stream_bytes`]
//! gives `B(L)`: the frames the host builds ([`strata::protocol::BatchBuilder`], the framing's
//! exact wire length). The rate is the baud rate's bytes (10 bits a byte) times
//! [`LINK_EFFICIENCY`].

use strata::geom::Triangle;
use strata::machine::MachineConfig;
use strata::move_ring::MoveStream;
use strata::plan::{PlanConfig, Planner};
use strata::printer::board::LOOKAHEAD_MOVES;
use strata::protocol::{frame, BatchBuilder};
use strata::slice::SliceConfig;
use strata::toolpath::{Feature, ToolEvent};

/// Share of the baud rate's bytes the triangle frames are assumed to get.
///
/// Streaming flat out, the simulated link delivers 0.99 of them (`strata simulate
/// ../shared/models/rockerarm_genus1.stl --max-deviation 0.05 --json`: 55,092 B of frames in
/// 2.216 s at 250000 baud); 0.9 leaves room for acknowledgements, resends and the board's
/// single receive slot.
pub const LINK_EFFICIENCY: f64 = 0.9;

/// Print time of each layer's start, from the toolpath stage's events.
pub struct LayerClock {
    stream: MoveStream,
    planner: Box<Planner<LOOKAHEAD_MOVES>>,
    /// Print time before each layer's first move, s (index = layer).
    starts_s: Vec<f64>,
    /// Whether each layer extrudes (index = layer): some have only their height change (a
    /// mesh thinner than a line, a part that ends below the layer's plane).
    extrudes: Vec<bool>,
}

impl LayerClock {
    /// A clock at the job's start (the origin, at rest), planning with `machine`'s limits.
    pub fn new(machine: &MachineConfig) -> Self {
        let planner = Box::new(Planner::new(&PlanConfig::from_machine(machine), [0; 4]));
        Self { stream: MoveStream::new(), planner, starts_s: Vec::new(), extrudes: Vec::new() }
    }

    /// Takes one event of the toolpath stage (as the device's move buffer takes it).
    pub fn event(&mut self, e: &ToolEvent<'_>) {
        match e {
            ToolEvent::LayerStart { index, .. } => {
                self.stream.start_layer(*index);
                let now = self.now_s();
                let layer = *index as usize;
                if self.starts_s.len() <= layer {
                    self.starts_s.resize(layer + 1, now);
                    self.extrudes.resize(layer + 1, false);
                }
            }
            ToolEvent::Move(m) => {
                if m.e_um > 0 && m.feature != Feature::Unretract {
                    if let Some(x) = self.extrudes.last_mut() {
                        *x = true;
                    }
                }
                let mv = self.stream.next(m).unpack();
                while self.planner.pop().is_some() {}
                if self.planner.is_full() {
                    self.planner.pop_forced();
                }
                // A move the planner refuses (zero feed) takes no time on the device either.
                let _ = self.planner.push(mv);
            }
            ToolEvent::LayerEnd(_) | ToolEvent::Progress => {}
        }
    }

    /// Planned print time so far (released and queued blocks), s.
    fn now_s(&self) -> f64 {
        self.planner.total_time_s().to_num::<f64>()
    }

    /// Print time before each layer's first move (index = layer), of the whole job (s), and
    /// whether each layer extrudes.
    pub fn finish(self) -> (Vec<f64>, f64, Vec<bool>) {
        let total = self.now_s();
        (self.starts_s, total, self.extrudes)
    }
}

/// Wire bytes the host has sent when the device can cut each layer (index = layer).
///
/// The frames up to the one carrying the first triangle at or above the layer's plane (all of
/// them for the layers the last triangle completes). `tris` sorted by lowest z, as streamed.
pub fn stream_bytes(tris: &[Triangle], config: &SliceConfig) -> Vec<u64> {
    let layers = config.layer_count() as usize;
    let mut needed = vec![0u64; layers];
    let mut sent = 0u64;
    let mut next_layer = 0usize;
    let mut batch = BatchBuilder::new();
    let mut start = 0usize;
    while start < tris.len() {
        batch.clear();
        let mut end = start;
        while end < tris.len() && batch.push(&tris[end]).is_ok() {
            end += 1;
        }
        if end == start {
            // A triangle no batch takes cannot be streamed at all (the session refuses it too).
            break;
        }
        sent += frame::wire_len(batch.payload()) as u64;
        // Planes completed by a triangle of this frame: its lowest z at or above them.
        let top = i64::from(tris[end - 1].z_min());
        while next_layer < layers && config.plane_z_um(next_layer as u32) <= top {
            needed[next_layer] = sent;
            next_layer += 1;
        }
        start = end;
    }
    needed[next_layer..].fill(sent);
    needed
}

/// How far the link falls behind the print.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pace {
    /// The largest lag, s: how long the printer would wait for the link at `layer` (0 or
    /// less: it never waits).
    pub worst_lag_s: f64,
    /// The layer where the lag is largest.
    pub layer: u32,
    /// Time the whole stream takes on the wire, s.
    pub stream_s: f64,
    /// Print time of the whole job, s.
    pub print_s: f64,
}

impl Pace {
    /// True when the link keeps ahead of every layer.
    pub fn keeps_ahead(&self) -> bool {
        self.worst_lag_s <= 0.0
    }

    /// The warning for `model` when the link at `baud` cannot stream it ahead of its print.
    pub fn warning(&self, model: &std::path::Path, baud: u32) -> String {
        format!(
            "{}: warning: at {baud} baud the link cannot stream this model ahead of its print: \
             the printer will wait up to {:.1} s for it at layer {} (streaming takes {:.1} s, \
             printing {:.1} s); allow more simplification (--max-deviation) or a faster link \
             (--baud)",
            model.display(),
            self.worst_lag_s,
            self.layer,
            self.stream_s,
            self.print_s
        )
    }
}

/// The lag of the link behind the print at every layer, for `bytes` ([`stream_bytes`]) and the
/// layers' print start times `starts_s` ([`LayerClock`]) at `baud`.
pub fn pace(bytes: &[u64], starts_s: &[f64], print_s: f64, baud: u32) -> Pace {
    let rate = f64::from(baud) / 10.0 * LINK_EFFICIENCY;
    let first = bytes.first().copied().unwrap_or(0) as f64 / rate;
    let mut worst = Pace {
        worst_lag_s: f64::NEG_INFINITY,
        layer: 0,
        stream_s: bytes.last().copied().unwrap_or(0) as f64 / rate,
        print_s,
    };
    for (layer, (&b, &start)) in bytes.iter().zip(starts_s).enumerate() {
        let lag = b as f64 / rate - first - start;
        if lag > worst.worst_lag_s {
            worst.worst_lag_s = lag;
            worst.layer = layer as u32;
        }
    }
    if worst.worst_lag_s == f64::NEG_INFINITY {
        worst.worst_lag_s = 0.0;
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;
    use strata::geom::Point3;

    fn config(layers: i32) -> SliceConfig {
        SliceConfig {
            first_layer_height_um: 200,
            layer_height_um: 200,
            model_height_um: 200 * layers,
            min_loop_area_um2: 0,
            join_tolerance_um: 20,
            max_gap_um: 2_000,
        }
    }

    /// A thin triangle from `z0` to `z1`, um (distinct corners so the coder cannot shorten it
    /// much).
    fn tri(i: i32, z0: i32, z1: i32) -> Triangle {
        Triangle {
            v: [
                Point3::new(1_000 + i, 2_000, z0),
                Point3::new(3_000, 4_000 + i, z1),
                Point3::new(5_000 + i, 1_000 + 3 * i, z1),
            ],
        }
    }

    #[test]
    fn each_layer_waits_for_the_frames_up_to_the_triangle_above_its_plane() {
        // Planes at 100, 300, 500, 700 um; 40 triangles starting below each plane.
        let cfg = config(4);
        let mut tris = Vec::new();
        for layer in 0..4 {
            for i in 0..40 {
                tris.push(tri(i, layer * 200, layer * 200 + 150));
            }
        }
        let bytes = stream_bytes(&tris, &cfg);
        assert_eq!(bytes.len(), 4);
        // Independent count: whole frames in order, each as full as a batch takes.
        let mut frames = Vec::new();
        let mut b = BatchBuilder::new();
        for t in &tris {
            if b.push(t).is_err() {
                frames.push((b.len(), frame::wire_len(b.payload()) as u64));
                b.clear();
                b.push(t).unwrap();
            }
        }
        frames.push((b.len(), frame::wire_len(b.payload()) as u64));
        let total: u64 = frames.iter().map(|f| f.1).sum();
        assert_eq!(*bytes.last().unwrap(), total);
        // Layer 0 needs the first triangle at or above plane 0 (100 um): triangle 40, of the
        // frame that holds it.
        let mut seen = 0;
        let mut upto = 0;
        for &(n, w) in &frames {
            seen += n;
            upto += w;
            if seen > 40 {
                break;
            }
        }
        assert_eq!(bytes[0], upto);
        assert!(bytes.windows(2).all(|w| w[0] <= w[1]));
    }

    #[test]
    fn the_lag_is_the_stream_time_beyond_the_print_time_before_the_layer() {
        // 10,000 B per layer at 100,000 baud (9,000 B/s): 1.11 s a layer on the wire.
        let bytes = [10_000, 20_000, 30_000, 40_000];
        let rate = 100_000.0 / 10.0 * LINK_EFFICIENCY;
        // Layers that print in 2 s: the link keeps ahead by 0.89 s a layer.
        let p = pace(&bytes, &[0.0, 2.0, 4.0, 6.0], 8.0, 100_000);
        assert!(p.keeps_ahead());
        assert!((p.worst_lag_s - 0.0).abs() < 1e-9, "layer 0 has no lag: {p:?}");
        // Layers that print in 0.5 s: layer 3 waits 3 x (1.11 - 0.5) s.
        let p = pace(&bytes, &[0.0, 0.5, 1.0, 1.5], 2.0, 100_000);
        assert!(!p.keeps_ahead());
        assert_eq!(p.layer, 3);
        assert!((p.worst_lag_s - (30_000.0 / rate - 1.5)).abs() < 1e-9, "{p:?}");
        assert!((p.stream_s - 40_000.0 / rate).abs() < 1e-9);
    }
}

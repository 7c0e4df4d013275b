//! The firmware's `TAG key=value` lines on QEMU's standard output (`COST`, `STEPS`, `MEM`,
//! `JOB`, `CLOCK`): parsed into [`Record`]s, a job's [`Costs`] and their [`CostSummary`] at the
//! Creality board's clock.

use std::collections::BTreeMap;

/// One `TAG key=value ...` line of the firmware's standard output.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Record {
    /// The first word (`COST`, `MEM`, `STEPS`, `JOB`).
    pub tag: String,
    /// The `key=value` pairs with decimal integer values.
    pub fields: BTreeMap<String, u64>,
    /// Every `key=value` pair as written.
    pub text: BTreeMap<String, String>,
}

/// Parses `TAG k=v k=v` (a tag in capitals, then only `key=value` words); `None` for other
/// lines.
pub fn parse_record(line: &str) -> Option<Record> {
    let mut words = line.split_whitespace();
    let tag = words.next()?;
    if !tag.chars().all(|c| c.is_ascii_uppercase() || c == '_') {
        return None;
    }
    let mut fields = BTreeMap::new();
    let mut text = BTreeMap::new();
    for w in words {
        let (k, v) = w.split_once('=')?;
        if let Ok(n) = v.parse::<u64>() {
            fields.insert(k.to_string(), n);
        }
        text.insert(k.to_string(), v.to_string());
    }
    (!text.is_empty()).then(|| Record { tag: tag.to_string(), fields, text })
}

/// The firmware's cost, step and memory lines of one job.
#[derive(Debug, Clone, Default)]
pub struct Costs {
    /// Per layer (`COST layer=K ...`): layer, instructions for toolpath and planning, print
    /// time in timer ticks.
    pub layers: Vec<LayerCost>,
    /// Every other record (job, interrupt, steps and memory lines).
    pub records: Vec<Record>,
}

/// One layer's cost.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LayerCost {
    /// Layer index.
    pub layer: u64,
    /// Instructions spent on the layer's toolpath and planning.
    pub compute_insns: u64,
    /// The slicing and toolpath part of `compute_insns` (the rest: planning, steps).
    pub service_insns: u64,
    /// The layer's print time, timer ticks.
    pub print_ticks: u64,
}

impl Costs {
    /// Collects the records of `lines`.
    pub fn parse(lines: &[String]) -> Self {
        let mut c = Self::default();
        for r in lines.iter().filter_map(|l| parse_record(l)) {
            match (r.fields.get("layer"), r.tag.as_str()) {
                (Some(&layer), "COST") => c.layers.push(LayerCost {
                    layer,
                    compute_insns: first(&r, &["compute_insns", "insns"]).unwrap_or(0),
                    service_insns: first(&r, &["service_insns"]).unwrap_or(0),
                    print_ticks: first(&r, &["print_ticks", "ticks"]).unwrap_or(0),
                }),
                _ => c.records.push(r),
            }
        }
        c
    }

    /// The last value of the first of `keys` a record tagged `tag` has.
    pub fn get(&self, tag: &str, keys: &[&str]) -> Option<u64> {
        self.record(tag, keys).and_then(|(r, k)| r.fields.get(k).copied())
    }

    /// The same as written (e.g. a hexadecimal hash).
    pub fn text(&self, tag: &str, keys: &[&str]) -> Option<&str> {
        self.record(tag, keys).and_then(|(r, k)| r.text.get(k).map(String::as_str))
    }

    fn record<'k>(&self, tag: &str, keys: &[&'k str]) -> Option<(&Record, &'k str)> {
        keys.iter().find_map(|&k| {
            self.records
                .iter()
                .rev()
                .find(|r| r.tag == tag && r.text.contains_key(k))
                .map(|r| (r, k))
        })
    }

    /// The firmware's `STEPS` line: steps per axis and final positions (X, Y, Z, E), the
    /// executed print time in timer ticks.
    pub fn steps(&self) -> Option<StepsLine> {
        let axes = ["x", "y", "z", "e"];
        let mut s = StepsLine::default();
        for (a, k) in axes.iter().enumerate() {
            s.steps[a] = self.get("STEPS", &[k])?;
            s.positions[a] = self.text("STEPS", &[&format!("pos_{k}")])?.parse().ok()?;
        }
        s.print_ticks = self.get("STEPS", &["print_ticks"]);
        s.hash = self.text("STEPS", &["hash"]).and_then(|h| u64::from_str_radix(h, 16).ok());
        s.late_dir_steps = self.get("STEPS", &["late_dir_steps"]);
        s.edge_ticks_max = self.get("STEPS", &["edge_ticks_max"]);
        Some(s)
    }
}

/// What the firmware's `STEPS` line says.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct StepsLine {
    /// Steps per axis.
    pub steps: [u64; 4],
    /// Final positions, steps.
    pub positions: [i64; 4],
    /// Executed print time, timer ticks.
    pub print_ticks: Option<u64>,
    /// Hash of every step (axis, direction, tick).
    pub hash: Option<u64>,
    /// Steps the executor delayed for DIR's setup time.
    pub late_dir_steps: Option<u64>,
    /// The longest a rising edge came after its commanded tick, timer ticks.
    pub edge_ticks_max: Option<u64>,
}

fn first(r: &Record, keys: &[&str]) -> Option<u64> {
    keys.iter().find_map(|k| r.fields.get(*k).copied())
}

/// Clock of the cost model: the Creality board's 72 MHz Cortex-M3.
pub const CPU_HZ: f64 = 72e6;
/// Cycles per instruction assumed (flash wait states, loads, branches).
pub const CYCLES_PER_INSN: f64 = 1.5;

/// The cost figures of one job.
#[derive(Debug, Clone, Copy, Default)]
pub struct CostSummary {
    /// Triangles sliced.
    pub triangles: u64,
    /// Slicing instructions per triangle.
    pub insns_per_triangle: f64,
    /// Layers with a cost line.
    pub layers: usize,
    /// Toolpath and planning instructions per layer, mean.
    pub layer_insns_mean: f64,
    /// The same, largest.
    pub layer_insns_max: u64,
    /// Interrupt instructions per step, mean.
    pub isr_insns_per_step: f64,
    /// Interrupt invocations (with the QEMU board's virtual clock, also those without a step).
    pub isr_calls: u64,
    /// Interrupt instructions per invocation, mean.
    pub isr_insns_per_call: f64,
    /// The most instructions of one interrupt.
    pub isr_insns_max: u64,
    /// Steps the interrupt made.
    pub steps: u64,
    /// Worst layer's real-time factor at [`CPU_HZ`] and [`CYCLES_PER_INSN`]: its print time
    /// over its compute time.
    pub worst_rtf: f64,
    /// Which layer.
    pub worst_rtf_layer: u64,
    /// Layers that extrude nothing (only their height change: nothing to print in real
    /// time, so left out of the worst factor).
    pub idle_layers: usize,
    /// Print time of those layers, s.
    pub idle_print_s: f64,
    /// Compute time of those layers at [`CPU_HZ`] and [`CYCLES_PER_INSN`], s.
    pub idle_compute_s: f64,
    /// The longest stretch of slicing and toolpath work without step generation in thread
    /// mode (the step queue must cover it), instructions.
    pub gen_gap_max_insns: u64,
    /// RAM in `.data` and `.bss`, bytes.
    pub data_bss: Option<u64>,
    /// Deepest stack use seen, bytes.
    pub stack_hwm: Option<u64>,
}

impl CostSummary {
    /// The figures of `c`, with print ticks at `timer_hz`; `extrudes[k]` false marks layer
    /// `k` as extruding nothing (layers beyond `extrudes` count as extruding).
    pub fn of(c: &Costs, timer_hz: f64, extrudes: &[bool]) -> Self {
        let triangles = c.get("COST", &["triangles"]).unwrap_or(0);
        let slice = c.get("COST", &["slice_insns"]).unwrap_or(0);
        let steps = c.get("COST", &["steps"]).unwrap_or(0);
        let isr_total = c.get("COST", &["isr_insns_total", "isr_insns"]).unwrap_or(0);
        let isr_calls = c.get("COST", &["isr_calls"]).unwrap_or(0);
        let n = c.layers.len();
        let total: u64 = c.layers.iter().map(|l| l.compute_insns).sum();
        let mut worst = (f64::INFINITY, 0);
        let (mut idle_layers, mut idle_print_s, mut idle_compute_s) = (0, 0.0, 0.0);
        for l in &c.layers {
            let compute_s = l.compute_insns as f64 * CYCLES_PER_INSN / CPU_HZ;
            let print_s = l.print_ticks as f64 / timer_hz;
            if extrudes.get(l.layer as usize) == Some(&false) {
                idle_layers += 1;
                idle_print_s += print_s;
                idle_compute_s += compute_s;
            } else if compute_s > 0.0 && print_s / compute_s < worst.0 {
                worst = (print_s / compute_s, l.layer);
            }
        }
        Self {
            triangles,
            insns_per_triangle: slice as f64 / triangles.max(1) as f64,
            layers: n,
            layer_insns_mean: total as f64 / n.max(1) as f64,
            layer_insns_max: c.layers.iter().map(|l| l.compute_insns).max().unwrap_or(0),
            isr_insns_per_step: isr_total as f64 / steps.max(1) as f64,
            isr_calls,
            isr_insns_per_call: isr_total as f64 / isr_calls.max(1) as f64,
            isr_insns_max: c.get("COST", &["isr_insns_max", "isr_max"]).unwrap_or(0),
            steps,
            worst_rtf: worst.0,
            worst_rtf_layer: worst.1,
            idle_layers,
            idle_print_s,
            idle_compute_s,
            gen_gap_max_insns: c.get("COST", &["gen_gap_max_insns"]).unwrap_or(0),
            data_bss: c.get("MEM", &["data_bss"]),
            stack_hwm: c.get("MEM", &["stack_hwm"]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cost_lines_parse_and_summarise() {
        let lines: Vec<String> = [
            "strata firmware qemu",
            "COST layer=0 compute_insns=1000 print_ticks=72000000",
            "COST layer=1 compute_insns=4000 print_ticks=7200000",
            "COST triangles=12 slice_insns=1200",
            "COST isr_calls=10 isr_insns_total=1000 isr_insns_max=300 steps=8",
            "STEPS x=5 y=3 z=0 e=0 pos_x=-1 pos_y=3 pos_z=0 pos_e=0 hash=00ff print_ticks=9",
            "MEM data_bss=60000 stack_hwm=2000 stack_size=4096",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let c = Costs::parse(&lines);
        assert_eq!(c.layers.len(), 2);
        let s = CostSummary::of(&c, 72e6, &[]);
        assert_eq!(s.triangles, 12);
        assert_eq!(s.insns_per_triangle, 100.0);
        assert_eq!(s.layer_insns_max, 4000);
        assert_eq!(s.isr_insns_per_step, 125.0);
        assert_eq!(s.isr_insns_per_call, 100.0);
        assert_eq!(s.isr_insns_max, 300);
        // Layer 1: 0.1 s of print over 4000 * 1.5 / 72e6 s of compute.
        assert_eq!(s.worst_rtf_layer, 1);
        assert!((s.worst_rtf - 1200.0).abs() < 1e-6, "{}", s.worst_rtf);
        assert_eq!(s.idle_layers, 0);
        // Layer 1 marked as extruding nothing: the worst is layer 0, 1 s over 1000 * 1.5 /
        // 72e6 s; layer 1's figures go to the idle sums.
        let s = CostSummary::of(&c, 72e6, &[true, false]);
        assert_eq!(s.worst_rtf_layer, 0);
        assert!((s.worst_rtf - 48_000.0).abs() < 1e-6, "{}", s.worst_rtf);
        assert_eq!(s.idle_layers, 1);
        assert!((s.idle_print_s - 0.1).abs() < 1e-12 && s.idle_compute_s > 0.0);
        assert_eq!(s.data_bss, Some(60000));
        let st = c.steps().unwrap();
        assert_eq!(st.steps, [5, 3, 0, 0]);
        assert_eq!(st.positions, [-1, 3, 0, 0]);
        assert_eq!((st.print_ticks, st.hash), (Some(9), Some(255)));
        assert!(parse_record("hello world").is_none());
        assert!(parse_record("SOFT LIMIT axis=1").is_none());
    }
}

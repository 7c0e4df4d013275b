//! Cortex-M3 cost of whole print jobs on the firmware's QEMU build: each model is streamed
//! to the emulated board by the real host code (as in `tests/hil_qemu.rs`), and the
//! firmware's `COST`/`MEM` lines (instructions counted by QEMU's `-icount shift=0`) are
//! summarised per model against the targets:
//!
//! - real-time factor of the worst layer (its print time over its toolpath and planning time
//!   at 72 MHz and 1.5 cycles per instruction) at least 20;
//! - step interrupt at most 150 instructions per step on average;
//! - worst interrupt under 900 cycles (X and Y both stepping at 40 kHz: 72e6 / 80e3).
//!
//! `cargo run --release -p strata-host --example job_cost -- [--echo] [--timeout S]
//! [--relay LOSS] [--max-deviation MM] [--layers K] MODEL.stl...` (job budget S seconds of
//! QEMU's clock, default 1800; admission's error bound MM, default 0.02 as `strata print`;
//! `--layers K` lists the K worst layers with their compute split between slicing/toolpaths
//! and planning/steps; `--relay` streams through the fault-injecting relay at that loss rate, 0 for none, and `STRATA_HIL_TRACE=1` then prints
//! every frame's header; `cylinder:R:H:SIDES:BAND` (mm) is a generated banded cylinder; model
//! names without a directory are looked up in `../shared/models/`); `tools/job-cost/run.sh`
//! builds the firmware first and runs the four sample models. Exits non-zero when a job
//! fails; a missed target is reported, not an error.

use std::path::{Path, PathBuf};
use std::time::Duration;

use strata::geom::Triangle;
use strata::machine::{MachineConfig, PrintSettings};
use strata::protocol::{DeviceState, JobOptions, JobSpec};
use strata_host::hil::{self, CostSummary, Costs, Qemu, CPU_HZ, CYCLES_PER_INSN};
use strata_host::serial::Port;
use strata_host::session::Source;
use strata_host::simjob::Faults;
use strata_host::{admission, model};

const RTF_TARGET: f64 = 20.0;
const ISR_MEAN_TARGET: f64 = 150.0;
/// Cycles between two interrupts when X and Y each step at 40 kHz.
const ISR_WORST_CYCLES: f64 = 72e6 / 80e3;

fn resolve(arg: &str) -> PathBuf {
    let p = Path::new(arg);
    if p.components().count() > 1 || p.is_file() {
        return p.to_path_buf();
    }
    strata_testkit::models::dir().join(arg)
}

struct Row {
    name: String,
    layers: u32,
    note: Option<String>,
    s: CostSummary,
    print_s: f64,
    wall_s: f64,
    layers_cost: Vec<hil::LayerCost>,
}

struct Opts {
    echo: bool,
    timeout: Duration,
    /// Through the fault-injecting relay at this loss rate.
    relay: Option<f64>,
    /// Admission's error bound, mm.
    max_deviation: f64,
    /// Worst layers to list with their split (slicing and toolpaths / planning and steps).
    worst_layers: usize,
}

/// `cylinder:R:H:SIDES:BAND` (mm) is [`hil::banded_cylinder`]; anything else an STL file.
fn load(arg: &str, machine: &MachineConfig) -> Result<(String, Vec<Triangle>), String> {
    if let Some(spec) = arg.strip_prefix("cylinder:") {
        let v: Vec<f64> = spec.split(':').filter_map(|x| x.parse().ok()).collect();
        let [r, h, n, band] = v[..] else {
            return Err(format!("{arg}: expected cylinder:R:H:SIDES:BAND (mm)"));
        };
        let um = |mm: f64| (mm * 1000.0).round() as i32;
        let tris = hil::banded_cylinder(r * 1000.0, um(h), n as usize, um(band));
        return Ok((arg.to_string(), tris));
    }
    let path = resolve(arg);
    let name = path.file_name().unwrap_or_default().to_string_lossy().into_owned();
    Ok((name, model::load(&path)?.placed_sorted(machine)?))
}

fn run(qemu: &Path, elf: &Path, arg: &str, o: &Opts) -> Result<Row, String> {
    let echo = o.echo;
    let machine = MachineConfig::default();
    let (name, tris) = load(arg, &machine)?;
    let job = JobSpec {
        settings: PrintSettings::default(),
        options: JobOptions::default(),
        model_height_um: tris.iter().map(Triangle::z_max).max().unwrap_or(0),
        triangles: tris.len() as u32,
    };
    let t0 = std::time::Instant::now();
    let (mut q, uart) = Qemu::start(qemu, elf, echo)?;
    let mut clock = q.clock()?;
    let (_relay, port) = match o.relay {
        Some(loss) => {
            let (r, p) = hil::Relay::spawn(uart, Faults::uniform(loss, 1), 250_000, clock.clone())?;
            (Some(r), p)
        }
        None => (None, uart),
    };
    port.set_read_timeout(Some(Duration::from_millis(1))).map_err(|e| e.to_string())?;
    port.set_write_timeout(Some(Duration::from_millis(1))).map_err(|e| e.to_string())?;
    let mut port = Port::new(port);
    let mut conn = hil::connect(&mut port, &mut clock)?;
    let (tris, job, note) =
        hil::admitted_on_link(&mut port, &mut conn, &mut clock, &tris, job, o.max_deviation)?;
    let mut next = 10.0;
    let budget_ms = o.timeout.as_millis() as u32;
    let source = Source::Model(&tris, job);
    let progress = hil::print_job(&mut port, &mut conn, &mut clock, source, budget_ms, |p| {
        if echo && t0.elapsed().as_secs_f64() > next {
            next += 10.0;
            eprintln!("{name}: {} triangles sent, status {:?}", p.triangles_sent, p.status);
        }
    })
    .map_err(|e| {
        let lines = q.lines();
        let tail = lines[lines.len().saturating_sub(6)..].join("\n  ");
        format!("{name}: {e}\n  qemu's last lines:\n  {tail}")
    })?;
    let st = progress.status.unwrap_or_default();
    if st.state != DeviceState::Done {
        return Err(format!("{name}: ended in {:?}", st.state));
    }
    q.wait_for(&mut clock, 60_000, |l| {
        l.iter().any(|l| l.contains("isr_calls=")) && l.iter().any(|l| l.starts_with("MEM"))
    })?;
    let costs = Costs::parse(&q.lines());
    let timer_hz = strata::step::StepConfig::from_machine(&machine).timer_hz as f64;
    // Which layers extrude: the host's toolpath stage on the triangles streamed (the
    // device's, bit for bit).
    let (_, times) = admission::toolpath_pass(&tris, &machine, &job, None)?;
    Ok(Row {
        name,
        layers: st.layers,
        note,
        s: CostSummary::of(&costs, timer_hz, &times.extrudes),
        print_s: st.done_ms as f64 / 1000.0,
        wall_s: t0.elapsed().as_secs_f64(),
        layers_cost: costs.layers,
    })
}

/// The `k` layers of `r` with the lowest real-time factor, with their compute split.
fn print_worst_layers(r: &Row, k: usize, timer_hz: f64) {
    let rtf = |l: &hil::LayerCost| {
        let compute_s = l.compute_insns as f64 * CYCLES_PER_INSN / CPU_HZ;
        l.print_ticks as f64 / timer_hz / compute_s.max(1e-12)
    };
    let mut layers: Vec<&hil::LayerCost> = r.layers_cost.iter().collect();
    layers.sort_by(|a, b| rtf(a).total_cmp(&rtf(b)));
    println!("\n{}: worst layers (insns: slicing+toolpaths / planning+steps)", r.name);
    for l in layers.iter().take(k) {
        println!(
            "  L{:<4} rtf {:>6.1}  print {:>6.2} s  compute {:>11}  service {:>11}  motion {:>11}",
            l.layer,
            rtf(l),
            l.print_ticks as f64 / timer_hz,
            l.compute_insns,
            l.service_insns,
            l.compute_insns - l.service_insns.min(l.compute_insns)
        );
    }
}

/// The layers left out of the worst factor, if any.
fn idle_note(s: &CostSummary) -> String {
    if s.idle_layers == 0 {
        return String::new();
    }
    let what = if s.idle_layers == 1 { "layer extrudes" } else { "layers extrude" };
    format!(
        " over the layers that extrude; {} {what} nothing (only their height change: {:.2} s \
         of print, {:.3} s of compute)",
        s.idle_layers, s.idle_print_s, s.idle_compute_s
    )
}

fn main() {
    let mut o = Opts {
        echo: false,
        timeout: Duration::from_secs(1800),
        relay: None,
        max_deviation: 0.02,
        worst_layers: 0,
    };
    let mut models = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--echo" => o.echo = true,
            "--timeout" => match args.next().and_then(|s| s.parse().ok()) {
                Some(s) => o.timeout = Duration::from_secs(s),
                None => models.clear(),
            },
            "--max-deviation" => match args.next().and_then(|s| s.parse().ok()) {
                Some(d) => o.max_deviation = d,
                None => models.clear(),
            },
            "--layers" => match args.next().and_then(|s| s.parse().ok()) {
                Some(k) => o.worst_layers = k,
                None => models.clear(),
            },
            "--relay" => match args.next().and_then(|s| s.parse().ok()) {
                Some(l) => o.relay = Some(l),
                None => models.clear(),
            },
            _ => models.push(a),
        }
    }
    if models.is_empty() {
        eprintln!(
            "usage: job_cost [--echo] [--timeout SECONDS] [--relay LOSS] [--max-deviation MM] \
             [--layers K] MODEL.stl..."
        );
        std::process::exit(2);
    }
    let (qemu, elf) = hil::locate().unwrap_or_else(|e| {
        eprintln!("job_cost: {e}");
        std::process::exit(2);
    });
    println!(
        "Cortex-M3 cost per job (QEMU {} -icount shift=0; {} MHz at {CYCLES_PER_INSN} cycles per \
         instruction; {})",
        hil::qemu_machine(&std::fs::read(&elf).unwrap_or_default()),
        CPU_HZ / 1e6,
        elf.display()
    );
    let mut failed = false;
    let mut rows = Vec::new();
    for m in &models {
        match run(&qemu, &elf, m, &o) {
            Ok(r) => rows.push(r),
            Err(e) => {
                eprintln!("{m}: FAILED: {e}");
                failed = true;
            }
        }
    }
    println!(
        "\n{:<26} {:>6} {:>6} {:>9} {:>11} {:>11} {:>9} {:>9} {:>9} {:>12} {:>8} {:>8}",
        "model",
        "tris",
        "layers",
        "ins/tri",
        "layer mean",
        "layer max",
        "isr/step",
        "isr/call",
        "isr max",
        "worst rtf",
        "data+bss",
        "stack"
    );
    for r in &rows {
        let s = &r.s;
        println!(
            "{:<26} {:>6} {:>6} {:>9.0} {:>11.0} {:>11} {:>9.1} {:>9.1} {:>9} {:>7.1} L{:<4} {:>8} {:>8}",
            r.name,
            s.triangles,
            r.layers,
            s.insns_per_triangle,
            s.layer_insns_mean,
            s.layer_insns_max,
            s.isr_insns_per_step,
            s.isr_insns_per_call,
            s.isr_insns_max,
            s.worst_rtf,
            s.worst_rtf_layer,
            s.data_bss.map_or("-".into(), |v| v.to_string()),
            s.stack_hwm.map_or("-".into(), |v| v.to_string()),
        );
    }
    if o.worst_layers > 0 {
        let timer_hz = strata::step::StepConfig::from_machine(&MachineConfig::default()).timer_hz;
        for r in &rows {
            print_worst_layers(r, o.worst_layers, timer_hz as f64);
        }
    }
    println!();
    for r in &rows {
        let s = &r.s;
        let worst_cycles = s.isr_insns_max as f64 * CYCLES_PER_INSN;
        let verdict = |ok: bool| if ok { "ok" } else { "MISSED" };
        println!(
            "{}: {} steps in {} interrupts, printed {:.0} s (device clock), {:.0} s wall{}; worst layer {:.1}x \
             (target >= {RTF_TARGET}x: {}){}; ISR {:.1} insns/step (target <= {ISR_MEAN_TARGET}: \
             {}); worst ISR {:.0} cycles (40 kHz on X and Y needs < {ISR_WORST_CYCLES:.0}: {}); \
             longest slicing/toolpath stretch without step generation {:.1} ms at {} MHz (the \
             step queue must cover it)",
            r.name,
            s.steps,
            s.isr_calls,
            r.print_s,
            r.wall_s,
            r.note.as_ref().map(|n| format!(", {n}")).unwrap_or_default(),
            s.worst_rtf,
            verdict(s.worst_rtf >= RTF_TARGET),
            idle_note(s),
            s.isr_insns_per_step,
            verdict(s.isr_insns_per_step <= ISR_MEAN_TARGET),
            worst_cycles,
            verdict(worst_cycles < ISR_WORST_CYCLES),
            s.gen_gap_max_insns as f64 * CYCLES_PER_INSN / CPU_HZ * 1e3,
            CPU_HZ / 1e6,
        );
    }
    if failed {
        std::process::exit(1);
    }
}

//! `strata print` and `strata ports`: stream a model to a printer over a serial port (or a
//! pseudo-terminal), with admission control, a progress bar, device status and Ctrl-C abort.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use strata::protocol::{DeviceState, LinkConfig, Status};
use strata_host::admission::{admit_job_paced, Admission};
use strata_host::clock::WallClock;
use strata_host::serial::{self, Port};
use strata_host::session::{HostEndpoint, Progress, Source};
use strata_host::{gcode_file, model};

use crate::settings::{job_of, machine_of, PrintArgs};
use crate::simulate::is_gcode;

/// Options of `strata print`.
#[derive(Debug, clap::Args)]
pub struct PrintCmdArgs {
    /// The STL model, or a G-code file (`.gcode`, `.gco`, `.g`) from any slicer.
    #[arg(required_unless_present = "from_card")]
    pub model: Option<PathBuf>,
    /// Print this file of the printer's SD card instead (G-code, or a job `strata upload`
    /// wrote; `strata card ls` lists them): the printer reads it itself and needs no host
    /// once it started.
    #[arg(long, value_name = "NAME", conflicts_with_all = ["model", "resume"])]
    pub from_card: Option<String>,
    /// With `--from-card`: leave once the printer started the job (it prints on alone).
    #[arg(long, requires = "from_card")]
    pub detach: bool,
    /// Serial port of the printer (e.g. /dev/ttyUSB0).
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 250_000)]
    pub baud: u32,
    /// Seconds the printer may stay silent, or take no data, before the print counts as lost
    /// (a slow USB bridge or a busy PC may need more than the protocol's 3 s).
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    pub link_timeout: f64,
    /// Largest geometric error simplification may introduce, mm.
    #[arg(long, value_name = "MM", default_value_t = 0.02)]
    pub max_deviation: f64,
    /// Resume the job the printer parked when its host went silent: give the same model and
    /// settings; the printer checks they are the same, reheats, brings the nozzle back and
    /// prints on from the layer where it stopped.
    #[arg(long)]
    pub resume: bool,
    /// Print settings.
    #[command(flatten)]
    pub print: Box<PrintArgs>,
}

/// What `strata print` sends, read and checked before the printer is contacted.
enum Prepared {
    /// A placed model, sliced on the printer.
    Model(Vec<strata::geom::Triangle>),
    /// G-code as the printer's reader reads it.
    Gcode(Vec<u8>, gcode_file::GcodeScan),
}

/// Runs `strata print`.
pub fn run(args: &PrintCmdArgs) -> Result<(), String> {
    let machine = machine_of(&args.print)?;
    let Some(model) = &args.model else {
        let card_name = args.from_card.as_deref().unwrap_or_default();
        return from_card(args, card_name);
    };
    let name = model.display();
    let prepared = if is_gcode(model) {
        let text = std::fs::read(model).map_err(|e| format!("{name}: {e}"))?;
        let scan = gcode_file::scan(&text, &machine).map_err(|e| format!("{name}: {e}"))?;
        for w in scan.warnings() {
            eprintln!("{name}: warning: {w}");
        }
        Prepared::Gcode(text, scan)
    } else {
        Prepared::Model(model::load(model)?.placed_sorted(&machine)?)
    };
    let (mut port, mut ep, mut clock, abort) = open_port(&args.port, args.baud, args.link_timeout)?;
    let greeting = serial::connect(&mut port, &mut ep, &mut clock)?;
    let caps = greeting.capacities;
    if let Some(parked) = greeting.parked.filter(|_| args.resume) {
        eprintln!(
            "printer: resuming the job it parked at layer {} ({} triangles taken)",
            parked.layer, parked.taken
        );
    }
    eprintln!(
        "printer: {} active triangles, {} contour points per layer, toolpath PTS {} LOOPS {} \
         CROSS {} PATH {} RING {} SPANS {}, {} B move buffer, {} KB RAM",
        caps.active_triangles,
        caps.contour_points,
        caps.toolpath_points,
        caps.toolpath_loops,
        caps.scan_crossings,
        caps.path_points,
        caps.window_ring_words,
        caps.window_spans,
        caps.move_buffer_bytes,
        caps.ram_bytes / 1024
    );
    let admitted_model;
    let (source, unit) = match &prepared {
        Prepared::Gcode(text, scan) => (Source::Gcode(text, scan.spec), "bytes"),
        Prepared::Model(tris) => {
            admitted_model =
                admitted(args, &machine, tris, &caps, &mut port, &mut ep, &mut clock, &abort)?;
            (Source::Model(&admitted_model.0, admitted_model.1), "triangles")
        }
    };
    let total = match source {
        Source::Model(t, _) => t.len(),
        Source::Gcode(t, _) => t.len(),
        Source::Card { .. } => 0,
    };
    let sent_of = |p: &Progress| match source {
        Source::Model(..) => p.triangles_sent,
        Source::Gcode(..) | Source::Card { .. } => p.gcode_bytes_sent,
    };
    // A bar on a terminal; plain lines otherwise (logs, CI), at every tenth of the stream
    // and every layer the printer completes.
    let terminal = std::io::stderr().is_terminal();
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {unit} {{msg}}"
        ))
        .map_err(|e| e.to_string())?,
    );
    let mut last_line: Option<(usize, u32)> = None;
    let result = serial::print(
        &mut port,
        &mut ep,
        &mut clock,
        &greeting,
        source,
        args.resume,
        &abort,
        |p| {
            let sent = sent_of(p);
            let text = progress_text(p, sent, total, unit);
            if terminal {
                bar.set_position(sent as u64);
                bar.set_message(text);
            } else {
                let key = (sent * 10 / total.max(1), p.status.map_or(0, |s| s.layer));
                if last_line != Some(key) {
                    last_line = Some(key);
                    eprintln!("progress: {text}");
                }
            }
        },
    );
    bar.finish_and_clear();
    let result = result.map_err(|e| {
        if abort.load(Ordering::Relaxed) {
            match e.strip_prefix("aborted by the user") {
                Some(rest) => format!("aborted by the user (Ctrl-C){rest}"),
                None => format!("aborted (Ctrl-C): {e}"),
            }
        } else {
            e
        }
    });
    let progress = result.map_err(|e| format!("{name}: {e}"))?;
    let s = progress.status.unwrap_or_default();
    let sent = sent_of(&progress);
    println!(
        "{name}: printed {} layers ({sent} {unit} streamed, {:.1} wire bytes per {}), state {:?}",
        s.layers,
        progress.triangle_wire_bytes as f64 / sent.max(1) as f64,
        unit.trim_end_matches('s'),
        s.state
    );
    if s.state != DeviceState::Done {
        return Err(format!("the printer ended in state {:?}", s.state));
    }
    Ok(())
}

/// An open printer port: the port, its endpoint, the wall clock and the Ctrl-C flag.
pub type OpenPort =
    (Port<Box<dyn serialport::SerialPort>>, HostEndpoint, WallClock, Arc<AtomicBool>);

/// The serial port open with the link's timeout checked, the endpoint, the clock and the
/// Ctrl-C flag.
pub fn open_port(path: &str, baud: u32, link_timeout_s: f64) -> Result<OpenPort, String> {
    if !(link_timeout_s.is_finite() && (0.5..=3600.0).contains(&link_timeout_s)) {
        return Err(format!("--link-timeout {link_timeout_s}: expected 0.5 to 3600 s"));
    }
    let port = serialport::new(path, baud)
        .timeout(Duration::from_millis(2))
        .open()
        .map_err(|e| format!("{path}: {e}"))?;
    let abort = Arc::new(AtomicBool::new(false));
    {
        let abort = abort.clone();
        // A second handler cannot be installed (tests call `run` once per process).
        let _ = ctrlc::set_handler(move || abort.store(true, Ordering::Relaxed));
    }
    let mut link = LinkConfig::default();
    link.dead_ms = (link_timeout_s * 1000.0).round() as u32;
    Ok((Port::new(port), HostEndpoint::new(link), WallClock::new(), abort))
}

/// `strata print --from-card NAME`: the printer prints its card's file; the host follows
/// its layers (or leaves at once with `--detach`).
fn from_card(args: &PrintCmdArgs, name: &str) -> Result<(), String> {
    let (mut port, mut ep, mut clock, abort) = open_port(&args.port, args.baud, args.link_timeout)?;
    let greeting = serial::connect(&mut port, &mut ep, &mut clock)?;
    let source = Source::Card { name, detach: args.detach };
    // A bar over the layers on a terminal (a model's job knows its count; G-code counts
    // them as it goes); plain lines at every layer otherwise.
    let terminal = std::io::stderr().is_terminal();
    let bar = ProgressBar::new(0);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} layer {pos}/{len} {msg}",
        )
        .map_err(|e| e.to_string())?,
    );
    let mut last_layer = None;
    let result =
        serial::print(&mut port, &mut ep, &mut clock, &greeting, source, false, &abort, |p| {
            let Some(s) = p.status.filter(|_| p.card_file_bytes.is_some()) else { return };
            let (hotend, bed) = (s.hotend_c_x10 as f64 / 10.0, s.bed_c_x10 as f64 / 10.0);
            let eta = eta_s(&s).map_or("--".into(), |t| format!("{}:{:02}", t / 60, t % 60));
            let text = format!(
                "{:?} | printed {} s | ETA {eta} | hotend {hotend:.1} C bed {bed:.1} C",
                s.state,
                s.done_ms / 1000
            );
            if terminal {
                bar.set_length(u64::from(s.layers.max(s.layer)));
                bar.set_position(u64::from(s.layer));
                bar.set_message(text);
            } else if last_layer != Some(s.layer) {
                last_layer = Some(s.layer);
                eprintln!("progress: layer {} | {text}", s.layer);
            }
        });
    bar.finish_and_clear();
    let progress = result.map_err(|e| format!("{name}: {e}"))?;
    let bytes = progress.card_file_bytes.unwrap_or(0);
    if args.detach {
        println!(
            "{name}: the printer is printing it from its card ({bytes} bytes); it needs no host"
        );
        return Ok(());
    }
    let s = progress.status.unwrap_or_default();
    println!(
        "{name}: printed from the card ({bytes} bytes, {} layers), state {:?}",
        s.layer, s.state
    );
    if s.state != DeviceState::Done {
        return Err(format!("the printer ended in state {:?}", s.state));
    }
    Ok(())
}

/// The model's triangles and job as admission control lets them go to a printer with `caps`
/// (simplified if need be), the link kept alive meanwhile.
#[allow(clippy::too_many_arguments)]
fn admitted(
    args: &PrintCmdArgs,
    machine: &strata::machine::MachineConfig,
    tris: &[strata::geom::Triangle],
    caps: &strata::protocol::Capacities,
    port: &mut Port<Box<dyn serialport::SerialPort>>,
    ep: &mut HostEndpoint,
    clock: &mut WallClock,
    abort: &AtomicBool,
) -> Result<(Vec<strata::geom::Triangle>, strata::protocol::JobSpec), String> {
    let model = args.model.as_deref().unwrap_or(std::path::Path::new("model"));
    let job = job_of(&args.print, tris)?;
    // Admission can take longer than the link's dead time (3 s): keep the link alive.
    let admitted = serial::keeping_link_alive(port, ep, clock, || {
        admit_job_paced(tris, machine, &job, caps, args.max_deviation, args.baud)
    })?;
    if abort.load(Ordering::Relaxed) {
        return Err("aborted by the user (Ctrl-C) before the job started".into());
    }
    let paced = admitted.map_err(|e| format!("{}: {e}", model.display()))?;
    if !paced.pace.keeps_ahead() {
        eprintln!("{}", paced.pace.warning(model, args.baud));
    }
    Ok(admitted_job(model, tris, job, paced.admission))
}

/// The triangles admission let go (the simplification said), and their job.
pub fn admitted_job(
    model: &std::path::Path,
    tris: &[strata::geom::Triangle],
    job: strata::protocol::JobSpec,
    admission: Admission,
) -> (Vec<strata::geom::Triangle>, strata::protocol::JobSpec) {
    let tris = match admission {
        Admission::Unchanged(_) => tris.to_vec(),
        Admission::Simplified(s) => {
            eprintln!(
                "{}: simplified from {} to {} triangles to fit the printer and its link (error \
                 bound {} mm, measured deviation {:.3} mm)",
                model.display(),
                s.triangles_in,
                s.triangles.len(),
                s.error_bound_mm,
                s.max_deviation_mm
            );
            s.triangles
        }
    };
    let job = strata::protocol::JobSpec { triangles: tris.len() as u32, ..job };
    (tris, job)
}

/// One progress report: triangles (or G-code bytes: the `unit`) and wire bytes streamed, the
/// printer's layer, state, print time and the time left (estimated from the print time of the
/// layers planned so far).
fn progress_text(p: &Progress, sent: usize, total: usize, unit: &str) -> String {
    let mut text = format!(
        "{sent}/{total} {unit} ({}%), {} B sent",
        sent * 100 / total.max(1),
        p.triangle_wire_bytes
    );
    if let Some(s) = p.status {
        let eta = match eta_s(&s) {
            Some(t) => format!("{}:{:02}", t / 60, t % 60),
            None => "--".into(),
        };
        text += &format!(
            " | layer {}/{} | {:?} | printed {} s | ETA {eta}",
            s.layer,
            s.layers,
            s.state,
            s.done_ms / 1000
        );
        if s.heating || s.hotend_c_x10 != 0 || s.bed_c_x10 != 0 {
            text += &format!(
                " | hotend {:.1} C bed {:.1} C{}",
                s.hotend_c_x10 as f64 / 10.0,
                s.bed_c_x10 as f64 / 10.0,
                if s.heating { " (heating)" } else { "" }
            );
        }
    } else {
        text += " | layer -/- | ETA --";
    }
    text
}

/// Seconds left: the print time of the planned layers, scaled to every layer, minus the time
/// printed (`None` until a layer is planned and motion has started).
fn eta_s(s: &Status) -> Option<u64> {
    if s.layer == 0 || s.done_ms == 0 {
        return None;
    }
    let total_ms = s.planned_ms as u64 * s.layers.max(s.layer) as u64 / s.layer as u64;
    Some(total_ms.saturating_sub(s.done_ms as u64) / 1000)
}

/// Runs `strata ports`.
pub fn ports() -> Result<(), String> {
    let ports = serialport::available_ports().map_err(|e| e.to_string())?;
    for line in port_lines(ports) {
        println!("{line}");
    }
    Ok(())
}

/// One line per port (`NAME<TAB>KIND`), or one line saying there is none.
fn port_lines(ports: Vec<serialport::SerialPortInfo>) -> Vec<String> {
    if ports.is_empty() {
        return vec!["no serial ports found".into()];
    }
    ports
        .into_iter()
        .map(|p| {
            let kind = match p.port_type {
                serialport::SerialPortType::UsbPort(u) => {
                    format!("USB {:04x}:{:04x} {}", u.vid, u.pid, u.product.unwrap_or_default())
                }
                serialport::SerialPortType::PciPort => "PCI".into(),
                serialport::SerialPortType::BluetoothPort => "Bluetooth".into(),
                serialport::SerialPortType::Unknown => "unknown".into(),
            };
            format!("{}\t{kind}", p.port_name)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serialport::{SerialPortInfo, SerialPortType, UsbPortInfo};

    #[test]
    fn no_ports_is_one_clear_line() {
        assert_eq!(port_lines(Vec::new()), ["no serial ports found"]);
    }

    #[test]
    fn ports_are_listed_with_their_kind() {
        let usb = UsbPortInfo {
            vid: 0x1a86,
            pid: 0x7523,
            serial_number: None,
            manufacturer: None,
            product: Some("USB Serial".into()),
        };
        let lines = port_lines(vec![
            SerialPortInfo {
                port_name: "/dev/ttyUSB0".into(),
                port_type: SerialPortType::UsbPort(usb),
            },
            SerialPortInfo { port_name: "/dev/ttyS0".into(), port_type: SerialPortType::Unknown },
        ]);
        assert_eq!(lines, ["/dev/ttyUSB0\tUSB 1a86:7523 USB Serial", "/dev/ttyS0\tunknown"]);
    }
}

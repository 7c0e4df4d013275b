//! `strata print` and `strata ports`: stream a model to a printer over a serial port (or a
//! pseudo-terminal), with admission control, a progress bar, device status and Ctrl-C abort.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use strata::protocol::DeviceState;
use strata_host::admission::{admit_job, Admission};
use strata_host::model;
use strata_host::serial;
use strata_host::session::HostEndpoint;

use crate::simulate::job_of;
use crate::slice_cmd::{machine_of, PrintArgs};

/// Options of `strata print`.
#[derive(Debug, clap::Args)]
pub struct PrintCmdArgs {
    /// The STL model.
    pub model: PathBuf,
    /// Serial port of the printer (e.g. /dev/ttyUSB0).
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 250_000)]
    pub baud: u32,
    /// Largest geometric error simplification may introduce, mm.
    #[arg(long, value_name = "MM", default_value_t = 0.02)]
    pub max_deviation: f64,
    /// Print settings.
    #[command(flatten)]
    pub print: Box<PrintArgs>,
}

/// Runs `strata print`.
pub fn run(args: &PrintCmdArgs) -> Result<(), String> {
    let machine = machine_of(&args.print)?;
    let loaded = model::load(&args.model)?;
    let tris = loaded.placed_sorted(&machine)?;
    let mut port = serialport::new(&args.port, args.baud)
        .timeout(Duration::from_millis(2))
        .open()
        .map_err(|e| format!("{}: {e}", args.port))?;
    let abort = Arc::new(AtomicBool::new(false));
    {
        let abort = abort.clone();
        // A second handler cannot be installed (tests call `run` once per process).
        let _ = ctrlc::set_handler(move || abort.store(true, Ordering::Relaxed));
    }
    let t0 = Instant::now();
    let mut ep = HostEndpoint::new(strata::protocol::LinkConfig::default());
    let caps = serial::connect(&mut port, &mut ep, t0)?;
    eprintln!(
        "printer: {} active triangles, {} contour points per layer, toolpath PTS {} LOOPS {} \
         CROSS {} PATH {} RING {} SPANS {}, {} buffered moves, {} KB RAM",
        caps.active_triangles,
        caps.contour_points,
        caps.toolpath_points,
        caps.toolpath_loops,
        caps.scan_crossings,
        caps.path_points,
        caps.window_ring_words,
        caps.window_spans,
        caps.layer_moves,
        caps.ram_bytes / 1024
    );
    let job = job_of(&args.print, &tris)?;
    let tris = match admit_job(&tris, &machine, &job, &caps, args.max_deviation)
        .map_err(|e| format!("{}: {e}", args.model.display()))?
    {
        Admission::Unchanged(_) => tris,
        Admission::Simplified(s) => {
            eprintln!(
                "{}: simplified from {} to {} triangles to fit the printer (error bound {} mm, \
                 measured deviation {:.3} mm)",
                args.model.display(),
                s.triangles_in,
                s.triangles.len(),
                s.error_bound_mm,
                s.max_deviation_mm
            );
            s.triangles
        }
    };
    let job = strata::protocol::JobSpec { triangles: tris.len() as u32, ..job };
    let bar = ProgressBar::new(tris.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} triangles {msg}",
        )
        .map_err(|e| e.to_string())?,
    );
    let result = serial::print(&mut port, &mut ep, t0, caps, &tris, job, &abort, |p| {
        bar.set_position(p.triangles_sent as u64);
        if let Some(s) = p.status {
            let eta = if s.planned_ms > s.done_ms && s.done_ms > 0 {
                format!(", ETA {} s", (s.planned_ms - s.done_ms) / 1000)
            } else {
                String::new()
            };
            bar.set_message(format!(
                "{} B | layer {}/{} | {:?} | printed {} s{eta}",
                p.triangle_wire_bytes,
                s.layer,
                s.layers,
                s.state,
                s.done_ms / 1000
            ));
        }
    });
    bar.finish_and_clear();
    let progress = result.map_err(|e| format!("{}: {e}", args.model.display()))?;
    let s = progress.status.unwrap_or_default();
    println!(
        "{}: printed {} layers ({} triangles streamed, {:.1} bytes per triangle), state {:?}",
        args.model.display(),
        s.layers,
        progress.triangles_sent,
        progress.triangle_wire_bytes as f64 / progress.triangles_sent.max(1) as f64,
        s.state
    );
    if s.state != DeviceState::Done {
        return Err(format!("the printer ended in state {:?}", s.state));
    }
    Ok(())
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

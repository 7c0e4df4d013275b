//! `strata card ...` and `strata upload`: the printer's SD card over the link.

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

use indicatif::{ProgressBar, ProgressStyle};
use strata_host::admission::admit_job;
use strata_host::session::CardWrite;
use strata_host::{job_file, model, serial};

use crate::print::{admitted_job, open_port};
use crate::settings::{job_of, machine_of, PrintArgs};
use crate::simulate::is_gcode;

/// Extension of a model job's file on the card.
const JOB_EXTENSION: &str = "sjob";

/// Options of `strata upload`.
#[derive(Debug, clap::Args)]
pub struct UploadArgs {
    /// A model (STL: placed, admitted for the printer and written as its job, with the
    /// settings below, as `strata print` streams it) or a G-code file (`.gcode`, `.gco`, `.g`,
    /// written as it is) for the printer's card.
    pub file: PathBuf,
    /// Its name on the card (default: the file's name; a model's job: its stem and `.sjob`).
    #[arg(long)]
    pub name: Option<String>,
    /// Largest geometric error simplification may introduce, mm.
    #[arg(long, value_name = "MM", default_value_t = 0.02)]
    pub max_deviation: f64,
    /// Serial port of the printer (e.g. /dev/ttyUSB0).
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 250_000)]
    pub baud: u32,
    /// Seconds the printer may stay silent before the link counts as lost.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    pub link_timeout: f64,
    /// Print settings (of a model's job).
    #[command(flatten)]
    pub print: Box<PrintArgs>,
}

/// Runs `strata upload`.
pub fn upload(args: &UploadArgs) -> Result<(), String> {
    let shown = args.file.display();
    let machine = machine_of(&args.print)?;
    let gcode = is_gcode(&args.file);
    // A model is read and placed before the printer is contacted.
    let placed = match gcode {
        true => None,
        false => Some(model::load(&args.file)?.placed_sorted(&machine)?),
    };
    let (mut port, mut ep, mut clock, abort) = open_port(&args.port, args.baud, args.link_timeout)?;
    let greeting = serial::connect(&mut port, &mut ep, &mut clock)?;
    let (data, default_name) = match placed {
        None => {
            let data = std::fs::read(&args.file).map_err(|e| format!("{shown}: {e}"))?;
            let file_name = args.file.file_name().and_then(|n| n.to_str()).unwrap_or_default();
            (data, file_name.to_string())
        }
        Some(tris) => {
            let job = job_of(&args.print, &tris)?;
            let caps = greeting.capacities;
            // Admission can take longer than the link's dead time: keep the link alive.
            let admission = serial::keeping_link_alive(&mut port, &mut ep, &mut clock, || {
                admit_job(&tris, &machine, &job, &caps, args.max_deviation)
            })?
            .map_err(|e| format!("{shown}: {e}"))?;
            if abort.load(Ordering::Relaxed) {
                return Err("aborted by the user (Ctrl-C) before the upload".into());
            }
            let (tris, job) = admitted_job(&args.file, &tris, job, admission);
            let data = job_file::encode(&job, &tris).map_err(|e| format!("{shown}: {e}"))?;
            (data, job_name(&args.file))
        }
    };
    let name = args.name.as_deref().unwrap_or(&default_name);
    let terminal = std::io::stderr().is_terminal();
    let bar = ProgressBar::new(data.len() as u64);
    bar.set_style(
        ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:30} {bytes}/{total_bytes} {bytes_per_sec}",
        )
        .map_err(|e| e.to_string())?,
    );
    let mut last_tenth = None;
    let total = data.len().max(1);
    let written = serial::card_write(
        &mut port,
        &mut ep,
        &mut clock,
        CardWrite::upload(name, &data),
        |sent| {
            if terminal {
                bar.set_position(sent as u64);
            } else if last_tenth != Some(sent * 10 / total) {
                last_tenth = Some(sent * 10 / total);
                eprintln!("progress: {sent}/{} bytes", data.len());
            }
        },
    );
    bar.finish_and_clear();
    let written = written.map_err(|e| format!("{shown}: {e}"))?;
    if written as usize != data.len() {
        return Err(format!("{shown}: the card holds {written} bytes of its {}", data.len()));
    }
    println!("{name}: {written} bytes written to the printer's card (`strata print --from-card {name:?}`)");
    Ok(())
}

/// A model's job's default name on the card: its stem and [`JOB_EXTENSION`].
fn job_name(model: &Path) -> String {
    let stem = model.file_stem().and_then(|n| n.to_str()).unwrap_or("model");
    format!("{stem}.{JOB_EXTENSION}")
}

/// What to do with the card.
#[derive(Debug, clap::Subcommand)]
pub enum CardCommand {
    /// List the files on the printer's SD card (its root directory).
    Ls {
        /// Serial port of the printer (e.g. /dev/ttyUSB0).
        #[arg(long)]
        port: String,
        /// Baud rate.
        #[arg(long, default_value_t = 250_000)]
        baud: u32,
        /// Seconds the printer may stay silent before the link counts as lost.
        #[arg(long, value_name = "S", default_value_t = 3.0)]
        link_timeout: f64,
    },
    /// Remove a file from the printer's SD card.
    Rm {
        /// Its name on the card.
        name: String,
        /// Serial port of the printer (e.g. /dev/ttyUSB0).
        #[arg(long)]
        port: String,
        /// Baud rate.
        #[arg(long, default_value_t = 250_000)]
        baud: u32,
        /// Seconds the printer may stay silent before the link counts as lost.
        #[arg(long, value_name = "S", default_value_t = 3.0)]
        link_timeout: f64,
    },
}

/// Runs `strata card ...`.
pub fn run(cmd: &CardCommand) -> Result<(), String> {
    match cmd {
        CardCommand::Ls { port, baud, link_timeout } => {
            let (mut port, mut ep, mut clock, _abort) = open_port(port, *baud, *link_timeout)?;
            serial::connect(&mut port, &mut ep, &mut clock)?;
            let entries = serial::card_list(&mut port, &mut ep, &mut clock)?;
            for e in &entries {
                if e.is_dir {
                    println!("{:>10}  {}/", "dir", e.name);
                } else {
                    println!("{:>10}  {}", e.size, e.name);
                }
            }
            let files = entries.iter().filter(|e| !e.is_dir).count();
            println!("{files} files");
            Ok(())
        }
        CardCommand::Rm { name, port, baud, link_timeout } => {
            let (mut port, mut ep, mut clock, _abort) = open_port(port, *baud, *link_timeout)?;
            serial::connect(&mut port, &mut ep, &mut clock)?;
            serial::card_write(&mut port, &mut ep, &mut clock, CardWrite::remove(name), |_| {})
                .map_err(|e| format!("{name}: {e}"))?;
            println!("{name}: removed from the printer's card");
            Ok(())
        }
    }
}

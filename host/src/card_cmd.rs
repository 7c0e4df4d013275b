//! `strata card ...` and `strata upload`: the printer's SD card over the link.

use std::io::IsTerminal;
use std::path::PathBuf;

use indicatif::{ProgressBar, ProgressStyle};
use strata_host::serial;
use strata_host::session::CardWrite;

use crate::print::open_port;
use crate::simulate::is_gcode;

/// Options of `strata upload`.
#[derive(Debug, clap::Args)]
pub struct UploadArgs {
    /// A G-code file (`.gcode`, `.gco`, `.g`) to write to the printer's card.
    pub file: PathBuf,
    /// Its name on the card (default: the file's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Serial port of the printer (e.g. /dev/ttyUSB0).
    #[arg(long)]
    pub port: String,
    /// Baud rate.
    #[arg(long, default_value_t = 250_000)]
    pub baud: u32,
    /// Seconds the printer may stay silent before the link counts as lost.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    pub link_timeout: f64,
}

/// Runs `strata upload`.
pub fn upload(args: &UploadArgs) -> Result<(), String> {
    let shown = args.file.display();
    if !is_gcode(&args.file) {
        return Err(format!(
            "{shown}: only G-code uploads to the card so far (a model's job is not built yet): \
             `strata slice {shown} -o FILE.gcode`, then `strata upload FILE.gcode`"
        ));
    }
    let data = std::fs::read(&args.file).map_err(|e| format!("{shown}: {e}"))?;
    let file_name = args.file.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    let name = args.name.as_deref().unwrap_or(file_name);
    let (mut port, mut ep, mut clock, _abort) =
        open_port(&args.port, args.baud, args.link_timeout)?;
    serial::connect(&mut port, &mut ep, &mut clock)?;
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

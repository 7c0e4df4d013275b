//! `strata`: the host tool. Inspect and slice models on the host with the same core the
//! printer runs.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod card_cmd;
mod inspect;
mod print;
mod settings;
mod simulate;
mod slice_cmd;

#[derive(Parser)]
#[command(
    name = "strata",
    version,
    about = "Slice on the printer: inspect, slice and stream STL models"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Show format, triangle count, bounding box and defects of a model.
    Inspect {
        /// The STL model.
        model: PathBuf,
        /// Print machine-readable JSON.
        #[arg(long)]
        json: bool,
    },
    /// Slice a model on the host.
    Slice(slice_cmd::SliceArgs),
    /// Stream a model through the real protocol into a simulated printer.
    Simulate(simulate::SimulateArgs),
    /// Stream a model to a printer over a serial port.
    Print(print::PrintCmdArgs),
    /// List serial ports.
    Ports,
    /// The printer's SD card: list it, remove a file.
    #[command(subcommand)]
    Card(card_cmd::CardCommand),
    /// Write a model's job (admitted and prepared here) or a G-code file to the printer's SD
    /// card.
    Upload(card_cmd::UploadArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match &cli.command {
        Command::Inspect { model, json } => inspect::run(model, *json),
        Command::Slice(args) => slice_cmd::run(args),
        Command::Simulate(args) => simulate::run(args),
        Command::Print(args) => print::run(args),
        Command::Ports => print::ports(),
        Command::Card(c) => card_cmd::run(c),
        Command::Upload(args) => card_cmd::upload(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("strata: error: {message}");
            ExitCode::FAILURE
        }
    }
}

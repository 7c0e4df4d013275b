//! `strata card ...`: the printer's SD card over the link.

use strata_host::serial;

use crate::print::open_port;

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
    }
}

//! The library half of the `strata` host tool: the host side of a print job over the
//! protocol ([`session`]), the simulated printer on a virtual clock ([`simjob`]) and
//! admission control against the device's capacities ([`admission`]). The binary wires them
//! to the command line; the tests drive them directly.

pub mod admission;
pub mod card_image;
pub mod clock;
pub mod gcode_file;
#[cfg(unix)]
pub mod hil;
pub mod job_file;
pub mod model;
pub mod pace;
pub mod preview;
pub mod serial;
pub mod session;
pub mod simjob;
pub mod simplify;
pub mod stages;

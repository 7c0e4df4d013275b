//! G-code: the Marlin-flavoured writer the host's `strata slice` uses ([`GcodeWriter`]) and
//! the reader that turns any slicer's G-code into planner moves and printer actions
//! ([`read`]).

pub mod input;
pub mod read;
mod write;

pub use write::*;

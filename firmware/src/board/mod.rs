//! The board module: the only part that differs between builds. Each board provides the same
//! items: `Board` (`now_ms`, `read`, `write`), `init`, `executor_config`, `with_motion`,
//! `kick`, `print_done_ms`, `job_started`, `job_ended`.

#[cfg(feature = "creality")]
mod creality;
#[cfg(feature = "creality")]
mod sdio;
#[cfg(feature = "creality")]
pub use creality::*;

#[cfg(feature = "qemu")]
mod qemu;
#[cfg(feature = "qemu")]
mod qemu_machine;
#[cfg(feature = "qemu")]
pub use qemu::*;

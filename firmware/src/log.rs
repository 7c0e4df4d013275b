//! `log!`: one line to the debug channel, never to the UART (which carries protocol frames
//! only): defmt over RTT on the Creality boards, semihosting on QEMU. Arguments are integers
//! (they must be both `Display` and `defmt::Format`).

/// Logs one line (`{}` placeholders, integer arguments).
#[cfg(feature = "qemu")]
#[macro_export]
macro_rules! log {
    ($($t:tt)*) => {
        cortex_m_semihosting::hprintln!($($t)*)
    };
}

/// Logs one line (`{}` placeholders, integer arguments).
#[cfg(feature = "creality")]
#[macro_export]
macro_rules! log {
    ($($t:tt)*) => {
        defmt::println!($($t)*)
    };
}

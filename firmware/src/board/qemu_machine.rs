//! The emulated machine under the QEMU board: its UART and its system clock. Everything else
//! of the QEMU board (virtual pins, accelerated print clock, simulated heaters) is the same on
//! both.
//!
//! - `qemu` alone: `lm3s6965evb` (Cortex-M3, 64 KB RAM, the Creality boards' RAM): PL011
//!   UART0 with 16-byte FIFOs; the system clock set to 200 MHz (SysTick count = 5 ns).
//! - `qemu-mps2`: `mps2-an385` (Cortex-M3, 4 MB RAM at 0x2000_0000, 4 MB for the image at 0):
//!   CMSDK APB UART0 (one byte each way); the fixed 25 MHz system clock (40 ns). It exists
//!   to run models with more than 64 KB holds (unsimplified, their offsets whole) on the
//!   same instruction set, with the same firmware, for their cost figures and their
//!   bit-exact comparison with the host simulation. It is not a board anyone flashes.
//!
//! The image carries the machine's name ([`MACHINE_TAG`]) so that the host starts QEMU with
//! the right `-machine`.

fn reg_read(addr: usize) -> u32 {
    // SAFETY: `addr` is one of this machine's memory-mapped registers below, always readable.
    unsafe { core::ptr::read_volatile(addr as *const u32) }
}

fn reg_write(addr: usize, v: u32) {
    // SAFETY: as in `reg_read`; these writes only configure and feed the UART and the clock.
    unsafe { core::ptr::write_volatile(addr as *mut u32, v) }
}

/// `strata-qemu-machine=<name>` in the image, for the host (`hil::qemu_machine`).
#[used]
#[no_mangle]
pub static MACHINE_TAG: [u8; TAG.len()] = *TAG;

#[cfg(not(feature = "qemu-mps2"))]
const TAG: &[u8; 31] = b"strata-qemu-machine=lm3s6965evb";
#[cfg(feature = "qemu-mps2")]
const TAG: &[u8; 30] = b"strata-qemu-machine=mps2-an385";

#[cfg(not(feature = "qemu-mps2"))]
mod imp {
    use super::{reg_read, reg_write};

    /// QEMU's `-machine`.
    pub const NAME: &str = "lm3s6965evb";
    /// SysTick counts per interrupt (x 5 ns: an interrupt every 10,000 instructions).
    pub const RELOAD: u32 = 2000;

    const UART0: usize = 0x4000_C000;
    const UART_DR: usize = UART0;
    const UART_FR: usize = UART0 + 0x018;
    const UART_LCRH: usize = UART0 + 0x02C;
    const UART_CR: usize = UART0 + 0x030;
    const FR_RXFE: u32 = 1 << 4;
    const FR_TXFF: u32 = 1 << 5;
    const SYSCTL_RCC: usize = 0x400F_E060;

    /// Sets the clock and the UART up; returns the SysTick period, ns.
    pub fn init() -> u32 {
        // 200 MHz: SYSDIV = 0 (QEMU: period = 5 ns x (SYSDIV + 1)); USESYSDIV.
        let rcc = reg_read(SYSCTL_RCC);
        reg_write(SYSCTL_RCC, (rcc & !(0xF << 23)) | (1 << 22));
        let sysdiv = (reg_read(SYSCTL_RCC) >> 23) & 0xF;
        // UART0: 8N1 with FIFOs; the baud rate does not matter to QEMU.
        reg_write(UART_CR, 0);
        reg_write(UART_LCRH, (3 << 5) | (1 << 4));
        reg_write(UART_CR, (1 << 9) | (1 << 8) | 1);
        5 * (sysdiv + 1)
    }

    /// A received byte, if one waits.
    pub fn uart_read() -> Option<u8> {
        (reg_read(UART_FR) & FR_RXFE == 0).then(|| reg_read(UART_DR) as u8)
    }

    /// Sends a byte (waits while the transmit FIFO is full).
    pub fn uart_write(b: u8) {
        while reg_read(UART_FR) & FR_TXFF != 0 {}
        reg_write(UART_DR, b as u32);
    }

    /// The SD card's bus: SSI0 (a PL022 at 0x4000_8000) and its chip select, GPIO D0
    /// (active low; QEMU wires the same line, active high, to the OLED's select).
    pub struct SdBus;

    const SSI0: usize = 0x4000_8000;
    const SSI_CR0: usize = SSI0;
    const SSI_CR1: usize = SSI0 + 0x004;
    const SSI_DR: usize = SSI0 + 0x008;
    const SSI_SR: usize = SSI0 + 0x00C;
    const SSI_CPSR: usize = SSI0 + 0x010;
    /// Receive FIFO not empty.
    const SR_RNE: u32 = 1 << 2;
    const GPIO_D: usize = 0x4000_7000;
    /// GPIO D0's data (the address bits 9:2 mask the pins written: D0 only).
    const GPIO_D0_DATA: usize = GPIO_D + (1 << 2);
    const GPIO_DIR: usize = GPIO_D + 0x400;
    const GPIO_DEN: usize = GPIO_D + 0x51C;

    impl SdBus {
        /// SSI0 as an SPI master, mode 0, 8-bit frames; D0 an output, the card released.
        pub fn new() -> Self {
            reg_write(GPIO_DIR, reg_read(GPIO_DIR) | 1);
            reg_write(GPIO_DEN, reg_read(GPIO_DEN) | 1);
            reg_write(GPIO_D0_DATA, 1);
            reg_write(SSI_CR1, 0);
            reg_write(SSI_CPSR, 2);
            // SPI frame format, SPO = SPH = 0, 8 data bits.
            reg_write(SSI_CR0, 7);
            // Master, enabled.
            reg_write(SSI_CR1, 1 << 1);
            Self
        }
    }

    impl strata::card::sd::SpiLink for SdBus {
        fn transfer(&mut self, out: u8) -> u8 {
            reg_write(SSI_DR, u32::from(out));
            while reg_read(SSI_SR) & SR_RNE == 0 {}
            reg_read(SSI_DR) as u8
        }

        fn select(&mut self, selected: bool) {
            reg_write(GPIO_D0_DATA, u32::from(!selected));
        }
    }
}

#[cfg(feature = "qemu-mps2")]
mod imp {
    use super::{reg_read, reg_write};

    /// QEMU's `-machine`.
    pub const NAME: &str = "mps2-an385";
    /// SysTick counts per interrupt (x 40 ns: an interrupt every 10,000 instructions).
    pub const RELOAD: u32 = 250;

    const UART0: usize = 0x4000_4000;
    const UART_DATA: usize = UART0;
    const UART_STATE: usize = UART0 + 0x004;
    const UART_CTRL: usize = UART0 + 0x008;
    const UART_BAUDDIV: usize = UART0 + 0x010;
    const STATE_TX_FULL: u32 = 1 << 0;
    const STATE_RX_FULL: u32 = 1 << 1;
    /// The fixed system clock (QEMU's `SYSCLK_FRQ`, 25 MHz), ns per SysTick count.
    const PERIOD_NS: u32 = 40;

    /// Sets the UART up; returns the SysTick period, ns.
    pub fn init() -> u32 {
        // The smallest divider the UART takes (QEMU ignores the baud rate).
        reg_write(UART_BAUDDIV, 16);
        reg_write(UART_CTRL, 0b11);
        PERIOD_NS
    }

    /// A received byte, if one waits.
    pub fn uart_read() -> Option<u8> {
        (reg_read(UART_STATE) & STATE_RX_FULL != 0).then(|| reg_read(UART_DATA) as u8)
    }

    /// Sends a byte (waits while the transmit buffer is full).
    pub fn uart_write(b: u8) {
        while reg_read(UART_STATE) & STATE_TX_FULL != 0 {}
        reg_write(UART_DATA, b as u32);
    }
}

pub use imp::*;

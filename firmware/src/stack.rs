//! Stack painting: the free RAM between the end of the statics and the stack pointer is
//! filled with a pattern at start-up; the lowest overwritten word gives the high-water mark.

use core::ptr::{addr_of, read_volatile, write_volatile};

const PAINT: u32 = 0xC0DE_5AFE;

extern "C" {
    /// Lowest stack address (end of .bss/.uninit), from cortex-m-rt's link.x.
    static _stack_end: u32;
    /// Initial stack pointer (top of RAM).
    static _stack_start: u32;
    /// Start of .data (RAM), from link.x.
    static __sdata: u32;
}

fn bounds() -> (usize, usize) {
    // Only the addresses of the linker symbols are taken, never their contents.
    (addr_of!(_stack_end) as usize, addr_of!(_stack_start) as usize)
}

/// Paints the unused stack below the current stack pointer. Call first thing in `main`.
#[inline(never)]
pub fn paint() {
    let (lo, _) = bounds();
    // Leave the words just below the current frame alone (this function's own use).
    let sp = cortex_m::register::msp::read() as usize - 64;
    let mut p = lo;
    while p < sp {
        // SAFETY: [_stack_end, sp) is RAM that no Rust object occupies: above every static,
        // below the live stack.
        unsafe { write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// (bytes of stack ever used, bytes available for the stack).
pub fn high_water() -> (u32, u32) {
    let (lo, hi) = bounds();
    let mut p = lo;
    // SAFETY: reading words of RAM inside the stack region (possibly in use: only compared).
    while p < hi && unsafe { read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    ((hi - p) as u32, (hi - lo) as u32)
}

/// Bytes of RAM taken by .data, .bss and .uninit (everything below the stack region).
pub fn data_bss() -> u32 {
    let (lo, _) = bounds();
    // The address of a linker symbol only.
    let start = addr_of!(__sdata) as usize;
    (lo - start) as u32
}

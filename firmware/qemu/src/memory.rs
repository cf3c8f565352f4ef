//! Memory use: stack painting for the stack peak, and section sizes from the linker symbols.

use core::ptr::{addr_of, read_volatile, write_volatile};

/// `FLASH` in `memory.x`.
const FLASH_ORIGIN: usize = 0;
const PAINT: u32 = 0xDEAD_BEEF;
/// Left unpainted below the live stack pointer: the painting function's own frame and a margin.
const MARGIN: usize = 256;

extern "C" {
    static _stack_start: u32;
    static _stack_end: u32;
    static __erodata: u32;
    static __sdata: u32;
    static __edata: u32;
    static __sbss: u32;
    static __ebss: u32;
    static __suninit: u32;
    static __euninit: u32;
}

fn addr(s: *const u32) -> usize {
    s as usize
}

/// Section sizes of the running image, in bytes.
#[derive(Clone, Copy, Debug)]
pub struct Sizes {
    /// Vector table, .text and .rodata: code and constants, a built-in model included.
    pub code: usize,
    /// Initial values of .data, stored in flash next to the code.
    pub data_init: usize,
    /// .data + .bss + .uninit: RAM that is not stack.
    pub static_ram: usize,
    /// What is left for the stack.
    pub stack_space: usize,
}

pub fn sizes() -> Sizes {
    {
        let data = addr(addr_of!(__edata)) - addr(addr_of!(__sdata));
        let bss = addr(addr_of!(__ebss)) - addr(addr_of!(__sbss));
        let uninit = addr(addr_of!(__euninit)) - addr(addr_of!(__suninit));
        // The vector table starts the flash.
        let code = addr(addr_of!(__erodata)) - FLASH_ORIGIN;
        Sizes {
            code,
            data_init: data,
            static_ram: data + bss + uninit,
            stack_space: addr(addr_of!(_stack_start)) - addr(addr_of!(_stack_end)),
        }
    }
}

fn stack_bounds() -> (usize, usize) {
    (addr(addr_of!(_stack_end)), addr(addr_of!(_stack_start)))
}

/// Fills the unused stack below the current stack pointer with a pattern. Call it early in
/// `main`, then [`stack_peak`] tells the deepest the stack has been since.
#[inline(never)]
pub fn paint_stack() {
    let (bottom, _) = stack_bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let mut p = bottom;
    while p + MARGIN < sp {
        // SAFETY: between the end of the static sections and below the live stack: memory that
        // nothing uses yet.
        unsafe { write_volatile(p as *mut u32, PAINT) };
        p += 4;
    }
}

/// Bytes of stack used at the deepest point since [`paint_stack`]: from the top of RAM down to
/// the lowest word whose paint was overwritten.
pub fn stack_peak() -> usize {
    let (bottom, top) = stack_bounds();
    let mut p = bottom;
    // SAFETY: reads inside the stack region.
    while p < top && unsafe { read_volatile(p as *const u32) } == PAINT {
        p += 4;
    }
    top - p
}

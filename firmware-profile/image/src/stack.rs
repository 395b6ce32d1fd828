//! The stack's deepest use, by painting: the free RAM between the end of the statics and the
//! stack pointer is filled with a pattern at start-up; later, the lowest word the pattern no
//! longer holds marks how deep the stack went.
#![allow(unsafe_code)]

const PAINT: u32 = 0xDEAD_BEEF;

extern "C" {
    // cortex-m-rt's linker script: the end of .bss (the free RAM starts here).
    static mut __ebss: u32;
}

/// Where the paint ends (the stack pointer at start-up, a little below): pass it to [`used`].
pub struct Painted {
    top: usize,
}

/// Paints the free RAM below the current stack pointer.
pub fn paint() -> Painted {
    let sp = cortex_m::register::msp::read() as usize;
    // Leave the frames of this call and its caller alone.
    let top = (sp - 256) & !3;
    let bottom = core::ptr::addr_of_mut!(__ebss) as usize;
    let mut at = bottom;
    while at < top {
        // SAFETY: `at` is word-aligned and lies between the end of the statics and the live
        // stack (below the stack pointer, above nothing allocated: there is no heap).
        unsafe { core::ptr::write_volatile(at as *mut u32, PAINT) };
        at += 4;
    }
    Painted { top: sp }
}

/// The stack's deepest use so far, bytes below the stack pointer at [`paint`]'s call.
pub fn used(p: Painted) -> usize {
    let bottom = core::ptr::addr_of_mut!(__ebss) as usize;
    let mut at = bottom;
    // SAFETY: reads of the painted region, word-aligned, below the live stack frames.
    while at < p.top && unsafe { core::ptr::read_volatile(at as *const u32) } == PAINT {
        at += 4;
    }
    p.top.saturating_sub(at)
}

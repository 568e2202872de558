//! The Cortex-M board instruments ([`Probe`]): SysTick as the tick counter and a painted stack
//! for its high-water mark.
//!
//! SysTick is a 24-bit down-counter of core clock cycles, read as an up-counter. On mps2-an386
//! the core clock is 25 MHz; under QEMU's `-icount shift=0` one tick is 40 guest instructions.
//! [`CortexProbe::start`] fills the free stack below the caller's frame with a pattern; the
//! lowest word no longer holding it marks the deepest the stack has grown.

use crate::device::Probe;
use cortex_m::peripheral::{syst::SystClkSource, SYST};
use deltaz_shared::protocol::BoardClock;

/// The counter's range: 24 bits.
const MASK: u32 = 0x00FF_FFFF;
/// The paint.
const PAINT: u32 = 0xA5A5_A5A5;
/// Bytes below the stack pointer left unpainted (this function's own frame).
const MARGIN: usize = 256;

extern "C" {
    /// Start of the heap = end of the statics (cortex-m-rt's linker script).
    static __sheap: u32;
    /// Top of the stack (cortex-m-rt's linker script).
    static _stack_start: u32;
}

/// SysTick, the stack gauge and the board's clock.
pub struct CortexProbe {
    _syst: SYST,
    clock: BoardClock,
}

impl CortexProbe {
    /// Start SysTick counting and paint the free stack. Call it early in `main`, before the big
    /// work: what lies below the caller's frame is free then. `clock` is the core clock the
    /// board set up (SysTick counts it).
    pub fn start(mut syst: SYST, clock: BoardClock) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(MASK);
        syst.clear_current();
        syst.enable_counter();
        let bottom = core::ptr::addr_of!(__sheap) as usize;
        let sp = cortex_m::register::msp::read() as usize;
        let mut word = bottom;
        while word + MARGIN < sp {
            // SAFETY: [__sheap, sp − MARGIN) is stack nobody uses yet (no heap in this
            // program); the addresses are word-aligned RAM from the linker script.
            unsafe { core::ptr::write_volatile(word as *mut u32, PAINT) };
            word += 4;
        }
        Self { _syst: syst, clock }
    }
}

impl Probe for CortexProbe {
    fn now(&mut self) -> u32 {
        MASK - SYST::get_current()
    }

    /// Ticks since `start`, modulo 2²⁴ (a compute longer than 0.67 s at 25 MHz wraps).
    fn since(&mut self, start: u32) -> u32 {
        self.now().wrapping_sub(start) & MASK
    }

    fn stack_peak(&mut self) -> u32 {
        let bottom = core::ptr::addr_of!(__sheap) as usize;
        let top = core::ptr::addr_of!(_stack_start) as usize;
        let mut word = bottom;
        // SAFETY: as in `start`: word-aligned RAM between the statics and the stack top.
        while word < top && unsafe { core::ptr::read_volatile(word as *const u32) } == PAINT {
            word += 4;
        }
        (top - word) as u32
    }

    fn clock(&self) -> Option<BoardClock> {
        Some(self.clock)
    }
}

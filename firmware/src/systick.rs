//! SysTick as the device's [`Clock`]: a 24-bit down-counter of core clock cycles, read as an
//! up-counter. On mps2-an386 the core clock is 25 MHz; under QEMU's `-icount shift=0` one tick is
//! 40 guest instructions.

use crate::device::Clock;
use cortex_m::peripheral::{syst::SystClkSource, SYST};

/// The counter's range: 24 bits.
const MASK: u32 = 0x00FF_FFFF;

/// SysTick, running from the core clock with the full 24-bit reload.
pub struct SysTickClock {
    _syst: SYST,
}

impl SysTickClock {
    /// Start SysTick counting.
    pub fn start(mut syst: SYST) -> Self {
        syst.set_clock_source(SystClkSource::Core);
        syst.set_reload(MASK);
        syst.clear_current();
        syst.enable_counter();
        Self { _syst: syst }
    }
}

impl Clock for SysTickClock {
    fn now(&mut self) -> u32 {
        MASK - SYST::get_current()
    }

    /// Ticks since `start`, modulo 2²⁴ (a compute longer than 0.67 s at 25 MHz wraps).
    fn since(&mut self, start: u32) -> u32 {
        self.now().wrapping_sub(start) & MASK
    }
}

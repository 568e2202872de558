//! Board shell for QEMU's `mps2-an386` (Cortex-M4F, CMSDK UART0 at 0x4000_4000).
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board {
    use core::fmt::Write;
    use cortex_m_rt::entry;
    use panic_halt as _;

    /// CMSDK APB UART0 of the mps2-an386 board.
    struct Uart0;

    const UART0: usize = 0x4000_4000;
    const DATA: usize = UART0;
    const STATE: usize = UART0 + 0x04;
    const CTRL: usize = UART0 + 0x08;
    const BAUDDIV: usize = UART0 + 0x10;

    impl Uart0 {
        fn init() -> Self {
            // SAFETY: these are the CMSDK UART0 registers of this board, word-aligned MMIO that
            // nothing else in the program touches.
            unsafe {
                core::ptr::write_volatile(BAUDDIV as *mut u32, 217);
                core::ptr::write_volatile(CTRL as *mut u32, 0b11);
            }
            Uart0
        }

        fn write_byte(&mut self, byte: u8) {
            // SAFETY: as in `init`; STATE bit 0 is "TX buffer full".
            unsafe {
                while core::ptr::read_volatile(STATE as *const u32) & 1 != 0 {}
                core::ptr::write_volatile(DATA as *mut u32, u32::from(byte));
            }
        }
    }

    impl Write for Uart0 {
        fn write_str(&mut self, s: &str) -> core::fmt::Result {
            s.bytes().for_each(|b| self.write_byte(b));
            Ok(())
        }
    }

    #[entry]
    fn main() -> ! {
        let mut uart = Uart0::init();
        let _ = match deltaz_firmware::smoke::smoke_point() {
            Some(p) => writeln!(uart, "deltaz smoke point {:.6} {:.6} {:.6}", p.x, p.y, p.z),
            None => writeln!(uart, "deltaz smoke degenerate"),
        };
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("mps2_an386 is a board binary: build it with --target thumbv7em-none-eabihf");
}

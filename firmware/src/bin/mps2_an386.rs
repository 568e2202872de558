//! Board shell for QEMU's `mps2-an386` (Cortex-M4F, CMSDK UART0 at 0x4000_4000).
//!
//! At boot it prints the smoke line (followed by a 0x00 so a host's frame reader drops it), then
//! serves the protocol on UART0 until a `Reset` request, and resets. UART0's RX interrupt
//! (IRQ 0) queues the received bytes in a ring (`rx_ring`), so the device receives the next
//! frame while it answers the last; with the ring empty the serve loop sleeps (WFI).
//!
//! The calibration "flash" is the top 64 KiB of the 4 MiB code SRAM (0x003F_0000), outside every
//! linker region (see `build.rs`): `-kernel` loads only the ELF's segments, so a system reset
//! (SYSRESETREQ, or `system_reset` in the monitor) reloads the program but keeps this region,
//! and the calibration survives. A new QEMU process starts with it zeroed: no calibration.
//! SysTick runs from the 25 MHz core clock; under `-icount shift=0` one tick is 40 instructions.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod board {
    use core::mem::MaybeUninit;
    use cortex_m::interrupt::InterruptNumber;
    use cortex_m::peripheral::{NVIC, SCB};
    use cortex_m_rt::{entry, exception};
    use deltaz_firmware::device::MAX_CALIBRATION;
    use deltaz_firmware::probe::CortexProbe;
    use deltaz_firmware::rx_ring::{RxRing, RX_RING};
    use deltaz_firmware::server::Server;
    use deltaz_firmware::smoke::{smoke_line, smoke_point, SMOKE_LINE};
    use deltaz_firmware::store::{Store, HEADER};
    use deltaz_shared::protocol::{BoardClock, ClockSource};
    use embedded_io::{ErrorType, Write};
    use embedded_storage::nor_flash::{
        check_erase, check_read, check_write, ErrorType as FlashErrorType, NorFlash,
        NorFlashErrorKind, ReadNorFlash,
    };
    use panic_halt as _;

    /// CMSDK APB UART0 of the mps2-an386 board.
    struct Uart0;

    const UART0: usize = 0x4000_4000;
    const DATA: usize = UART0;
    const STATE: usize = UART0 + 0x04;
    const CTRL: usize = UART0 + 0x08;
    const INTCLEAR: usize = UART0 + 0x0C;
    const BAUDDIV: usize = UART0 + 0x10;
    const TX_FULL: u32 = 1;
    const RX_FULL: u32 = 2;
    /// STATE: the receiver overran (a byte lost; write 1 to clear).
    const RX_OVERRUN: u32 = 8;
    /// CTRL: transmitter (bit 0), receiver (1) and RX interrupt (3) enabled.
    const TX_RX_RXINT: u32 = 0b1011;
    /// INTSTATUS/INTCLEAR: the RX interrupt.
    const RX_INT: u32 = 2;

    /// UART0's RX interrupt (IRQ 0 on mps2-an386).
    #[derive(Clone, Copy)]
    struct Uart0Rx;

    // SAFETY: 0 is UART0's RX interrupt line on this board, a valid IRQ number.
    unsafe impl InterruptNumber for Uart0Rx {
        fn number(self) -> u16 {
            0
        }
    }

    impl Uart0 {
        fn init() -> Self {
            // SAFETY: these are the CMSDK UART0 registers of this board, word-aligned MMIO that
            // nothing else in the program touches.
            unsafe {
                core::ptr::write_volatile(BAUDDIV as *mut u32, 217);
                core::ptr::write_volatile(CTRL as *mut u32, TX_RX_RXINT);
            }
            Uart0
        }

        fn state(&self) -> u32 {
            // SAFETY: as in `init`; reading STATE has no side effect.
            unsafe { core::ptr::read_volatile(STATE as *const u32) }
        }

        fn write_byte(&mut self, byte: u8) {
            while self.state() & TX_FULL != 0 {}
            // SAFETY: as in `init`; TX has room.
            unsafe { core::ptr::write_volatile(DATA as *mut u32, u32::from(byte)) };
        }
    }

    impl ErrorType for Uart0 {
        type Error = core::convert::Infallible;
    }

    impl Write for Uart0 {
        fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
            buf.iter().for_each(|&b| self.write_byte(b));
            Ok(buf.len())
        }

        fn flush(&mut self) -> Result<(), Self::Error> {
            Ok(())
        }
    }

    /// The bytes UART0 receives, queued by its RX interrupt for the serve loop.
    static RX: RxRing<RX_RING> = RxRing::new();

    /// Every interrupt comes here (no device crate: cortex-m-rt's default vector table). IRQ 0,
    /// UART0's RX, moves the received bytes into [`RX`] (an overrun after them is a gap); any
    /// other (none is enabled) resets the board rather than hang.
    #[exception]
    unsafe fn DefaultHandler(irqn: i16) {
        if irqn != 0 {
            SCB::sys_reset();
        }
        let uart = Uart0;
        loop {
            let state = uart.state();
            if state & (RX_FULL | RX_OVERRUN) == 0 {
                break;
            }
            // SAFETY: as in `init`; the handler only reads DATA and clears receive flags, the
            // serve loop only writes DATA (transmit) and reads STATE, so neither disturbs the
            // other. Reading DATA takes the byte; writing 1 to STATE's overrun bit clears it;
            // INTCLEAR drops the RX interrupt (a byte arriving after it raises it again, one
            // arriving before is taken by the next turn of the loop).
            unsafe {
                if state & RX_FULL != 0 {
                    RX.push(core::ptr::read_volatile(DATA as *const u32) as u8);
                }
                if state & RX_OVERRUN != 0 {
                    core::ptr::write_volatile(STATE as *mut u32, RX_OVERRUN);
                    RX.lose();
                }
                core::ptr::write_volatile(INTCLEAR as *mut u32, RX_INT);
            }
        }
    }

    /// Start of the calibration region (see the module docs and `build.rs`).
    const REGION: usize = 0x003F_0000;
    /// Its length.
    const REGION_LEN: usize = 64 * 1024;
    /// One slot: the header and the largest calibration, in whole 4 KiB sectors.
    const SLOT: u32 = ((HEADER + MAX_CALIBRATION).div_ceil(4096) * 4096) as u32;
    const _: () = assert!(2 * SLOT as usize <= REGION_LEN);

    /// The emulated NOR flash: the calibration region with flash semantics (erase to 0xFF,
    /// writes clear bits), so the store logic is the same as on a real board.
    struct RegionFlash;

    impl FlashErrorType for RegionFlash {
        type Error = NorFlashErrorKind;
    }

    impl ReadNorFlash for RegionFlash {
        const READ_SIZE: usize = 1;

        fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
            check_read(self, offset, bytes.len())?;
            for (i, b) in bytes.iter_mut().enumerate() {
                // SAFETY: `check_read` kept offset + i inside the region, RAM reserved for this
                // store alone (outside every linker region).
                *b = unsafe {
                    core::ptr::read_volatile((REGION + offset as usize + i) as *const u8)
                };
            }
            Ok(())
        }

        fn capacity(&self) -> usize {
            REGION_LEN
        }
    }

    impl NorFlash for RegionFlash {
        const WRITE_SIZE: usize = 4;
        const ERASE_SIZE: usize = 4096;

        fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
            check_erase(self, from, to)?;
            for a in (REGION + from as usize..REGION + to as usize).step_by(4) {
                // SAFETY: as in `read`; `check_erase` kept the word-aligned range inside.
                unsafe { core::ptr::write_volatile(a as *mut u32, u32::MAX) };
            }
            Ok(())
        }

        fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
            check_write(self, offset, bytes.len())?;
            for (i, b) in bytes.iter().enumerate() {
                let a = (REGION + offset as usize + i) as *mut u8;
                // SAFETY: as in `read`; `check_write` kept the range inside.
                unsafe { core::ptr::write_volatile(a, core::ptr::read_volatile(a) & b) };
            }
            Ok(())
        }
    }

    #[entry]
    fn main() -> ! {
        let mut uart = Uart0::init();
        let mut line = [0u8; SMOKE_LINE];
        let n = smoke_line(smoke_point(), &mut line);
        line.iter().take(n).for_each(|&b| uart.write_byte(b));
        uart.write_byte(0);
        // The board's one clock: 25 MHz.
        let clock = BoardClock {
            hz: 25_000_000,
            source: ClockSource::Fixed,
        };
        let probe = cortex_m::Peripherals::take().map(|p| CortexProbe::start(p.SYST, clock));
        let store = Store::new(RegionFlash, [(0, SLOT), (SLOT, 2 * SLOT)]);
        if let (Some(probe), Ok(store)) = (probe, store) {
            // The server lives in a static, built there in place (no stack copy of it).
            if let Some(slot) = cortex_m::singleton!(: MaybeUninit<Server<RegionFlash, CortexProbe>> = MaybeUninit::uninit())
            {
                let server = Server::boot_in(slot, store, probe);
                // SAFETY: the handler (`DefaultHandler`) touches only the UART's receive side
                // and `RX`, a lock-free queue made for a producer preempting its consumer.
                unsafe { NVIC::unmask(Uart0Rx) };
                let Ok(()) = server.serve(&RX, || RX.sleep_while_idle(), || {}, &mut uart);
            }
        }
        SCB::sys_reset()
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("mps2_an386 is a board binary: build it with --target thumbv7em-none-eabihf");
}

//! Board shell for the STM32 Nucleo-F401RE (84 MHz Cortex-M4F, 512 KiB flash, 96 KiB SRAM;
//! stm32f4xx-hal): the protocol on USART2 (PA2/PA3, wired to the ST-LINK's USB virtual COM port)
//! at 2 Mbaud, the program in flash sectors 0-3 (64 KiB, see `build.rs`), the calibration store
//! in sectors 4 (64 KiB at 0x0801_0000) and 5 (128 KiB at 0x0802_0000), SysTick at the core
//! clock. The server (39.8 KB) is written in place into a static and the stack peaks at about
//! 6.9 KB (measured under QEMU with the same code).
//!
//! Build: `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release
//! --features nucleo-f401re --bin nucleo_f401re`; flash with probe-rs:
//! `probe-rs run --chip STM32F401RETx target/thumbv7em-none-eabihf/release/nucleo_f401re`.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use cortex_m::peripheral::SCB;
use cortex_m_rt::entry;
use deltaz_firmware::probe::CortexProbe;
use deltaz_firmware::server::Server;
use deltaz_firmware::store::Store;
use embedded_storage::nor_flash::{
    ErrorType as FlashErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use panic_halt as _;
use stm32f4xx_hal::flash::{FlashExt, LockedFlash};
use stm32f4xx_hal::prelude::*;
use stm32f4xx_hal::serial::{config::Config, Serial};
use stm32f4xx_hal::{block, pac, rcc};

/// Sector 4 (offset from the flash base).
const SLOT_A: (u32, u32) = (0x1_0000, 0x2_0000);
/// Sector 5.
const SLOT_B: (u32, u32) = (0x2_0000, 0x4_0000);

/// The on-chip flash, unlocked only for the duration of each erase or write.
struct Flash(LockedFlash);

impl FlashErrorType for Flash {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        ReadNorFlash::read(&mut self.0, offset, bytes).map_err(|e| e.kind())
    }

    fn capacity(&self) -> usize {
        ReadNorFlash::capacity(&self.0)
    }
}

impl NorFlash for Flash {
    const WRITE_SIZE: usize = 1;
    /// Sector 4's size; sector 5 is two of it (the HAL erases whole sectors).
    const ERASE_SIZE: usize = 64 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        NorFlash::erase(&mut self.0.unlocked(), from, to).map_err(|e| e.kind())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        NorFlash::write(&mut self.0.unlocked(), offset, bytes).map_err(|e| e.kind())
    }
}

/// USART2 as an embedded-io serial port (the HAL speaks embedded-io 0.6; the library 0.7).
struct Vcp(Serial<pac::USART2>);

impl embedded_io::ErrorType for Vcp {
    type Error = embedded_io::ErrorKind;
}

impl embedded_io::Read for Vcp {
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        let Some(first) = buf.first_mut() else {
            return Ok(0);
        };
        // Overrun and framing errors drop bytes; the framing layer resynchronises at the
        // next delimiter, so keep reading.
        *first = loop {
            if let Ok(byte) = block!(self.0.read()) {
                break byte;
            }
        };
        Ok(1)
    }
}

impl embedded_io::Write for Vcp {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &byte in buf {
            block!(self.0.write(byte)).map_err(|_| embedded_io::ErrorKind::Other)?;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        block!(self.0.flush()).map_err(|_| embedded_io::ErrorKind::Other)
    }
}

#[entry]
fn main() -> ! {
    if let (Some(dp), Some(cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) {
        // 8 MHz from the ST-LINK's MCO (bypass), PLL to 84 MHz; APB1 at 42 MHz gives 2 Mbaud
        // exactly (USARTDIV 1.3125).
        let cfg = rcc::Config::hse(8.MHz())
            .bypass_hse_oscillator()
            .sysclk(84.MHz())
            .pclk1(42.MHz());
        let mut rcc = dp.RCC.freeze(cfg);
        let gpioa = dp.GPIOA.split(&mut rcc);
        let serial = dp.USART2.serial(
            (gpioa.pa2, gpioa.pa3),
            Config::default().baudrate(2_000_000.bps()),
            &mut rcc,
        );
        let store = Store::new(Flash(LockedFlash::new(dp.FLASH)), [SLOT_A, SLOT_B]);
        if let (Ok(serial), Ok(store)) = (serial, store) {
            let probe = CortexProbe::start(cp.SYST);
            // The server lives in a static, built there in place (no stack copy of it).
            if let Some(slot) = cortex_m::singleton!(: MaybeUninit<Server<Flash, CortexProbe>> = MaybeUninit::uninit())
            {
                let server = Server::boot_in(slot, store, probe);
                let _ = server.serve(&mut Vcp(serial));
            }
        }
    }
    SCB::sys_reset()
}

//! Board shell for the STM32 Nucleo-F429ZI (stm32f4xx-hal): the protocol on USART3 (PD8/PD9,
//! wired to the ST-LINK's USB virtual COM port) at 2 Mbaud, the calibration store in flash
//! sectors 10 and 11 (128 KiB each at 0x080C_0000 and 0x080E_0000; the program lives in sectors
//! 0-9, see `build.rs`), SysTick at the 168 MHz core clock. The server (102 KB) lives in a
//! static, built there in place, and the stack peaks at about 67 KB (measured under QEMU with the
//! same code): 169 KB of the F429's 192 KB of SRAM.
//!
//! Build: `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release
//! --features nucleo-f429zi --bin nucleo_f429zi`.
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

/// Sector 10 (offset from the flash base).
const SLOT_A: (u32, u32) = (0xC_0000, 0xE_0000);
/// Sector 11.
const SLOT_B: (u32, u32) = (0xE_0000, 0x10_0000);

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
    const ERASE_SIZE: usize = 128 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        NorFlash::erase(&mut self.0.unlocked(), from, to).map_err(|e| e.kind())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        NorFlash::write(&mut self.0.unlocked(), offset, bytes).map_err(|e| e.kind())
    }
}

/// USART3 as an embedded-io serial port (the HAL speaks embedded-io 0.6; the library 0.7).
struct Vcp(Serial<pac::USART3>);

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
        // 8 MHz from the ST-LINK's MCO (bypass), PLL to 168 MHz; APB1 at 42 MHz gives 2 Mbaud
        // exactly (USARTDIV 1.3125).
        let cfg = rcc::Config::hse(8.MHz())
            .bypass_hse_oscillator()
            .sysclk(168.MHz())
            .pclk1(42.MHz());
        let mut rcc = dp.RCC.freeze(cfg);
        let gpiod = dp.GPIOD.split(&mut rcc);
        let serial = dp.USART3.serial(
            (gpiod.pd8, gpiod.pd9),
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

//! Board shell for the STM32 Nucleo-F401RE (84 MHz Cortex-M4F, 512 KiB flash, 96 KiB SRAM),
//! on the `stm32f4` register definitions (no HAL: its clock set-up brought panic paths and
//! 8.7 KB of flash): the protocol on USART2 (PA2/PA3, wired to the ST-LINK's USB virtual COM
//! port) at 2 Mbaud, the program in flash sectors 0-3 (64 KiB, see `build.rs`), the
//! calibration store in sectors 4 (64 KiB at 0x0801_0000) and 5 (128 KiB at 0x0802_0000),
//! SysTick at the core clock. The server (41.1 KB) is written in place into a static and the
//! stack peaks at about 2.9 KB (measured under QEMU with the same code): 45.1 KB in all.
//!
//! - **Watchdog**: the independent watchdog (IWDG, its own ~32 kHz LSI) resets the board when
//!   it is not fed for about 5 s ([`WATCHDOG_RELOAD`]); it is fed after every frame answered
//!   (progress: a stream at line rate that never lets the receive ring run empty keeps it fed),
//!   while the serve loop waits with an empty ring (woken by SysTick at least every 0.2 s) and
//!   in every flash wait. The longest
//!   operation, erasing the 128 KiB sector 5 (2 s at most), stalls the CPU (the code runs from
//!   the same flash bank), so the timeout covers it even with the LSI at its fastest (47 kHz:
//!   3.4 s).
//! - **Reception**: USART2's RX interrupt queues each byte in a ring (`rx_ring`, its size
//!   from the link budget), so the board receives while it computes and answers instead of
//!   overrunning the one-byte data register; a full ring or a UART error is a gap, and the
//!   frame it hits is answered `Overrun` (a resync).
//! - **Idle**: with the ring empty the board sleeps (WFI) until the RX interrupt or SysTick,
//!   instead of polling.
//!
//! Build: `cargo build -p deltaz-firmware --target thumbv7em-none-eabihf --release
//! --features nucleo-f401re --bin nucleo_f401re`; flash and run with probe-rs:
//! `probe-rs run --chip STM32F401RETx target/thumbv7em-none-eabihf/release/nucleo_f401re`.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use cortex_m::peripheral::{NVIC, SCB};
use cortex_m_rt::{entry, exception};
use deltaz_firmware::probe::CortexProbe;
use deltaz_firmware::rx_ring::{RxRing, RX_RING};
use deltaz_firmware::server::Server;
use deltaz_firmware::store::Store;
use deltaz_shared::protocol::{BoardClock, ClockSource};
use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType as FlashErrorType, NorFlash, NorFlashErrorKind,
    ReadNorFlash,
};
use panic_halt as _;
use stm32f4::stm32f401::{self as pac, interrupt};

/// Sector 4 (offset from the flash base).
const SLOT_A: (u32, u32) = (0x1_0000, 0x2_0000);
/// Sector 5.
const SLOT_B: (u32, u32) = (0x2_0000, 0x4_0000);
/// The on-chip flash: base address and size.
const FLASH_BASE: usize = 0x0800_0000;
const FLASH_SIZE: usize = 512 * 1024;
/// Where each flash sector starts (offsets), and the end of the last.
const SECTORS: [u32; 9] = [
    0x0_0000, 0x0_4000, 0x0_8000, 0x0_C000, 0x1_0000, 0x2_0000, 0x4_0000, 0x6_0000, 0x8_0000,
];
/// IWDG: LSI / 64 (500 Hz at 32 kHz), reload 2500: about 5 s (3.4 s at 47 kHz, 9.4 s at
/// 17 kHz, the LSI's limits).
const WATCHDOG_RELOAD: u16 = 2500;
/// Polls of a clock's or the watchdog's ready flag before the board goes on without it: at
/// least 8 ms at 84 MHz (a poll is a few cycles), where the HSE starts within 2 ms, the PLL
/// locks within 0.1 ms and the IWDG's registers update within 6 LSI periods (0.4 ms).
const READY_POLLS: u32 = 200_000;
/// Polls of the flash's busy flag before an operation counts as failed: at least 2.4 s at
/// 84 MHz (each poll also feeds the watchdog, about 10 cycles), beyond a 128 KiB sector's
/// erase (2 s at most).
const FLASH_POLLS: u32 = 20_000_000;
/// Polls of the USART's transmit flags: a byte takes 5 µs at 2 Mbaud (420 cycles at 84 MHz).
const TX_POLLS: u32 = 100_000;

/// Whether `ready` holds within `polls` polls: every wait of the board is bounded (a clock
/// that does not start, or an emulator that does not model a flag, cannot hang it).
fn within(polls: u32, mut ready: impl FnMut() -> bool) -> bool {
    (0..polls).any(|_| ready())
}

/// The independent watchdog, started: a handle that feeds it (the board's two users, the
/// serve loop's idle wait and the flash, each hold one).
#[derive(Clone, Copy)]
struct Watchdog;

impl Watchdog {
    fn start(iwdg: pac::IWDG) -> Self {
        iwdg.kr().write(|w| w.key().start());
        iwdg.kr().write(|w| w.key().unlock());
        iwdg.pr().write(|w| w.pr().divide_by64());
        iwdg.rlr().write(|w| w.rl().set(WATCHDOG_RELOAD));
        within(READY_POLLS, || iwdg.sr().read().bits() == 0);
        Watchdog.feed();
        Watchdog
    }

    fn feed(self) {
        // SAFETY: only a started `Watchdog` exists (the IWDG was taken by `start`); the feed is
        // one write of the key register, whole and idempotent, so concurrent handles are fine.
        let iwdg = unsafe { pac::IWDG::steal() };
        iwdg.kr().write(|w| w.key().feed());
    }
}

/// 84 MHz from the ST-LINK's 8 MHz MCO (HSE bypass): PLL M = 8 (1 MHz in), N = 336, P = 4;
/// AHB 84 MHz, APB1 42 MHz (÷ 2, its limit), APB2 84 MHz; flash 2 wait states, prefetch and
/// instruction cache (not the data cache: the store erases and writes the flash it reads).
/// Every wait is bounded ([`READY_POLLS`]): without the MCO (a board without it, an emulator)
/// the PLL runs from the internal 16 MHz oscillator (M = 16) instead, and when the PLL does not
/// lock either the board stays on the internal oscillator (16 MHz, APB1 undivided). Returns
/// the clock it runs on (`Info` reports it).
fn clocks(rcc: &pac::RCC, flash: &pac::FLASH) -> BoardClock {
    // The bypass is set while the HSE is off, then the HSE started.
    rcc.cr().modify(|_, w| w.hsebyp().set_bit());
    rcc.cr().modify(|_, w| w.hseon().set_bit());
    let external = within(READY_POLLS, || rcc.cr().read().hserdy().bit_is_set());
    if !external {
        rcc.cr().modify(|_, w| w.hseon().clear_bit());
        rcc.cr().modify(|_, w| w.hsebyp().clear_bit());
    }
    // SAFETY: M = 8 or 16, N = 336, Q = 7 are in their fields' ranges (2..=63, 50..=432,
    // 2..=15) and give a 336 MHz VCO from a 1 MHz input, both within the datasheet's limits.
    rcc.pllcfgr().write(|w| unsafe {
        let w = w
            .pllm()
            .bits(if external { 8 } else { 16 })
            .plln()
            .bits(336)
            .pllq()
            .bits(7)
            .pllp()
            .div4();
        if external {
            w.pllsrc().hse()
        } else {
            w.pllsrc().hsi()
        }
    });
    rcc.cr().modify(|_, w| w.pllon().set_bit());
    flash
        .acr()
        .write(|w| w.latency().ws2().prften().enabled().icen().enabled());
    if within(READY_POLLS, || rcc.cr().read().pllrdy().bit_is_set()) {
        // APB1 halved before the switch, so it never runs above 42 MHz.
        rcc.cfgr().modify(|_, w| w.ppre1().div2());
        rcc.cfgr().modify(|_, w| w.sw().pll());
        if within(READY_POLLS, || rcc.cfgr().read().sws().is_pll()) {
            let source = if external {
                ClockSource::External
            } else {
                ClockSource::InternalPll
            };
            return BoardClock {
                hz: 84_000_000,
                source,
            };
        }
        rcc.cfgr().modify(|_, w| w.sw().hsi());
        rcc.cfgr().modify(|_, w| w.ppre1().div1());
    }
    rcc.cr().modify(|_, w| w.pllon().clear_bit());
    BoardClock {
        hz: 16_000_000,
        source: ClockSource::Internal,
    }
}

/// USART2 on PA2 (TX) and PA3 (RX, pulled up), alternate function 7: 2 Mbaud 8N1 from APB1
/// (at 84 MHz 42 MHz: USARTDIV 1.3125 = 1 + 5/16, exact; on the internal oscillator alone
/// 16 MHz, oversampling by 8: USARTDIV 1, exact), its interrupt on a received byte or an
/// overrun.
fn usart2(rcc: &pac::RCC, gpioa: &pac::GPIOA, usart: &pac::USART2, clock: BoardClock) {
    rcc.ahb1enr().modify(|_, w| w.gpioaen().set_bit());
    rcc.apb1enr().modify(|_, w| w.usart2en().set_bit());
    gpioa.afrl().modify(|_, w| w.afrl2().af7().afrl3().af7());
    gpioa.pupdr().modify(|_, w| w.pupdr3().pull_up());
    gpioa
        .moder()
        .modify(|_, w| w.moder2().alternate().moder3().alternate());
    let pll = clock.hz == 84_000_000;
    usart.brr().write(|w| {
        w.div_mantissa()
            .set(1)
            .div_fraction()
            .set(if pll { 5 } else { 0 })
    });
    usart.cr1().write(|w| {
        w.over8()
            .bit(!pll)
            .ue()
            .set_bit()
            .te()
            .set_bit()
            .re()
            .set_bit()
            .rxneie()
            .set_bit()
    });
}

/// USART2's transmit side as an embedded-io serial port (its receive side is the interrupt's).
struct Vcp {
    usart: pac::USART2,
}

impl embedded_io::ErrorType for Vcp {
    type Error = core::convert::Infallible;
}

impl embedded_io::Write for Vcp {
    fn write(&mut self, buf: &[u8]) -> Result<usize, Self::Error> {
        for &byte in buf {
            // Bounded: a transmitter that never empties loses the byte (the host resends).
            within(TX_POLLS, || self.usart.sr().read().txe().bit_is_set());
            self.usart.dr().write(|w| w.dr().set(u16::from(byte)));
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> Result<(), Self::Error> {
        within(TX_POLLS, || self.usart.sr().read().tc().bit_is_set());
        Ok(())
    }
}

/// The on-chip flash, unlocked only for the duration of each erase or write; every wait
/// feeds the watchdog.
struct Flash {
    flash: pac::FLASH,
    dog: Watchdog,
}

impl Flash {
    /// Unlock the control register, run `op`, wait for the end, lock again; a programming
    /// error flag fails it.
    fn operate(&mut self, op: impl FnOnce(&pac::FLASH)) -> Result<(), NorFlashErrorKind> {
        let f = &self.flash;
        if !self.wait() {
            return Err(NorFlashErrorKind::Other);
        }
        f.keyr().write(|w| w.key().set(0x4567_0123));
        f.keyr().write(|w| w.key().set(0xCDEF_89AB));
        // Clear the error flags of an earlier operation (write 1 to clear).
        f.sr().write(|w| {
            w.pgserr()
                .clear_bit_by_one()
                .pgperr()
                .clear_bit_by_one()
                .pgaerr()
                .clear_bit_by_one()
                .wrperr()
                .clear_bit_by_one()
                .operr()
                .clear_bit_by_one()
        });
        op(f);
        let finished = self.wait();
        let sr = self.flash.sr().read();
        let failed = !finished
            || sr.pgserr().bit_is_set()
            || sr.pgperr().bit_is_set()
            || sr.pgaerr().bit_is_set()
            || sr.wrperr().bit_is_set()
            || sr.operr().bit_is_set();
        self.flash.cr().write(|w| w.lock().set_bit());
        if failed {
            Err(NorFlashErrorKind::Other)
        } else {
            Ok(())
        }
    }

    /// Wait for the flash to finish, feeding the watchdog; `false` when it does not within
    /// [`FLASH_POLLS`].
    fn wait(&self) -> bool {
        within(FLASH_POLLS, || {
            self.dog.feed();
            self.flash.sr().read().bsy().bit_is_clear()
        })
    }
}

impl FlashErrorType for Flash {
    type Error = NorFlashErrorKind;
}

impl ReadNorFlash for Flash {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_read(self, offset, bytes.len())?;
        for (i, b) in bytes.iter_mut().enumerate() {
            // SAFETY: `check_read` kept offset + i inside the 512 KiB of flash, which is
            // always readable memory.
            *b = unsafe {
                core::ptr::read_volatile((FLASH_BASE + offset as usize + i) as *const u8)
            };
        }
        Ok(())
    }

    fn capacity(&self) -> usize {
        FLASH_SIZE
    }
}

impl NorFlash for Flash {
    const WRITE_SIZE: usize = 1;
    /// The smallest sector's size; `erase` takes whole sectors only.
    const ERASE_SIZE: usize = 16 * 1024;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(self, from, to)?;
        let whole = |at: u32| SECTORS.contains(&at);
        if !(whole(from) && whole(to)) {
            return Err(NorFlashErrorKind::NotAligned);
        }
        for (sector, start) in SECTORS.iter().enumerate() {
            if (from..to).contains(start) {
                self.operate(|f| {
                    // `modify`, not `write`: a write starts from CR's reset value, whose LOCK
                    // bit would lock the register again before STRT.
                    // SAFETY: `sector` < 8 fits SNB (4 bits); x32 parallelism needs
                    // 2.7-3.6 V (the Nucleo runs at 3.3 V).
                    f.cr().modify(|_, w| {
                        unsafe { w.ser().set_bit().snb().bits(sector as u8) }
                            .psize()
                            .psize32()
                    });
                    f.cr().modify(|_, w| w.strt().set_bit());
                })?;
            }
        }
        Ok(())
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_write(self, offset, bytes.len())?;
        for (i, &byte) in bytes.iter().enumerate() {
            let at = (FLASH_BASE + offset as usize + i) as *mut u8;
            self.operate(|f| {
                // `modify`: a `write` would set LOCK too (CR's reset value).
                f.cr().modify(|_, w| w.pg().set_bit().psize().psize8());
                // SAFETY: `check_write` kept the address inside the flash; with PG set, a byte
                // write to it programs that byte (an erased one: the store writes each once).
                unsafe { core::ptr::write_volatile(at, byte) };
            })?;
        }
        Ok(())
    }
}

/// The bytes USART2 receives, queued by its RX interrupt for the serve loop.
static RX: RxRing<RX_RING> = RxRing::new();

/// USART2's RX interrupt (RXNE, or an overrun): the byte into [`RX`]; an overrun, a framing
/// error or noise on the line is a gap (the byte with a framing error or noise is dropped).
#[interrupt]
fn USART2() {
    // SAFETY: the handler only reads SR and DR (the receive side: the SR-then-DR read clears
    // RXNE and the error flags); the serve loop's `Vcp` only writes DR and reads SR (the
    // transmit side), so neither disturbs the other.
    let usart = unsafe { pac::USART2::steal() };
    let sr = usart.sr().read();
    if sr.rxne().bit_is_set() || sr.ore().bit_is_set() {
        let byte = usart.dr().read().dr().bits() as u8;
        if sr.fe().bit_is_set() || sr.nf().bit_is_set() {
            RX.lose();
        } else {
            RX.push(byte);
        }
        // The byte lost to an overrun came after the one just read.
        if sr.ore().bit_is_set() {
            RX.lose();
        }
    }
}

/// SysTick wraps every 0.2 s (2²⁴ cycles at 84 MHz; 1.05 s on the internal 16 MHz oscillator,
/// still within the watchdog's 3.4 s) and wakes the idle wait to feed the
/// watchdog; nothing else to do.
#[exception]
fn SysTick() {}

#[entry]
fn main() -> ! {
    if let (Some(dp), Some(cp)) = (pac::Peripherals::take(), cortex_m::Peripherals::take()) {
        let clock = clocks(&dp.RCC, &dp.FLASH);
        usart2(&dp.RCC, &dp.GPIOA, &dp.USART2, clock);
        let mut syst = cp.SYST;
        syst.enable_interrupt();
        let probe = CortexProbe::start(syst, clock);
        // The watchdog stops while a debugger (probe-rs) holds the core halted.
        dp.DBGMCU
            .apb1_fz()
            .modify(|_, w| w.dbg_iwdg_stop().set_bit());
        let dog = Watchdog::start(dp.IWDG);
        let flash = Flash {
            flash: dp.FLASH,
            dog,
        };
        if let Ok(store) = Store::new(flash, [SLOT_A, SLOT_B]) {
            // The server lives in a static, built there in place (no stack copy of it).
            if let Some(slot) = cortex_m::singleton!(: MaybeUninit<Server<Flash, CortexProbe>> = MaybeUninit::uninit())
            {
                let server = Server::boot_in(slot, store, probe);
                // SAFETY: the handler (`USART2`) touches only the receive side and `RX`, a
                // lock-free queue made for a producer preempting its consumer.
                unsafe { NVIC::unmask(pac::Interrupt::USART2) };
                // Fed while waiting for the host and after every frame answered: by progress,
                // so a stream that never lets the ring run empty keeps it fed.
                let idle = || {
                    dog.feed();
                    RX.sleep_while_idle();
                };
                let progress = || dog.feed();
                let Ok(()) = server.serve(&RX, idle, progress, &mut Vcp { usart: dp.USART2 });
            }
        }
    }
    SCB::sys_reset()
}

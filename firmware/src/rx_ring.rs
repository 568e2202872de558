//! The bytes a board's UART receives, queued by its RX interrupt handler for the serve loop: a
//! single-producer single-consumer ring of atomics (no lock, no `unsafe`), so reception goes on
//! while the device computes and sends an answer instead of overrunning the UART's one-byte
//! data register.
//!
//! When the ring is full (or the UART itself reports an overrun or framing error), the bytes are
//! lost: the ring drops every further byte until the serve loop has emptied it, then reports
//! one [`Received::Gap`] exactly where the bytes went missing. The server drops the frame in
//! progress there and answers it with `WireError::Overrun` at its delimiter (a bad frame in the
//! device's statistics): a resynchronisation, never a frame with bytes missing.
//!
//! # Size: the link budget
//! At 2 Mbaud 8N1 a byte takes 5 µs (200,000 B/s). A 440-dot labelled frame is a 2,235-byte
//! request (5.08 B per point) and a 4,413-byte answer (10.03 B per point): the answer takes
//! 22 ms on the line, and its compute (about 249,000 instructions, 3 ms at 84 MHz) is
//! interleaved with it (the answer is streamed out as it is computed). Meanwhile the server's
//! receive buffer holds the request being answered (it is read in place), and the bytes that
//! arrive wait here: 600 B during the compute alone, 2,235 B (the whole next request) with two
//! requests in flight. So before each COBS block of the answer the serve loop moves what the
//! ring holds of the next request into the receive buffer behind the one answered
//! ([`crate::server::Server::serve`]: 3,648 B less that request, 1,412 B behind a 440-dot one):
//! the ring holds only the rest, 826 B at line rate (`tests/tests/it/full_duplex.rs`). Without
//! the ring the device's RAM (static and stack peak) is 46,656 B of the 48 KB budget, so the
//! ring gets 1 KiB ([`RX_RING`], 47,692 B in all): a second 440-dot request in flight with 197 B
//! to spare, and interrupt latency. A host keeps at most two requests, of
//! [`crate::server::IN_FLIGHT_BYTES`] together, in flight to a board (a third would wait whole
//! here while the second is answered).

use core::sync::atomic::{AtomicBool, AtomicU8, AtomicUsize, Ordering};

/// The ring's size in bytes (it holds one less): see the module docs.
pub const RX_RING: usize = 1024;

/// What the serve loop takes from the ring.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Received {
    /// The next byte on the line.
    Byte(u8),
    /// Bytes were lost here (the ring was full or the UART overran).
    Gap,
}

/// A ring of `N` bytes between one producer (the RX interrupt handler: [`RxRing::push`],
/// [`RxRing::lose`]) and one consumer (the serve loop: [`RxRing::pop`]). Both sides may run
/// on other cores or preempt each other; each index is written by one side only.
pub struct RxRing<const N: usize> {
    bytes: [AtomicU8; N],
    /// Where the producer writes next (written by the producer only), `0..N`.
    head: AtomicUsize,
    /// Where the consumer reads next (written by the consumer only), `0..N`.
    tail: AtomicUsize,
    /// Bytes were lost: the producer drops everything until the consumer has emptied the ring
    /// and cleared this (set by the producer, cleared by the consumer).
    lost: AtomicBool,
}

impl<const N: usize> Default for RxRing<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RxRing<N> {
    /// An empty ring (usable in a `static`).
    pub const fn new() -> Self {
        const { assert!(N >= 2, "a ring holds N - 1 bytes") };
        Self {
            bytes: [const { AtomicU8::new(0) }; N],
            head: AtomicUsize::new(0),
            tail: AtomicUsize::new(0),
            lost: AtomicBool::new(false),
        }
    }

    /// Producer: queue a received byte, or lose it (and everything after it until the
    /// consumer has caught up) when the ring is full.
    pub fn push(&self, byte: u8) {
        if self.lost.load(Ordering::Acquire) {
            return;
        }
        let head = self.head.load(Ordering::Relaxed);
        let next = if head + 1 == N { 0 } else { head + 1 };
        match self.bytes.get(head) {
            // The consumer's Release store of `tail` ordered its read of the slot first.
            Some(slot) if next != self.tail.load(Ordering::Acquire) => {
                slot.store(byte, Ordering::Relaxed);
                self.head.store(next, Ordering::Release);
            }
            _ => self.lose(),
        }
    }

    /// Producer: bytes were lost before the next one (the ring was full, or the UART reports
    /// an overrun or a framing error).
    pub fn lose(&self) {
        self.lost.store(true, Ordering::Release);
    }

    /// Consumer: the next byte, a gap where bytes were lost, or `None` when the ring is empty.
    pub fn pop(&self) -> Option<Received> {
        // The flag first: once it is set the producer queues nothing, so an empty ring after
        // it stays empty and the gap comes after every byte still queued.
        let lost = self.lost.load(Ordering::Acquire);
        let tail = self.tail.load(Ordering::Relaxed);
        if tail == self.head.load(Ordering::Acquire) {
            if !lost {
                return None;
            }
            self.lost.store(false, Ordering::Release);
            return Some(Received::Gap);
        }
        let byte = self.bytes.get(tail)?.load(Ordering::Relaxed);
        let next = if tail + 1 == N { 0 } else { tail + 1 };
        self.tail.store(next, Ordering::Release);
        Some(Received::Byte(byte))
    }

    /// The bytes queued now (a reading either side may take: the other may change it at once).
    pub fn queued(&self) -> usize {
        let head = self.head.load(Ordering::Acquire);
        let tail = self.tail.load(Ordering::Acquire);
        if head >= tail {
            head - tail
        } else {
            head + N - tail
        }
    }

    /// Whether the consumer has nothing to take (no byte, no gap): the serve loop may sleep.
    pub fn is_idle(&self) -> bool {
        !self.lost.load(Ordering::Acquire)
            && self.tail.load(Ordering::Relaxed) == self.head.load(Ordering::Acquire)
    }

    /// Consumer on a Cortex-M board: sleep (WFI) while the ring is idle. The check and the WFI
    /// run with interrupts masked (PRIMASK), so a byte queued by the RX interrupt just before
    /// cannot be missed: its pending interrupt ends the WFI, and its handler runs when PRIMASK
    /// clears.
    #[cfg(target_os = "none")]
    pub fn sleep_while_idle(&self) {
        cortex_m::interrupt::free(|_| {
            if self.is_idle() {
                cortex_m::asm::wfi();
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn drain<const N: usize>(ring: &RxRing<N>) -> Vec<Received> {
        core::iter::from_fn(|| ring.pop()).collect()
    }

    #[test]
    fn bytes_come_out_in_order_across_the_wrap() {
        let ring = RxRing::<8>::new();
        let mut expected = Vec::new();
        for round in 0..5u8 {
            for i in 0..5 {
                ring.push(round * 10 + i);
                expected.push(Received::Byte(round * 10 + i));
            }
            assert_eq!(drain(&ring), expected);
            expected.clear();
            assert!(ring.is_idle());
        }
    }

    #[test]
    fn a_full_ring_loses_bytes_until_drained_then_reports_one_gap() {
        let ring = RxRing::<8>::new();
        (1..=7).for_each(|b| ring.push(b));
        // Full (7 of 8): these are lost, and so is everything until the ring is empty, even
        // after the consumer made room.
        ring.push(8);
        assert_eq!(ring.pop(), Some(Received::Byte(1)));
        ring.push(9);
        assert!(!ring.is_idle());
        let rest = drain(&ring);
        assert_eq!(rest.last(), Some(&Received::Gap));
        assert_eq!(rest.len(), 7);
        assert!((2..=7).all(|b| rest.contains(&Received::Byte(b))));
        // After the gap the ring takes bytes again.
        ring.push(10);
        assert_eq!(drain(&ring), [Received::Byte(10)]);
    }

    #[test]
    fn a_uart_error_is_a_gap_after_the_bytes_before_it() {
        let ring = RxRing::<8>::new();
        ring.push(1);
        ring.lose();
        ring.push(2);
        assert_eq!(drain(&ring), [Received::Byte(1), Received::Gap]);
        assert!(ring.is_idle());
    }
}

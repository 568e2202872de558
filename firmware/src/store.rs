//! The calibration store: two slots in NOR flash, power-fail safe.
//!
//! Each slot is its own erase region:
//!
//! | offset | bytes | content |
//! |---|---|---|
//! | 0 | 4 | magic `DZC1` (u32 LE 0x3143_5A44) |
//! | 4 | 4 | generation (u32 LE, +1 per save) |
//! | 8 | 4 | blob length |
//! | 12 | 4 | CRC-32 of the blob |
//! | 16 | 4 | CRC-32 of bytes 0..16 |
//! | 20 | 12 | 0xFF |
//! | 32 | len | the blob (padded with 0xFF to the write size) |
//!
//! A save goes to the slot that does *not* hold the newest valid calibration:
//!
//! | step | operation | if the power fails here |
//! |---|---|---|
//! | 1 | erase the slot, check it reads back erased | the other slot still holds the newest |
//! | 2 | write the blob after the header | header still erased: slot invalid |
//! | 3 | read back and check the CRC | — |
//! | 4 | write the header | header CRC or blob CRC fails: slot invalid |
//! | 5 | read back and validate the slot | — |
//!
//! At boot the valid slot with the highest generation wins, so a reader sees the old calibration
//! or the new one, never a mix. Why not `sequential-storage`: its API is async (a blocking flash
//! needs an adapter and an executor), one item is all this store holds, and the two-slot scheme
//! is short enough to test exhaustively here (a power cut at every flash operation).

use deltaz_shared::protocol::frame::CRC;
use embedded_storage::nor_flash::{NorFlash, NorFlashErrorKind};

const MAGIC: u32 = 0x3143_5A44;
/// Header bytes at the start of each slot.
pub const HEADER: usize = 32;
/// Bytes moved per flash read or write.
const PIECE: usize = 256;

/// Why the store failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreError {
    /// The flash reported this error.
    Flash(NorFlashErrorKind),
    /// The slots are not aligned to erase sectors, overlap, or are too small.
    Layout,
    /// The blob does not fit a slot.
    TooLarge,
    /// What was written does not read back.
    Verify,
}

impl<E: embedded_storage::nor_flash::NorFlashError> From<E> for StoreError {
    fn from(e: E) -> Self {
        StoreError::Flash(e.kind())
    }
}

/// A valid stored calibration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Stored {
    /// Which slot (0 or 1).
    pub slot: usize,
    /// Its generation.
    pub generation: u32,
    /// Blob length (bytes).
    pub len: usize,
}

/// The largest write unit of a flash the store works with (bytes).
const MAX_WRITE: usize = 16;

/// A blob being written into the spare slot ([`Store::begin`]); not yet valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pending {
    /// The slot written.
    pub slot: usize,
    generation: u32,
    len: usize,
    /// Bytes on the flash.
    written: usize,
    /// Bytes short of a write unit, waiting for the next.
    tail: [u8; MAX_WRITE],
    tail_len: usize,
}

impl Pending {
    /// The announced length.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the announced length is 0.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Bytes taken so far.
    pub fn received(&self) -> usize {
        self.written + self.tail_len
    }
}

/// Two slots of a NOR flash (see the module docs).
pub struct Store<F> {
    flash: F,
    slots: [(u32, u32); 2],
}

impl<F: NorFlash> Store<F> {
    /// A store over `flash` with slots `[start, end)` (byte offsets), each aligned to the erase
    /// size, not overlapping, and larger than the header.
    pub fn new(flash: F, slots: [(u32, u32); 2]) -> Result<Self, StoreError> {
        let erase = F::ERASE_SIZE as u32;
        let aligned = slots.iter().all(|&(s, e)| {
            s % erase == 0
                && e % erase == 0
                && e > s + HEADER as u32
                && e as usize <= flash.capacity()
        });
        let [a, b] = slots;
        if !aligned
            || (a.0 < b.1 && b.0 < a.1)
            || !HEADER.is_multiple_of(F::WRITE_SIZE)
            || !PIECE.is_multiple_of(F::WRITE_SIZE)
            || F::WRITE_SIZE > MAX_WRITE
        {
            return Err(StoreError::Layout);
        }
        Ok(Self { flash, slots })
    }

    /// The largest blob a slot holds.
    pub fn capacity(&self) -> usize {
        self.slots
            .iter()
            .map(|&(s, e)| (e - s) as usize - HEADER)
            .min()
            .unwrap_or(0)
    }

    /// The flash (for a test's inspection).
    pub fn flash(&self) -> &F {
        &self.flash
    }

    /// Give the flash back.
    pub fn into_flash(self) -> F {
        self.flash
    }

    /// The newest valid calibration, if any.
    pub fn newest(&mut self) -> Option<Stored> {
        let a = self.check(0);
        let b = self.check(1);
        match (a, b) {
            (Some(a), Some(b)) => Some(if b.generation > a.generation { b } else { a }),
            (a, b) => a.or(b),
        }
    }

    /// Read the newest valid calibration into `out`; returns it and its bytes.
    pub fn load<'o>(&mut self, out: &'o mut [u8]) -> Option<(Stored, &'o [u8])> {
        let stored = self.newest()?;
        let blob = out.get_mut(..stored.len)?;
        let start = self.range(stored.slot).0 + HEADER as u32;
        self.flash.read(start, blob).ok()?;
        // The slot was validated a moment ago; check again what was actually read.
        (CRC.checksum(blob) == self.header(stored.slot)?.2).then_some((stored, &*blob))
    }

    /// Save `blob` as the new newest calibration (steps in the module docs): [`Store::begin`],
    /// [`Store::append`], [`Store::seal`].
    pub fn save(&mut self, blob: &[u8]) -> Result<Stored, StoreError> {
        let mut pending = self.begin(blob.len())?;
        for piece in blob.chunks(PIECE) {
            self.append(&mut pending, piece)?;
        }
        if self.pending_crc(&mut pending)? != CRC.checksum(blob) {
            return Err(StoreError::Verify);
        }
        self.seal(&pending)
    }

    /// Start saving a blob of `len` bytes (step 1): erase the slot that does not hold the newest
    /// calibration. The newest stays valid until [`Store::seal`].
    pub fn begin(&mut self, len: usize) -> Result<Pending, StoreError> {
        if len > self.capacity() {
            return Err(StoreError::TooLarge);
        }
        let newest = self.newest();
        let slot = match newest {
            Some(s) => 1 - s.slot,
            None => 0,
        };
        let (start, end) = self.range(slot);
        self.flash.erase(start, end)?;
        // What the save will write must read back erased: a flash whose erase does not take
        // (or an emulator without a flash interface) refuses the upload here, at its start.
        let written = (HEADER + len).div_ceil(F::WRITE_SIZE) * F::WRITE_SIZE;
        let mut piece = [0u8; PIECE];
        let mut at = 0;
        while at < written {
            let n = (written - at).min(PIECE);
            let bytes = piece.get_mut(..n).unwrap_or_default();
            self.flash.read(start + at as u32, bytes)?;
            if bytes.iter().any(|&b| b != 0xFF) {
                return Err(StoreError::Verify);
            }
            at += n;
        }
        Ok(Pending {
            slot,
            generation: newest.map_or(1, |s| s.generation.wrapping_add(1)),
            len,
            written: 0,
            tail: [0xFF; MAX_WRITE],
            tail_len: 0,
        })
    }

    /// Write the blob's next bytes (step 2), as they arrive: whole write units go to the flash,
    /// a remainder waits in `pending` for the next bytes.
    pub fn append(&mut self, pending: &mut Pending, mut data: &[u8]) -> Result<(), StoreError> {
        let unit = F::WRITE_SIZE;
        if pending.received() + data.len() > pending.len {
            return Err(StoreError::TooLarge);
        }
        let base = self.range(pending.slot).0 + HEADER as u32;
        if pending.tail_len > 0 {
            let room = pending
                .tail
                .get_mut(pending.tail_len..unit)
                .unwrap_or_default();
            let take = room.len().min(data.len());
            room.iter_mut().zip(data).for_each(|(t, &b)| *t = b);
            pending.tail_len += take;
            data = data.get(take..).unwrap_or_default();
            if pending.tail_len < unit {
                return Ok(());
            }
            let unit_bytes = pending.tail.get(..unit).ok_or(StoreError::Layout)?;
            self.flash
                .write(base + pending.written as u32, unit_bytes)?;
            pending.written += unit;
            pending.tail_len = 0;
        }
        let (whole, rest) = data
            .split_at_checked(data.len() / unit * unit)
            .ok_or(StoreError::Layout)?;
        if !whole.is_empty() {
            self.flash.write(base + pending.written as u32, whole)?;
            pending.written += whole.len();
        }
        // rest.len() < unit ≤ MAX_WRITE: all of it fits the tail.
        pending.tail.iter_mut().zip(rest).for_each(|(t, &b)| *t = b);
        pending.tail_len = rest.len();
        Ok(())
    }

    /// Write the remainder, padded with 0xFF, and read back the CRC-32 of what was written
    /// (step 3).
    pub fn pending_crc(&mut self, pending: &mut Pending) -> Result<u32, StoreError> {
        if pending.tail_len > 0 {
            let unit = F::WRITE_SIZE;
            if let Some(padding) = pending.tail.get_mut(pending.tail_len..) {
                padding.fill(0xFF);
            }
            let base = self.range(pending.slot).0 + HEADER as u32;
            let unit_bytes = pending.tail.get(..unit).ok_or(StoreError::Layout)?;
            self.flash
                .write(base + pending.written as u32, unit_bytes)?;
            pending.written += pending.tail_len;
            pending.tail_len = 0;
        }
        self.data_crc(pending.slot, pending.received())
    }

    /// Whether the pending blob's bytes from `offset` are `data` (a chunk sent again).
    pub fn matches(&mut self, pending: &Pending, offset: usize, data: &[u8]) -> bool {
        let Some(end) = offset.checked_add(data.len()) else {
            return false;
        };
        if end > pending.received() {
            return false;
        }
        let mut piece = [0u8; 64];
        for (i, expected) in data.chunks(piece.len()).enumerate() {
            let at = offset + i * piece.len();
            let Some(got) = piece.get_mut(..expected.len()) else {
                return false;
            };
            for (k, b) in got.iter_mut().enumerate() {
                if let Some(&t) = (at + k)
                    .checked_sub(pending.written)
                    .and_then(|t| pending.tail.get(t))
                {
                    *b = t;
                } else if self
                    .read(pending.slot, at + k, core::slice::from_mut(b))
                    .is_err()
                {
                    return false;
                }
            }
            if got != expected {
                return false;
            }
        }
        true
    }

    /// Read `out.len()` bytes of the blob in `slot` from `offset` (a pending one too).
    pub fn read(&mut self, slot: usize, offset: usize, out: &mut [u8]) -> Result<(), StoreError> {
        if offset + out.len() > self.capacity() {
            return Err(StoreError::TooLarge);
        }
        let start = self.range(slot).0 + (HEADER + offset) as u32;
        self.flash.read(start, out)?;
        Ok(())
    }

    /// Make a complete, checked blob the newest calibration (steps 4-5): write its header and
    /// validate the slot.
    pub fn seal(&mut self, pending: &Pending) -> Result<Stored, StoreError> {
        let slot = pending.slot;
        if pending.tail_len > 0 || pending.received() != pending.len {
            return Err(StoreError::Verify);
        }
        let crc = self.data_crc(slot, pending.len)?;
        let mut header = [0xFFu8; HEADER];
        let words = [MAGIC, pending.generation, pending.len as u32, crc];
        for (bytes, v) in header.chunks_exact_mut(4).zip(words) {
            bytes.copy_from_slice(&v.to_le_bytes());
        }
        let header_crc = CRC.checksum(&header[..16]);
        header[16..20].copy_from_slice(&header_crc.to_le_bytes());
        self.flash.write(self.range(slot).0, &header)?;
        let stored = Stored {
            slot,
            generation: pending.generation,
            len: pending.len,
        };
        if self.check(slot) != Some(stored) {
            return Err(StoreError::Verify);
        }
        Ok(stored)
    }

    /// Slot `slot`'s `[start, end)` (slot 0, or slot 1 for any other number).
    fn range(&self, slot: usize) -> (u32, u32) {
        let [a, b] = self.slots;
        if slot == 0 {
            a
        } else {
            b
        }
    }

    /// The slot's header as `(generation, len, blob CRC)`, or `None` when unreadable, erased, or
    /// its CRC fails.
    fn header(&mut self, slot: usize) -> Option<(u32, usize, u32)> {
        let mut h = [0u8; HEADER];
        self.flash.read(self.range(slot).0, &mut h).ok()?;
        let word = |i: usize| u32::from_le_bytes([h[i], h[i + 1], h[i + 2], h[i + 3]]);
        if word(0) != MAGIC || CRC.checksum(&h[..16]) != word(16) {
            return None;
        }
        let len = word(8) as usize;
        (len <= self.capacity()).then_some((word(4), len, word(12)))
    }

    /// CRC-32 of the first `len` bytes of the slot's blob area, read piecewise.
    fn data_crc(&mut self, slot: usize, len: usize) -> Result<u32, StoreError> {
        let mut digest = CRC.digest();
        let mut piece = [0u8; PIECE];
        let start = self.range(slot).0 + HEADER as u32;
        let mut done = 0;
        while let Some(bytes) = piece
            .get_mut(..(len - done).min(PIECE))
            .filter(|b| !b.is_empty())
        {
            self.flash.read(start + done as u32, bytes)?;
            digest.update(bytes);
            done += bytes.len();
        }
        Ok(digest.finalize())
    }

    /// The slot's calibration if its header and blob are intact.
    fn check(&mut self, slot: usize) -> Option<Stored> {
        let (generation, len, crc) = self.header(slot)?;
        (self.data_crc(slot, len).ok()? == crc).then_some(Stored {
            slot,
            generation,
            len,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ram_flash::RamFlash;

    type Flash = RamFlash<{ 4 * 4096 }>;
    const SLOTS: [(u32, u32); 2] = [(0, 8192), (8192, 16384)];

    fn blob(seed: u8, len: usize) -> Vec<u8> {
        (0..len)
            .map(|i| (i as u8).wrapping_mul(31) ^ seed)
            .collect()
    }

    #[test]
    fn save_load_and_alternate_slots() {
        let mut store = Store::new(Flash::new(), SLOTS).unwrap();
        assert_eq!(store.capacity(), 8192 - 32);
        assert_eq!(store.newest(), None);
        let mut out = [0u8; 8192];
        for (i, len) in [1000usize, 333, 8160].into_iter().enumerate() {
            let b = blob(i as u8, len);
            let s = store.save(&b).unwrap();
            assert_eq!((s.slot, s.generation), (i % 2, i as u32 + 1));
            let (loaded, bytes) = store.load(&mut out).unwrap();
            assert_eq!(loaded, s);
            assert_eq!(bytes, &b[..]);
        }
        assert_eq!(store.save(&blob(9, 8161)), Err(StoreError::TooLarge));
    }

    /// The slot header's bytes are pinned: magic "DZC1", generation, length, the blob's CRC-32
    /// and the header's own CRC-32, little endian, then erased bytes up to the blob.
    #[test]
    fn slot_header_is_golden() {
        let mut store = Store::new(Flash::new(), SLOTS).unwrap();
        store.save(b"deltaz").unwrap();
        // The CRCs are CRC-32/ISO-HDLC (zlib's crc32) of b"deltaz" and of the first 16 bytes.
        let golden: [u8; HEADER + 6] = [
            0x44, 0x5a, 0x43, 0x31, 1, 0, 0, 0, 6, 0, 0, 0, 0x21, 0x5e, 0x4b, 0x9d, 0xb2, 0x79,
            0x00, 0xa6, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff,
            b'd', b'e', b'l', b't', b'a', b'z',
        ];
        let stored = &store.flash().bytes()[..HEADER + 6];
        assert_eq!(stored, golden, "{stored:02x?}");
    }

    #[test]
    fn rejects_bad_layouts() {
        let overlap = [(0, 8192), (4096, 12288)];
        assert!(matches!(
            Store::new(Flash::new(), overlap),
            Err(StoreError::Layout)
        ));
        let unaligned = [(0, 8192), (8192, 10000)];
        assert!(matches!(
            Store::new(Flash::new(), unaligned),
            Err(StoreError::Layout)
        ));
        let beyond = [(0, 8192), (8192, 20480)];
        assert!(matches!(
            Store::new(Flash::new(), beyond),
            Err(StoreError::Layout)
        ));
    }

    /// A power cut at every flash operation of a save: after reboot the store holds the old
    /// blob or the new one, byte for byte, and the next save works.
    #[test]
    fn power_cut_at_every_operation() {
        let old = blob(1, 3000);
        let new = blob(2, 2500);
        let mut base = Store::new(Flash::new(), SLOTS).unwrap();
        base.save(&blob(0, 100)).unwrap();
        base.save(&old).unwrap();
        let base = base.into_flash();
        let (mut saw_old, mut saw_new) = (0, 0);
        for cut in 0.. {
            let mut flash = base.clone();
            flash.cut_power_after(cut);
            let before = flash.ops();
            let mut store = Store::new(flash, SLOTS).unwrap();
            let result = store.save(&new);
            let mut flash = store.into_flash();
            flash.restore_power();
            let mut rebooted = Store::new(flash, SLOTS).unwrap();
            let mut out = [0u8; 8192];
            let (_, bytes) = rebooted.load(&mut out).expect("a calibration survives");
            if bytes == &old[..] {
                saw_old += 1;
                assert!(
                    result.is_err(),
                    "cut {cut}: save reported success but old is active"
                );
            } else {
                assert_eq!(bytes, &new[..], "cut {cut}: neither old nor new");
                saw_new += 1;
            }
            let done = rebooted.flash().ops() - before;
            if result.is_ok() {
                // The whole save ran: every operation had its cut tried.
                assert_eq!(done, cut, "cut {cut}");
                break;
            }
            let third = blob(3, 777);
            rebooted.save(&third).unwrap();
            assert_eq!(rebooted.load(&mut out).unwrap().1, &third[..]);
        }
        // erase + 10 pieces of 256 B + header = 12 operations; the cut at the header write is
        // the last that leaves the old one.
        assert_eq!((saw_old, saw_new), (12, 1));
    }
}

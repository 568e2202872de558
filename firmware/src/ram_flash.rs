//! A NOR flash in RAM: the store of the in-process device on the host and of the tests. It
//! checks alignment and bounds, erases to 0xFF, lets a write only clear bits, counts operations,
//! and can cut the power: after a budget of operations the next one is torn (half done) and every
//! later one fails, as on a board whose supply drops mid-write.

use embedded_storage::nor_flash::{
    check_erase, check_read, check_write, ErrorType, NorFlash, NorFlashErrorKind, ReadNorFlash,
};

/// A RAM-backed NOR flash of `N` bytes (erase sectors of [`RamFlash::ERASE`] bytes).
#[derive(Clone)]
pub struct RamFlash<const N: usize> {
    bytes: [u8; N],
    power: Power,
    ops: usize,
}

#[derive(Clone, Copy)]
enum Power {
    On,
    /// This many more operations complete, then one is torn.
    Until(usize),
    Off,
}

impl<const N: usize> Default for RamFlash<N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const N: usize> RamFlash<N> {
    /// Sector size (bytes).
    pub const ERASE: usize = 4096;
    /// Write granule (bytes).
    pub const WRITE: usize = 4;

    /// An erased flash.
    pub fn new() -> Self {
        Self {
            bytes: [0xFF; N],
            power: Power::On,
            ops: 0,
        }
    }

    /// Let `ops` more erase/write operations complete; the one after is torn.
    pub fn cut_power_after(&mut self, ops: usize) {
        self.power = Power::Until(ops);
    }

    /// Power back on: no more cuts.
    pub fn restore_power(&mut self) {
        self.power = Power::On;
    }

    /// Erase and write operations done so far (torn ones included).
    pub fn ops(&self) -> usize {
        self.ops
    }

    /// The raw contents.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// How many of an operation's `len` bytes happen, and whether it is torn (then only half);
    /// refused when the power is off.
    fn power(&mut self, len: usize) -> Result<(usize, bool), NorFlashErrorKind> {
        self.ops += 1;
        match self.power {
            Power::On => Ok((len, false)),
            Power::Off => Err(NorFlashErrorKind::Other),
            Power::Until(0) => {
                self.power = Power::Off;
                Ok((len / 2, true))
            }
            Power::Until(left) => {
                self.power = Power::Until(left - 1);
                Ok((len, false))
            }
        }
    }
}

/// A torn operation fails after doing its part.
fn outcome(torn: bool) -> Result<(), NorFlashErrorKind> {
    if torn {
        Err(NorFlashErrorKind::Other)
    } else {
        Ok(())
    }
}

impl<const N: usize> ErrorType for RamFlash<N> {
    type Error = NorFlashErrorKind;
}

impl<const N: usize> ReadNorFlash for RamFlash<N> {
    const READ_SIZE: usize = 1;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        check_read(self, offset, bytes.len())?;
        let start = offset as usize;
        bytes.copy_from_slice(&self.bytes[start..start + bytes.len()]);
        Ok(())
    }

    fn capacity(&self) -> usize {
        N
    }
}

impl<const N: usize> NorFlash for RamFlash<N> {
    const WRITE_SIZE: usize = Self::WRITE;
    const ERASE_SIZE: usize = Self::ERASE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        check_erase(self, from, to)?;
        let (from, to) = (from as usize, to as usize);
        let (n, torn) = self.power(to - from)?;
        self.bytes[from..from + n].fill(0xFF);
        outcome(torn)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        check_write(self, offset, bytes.len())?;
        let start = offset as usize;
        let (n, torn) = self.power(bytes.len())?;
        for (cell, b) in self.bytes[start..start + n].iter_mut().zip(bytes) {
            *cell &= b;
        }
        outcome(torn)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nor_semantics_alignment_and_power_cut() {
        let mut f = RamFlash::<8192>::new();
        f.write(0, &[0x0F, 0xF0, 0xFF, 0x00]).unwrap();
        f.write(0, &[0xF1, 0xFF, 0x0F, 0xFF]).unwrap();
        assert_eq!(
            &f.bytes()[..4],
            &[0x01, 0xF0, 0x0F, 0x00],
            "writes only clear bits"
        );
        assert_eq!(f.write(2, &[0; 4]), Err(NorFlashErrorKind::NotAligned));
        assert_eq!(f.erase(0, 100), Err(NorFlashErrorKind::NotAligned));
        assert_eq!(f.erase(4096, 12288), Err(NorFlashErrorKind::OutOfBounds));
        f.cut_power_after(1);
        f.erase(0, 4096).unwrap();
        assert_eq!(f.write(8, &[0; 8]), Err(NorFlashErrorKind::Other));
        assert_eq!(
            &f.bytes()[8..16],
            &[0, 0, 0, 0, 0xFF, 0xFF, 0xFF, 0xFF],
            "torn write"
        );
        assert_eq!(f.erase(0, 4096), Err(NorFlashErrorKind::Other));
        assert_eq!(f.bytes()[8], 0, "no power, no erase");
        assert_eq!(f.ops(), 5);
    }
}

//! The device's side of the protocol without copies: a request read in place from the receive
//! buffer ([`RequestView`], its batch iterated rather than collected) and a response written
//! straight into the transmit buffer ([`FrameWriter`]), field by field. The bytes are those of
//! [`super::Request`] and [`super::Response`] through serde (the protocol goldens check both
//! ways); only no 3 KB request or 10 KB response value is ever built.

use super::fixed::{Centroid, Dot, PointResult};
use super::frame::{unframe, WireError, CRC};
use super::REQUEST_KINDS;
use core::marker::PhantomData;
use postcard::ser_flavors::{Cobs, Flavor, Slice};
use serde::{Deserialize, Serialize};

/// The wire tags (variant indices) of the responses, in [`super::ResponseBody`]'s order.
pub mod tag {
    /// `Info(DeviceInfo)`.
    pub const INFO: u32 = 0;
    /// `UploadReady { len }`.
    pub const UPLOAD_READY: u32 = 1;
    /// `ChunkAccepted { next_offset }`.
    pub const CHUNK_ACCEPTED: u32 = 2;
    /// `Committed { fingerprint, generation }`.
    pub const COMMITTED: u32 = 3;
    /// `Points { fingerprint, points }`.
    pub const POINTS: u32 = 4;
    /// `Stats(DeviceStats)`.
    pub const STATS: u32 = 5;
    /// `Resetting`.
    pub const RESETTING: u32 = 6;
    /// `Error(ErrorCode)`.
    pub const ERROR: u32 = 7;
    /// `Identified { fingerprint, points }`.
    pub const IDENTIFIED: u32 = 8;
}

/// A request as it lies in the receive buffer.
#[derive(Debug, Clone, PartialEq)]
pub enum RequestView<'a> {
    /// See [`super::RequestBody::Info`].
    Info,
    /// See [`super::RequestBody::UploadBegin`].
    UploadBegin {
        /// Total length.
        len: u32,
        /// CRC-32 of the blob.
        crc: u32,
    },
    /// See [`super::RequestBody::UploadChunk`].
    UploadChunk {
        /// Where `data` starts in the blob.
        offset: u32,
        /// The bytes, in the receive buffer.
        data: &'a [u8],
    },
    /// See [`super::RequestBody::UploadCommit`].
    UploadCommit,
    /// See [`super::RequestBody::Compute`].
    Compute(Batch<'a, Centroid>),
    /// See [`super::RequestBody::Stats`].
    Stats,
    /// See [`super::RequestBody::Reset`].
    Reset,
    /// See [`super::RequestBody::Identify`].
    Identify(Batch<'a, Dot>),
}

/// A batch of centroids or dots in the receive buffer, checked when the request was read:
/// iterating it cannot fail.
#[derive(Debug, Clone, PartialEq)]
pub struct Batch<'a, T> {
    bytes: &'a [u8],
    len: usize,
    item: PhantomData<T>,
}

/// One item of a batch on the wire.
pub trait WireItem: Sized {
    /// The item at the start of `bytes` after one of id `previous`, and the bytes after it.
    fn take(bytes: &[u8], previous: u16) -> Option<(Self, &[u8])>;
    /// Its ray id (0 for a dot).
    fn id(&self) -> u16;
}

impl WireItem for Dot {
    fn take(bytes: &[u8], _: u16) -> Option<(Self, &[u8])> {
        // postcard's bytes of a `Dot` (a `[u8; 4]`), read directly.
        match *bytes {
            [a, b, c, d, ref rest @ ..] => Some((
                Dot {
                    col: u16::from_le_bytes([a, b]),
                    row: u16::from_le_bytes([c, d]),
                },
                rest,
            )),
            _ => None,
        }
    }
    fn id(&self) -> u16 {
        0
    }
}

impl WireItem for Centroid {
    fn take(bytes: &[u8], previous: u16) -> Option<(Self, &[u8])> {
        // The id difference: a zigzag varint, read directly when it is one byte (−64 ..= 63,
        // a batch sorted by id), by postcard otherwise.
        let (delta, rest) = match *bytes {
            [byte, ref rest @ ..] if byte < 0x80 => {
                let half = i32::from(byte >> 1);
                (if byte & 1 == 0 { half } else { -half - 1 }, rest)
            }
            _ => postcard::take_from_bytes::<i32>(bytes).ok()?,
        };
        let (dot, rest) = Dot::take(rest, previous)?;
        let id = u16::try_from(i32::from(previous).checked_add(delta)?).ok()?;
        Some((
            Centroid {
                id,
                col: dot.col,
                row: dot.row,
            },
            rest,
        ))
    }
    fn id(&self) -> u16 {
        self.id
    }
}

impl<'a, T: WireItem> Batch<'a, T> {
    /// Check a batch of at most `max` items that must fill `bytes` exactly.
    fn read(bytes: &'a [u8], max: usize) -> Option<Self> {
        let (len, mut rest) = postcard::take_from_bytes::<u32>(bytes).ok()?;
        let len = usize::try_from(len).ok().filter(|&n| n <= max)?;
        let items = rest;
        let mut previous = 0;
        for _ in 0..len {
            let (item, tail) = T::take(rest, previous)?;
            previous = item.id();
            rest = tail;
        }
        rest.is_empty().then_some(Self {
            bytes: items,
            len,
            item: PhantomData,
        })
    }

    /// The number of items.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The items, in order.
    pub fn iter(&self) -> BatchIter<'a, T> {
        BatchIter {
            bytes: self.bytes,
            left: self.len,
            previous: 0,
            item: PhantomData,
        }
    }
}

/// The items of a [`Batch`].
pub struct BatchIter<'a, T> {
    bytes: &'a [u8],
    left: usize,
    previous: u16,
    item: PhantomData<T>,
}

impl<T: WireItem> Iterator for BatchIter<'_, T> {
    type Item = T;

    fn next(&mut self) -> Option<T> {
        self.left = self.left.checked_sub(1)?;
        let (item, rest) = T::take(self.bytes, self.previous)?;
        self.previous = item.id();
        self.bytes = rest;
        Some(item)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        (self.left, Some(self.left))
    }
}

impl<T: WireItem> ExactSizeIterator for BatchIter<'_, T> {}

/// Read a request frame (the bytes between two delimiters, decoded in place) as a view into
/// it: the same frames [`super::decode_request`] accepts, the same errors (with the request's
/// seq once the CRC held and the seq could be read).
pub fn view_request(frame: &mut [u8]) -> Result<(u32, RequestView<'_>), (u32, WireError)> {
    let body = unframe(frame).map_err(|e| (0, e))?;
    let (seq, rest) =
        postcard::take_from_bytes::<u32>(body).map_err(|_| (0, WireError::Malformed))?;
    let (kind, rest) =
        postcard::take_from_bytes::<u32>(rest).map_err(|_| (seq, WireError::Malformed))?;
    if kind >= REQUEST_KINDS {
        return Err((seq, WireError::UnknownMessage));
    }
    let view = read_body(kind, rest).ok_or((seq, WireError::Malformed))?;
    Ok((seq, view))
}

/// The body of a request of kind `kind` filling `bytes` exactly.
fn read_body(kind: u32, bytes: &[u8]) -> Option<RequestView<'_>> {
    fn all<'a, T: Deserialize<'a>>(bytes: &'a [u8]) -> Option<T> {
        match postcard::take_from_bytes(bytes) {
            Ok((v, [])) => Some(v),
            _ => None,
        }
    }
    Some(match kind {
        0 => all::<()>(bytes).map(|()| RequestView::Info)?,
        1 => {
            let (len, crc) = all::<(u32, u32)>(bytes)?;
            RequestView::UploadBegin { len, crc }
        }
        2 => {
            let (offset, rest) = postcard::take_from_bytes::<u32>(bytes).ok()?;
            let (n, data) = postcard::take_from_bytes::<u32>(rest).ok()?;
            let n = usize::try_from(n).ok()?;
            if n != data.len() || n > super::CHUNK_SIZE {
                return None;
            }
            RequestView::UploadChunk { offset, data }
        }
        3 => all::<()>(bytes).map(|()| RequestView::UploadCommit)?,
        4 => RequestView::Compute(Batch::read(bytes, super::MAX_BATCH)?),
        5 => all::<()>(bytes).map(|()| RequestView::Stats)?,
        6 => all::<()>(bytes).map(|()| RequestView::Reset)?,
        7 => RequestView::Identify(Batch::read(bytes, super::MAX_BATCH)?),
        _ => return None,
    })
}

/// COBS streamed: each block goes to `out` as soon as it is complete, so at most 255 bytes of a
/// frame are ever held (the bytes of postcard's `Cobs` flavor: a full block of 254 bytes, a
/// last block's code, then the 0x00 delimiter).
pub struct CobsSink<'o> {
    out: &'o mut dyn FnMut(&[u8]),
    /// The block's code byte, then its bytes `1..=len`; 256 long, so a `u8` index is always in
    /// it (no bounds check on the hot path).
    block: [u8; 256],
    /// Bytes in the block: 0 ..= 253 between pushes (a 254th sends it).
    len: u8,
}

/// The most data bytes in one COBS block.
const COBS_BLOCK: u8 = 254;

impl<'o> CobsSink<'o> {
    /// A sink handing the encoded bytes to `out`.
    pub fn new(out: &'o mut dyn FnMut(&[u8])) -> Self {
        Self {
            out,
            block: [0; 256],
            len: 0,
        }
    }

    /// Send the current block with its code.
    #[inline(never)]
    fn emit(&mut self) {
        let len = core::mem::take(&mut self.len);
        self.block[0] = len + 1;
        (self.out)(&self.block[..=usize::from(len)]);
    }
}

impl Flavor for CobsSink<'_> {
    type Output = ();

    #[inline]
    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.try_extend(&[data])
    }

    /// The bytes of a point go through here: the block's length stays in a register.
    #[inline]
    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        let mut len = self.len;
        for &byte in data {
            if byte == 0 {
                self.len = len;
                self.emit();
                len = 0;
                continue;
            }
            // len ≤ 253 here: it is sent and reset when it reaches 254.
            len = len.wrapping_add(1);
            self.block[usize::from(len)] = byte;
            if len == COBS_BLOCK {
                self.len = len;
                self.emit();
                len = 0;
            }
        }
        self.len = len;
        Ok(())
    }

    fn finalize(mut self) -> postcard::Result<()> {
        self.emit();
        (self.out)(&[0]);
        Ok(())
    }
}

/// A response frame written field by field: postcard's encoding of each field, the CRC and COBS
/// as [`super::encode_frame`] applies them, into a buffer ([`FrameWriter::new`]) or straight out
/// ([`FrameWriter::streamed`]).
pub struct FrameWriter<F: Flavor> {
    out: postcard::Serializer<Checksummed<F>>,
    ids: i32,
}

/// postcard's `CrcModifier` with a bulk path: a point's 3 bytes go through one CRC update
/// (`try_extend`) instead of three.
struct Checksummed<F> {
    inner: F,
    digest: crc::Digest<'static, u32>,
}

impl<F: Flavor> Flavor for Checksummed<F> {
    type Output = F::Output;

    #[inline]
    fn try_push(&mut self, data: u8) -> postcard::Result<()> {
        self.digest.update(&[data]);
        self.inner.try_push(data)
    }

    #[inline]
    fn try_extend(&mut self, data: &[u8]) -> postcard::Result<()> {
        self.digest.update(data);
        self.inner.try_extend(data)
    }

    fn finalize(mut self) -> postcard::Result<F::Output> {
        let crc = self.digest.finalize().to_le_bytes();
        self.inner.try_extend(&crc)?;
        self.inner.finalize()
    }
}

impl<'b> FrameWriter<Cobs<Slice<'b>>> {
    /// Start the response to request `seq` of kind `tag` in `buf`.
    pub fn new(buf: &'b mut [u8], seq: u32, tag: u32) -> Result<Self, WireError> {
        let cobs = Cobs::try_new(Slice::new(buf)).map_err(|_| WireError::BufferFull)?;
        let mut me = Self::over(cobs);
        me.put(&seq)?;
        me.put(&tag)?;
        Ok(me)
    }
}

impl<'o> FrameWriter<CobsSink<'o>> {
    /// Start the response to request `seq` of kind `tag`, its bytes handed to `out` block by
    /// block (a UART: no transmit buffer), after a leading delimiter: a frame cut short on the
    /// line (its end lost) ends there instead of taking the next frame with it.
    pub fn streamed(out: &'o mut dyn FnMut(&[u8]), seq: u32, tag: u32) -> Self {
        out(&[0]);
        let mut me = Self::over(CobsSink::new(out));
        // A sink takes every byte (its pushes cannot fail): nothing to report here.
        let _ = me.put(&seq).and_then(|()| me.put(&tag));
        me
    }
}

impl<F: Flavor> FrameWriter<F> {
    /// A frame writer over `cobs`, nothing written yet.
    fn over(cobs: F) -> Self {
        Self {
            out: postcard::Serializer {
                output: Checksummed {
                    inner: cobs,
                    digest: CRC.digest(),
                },
            },
            ids: 0,
        }
    }

    /// Append one field.
    pub fn put<T: Serialize + ?Sized>(&mut self, value: &T) -> Result<(), WireError> {
        value
            .serialize(&mut self.out)
            .map_err(|_| WireError::BufferFull)
    }

    /// Append one result of a `Points` batch: its 3 bytes at once (those serde writes).
    pub fn put_point(&mut self, result: &PointResult) -> Result<(), WireError> {
        self.out
            .output
            .try_extend(&result.to_bytes())
            .map_err(|_| WireError::BufferFull)
    }

    /// Append one result of an `Identified` batch: its ray id delta-coded against the previous
    /// one's (see [`super::delta`]).
    pub fn put_identified(&mut self, id: u16, result: &PointResult) -> Result<(), WireError> {
        let id = i32::from(id);
        let delta = id - core::mem::replace(&mut self.ids, id);
        self.put(&delta)?;
        self.put_point(result)
    }

    /// Close the frame (the CRC, the last COBS block, the delimiter): the frame in the buffer,
    /// or nothing for a stream.
    pub fn finish(self) -> Result<F::Output, WireError> {
        self.out
            .output
            .finalize()
            .map_err(|_| WireError::BufferFull)
    }
}

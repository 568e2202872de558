//! Framing: `COBS(postcard(message) ‖ CRC-32(postcard bytes) as u32 LE) ‖ 0x00`.
//!
//! The CRC is CRC-32/ISO-HDLC (the zlib one). COBS removes every zero byte from the frame so the
//! single 0x00 delimits frames; a receiver that loses sync drops bytes up to the next zero.

use super::{Request, Response, MAX_FRAME, REQUEST_KINDS};
use postcard::ser_flavors::{crc::CrcModifier, Cobs, Slice};
use serde::{Deserialize, Serialize};

/// The CRC used for frames and calibration blobs: CRC-32/ISO-HDLC.
pub static CRC: crc::Crc<u32> = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);

/// Why a frame could not be read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[non_exhaustive]
pub enum WireError {
    /// The bytes are not valid COBS.
    Cobs,
    /// Fewer bytes than a message and its CRC need.
    TooShort,
    /// The CRC does not match the bytes.
    BadCrc,
    /// Longer than the receiver's buffer.
    Oversized,
    /// The CRC matches but the bytes are not a message of this protocol.
    Malformed,
    /// The CRC matches but the message kind is unknown (a newer protocol?).
    UnknownMessage,
    /// The message does not fit the sender's buffer.
    BufferFull,
    /// Bytes of the frame were lost in reception (the receiver's queue was full or its UART
    /// overran).
    Overrun,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(match self {
            WireError::Cobs => "the bytes are not valid COBS",
            WireError::TooShort => "fewer bytes than a message and its CRC need",
            WireError::BadCrc => "the CRC does not match the bytes",
            WireError::Oversized => "longer than the receiver's buffer",
            WireError::Malformed => "the CRC matches but the bytes are not a message",
            WireError::UnknownMessage => "the CRC matches but the message kind is unknown",
            WireError::BufferFull => "the message does not fit the sender's buffer",
            WireError::Overrun => "bytes of the frame were lost in reception",
        })
    }
}

/// Encode `message` as one frame into `buf` (delimiter included); returns the frame.
pub fn encode_frame<'b, M: Serialize>(
    message: &M,
    buf: &'b mut [u8],
) -> Result<&'b [u8], WireError> {
    let cobs = Cobs::try_new(Slice::new(buf)).map_err(|_| WireError::BufferFull)?;
    let frame = postcard::serialize_with_flavor(message, CrcModifier::new(cobs, CRC.digest()))
        .map_err(|_| WireError::BufferFull)?;
    Ok(frame)
}

/// Undo COBS in place and check the CRC: the postcard bytes of the message. `frame` holds the
/// bytes between two delimiters (no 0x00).
pub(crate) fn unframe(frame: &mut [u8]) -> Result<&[u8], WireError> {
    if frame.len() > MAX_FRAME {
        return Err(WireError::Oversized);
    }
    let len = cobs_decode_in_place(frame).ok_or(WireError::Cobs)?;
    let body_len = len.checked_sub(4).ok_or(WireError::TooShort)?;
    let decoded = frame.get(..len).ok_or(WireError::Cobs)?;
    let (body, crc) = decoded
        .split_at_checked(body_len)
        .ok_or(WireError::TooShort)?;
    if CRC.checksum(body).to_le_bytes() != crc {
        return Err(WireError::BadCrc);
    }
    Ok(body)
}

/// Undo COBS in place, up to the first 0x00 if any: the decoded length, or `None` for an empty
/// buffer or a block running past the end. What the `cobs` crate's `decode_in_place` does, with
/// checked accesses only (the device's request path has no panic path).
fn cobs_decode_in_place(buf: &mut [u8]) -> Option<usize> {
    if buf.is_empty() {
        return None;
    }
    let end = buf.iter().position(|&b| b == 0).unwrap_or(buf.len());
    let (mut read, mut write) = (0, 0);
    while read < end {
        // A code byte: the next block holds code − 1 bytes, then (unless the code is 0xFF or the
        // frame ends) a zero.
        let code = *buf.get(read)?;
        let block_end = read + usize::from(code);
        if block_end > end {
            return None;
        }
        for at in read + 1..block_end {
            let byte = *buf.get(at)?;
            *buf.get_mut(write)? = byte;
            write += 1;
        }
        read = block_end;
        if code != 0xFF && read < end {
            *buf.get_mut(write)? = 0;
            write += 1;
        }
    }
    Some(write)
}

/// The whole of `bytes` as one `M`: trailing bytes are malformed.
fn exact<'a, M: Deserialize<'a>>(bytes: &'a [u8]) -> Result<M, WireError> {
    match postcard::take_from_bytes(bytes) {
        Ok((message, [])) => Ok(message),
        _ => Err(WireError::Malformed),
    }
}

/// Decode a request frame (the bytes between two delimiters, decoded in place). On failure the
/// error comes with the request's seq when the CRC held and the seq could be read.
pub fn decode_request(frame: &mut [u8]) -> Result<Request, (u32, WireError)> {
    let body = unframe(frame).map_err(|e| (0, e))?;
    let (seq, rest) =
        postcard::take_from_bytes::<u32>(body).map_err(|_| (0, WireError::Malformed))?;
    let (kind, _) =
        postcard::take_from_bytes::<u32>(rest).map_err(|_| (seq, WireError::Malformed))?;
    if kind >= REQUEST_KINDS {
        return Err((seq, WireError::UnknownMessage));
    }
    exact(body).map_err(|e| (seq, e))
}

/// Decode a response frame (the bytes between two delimiters, decoded in place).
pub fn decode_response(frame: &mut [u8]) -> Result<Response, WireError> {
    exact(unframe(frame)?)
}

#[cfg(test)]
mod tests {
    use super::cobs_decode_in_place;
    use postcard::ser_flavors::{Cobs, Flavor, Slice};

    /// postcard's COBS encoding decodes back, for every length across a block boundary and
    /// runs of zeros; a block running past the end and an empty frame are refused.
    #[test]
    fn cobs_decodes_postcard_cobs() {
        let mut seed = 0x2545_F491_u32;
        for len in 0..600 {
            let data: Vec<u8> = (0..len)
                .map(|i| {
                    seed ^= seed << 13;
                    seed ^= seed >> 17;
                    seed ^= seed << 5;
                    if i % 97 < 3 || seed.is_multiple_of(7) {
                        0
                    } else {
                        seed as u8
                    }
                })
                .collect();
            let mut buf = vec![0u8; len + len / 254 + 2];
            let mut cobs = Cobs::try_new(Slice::new(&mut buf)).unwrap();
            cobs.try_extend(&data).unwrap();
            let encoded = cobs.finalize().unwrap();
            // Without the delimiter, as the server hands a frame over.
            let mut frame = encoded[..encoded.len() - 1].to_vec();
            let n = cobs_decode_in_place(&mut frame).unwrap();
            assert_eq!(&frame[..n], &data[..], "{len} bytes");
        }
        assert_eq!(cobs_decode_in_place(&mut []), None);
        assert_eq!(cobs_decode_in_place(&mut [3, 1]), None);
        assert_eq!(cobs_decode_in_place(&mut [2, 7, 1]), Some(2));
        // The first zero ends the frame.
        assert_eq!(cobs_decode_in_place(&mut [2, 7, 0, 9]), Some(1));
    }
}

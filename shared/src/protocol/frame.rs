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
    let len = cobs::decode_in_place(frame).map_err(|_| WireError::Cobs)?;
    let body_len = len.checked_sub(4).ok_or(WireError::TooShort)?;
    let (body, crc) = frame[..len].split_at(body_len);
    if CRC.checksum(body).to_le_bytes() != crc {
        return Err(WireError::BadCrc);
    }
    Ok(body)
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

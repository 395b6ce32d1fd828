//! Dynamixel Protocol 2.0 packets, `no_std` and allocation free: CRC-16, byte stuffing exactly
//! as the e-manual specifies, and encoding/decoding of instruction and status packets.
//!
//! Packet: `FF FF FD 00 | ID | LEN_L LEN_H | INST | params… | CRC_L CRC_H`, where LEN counts
//! INST, the (stuffed) parameters and the CRC. CRC-16 with polynomial 0x8005, initial value 0,
//! no reflection, over everything before it. Stuffing: after every `FF FF FD` in the
//! instruction and parameter bytes an extra `FD` is inserted (and removed on receipt), so the
//! header pattern never appears inside a packet.

/// The packet header.
pub const HEADER: [u8; 4] = [0xFF, 0xFF, 0xFD, 0x00];
/// The broadcast id.
pub const BROADCAST_ID: u8 = 0xFE;
/// Bytes of a packet around its parameters: header 4, id 1, length 2, instruction 1, CRC 2.
pub const OVERHEAD: usize = 10;

/// Instruction codes.
#[allow(missing_docs)]
pub mod instruction {
    pub const PING: u8 = 0x01;
    pub const READ: u8 = 0x02;
    pub const WRITE: u8 = 0x03;
    pub const REG_WRITE: u8 = 0x04;
    pub const ACTION: u8 = 0x05;
    pub const FACTORY_RESET: u8 = 0x06;
    pub const REBOOT: u8 = 0x08;
    pub const CLEAR: u8 = 0x10;
    pub const STATUS: u8 = 0x55;
    pub const SYNC_READ: u8 = 0x82;
    pub const SYNC_WRITE: u8 = 0x83;
    pub const FAST_SYNC_READ: u8 = 0x8A;
    pub const BULK_READ: u8 = 0x92;
    pub const BULK_WRITE: u8 = 0x93;
    pub const FAST_BULK_READ: u8 = 0x9A;
}

const fn crc_table() -> [u16; 256] {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = (i as u16) << 8;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x8005
            } else {
                crc << 1
            };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
}

static CRC_TABLE: [u16; 256] = crc_table();

/// CRC-16 (polynomial 0x8005, initial 0, not reflected), continuing from `crc`.
#[must_use]
pub fn crc16_update(mut crc: u16, data: &[u8]) -> u16 {
    for &b in data {
        let i = ((crc >> 8) as u8 ^ b) as usize;
        crc = (crc << 8) ^ CRC_TABLE[i];
    }
    crc
}

/// CRC-16 of `data`.
#[must_use]
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0, data)
}

/// Why a packet cannot be written or read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum CodecError {
    /// The output buffer is too small.
    BufferFull,
    /// More bytes are needed to finish the packet.
    Incomplete,
    /// The bytes do not start with the header.
    BadHeader,
    /// The length field is impossible (below 3, or the packet would exceed the buffer).
    BadLength,
    /// The CRC does not match.
    BadCrc {
        /// CRC in the packet.
        got: u16,
        /// CRC of the bytes.
        want: u16,
    },
    /// A stuffed packet whose stuffing is wrong (`FF FF FD` followed by something else than
    /// `FD`).
    BadStuffing,
}

impl core::fmt::Display for CodecError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            CodecError::BufferFull => write!(f, "buffer too small"),
            CodecError::Incomplete => write!(f, "incomplete packet"),
            CodecError::BadHeader => write!(f, "no packet header"),
            CodecError::BadLength => write!(f, "impossible length field"),
            CodecError::BadCrc { got, want } => write!(f, "CRC {got:04X}, expected {want:04X}"),
            CodecError::BadStuffing => write!(f, "bad byte stuffing"),
        }
    }
}

impl core::error::Error for CodecError {}

/// Tracks the `FF FF FD` pattern byte by byte: the state is how much of it has just been
/// seen. A byte that breaks the pattern is checked again as a possible start.
#[derive(Clone, Copy, Debug, Default)]
struct PatternState(u8);

impl PatternState {
    /// Feeds a byte; true when it completes `FF FF FD`.
    #[inline]
    fn feed(&mut self, b: u8) -> bool {
        if b == 0xFF {
            // "FF FF FF": the last two still start the pattern.
            self.0 = if self.0 == 0 { 1 } else { 2 };
            return false;
        }
        let done = self.0 == 2 && b == 0xFD;
        self.0 = 0;
        done
    }
}

/// Writes `data` stuffed into `out`; returns the number of bytes written.
///
/// # Errors
/// [`CodecError::BufferFull`].
pub fn stuff(data: &[u8], out: &mut [u8]) -> Result<usize, CodecError> {
    let mut n = 0;
    let mut state = PatternState::default();
    let mut put = |b: u8, n: &mut usize| -> Result<(), CodecError> {
        *out.get_mut(*n).ok_or(CodecError::BufferFull)? = b;
        *n += 1;
        Ok(())
    };
    for &b in data {
        put(b, &mut n)?;
        if state.feed(b) {
            put(0xFD, &mut n)?;
        }
    }
    Ok(n)
}

/// The stuffed length of `data`.
#[must_use]
pub fn stuffed_len(data: &[u8]) -> usize {
    let mut state = PatternState::default();
    data.len() + data.iter().filter(|&&b| state.feed(b)).count()
}

/// Removes stuffing: writes the original bytes into `out` and returns their number.
///
/// # Errors
/// [`CodecError::BadStuffing`] when `FF FF FD` is followed by anything but `FD` (or ends the
/// data); [`CodecError::BufferFull`].
pub fn unstuff(data: &[u8], out: &mut [u8]) -> Result<usize, CodecError> {
    unstuff_after(PatternState::default(), data, out)
}

/// [`unstuff`] continuing a pattern already begun by the bytes before `data`.
fn unstuff_after(mut state: PatternState, data: &[u8], out: &mut [u8]) -> Result<usize, CodecError> {
    let mut n = 0;
    let mut i = 0;
    while i < data.len() {
        let b = data[i];
        *out.get_mut(n).ok_or(CodecError::BufferFull)? = b;
        n += 1;
        if state.feed(b) {
            match data.get(i + 1) {
                Some(0xFD) => i += 1,
                _ => return Err(CodecError::BadStuffing),
            }
        }
        i += 1;
    }
    Ok(n)
}

/// Writes a whole packet: header, id, length, instruction, stuffed parameters, CRC.
/// Returns the packet's length in bytes.
///
/// # Errors
/// [`CodecError::BufferFull`]; [`CodecError::BadLength`] when the packet exceeds 65535 bytes.
pub fn encode(id: u8, instruction: u8, params: &[u8], out: &mut [u8]) -> Result<usize, CodecError> {
    if out.len() < OVERHEAD {
        return Err(CodecError::BufferFull);
    }
    out[..4].copy_from_slice(&HEADER);
    out[4] = id;
    // Stuffing covers the instruction byte and the parameters.
    let mut state = PatternState::default();
    let _ = state.feed(instruction); // an instruction byte alone never completes the pattern
    out[7] = instruction;
    let mut n = 8;
    let mut scan = state;
    if !params.iter().any(|&b| scan.feed(b)) {
        // Nothing to stuff (the common case): one copy.
        out.get_mut(n..n + params.len())
            .ok_or(CodecError::BufferFull)?
            .copy_from_slice(params);
        n += params.len();
    } else {
        for &b in params {
            *out.get_mut(n).ok_or(CodecError::BufferFull)? = b;
            n += 1;
            if state.feed(b) {
                *out.get_mut(n).ok_or(CodecError::BufferFull)? = 0xFD;
                n += 1;
            }
        }
    }
    let len = n - 7 + 2;
    let len16 = u16::try_from(len).map_err(|_| CodecError::BadLength)?;
    out[5..7].copy_from_slice(&len16.to_le_bytes());
    let crc = crc16(&out[..n]);
    out.get_mut(n..n + 2)
        .ok_or(CodecError::BufferFull)?
        .copy_from_slice(&crc.to_le_bytes());
    Ok(n + 2)
}

/// A decoded packet; its parameters live in the caller's buffer, unstuffed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Packet<'a> {
    /// Packet id.
    pub id: u8,
    /// Instruction (0x55 for a status packet).
    pub instruction: u8,
    /// Parameters, unstuffed. For a status packet the first is the error byte.
    pub params: &'a [u8],
}

impl Packet<'_> {
    /// A status packet's error byte and data.
    #[must_use]
    pub fn status(&self) -> Option<(u8, &[u8])> {
        if self.instruction == instruction::STATUS {
            self.params.split_first().map(|(e, d)| (*e, d))
        } else {
            None
        }
    }
}

/// The total length of the packet at the start of `bytes` once its length field is there.
///
/// # Errors
/// [`CodecError::Incomplete`] before 7 bytes, [`CodecError::BadHeader`], [`CodecError::BadLength`].
pub fn packet_len(bytes: &[u8]) -> Result<usize, CodecError> {
    let head = bytes.len().min(4);
    if bytes[..head] != HEADER[..head] {
        return Err(CodecError::BadHeader);
    }
    if bytes.len() < 7 {
        return Err(CodecError::Incomplete);
    }
    let len = usize::from(u16::from_le_bytes([bytes[5], bytes[6]]));
    if len < 3 {
        return Err(CodecError::BadLength);
    }
    Ok(7 + len)
}

/// Decodes the packet at the start of `bytes`, unstuffing its parameters into `params_out`.
/// Returns the packet and the number of bytes it took.
///
/// # Errors
/// [`CodecError`]: incomplete data, a wrong header, length, CRC or stuffing, or a parameter
/// buffer that is too small.
pub fn decode<'p>(bytes: &[u8], params_out: &'p mut [u8]) -> Result<(Packet<'p>, usize), CodecError> {
    let total = packet_len(bytes)?;
    if bytes.len() < total {
        return Err(CodecError::Incomplete);
    }
    let want = crc16(&bytes[..total - 2]);
    let got = u16::from_le_bytes([bytes[total - 2], bytes[total - 1]]);
    if got != want {
        return Err(CodecError::BadCrc { got, want });
    }
    let instruction = bytes[7];
    // Unstuff the instruction byte together with the parameters: the pattern may span them.
    let mut state = PatternState::default();
    let _ = state.feed(instruction);
    let n = unstuff_after(state, &bytes[8..total - 2], params_out)?;
    Ok((
        Packet {
            id: bytes[4],
            instruction,
            params: &params_out[..n],
        },
        total,
    ))
}

/// The offset of the first packet header in `bytes`, or where a header could still begin at
/// the end (so the caller can keep those bytes and wait for more).
#[must_use]
pub fn find_header(bytes: &[u8]) -> usize {
    (0..bytes.len())
        .find(|&i| {
            let rest = &bytes[i..];
            let k = rest.len().min(4);
            rest[..k] == HEADER[..k]
        })
        .unwrap_or(bytes.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_check_value() {
        // CRC-16/BUYPASS (poly 0x8005, init 0, no reflection) of "123456789" is 0xFEE8.
        assert_eq!(crc16(b"123456789"), 0xFEE8);
    }

    #[test]
    fn stuffing_handles_overlapping_patterns() {
        let mut out = [0u8; 16];
        let n = stuff(&[0xFF, 0xFF, 0xFF, 0xFD], &mut out).unwrap();
        assert_eq!(&out[..n], &[0xFF, 0xFF, 0xFF, 0xFD, 0xFD]);
        let mut back = [0u8; 16];
        let m = unstuff(&out[..n], &mut back).unwrap();
        assert_eq!(&back[..m], &[0xFF, 0xFF, 0xFF, 0xFD]);
        assert_eq!(
            unstuff(&[0xFF, 0xFF, 0xFD, 0x00], &mut back),
            Err(CodecError::BadStuffing)
        );
    }

    #[test]
    fn encode_stuffs_a_pattern_begun_by_the_instruction_byte() {
        // `FF` (instruction) + `FF FD` (parameters): stuffed, though the parameters alone
        // hold no pattern; parameters without one are copied as they are.
        for (instruction, params, stuffed) in [
            (0xFF, &[0xFF, 0xFD, 0x01][..], &[0xFF, 0xFD, 0xFD, 0x01][..]),
            (0x03, &[0xFF, 0xFD, 0x01][..], &[0xFF, 0xFD, 0x01][..]),
            (
                0x03,
                &[0x01, 0xFF, 0xFF, 0xFD][..],
                &[0x01, 0xFF, 0xFF, 0xFD, 0xFD][..],
            ),
        ] {
            let mut out = [0u8; 32];
            let n = encode(7, instruction, params, &mut out).unwrap();
            assert_eq!(&out[8..n - 2], stuffed, "{instruction:02X} {params:02X?}");
            let mut back = [0u8; 32];
            let (packet, used) = decode(&out[..n], &mut back).unwrap();
            assert_eq!(
                (packet.instruction, packet.params, used),
                (instruction, params, n)
            );
        }
    }
}

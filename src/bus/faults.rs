//! A seeded fault injector for the replies of a virtual chain.
//!
//! Each status packet a chain sends may be hit by one fault, chosen by a seeded generator so a
//! failing run can be replayed. [`Fault::expected`] says how a correct host reports each one.

use super::ErrorKind;
use crate::protocol;

/// One kind of fault on a reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Fault {
    /// The reply never comes.
    Drop,
    /// A CRC byte is flipped.
    BadCrc,
    /// The reply stops short (the last reply of a burst).
    Truncate,
    /// The reply carries another id (valid CRC).
    WrongId,
    /// A second servo with the same id answers too (not on the last reply of a burst).
    DuplicateId,
    /// Line noise (bytes that cannot start a header) before the reply.
    ExtraBytes,
    /// An old reply arrives after the burst, before the next instruction.
    StaleBytes,
    /// The reply comes later than the host waits.
    Delay,
}

impl Fault {
    /// All faults.
    pub const ALL: [Fault; 8] = [
        Fault::Drop,
        Fault::BadCrc,
        Fault::Truncate,
        Fault::WrongId,
        Fault::DuplicateId,
        Fault::ExtraBytes,
        Fault::StaleBytes,
        Fault::Delay,
    ];

    /// Lower-case name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Fault::Drop => "drop",
            Fault::BadCrc => "bad_crc",
            Fault::Truncate => "truncate",
            Fault::WrongId => "wrong_id",
            Fault::DuplicateId => "duplicate_id",
            Fault::ExtraBytes => "extra_bytes",
            Fault::StaleBytes => "stale_bytes",
            Fault::Delay => "delay",
        }
    }

    /// The error kinds a correct host may report for this fault; empty when the host must
    /// recover by itself and return the right values (noise and stale bytes are skipped or
    /// flushed).
    #[must_use]
    pub fn expected(self) -> &'static [ErrorKind] {
        match self {
            // A lost reply shows as silence, or as the next servo's reply in its slot.
            Fault::Drop => &[ErrorKind::Timeout, ErrorKind::WrongId],
            Fault::BadCrc => &[ErrorKind::Crc],
            Fault::Truncate | Fault::Delay => &[ErrorKind::Timeout],
            Fault::WrongId | Fault::DuplicateId => &[ErrorKind::WrongId],
            Fault::ExtraBytes | Fault::StaleBytes => &[],
        }
    }
}

/// SplitMix64: small, seeded, good enough to pick faults.
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator from a seed.
    #[must_use]
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    /// True with probability `p`.
    pub fn chance(&mut self, p: f64) -> bool {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 <= p && p > 0.0
    }
}

/// What happens to one reply.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Injected {
    /// The fault applied, if any.
    pub fault: Option<Fault>,
    /// Bytes to send in its place (may be empty).
    pub bytes: Vec<u8>,
    /// Extra delay before them, µs.
    pub extra_delay_us: u32,
    /// Bytes to send once the whole burst is out (stale data).
    pub after_burst: Vec<u8>,
}

/// Picks and applies faults.
#[derive(Clone, Debug)]
pub struct FaultInjector {
    rng: Rng,
    rate: f64,
    kinds: Vec<Fault>,
    delay_us: u32,
    previous: Vec<u8>,
    armed: Option<(Fault, usize)>,
    reply_index: usize,
    last_applied: Option<Fault>,
    /// Faults applied so far, by kind (index of [`Fault::ALL`]).
    pub counts: [u64; 8],
}

impl FaultInjector {
    /// Hits each reply with probability `rate` by one of `kinds`; a delay fault holds the reply
    /// back `delay_us`.
    #[must_use]
    pub fn new(seed: u64, rate: f64, kinds: &[Fault], delay_us: u32) -> FaultInjector {
        FaultInjector {
            rng: Rng::new(seed),
            rate,
            kinds: kinds.to_vec(),
            delay_us,
            previous: Vec::new(),
            armed: None,
            reply_index: 0,
            last_applied: None,
            counts: [0; 8],
        }
    }

    /// Changes the chance that a reply is hit (0 turns injection off, the seeded sequence
    /// goes on).
    pub fn set_rate(&mut self, rate: f64) {
        self.rate = rate;
    }

    /// Total faults applied.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// Applies `fault` to reply number `at` (0-based) of the next burst, once, whatever the
    /// rate: one known fault per transaction, for tests that check how each is reported.
    pub fn arm(&mut self, fault: Fault, at: usize) {
        self.armed = Some((fault, at));
    }

    /// The fault applied most recently (after a fallback, e.g. a truncation in the middle of a
    /// burst becomes a drop), cleared by reading it.
    pub fn take_last(&mut self) -> Option<Fault> {
        self.last_applied.take()
    }

    /// Decides the fate of one reply; `last` is true for the last reply of a burst.
    pub fn apply(&mut self, reply: &[u8], last: bool) -> Injected {
        let mut out = Injected {
            bytes: reply.to_vec(),
            ..Injected::default()
        };
        let stale = std::mem::replace(&mut self.previous, reply.to_vec());
        let index = self.reply_index;
        self.reply_index = if last { 0 } else { index + 1 };
        let mut fault = match self.armed {
            Some((f, at)) if at == index || (last && at > index) => {
                self.armed = None;
                f
            }
            Some(_) => return out,
            None if self.kinds.is_empty() || !self.rng.chance(self.rate) => return out,
            None => self.kinds[self.rng.below(self.kinds.len() as u64) as usize],
        };
        // Faults that only make sense at one place in a burst fall back to a plain drop.
        if (fault == Fault::DuplicateId && last) || (fault == Fault::Truncate && !last) {
            fault = Fault::Drop;
        }
        if fault == Fault::StaleBytes && stale.is_empty() {
            fault = Fault::ExtraBytes;
        }
        let n = reply.len();
        match fault {
            Fault::Drop => out.bytes.clear(),
            Fault::BadCrc => {
                let flip = 1 + self.rng.below(255) as u8;
                out.bytes[n - 1 - self.rng.below(2) as usize] ^= flip;
            }
            Fault::Truncate => out.bytes.truncate(1 + self.rng.below(n as u64 - 1) as usize),
            Fault::WrongId => {
                // An id that is on no bus here (253 is reserved by the protocol).
                out.bytes[4] = 253;
                let crc = protocol::crc16(&out.bytes[..n - 2]).to_le_bytes();
                out.bytes[n - 2..].copy_from_slice(&crc);
            }
            Fault::DuplicateId => {
                // The twin reports another position: same id, different data, valid CRC.
                let mut twin = reply.to_vec();
                if n > 11 {
                    twin[9] ^= 0x01;
                    let crc = protocol::crc16(&twin[..n - 2]).to_le_bytes();
                    twin[n - 2..].copy_from_slice(&crc);
                }
                out.bytes.extend_from_slice(&twin);
            }
            Fault::ExtraBytes => {
                let k = 1 + self.rng.below(8) as usize;
                let noise: Vec<u8> = (0..k).map(|_| (self.rng.below(0xFF)) as u8).collect();
                out.bytes.splice(0..0, noise);
            }
            Fault::StaleBytes => out.after_burst = stale,
            Fault::Delay => out.extra_delay_us = self.delay_us,
        }
        self.counts[Fault::ALL.iter().position(|f| *f == fault).unwrap_or(0)] += 1;
        self.last_applied = Some(fault);
        out.fault = Some(fault);
        out
    }
}

//! The host side of Protocol 2.0 on the project's own codec, over any byte transport.
//!
//! Every reply is checked before its data is used: CRC, stuffing, length, instruction, id,
//! error byte and parameter count. After a failed reply the line is drained until quiet, so a
//! late or extra reply cannot be taken for the answer to the next instruction — except where
//! a servo simply did not answer and the rest of the read came whole and in order (a later
//! servo's reply in its slot, or a fast reply missing its block): then nothing more is due and
//! the silent servo costs that read only. Bytes that came before an instruction are dropped
//! when it is sent.

use std::io;
use std::time::Duration;

use super::{invalid_request, BusError, PingInfo, ServoBus};
use crate::device::{Received, Receiver, MAX_PACKET};
use crate::profile::ReadMode;
use crate::protocol::{self, instruction, CodecError, BROADCAST_ID};
use crate::servo::{addr, status_error, MAX_SERVOS};

/// A byte link to a bus.
pub trait Transport {
    /// Sends bytes, first dropping input that arrived before (stale replies).
    ///
    /// # Errors
    /// I/O.
    fn send(&mut self, bytes: &[u8]) -> io::Result<()>;

    /// Reads what arrives within `timeout` (what has arrived, without waiting, when it is
    /// zero); `Ok(0)` when nothing did.
    ///
    /// # Errors
    /// I/O.
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize>;

    /// Time since some fixed start (wall clock, or the transport's virtual clock).
    fn now(&self) -> Duration;

    /// Line speed, bit/s.
    fn baud(&self) -> u32;
}

/// Time `bytes` take on a line at `baud` (10 bits per byte).
#[must_use]
pub fn wire_time(bytes: usize, baud: u32) -> Duration {
    Duration::from_nanos((bytes as u64 * 10 * 1_000_000_000).div_ceil(u64::from(baud.max(1))))
}

/// A [`ServoBus`] speaking Protocol 2.0 with [`crate::protocol`] over a [`Transport`].
#[derive(Debug)]
pub struct PacketBus<T> {
    link: T,
    rx: Receiver,
    tx: [u8; MAX_PACKET],
    params: [u8; MAX_PACKET],
    margin: Duration,
    quiet: Duration,
    /// How the loop's positions are read.
    read: ReadMode,
    /// The margin of single transactions (ping, read, write, reboot).
    single_margin: Duration,
    /// When the line is next free, as far as the host knows (transport time): the end of the
    /// last instruction sent and of the replies it asked for. Reply deadlines count from it.
    line_free: Duration,
    /// A read sent by [`ServoBus::request_positions`] whose replies are not collected yet.
    pending: Option<PendingRead>,
    /// A Read on the wire in a position read's slot: id, address, length, when it left.
    pending_single: Option<(u8, u16, u16, Duration)>,
    /// A block of another device read with the positions ([`ServoBus::merge_into_reads`]).
    merged: Option<MergedBlock>,
    /// The first id whose reply carried the hardware-alert flag since the last
    /// [`ServoBus::take_alert`].
    alert: Option<u8>,
}

/// The largest block [`ServoBus::merge_into_reads`] takes, bytes.
pub const MAX_MERGED: usize = 64;

/// A device's block read in the positions' Bulk Read, after the servos' entries.
#[derive(Clone, Copy, Debug)]
struct MergedBlock {
    id: u8,
    address: u16,
    len: u16,
    data: [u8; MAX_MERGED],
    /// What the last collected read gave for it: `None` until one was collected since the
    /// last [`ServoBus::take_merged`], then whether its reply passed every check.
    fresh: Option<bool>,
}

/// A position read on the wire whose replies the host has not taken yet.
#[derive(Clone, Copy, Debug)]
struct PendingRead {
    ids: [u8; crate::servo::MAX_SERVOS],
    n: usize,
    /// When the request's last byte left (transport time).
    sent: Duration,
    /// Whether the merged block was asked after the positions.
    merged: bool,
}

impl<T: Transport> PacketBus<T> {
    /// A bus on `link`; a reply may come up to `margin` later than its wire time (return
    /// delay, adapter latency).
    pub fn new(link: T, margin: Duration) -> PacketBus<T> {
        PacketBus {
            link,
            rx: Receiver::default(),
            tx: [0; MAX_PACKET],
            params: [0; MAX_PACKET],
            margin,
            quiet: 2 * margin,
            read: ReadMode::Sync,
            single_margin: margin,
            line_free: Duration::ZERO,
            pending: None,
            pending_single: None,
            merged: None,
            alert: None,
        }
    }

    /// Notes a reply's error byte: the first id whose reply has the hardware-alert flag is
    /// kept for [`ServoBus::take_alert`].
    fn note_alert(&mut self, id: u8, error: u8) {
        if error & status_error::ALERT != 0 && self.alert.is_none() {
            self.alert = Some(id);
        }
    }

    /// Waits `margin` past the wire time for the reply to a single transaction (start-up,
    /// configuration) instead of the tick's margin: they need not fit in a tick.
    #[must_use]
    pub fn with_single_margin(mut self, margin: Duration) -> PacketBus<T> {
        self.single_margin = margin;
        self
    }

    /// Reads positions (the loop's read) with Fast Sync Read: one reply for all servos.
    #[must_use]
    pub fn with_fast_reads(self, fast: bool) -> PacketBus<T> {
        self.with_read_mode(if fast { ReadMode::FastSync } else { ReadMode::Sync })
    }

    /// Reads positions (the loop's read) with `mode`.
    #[must_use]
    pub fn with_read_mode(mut self, mode: ReadMode) -> PacketBus<T> {
        self.read = mode;
        self
    }

    /// Bulk Read (0x92): each entry (id, address, length) answered by its own status packet,
    /// in entry order; `out` holds the entries' data one after another and is written only
    /// when every reply passed.
    ///
    /// # Errors
    /// The first reply that failed ([`BusError`]).
    pub fn bulk_read(&mut self, entries: &[(u8, u16, u16)], out: &mut [u8]) -> Result<(), BusError> {
        let total: usize = entries.iter().map(|e| usize::from(e.2)).sum();
        if out.len() < total || entries.len() > MAX_SERVOS {
            return Err(invalid_request(
                "bulk read of more than 32 entries, or output too short",
            ));
        }
        let sent = self.bulk_request(instruction::BULK_READ, entries)?;
        let mut scratch = [0u8; MAX_PACKET];
        let mut at = 0;
        let mut due = sent;
        for &(id, _, len) in entries {
            let len = usize::from(len);
            let one = wire_time(11 + len, self.link.baud());
            due += one;
            if let Err(e) = self.status_by(id, Some(len), due.max(self.link.now() + one) + self.single_margin)
            {
                self.drain();
                return Err(e);
            }
            scratch[at..at + len].copy_from_slice(&self.params[1..=len]);
            at += len;
        }
        out[..total].copy_from_slice(&scratch[..total]);
        Ok(())
    }

    /// Fast Bulk Read (0x9A): each entry (id, address, length) a block of one combined reply,
    /// checked on its own as in [`PacketBus::fast_sync_read`]; `out` holds the entries' data
    /// one after another, `valid` says whose holds.
    ///
    /// # Errors
    /// As [`PacketBus::fast_sync_read`]: the first entry without a good block; the others'
    /// data is in `out` all the same.
    pub fn fast_bulk_read(
        &mut self,
        entries: &[(u8, u16, u16)],
        out: &mut [u8],
        valid: &mut [bool],
    ) -> Result<(), BusError> {
        if entries.len() > MAX_SERVOS {
            return Err(invalid_request("fast bulk read of more than 32 entries"));
        }
        let mut ids = [0u8; MAX_SERVOS];
        let mut lens = [0u16; MAX_SERVOS];
        for (k, e) in entries.iter().enumerate() {
            (ids[k], lens[k]) = (e.0, e.2);
        }
        let n = entries.len();
        let sent = self.bulk_request(instruction::FAST_BULK_READ, entries)?;
        self.fast_replies(&ids[..n], &lens[..n], out, valid, (sent, self.single_margin))
    }

    /// Sends a Bulk or Fast Bulk Read request; returns when its last byte leaves.
    fn bulk_request(&mut self, inst: u8, entries: &[(u8, u16, u16)]) -> Result<Duration, BusError> {
        let data: usize = entries.iter().map(|e| usize::from(e.2)).sum();
        if entries.is_empty() || 5 * entries.len() > MAX_PACKET || 8 + 4 * entries.len() + data > MAX_PACKET {
            return Err(invalid_request("bulk read too large"));
        }
        let mut p = [0u8; MAX_PACKET];
        for (k, &(id, a, l)) in entries.iter().enumerate() {
            p[5 * k] = id;
            p[5 * k + 1..5 * k + 3].copy_from_slice(&a.to_le_bytes());
            p[5 * k + 3..5 * k + 5].copy_from_slice(&l.to_le_bytes());
        }
        let sent = self.send(BROADCAST_ID, inst, &p[..5 * entries.len()])?;
        let reply = if inst == instruction::FAST_BULK_READ {
            8 + 4 * entries.len() + data
        } else {
            11 * entries.len() + data
        };
        self.line_free = self.line_free.max(sent + wire_time(reply, self.link.baud()));
        Ok(sent)
    }

    /// Fast Sync Read (0x8A) of `len` bytes at `address` from `ids`: one status packet from the
    /// broadcast id whose blocks each hold a servo's error, id, data and the CRC of the packet
    /// up to there. Every block is checked on its own (its id among those asked, its CRC), so
    /// a silent or corrupt servo is named while the others' data, whose checks hold, is
    /// written to `out` (`len` bytes per id, in `ids` order); `valid` says whose.
    ///
    /// # Errors
    /// The first servo without a good block: [`BusError::Timeout`] when it is missing,
    /// [`BusError::Crc`] when its block is corrupt, [`BusError::Servo`] for its error; the
    /// others' data is in `out` all the same.
    pub fn fast_sync_read(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
        valid: &mut [bool],
    ) -> Result<(), BusError> {
        let sent = self.fast_sync_request(address, len, ids)?;
        self.fast_sync_replies(len, ids, out, valid, (sent, self.single_margin))
    }

    /// Sends a Fast Sync Read request; returns when its last byte leaves.
    fn fast_sync_request(&mut self, address: u16, len: u16, ids: &[u8]) -> Result<Duration, BusError> {
        self.sync_request(instruction::FAST_SYNC_READ, address, len, ids)
    }

    /// Sends a Sync or Fast Sync Read request (address, length, ids); returns when its last
    /// byte leaves, the line taken until the replies' wire time has passed.
    fn sync_request(&mut self, inst: u8, address: u16, len: u16, ids: &[u8]) -> Result<Duration, BusError> {
        let n = usize::from(len);
        let fast = inst == instruction::FAST_SYNC_READ;
        // One reply packet (fast), or replies whose data is collected in one packet's room.
        let (reply, too_large) = if fast {
            let reply = 8 + (4 + n) * ids.len();
            (reply, ids.is_empty() || reply > MAX_PACKET)
        } else {
            ((11 + n) * ids.len(), ids.len() * n > MAX_PACKET)
        };
        if too_large || 4 + ids.len() > MAX_PACKET {
            return Err(invalid_request("sync read too large"));
        }
        let mut p = [0u8; MAX_PACKET];
        p[..2].copy_from_slice(&address.to_le_bytes());
        p[2..4].copy_from_slice(&len.to_le_bytes());
        p[4..4 + ids.len()].copy_from_slice(ids);
        let sent = self.send(BROADCAST_ID, inst, &p[..4 + ids.len()])?;
        self.line_free = self.line_free.max(sent + wire_time(reply, self.link.baud()));
        Ok(sent)
    }

    /// Takes the one reply of a Fast Sync Read whose request left at `sent`: due by its wire
    /// time and the margin.
    fn fast_sync_replies(
        &mut self,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
        valid: &mut [bool],
        (sent, margin): (Duration, Duration),
    ) -> Result<(), BusError> {
        if ids.len() > 256 {
            return Err(invalid_request("fast sync read of more than 256 servos"));
        }
        let lens = [len; 256];
        self.fast_replies(ids, &lens[..ids.len()], out, valid, (sent, margin))
    }

    /// Takes the one combined reply of a Fast Sync or Fast Bulk Read whose request left at
    /// `sent` (due by its wire time and the margin): blocks of error, id, data (`lens[k]`
    /// bytes for `ids[k]`) and the CRC of the packet up to there, each checked on its own.
    fn fast_replies(
        &mut self,
        ids: &[u8],
        lens: &[u16],
        out: &mut [u8],
        valid: &mut [bool],
        (sent, margin): (Duration, Duration),
    ) -> Result<(), BusError> {
        let total: usize = lens.iter().map(|l| usize::from(*l)).sum();
        let expect = 8 + 4 * ids.len() + total;
        if out.len() < total || valid.len() < ids.len() || ids.len() > 256 || expect > MAX_PACKET {
            return Err(invalid_request(
                "output shorter than the data asked, or too large",
            ));
        }
        let mut offsets = [0usize; 256];
        for k in 1..ids.len() {
            offsets[k] = offsets[k - 1] + usize::from(lens[k - 1]);
        }
        valid[..ids.len()].fill(false);
        let mut errors = [0u8; 256];
        let deadline = sent + wire_time(expect, self.link.baud()) + margin;
        let mut raw = [0u8; MAX_PACKET];
        let got = loop {
            if let Received::Packet(packet) = self.rx.next_packet() {
                let k = packet.len();
                raw[..k].copy_from_slice(packet);
                self.rx.consume(k);
                if raw[4] == BROADCAST_ID && raw[7] == instruction::STATUS {
                    break k;
                }
                continue;
            }
            // Past the deadline, what has already come in still counts (a pipelined read
            // taken late): one look without waiting.
            let left = deadline.saturating_sub(self.link.now());
            let mut buf = [0u8; 512];
            let r = self.link.recv(&mut buf, left)?;
            if r == 0 && left.is_zero() {
                break 0;
            }
            self.rx.push(&buf[..r]);
        };
        // Blocks: error, id, data, CRC of everything before the CRC.
        let mut at = 8;
        while got > 0 && at + 4 <= got {
            let (error, id) = (raw[at], raw[at + 1]);
            // An id not asked (or asked already) leaves the block's length unknown: the rest
            // is not to be trusted.
            let Some(k) = ids
                .iter()
                .position(|&i| i == id)
                .filter(|k| !valid[*k] && errors[*k] == 0)
            else {
                break;
            };
            let n = usize::from(lens[k]);
            let end = at + 2 + n;
            if end + 2 > got {
                break;
            }
            let crc = u16::from_le_bytes([raw[end], raw[end + 1]]);
            if protocol::crc16(&raw[..end]) != crc {
                // Everything after a corrupt block is suspect.
                break;
            }
            out[offsets[k]..offsets[k] + n].copy_from_slice(&raw[at + 2..end]);
            self.note_alert(id, error);
            errors[k] = error & 0x7F;
            valid[k] = error & 0x7F == 0;
            at = end + 2;
        }
        let broken = got > 0 && at != got;
        match ids.iter().zip(valid.iter()).position(|(_, v)| !v) {
            None => Ok(()),
            Some(k) => {
                if broken || got == 0 {
                    self.drain();
                } else {
                    // The one reply came whole, a servo's block missing: nothing more is due.
                    self.rx.clear();
                }
                let id = ids[k];
                Err(if errors[k] != 0 {
                    BusError::Servo { id, error: errors[k] }
                } else if broken {
                    BusError::Crc { id }
                } else {
                    BusError::Timeout { id }
                })
            }
        }
    }

    /// Sends a Sync Read request; returns when its last byte leaves.
    fn sync_read_request(&mut self, address: u16, len: u16, ids: &[u8]) -> Result<Duration, BusError> {
        self.sync_request(instruction::SYNC_READ, address, len, ids)
    }

    /// Takes the replies of a Sync Read whose request left at `sent`, in id order: servo `k`'s
    /// is due by the wire time of the replies up to its own and the margin, or a reply's wire
    /// time and the margin after the one before. `out` is written only when every reply passed.
    fn sync_read_replies(
        &mut self,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
        sent: Duration,
        margin: Duration,
    ) -> Result<(), BusError> {
        let len = usize::from(len);
        if out.len() < ids.len() * len {
            return Err(invalid_request("output shorter than ids × len"));
        }
        let mut scratch = [0u8; MAX_PACKET];
        let one = wire_time(11 + len, self.link.baud());
        for (k, &id) in ids.iter().enumerate() {
            // Due by the wire time of the replies so far, and at least a reply's wire time
            // after the previous one came (return delays the host does not know).
            let due = (sent + one * (k as u32 + 1)).max(self.link.now() + one) + margin;
            if let Err(e) = self.status_by(id, Some(len), due) {
                // A servo that did not answer, a later servo's reply in its slot: the rest of
                // the read is well-formed and ends by its wire time — take it and go on, so the
                // silent servo costs this read only. An empty slot (the chain stalled, a reply
                // late) or anything garbled: drain until quiet, late bytes must not reach the
                // next read.
                match e {
                    BusError::WrongId { got, .. } if ids[k + 1..].contains(&got) => {
                        let after = k + 1 + ids[k + 1..].iter().position(|&i| i == got).unwrap_or(0);
                        self.finish_read(&ids[after + 1..], sent + one * ids.len() as u32 + margin);
                    }
                    _ => self.drain(),
                }
                return Err(e);
            }
            scratch[k * len..(k + 1) * len].copy_from_slice(&self.params[1..=len]);
        }
        out[..ids.len() * len].copy_from_slice(&scratch[..ids.len() * len]);
        Ok(())
    }

    /// Takes the replies of the pending position read (if any) and throws them away: the line
    /// is quiet for the next instruction.
    fn settle(&mut self) {
        if let Some((id, _, len, sent)) = self.pending_single.take() {
            if self
                .status(id, Some(usize::from(len)), sent, self.margin)
                .is_err()
            {
                self.drain();
            }
        }
        if let Some(p) = self.pending.take() {
            let mut out = [0i32; crate::servo::MAX_SERVOS];
            let _ = self.take_positions(&p, &mut out);
            if let Some(m) = &mut self.merged {
                m.fresh = None;
            }
        }
    }

    /// The positions of a read on the wire (and the merged block's reply after them).
    fn take_positions(&mut self, p: &PendingRead, out: &mut [i32]) -> Result<(), BusError> {
        let ids = &p.ids[..p.n];
        let mut data = [0u8; 4 * crate::servo::MAX_SERVOS];
        let fast = matches!(self.read, ReadMode::FastSync | ReadMode::FastBulk);
        if let (true, true, Some(m)) = (p.merged, fast, self.merged) {
            // A Fast Bulk Read: one reply, the servos' blocks then the device's, each checked
            // on its own. The positions are used only when every servo's block held (all or
            // nothing, as a Fast Sync Read); the device's block stands on its own.
            let mut ids = [0u8; MAX_SERVOS];
            let mut lens = [4u16; MAX_SERVOS];
            ids[..p.n].copy_from_slice(&p.ids[..p.n]);
            (ids[p.n], lens[p.n]) = (m.id, m.len);
            let mut buf = [0u8; 4 * MAX_SERVOS + MAX_MERGED];
            let mut valid = [false; MAX_SERVOS];
            let all = self.fast_replies(
                &ids[..=p.n],
                &lens[..=p.n],
                &mut buf,
                &mut valid,
                (p.sent, self.margin),
            );
            let mut block = m;
            let len = usize::from(m.len);
            block.fresh = Some(valid[p.n]);
            if valid[p.n] {
                block.data[..len].copy_from_slice(&buf[4 * p.n..4 * p.n + len]);
            }
            self.merged = Some(block);
            if !valid[..p.n].iter().all(|&v| v) {
                return Err(all.err().unwrap_or(BusError::Timeout { id: ids[0] }));
            }
            data[..4 * p.n].copy_from_slice(&buf[..4 * p.n]);
        } else if let (true, Some(m)) = (p.merged, self.merged) {
            // A Bulk Read: the servos' status packets in entry order, then the device's.
            let positions = self.sync_read_replies(4, ids, &mut data[..4 * p.n], p.sent, self.margin);
            let mut block = m;
            block.fresh = Some(false);
            if positions.is_err() {
                // The device's reply may still be on its way: the line is drained past it.
                self.drain();
            } else {
                let len = usize::from(m.len);
                let baud = self.link.baud();
                let due = p.sent + wire_time(11 + 4, baud) * p.n as u32 + wire_time(11 + len, baud);
                let due = due.max(self.link.now() + wire_time(11 + len, baud)) + self.margin;
                if self.status_by(m.id, Some(len), due).is_ok() {
                    block.data[..len].copy_from_slice(&self.params[1..=len]);
                    block.fresh = Some(true);
                } else {
                    self.drain();
                }
            }
            self.merged = Some(block);
            positions?;
        } else if matches!(self.read, ReadMode::FastSync | ReadMode::FastBulk) {
            // All or nothing for the loop: a tick uses a read only when every servo's held.
            let mut valid = [false; crate::servo::MAX_SERVOS];
            self.fast_sync_replies(4, ids, &mut data[..4 * p.n], &mut valid, (p.sent, self.margin))?;
        } else {
            // Sync and Bulk Read: a status packet per servo, in order.
            self.sync_read_replies(4, ids, &mut data[..4 * p.n], p.sent, self.margin)?;
        }
        for (k, o) in out.iter_mut().enumerate().take(p.n) {
            *o = i32::from_le_bytes([data[4 * k], data[4 * k + 1], data[4 * k + 2], data[4 * k + 3]]);
        }
        Ok(())
    }

    /// The transport.
    pub fn link(&self) -> &T {
        &self.link
    }

    /// The transport, mutable.
    pub fn link_mut(&mut self) -> &mut T {
        &mut self.link
    }

    /// Sends an instruction (after the replies of a pending read); returns when its last byte
    /// leaves: after whatever was on the line (half duplex) and its own wire time.
    fn send(&mut self, id: u8, inst: u8, params: &[u8]) -> Result<Duration, BusError> {
        self.settle();
        let n = protocol::encode(id, inst, params, &mut self.tx)
            .map_err(|_| invalid_request("instruction too long"))?;
        // Whatever came in before this instruction is no reply to it: dropped unread.
        self.rx.clear();
        let mut buf = [0u8; 512];
        while let Ok(n) = self.link.recv(&mut buf, Duration::ZERO) {
            if n == 0 {
                break;
            }
        }
        let start = self.link.now().max(self.line_free);
        self.link.send(&self.tx[..n])?;
        self.line_free = start + wire_time(n, self.link.baud());
        Ok(self.line_free)
    }

    /// The next complete packet received, decoded (parameters in `self.params`) and removed
    /// from the buffer: `(id, instruction, parameter count)`; `None` while incomplete.
    fn take_packet(&mut self) -> Option<Result<(u8, u8, usize), CodecError>> {
        let Received::Packet(raw) = self.rx.next_packet() else {
            return None;
        };
        let n = raw.len();
        let decoded =
            protocol::decode(raw, &mut self.params).map(|(p, _)| (p.id, p.instruction, p.params.len()));
        self.rx.consume(n);
        Some(decoded)
    }

    /// Waits for one status packet from `id` with exactly `len` data bytes (any length when
    /// `None`); returns the data length, the data in `self.params[1..]`.
    fn status(
        &mut self,
        id: u8,
        len: Option<usize>,
        sent: Duration,
        margin: Duration,
    ) -> Result<usize, BusError> {
        let expect = len.unwrap_or(3);
        self.status_by(id, len, sent + wire_time(11 + expect, self.link.baud()) + margin)
    }

    /// [`Self::status`] by an absolute deadline (transport time).
    fn status_by(&mut self, id: u8, len: Option<usize>, deadline: Duration) -> Result<usize, BusError> {
        loop {
            match self.take_packet() {
                Some(decoded) => {
                    let (got, inst, plen) = decoded.map_err(|e| match e {
                        CodecError::BadCrc { .. } => BusError::Crc { id },
                        CodecError::BadStuffing => BusError::Malformed {
                            id,
                            what: "byte stuffing",
                        },
                        _ => BusError::Malformed { id, what: "packet" },
                    })?;
                    if self.rx.take_broken() > 0 {
                        // A packet broke off before this one: this may be an old reply that
                        // came late, with a valid CRC and the right id but stale data.
                        return Err(BusError::Malformed {
                            id,
                            what: "a broken packet before the reply",
                        });
                    }
                    if inst != instruction::STATUS {
                        // Our own instruction echoed on a half-duplex adapter.
                        continue;
                    }
                    if got != id {
                        return Err(BusError::WrongId { expected: id, got });
                    }
                    if plen == 0 {
                        return Err(BusError::Malformed {
                            id,
                            what: "status without error byte",
                        });
                    }
                    self.note_alert(id, self.params[0]);
                    let error = self.params[0] & 0x7F;
                    if error != 0 {
                        return Err(BusError::Servo { id, error });
                    }
                    if len.is_some_and(|l| l != plen - 1) {
                        return Err(BusError::Malformed {
                            id,
                            what: "parameter count",
                        });
                    }
                    return Ok(plen - 1);
                }
                None => {
                    // Past the deadline, what has already come in still counts.
                    let left = deadline.saturating_sub(self.link.now());
                    let mut buf = [0u8; 512];
                    let got = self.link.recv(&mut buf, left)?;
                    if got == 0 && left.is_zero() {
                        return Err(BusError::Timeout { id });
                    }
                    self.rx.push(&buf[..got]);
                }
            }
        }
    }

    /// After a read that lost a servo's reply, a later servo's in its slot: takes the replies
    /// still due — `rest`, in order, by the read's `deadline` — and drops them. Anything else
    /// (a reply out of order, a broken or corrupt packet, the deadline passing) means the line
    /// is not what a silent servo leaves: drained until quiet.
    fn finish_read(&mut self, rest: &[u8], deadline: Duration) {
        let mut buf = [0u8; 512];
        let mut next = 0;
        while next < rest.len() {
            match self.take_packet() {
                Some(Ok((id, inst, _)))
                    if inst == instruction::STATUS && id == rest[next] && self.rx.take_broken() == 0 =>
                {
                    next += 1;
                }
                Some(Ok((_, inst, _))) if inst != instruction::STATUS => {}
                Some(_) => return self.drain(),
                None => {
                    let left = deadline.saturating_sub(self.link.now());
                    match self.link.recv(&mut buf, left) {
                        Ok(n) if n > 0 => self.rx.push(&buf[..n]),
                        _ => return self.drain(),
                    }
                }
            }
        }
        if self.rx.pending() > 0 {
            return self.drain();
        }
        self.rx.clear();
    }

    /// After a failure: read until the line has been quiet for a while, and drop it all.
    fn drain(&mut self) {
        let mut buf = [0u8; 512];
        while let Ok(n) = self.link.recv(&mut buf, self.quiet) {
            if n == 0 {
                break;
            }
        }
        self.rx.clear();
    }

    fn transact(&mut self, id: u8, inst: u8, params: &[u8], len: Option<usize>) -> Result<usize, BusError> {
        let sent = self.send(id, inst, params)?;
        // Single transactions (start-up, configuration) are not the tick's: they wait longer
        // than its reads, which must cost at most a tick.
        let r = self.status(id, len, sent, self.single_margin);
        if r.is_err() {
            self.drain();
        }
        r
    }
}

impl<T: Transport> ServoBus for PacketBus<T> {
    fn ping(&mut self, id: u8) -> Result<PingInfo, BusError> {
        self.transact(id, instruction::PING, &[], Some(3))?;
        let p = &self.params[1..4];
        Ok(PingInfo {
            id,
            model_number: u16::from_le_bytes([p[0], p[1]]),
            firmware: p[2],
        })
    }

    fn scan(&mut self) -> Result<Vec<PingInfo>, BusError> {
        self.send(BROADCAST_ID, instruction::PING, &[])?;
        let mut found = Vec::new();
        // Replies come in id order, each after its return delay (up to 508 µs); stop after a
        // silence once something answered.
        let timeout = (wire_time(14, self.link.baud()) + Duration::from_micros(510)) * 253 + self.margin;
        let deadline = self.link.now() + timeout;
        let mut buf = [0u8; 512];
        loop {
            match self.take_packet() {
                Some(decoded) => {
                    if let Ok((id, instruction::STATUS, 4)) = decoded {
                        let p = &self.params[1..4];
                        if !found.iter().any(|f: &PingInfo| f.id == id) {
                            found.push(PingInfo {
                                id,
                                model_number: u16::from_le_bytes([p[0], p[1]]),
                                firmware: p[2],
                            });
                        }
                    }
                }
                None => {
                    let now = self.link.now();
                    if now >= deadline {
                        break;
                    }
                    let got = self.link.recv(
                        &mut buf,
                        (deadline - now).min(self.quiet.max(Duration::from_millis(20))),
                    )?;
                    if got == 0 && self.rx.pending() == 0 && !found.is_empty() {
                        break;
                    }
                    self.rx.push(&buf[..got]);
                }
            }
        }
        found.sort_by_key(|f| f.id);
        Ok(found)
    }

    fn request_read(&mut self, id: u8, address: u16, len: u16) -> Result<(), BusError> {
        if usize::from(len) >= MAX_PACKET {
            return Err(invalid_request("read too long"));
        }
        let (a, l) = (address.to_le_bytes(), len.to_le_bytes());
        let sent = self.send(id, instruction::READ, &[a[0], a[1], l[0], l[1]])?;
        self.pending_single = Some((id, address, len, sent));
        Ok(())
    }

    fn collect_read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), BusError> {
        match self.pending_single {
            Some((pid, pa, pl, sent)) if (pid, pa, usize::from(pl)) == (id, address, out.len()) => {
                self.pending_single = None;
                let r = self.status(id, Some(out.len()), sent, self.margin);
                if r.is_err() {
                    self.drain();
                }
                r?;
                out.copy_from_slice(&self.params[1..=out.len()]);
                Ok(())
            }
            _ => self.read(id, address, out),
        }
    }

    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), BusError> {
        if out.len() >= MAX_PACKET {
            return Err(invalid_request("read too long"));
        }
        let n = out.len() as u16;
        let a = address.to_le_bytes();
        let l = n.to_le_bytes();
        self.transact(id, instruction::READ, &[a[0], a[1], l[0], l[1]], Some(out.len()))?;
        out.copy_from_slice(&self.params[1..=out.len()]);
        Ok(())
    }

    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), BusError> {
        if 2 + data.len() > MAX_PACKET {
            return Err(invalid_request("instruction too long"));
        }
        let mut p = [0u8; MAX_PACKET];
        let a = address.to_le_bytes();
        p[..2].copy_from_slice(&a);
        p[2..2 + data.len()].copy_from_slice(data);
        if id == BROADCAST_ID {
            return self
                .send(id, instruction::WRITE, &p[..2 + data.len()])
                .map(|_| ());
        }
        self.transact(id, instruction::WRITE, &p[..2 + data.len()], Some(0))
            .map(|_| ())
    }

    fn sync_write(&mut self, address: u16, len: u16, ids: &[u8], data: &[u8]) -> Result<(), BusError> {
        let len = usize::from(len);
        if 4 + ids.len() * (1 + len) > MAX_PACKET || data.len() < ids.len() * len {
            return Err(invalid_request(
                "sync write too long, or data shorter than ids × len",
            ));
        }
        let mut p = [0u8; MAX_PACKET];
        p[..2].copy_from_slice(&address.to_le_bytes());
        p[2..4].copy_from_slice(&(len as u16).to_le_bytes());
        let mut at = 4;
        for (k, &id) in ids.iter().enumerate() {
            p[at] = id;
            p[at + 1..at + 1 + len].copy_from_slice(&data[k * len..(k + 1) * len]);
            at += 1 + len;
        }
        self.send(BROADCAST_ID, instruction::SYNC_WRITE, &p[..at])
            .map(|_| ())
    }

    fn sync_read(&mut self, address: u16, len: u16, ids: &[u8], out: &mut [u8]) -> Result<(), BusError> {
        if out.len() < ids.len() * usize::from(len) {
            return Err(invalid_request("output shorter than ids × len"));
        }
        let sent = self.sync_read_request(address, len, ids)?;
        // Not the tick's read (that is `read_positions`): the single transactions' margin.
        self.sync_read_replies(len, ids, out, sent, self.single_margin)
    }

    fn reboot(&mut self, id: u8) -> Result<(), BusError> {
        self.transact(id, instruction::REBOOT, &[], Some(0)).map(|_| ())
    }

    fn read_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), BusError> {
        self.request_positions(ids)?;
        self.collect_positions(ids, out)
    }

    fn merge_into_reads(&mut self, id: u8, address: u16, len: u16) -> bool {
        if usize::from(len) > MAX_MERGED {
            return false;
        }
        self.settle();
        self.merged = Some(MergedBlock {
            id,
            address,
            len,
            data: [0; MAX_MERGED],
            fresh: None,
        });
        true
    }

    fn take_alert(&mut self) -> Option<u8> {
        self.alert.take()
    }

    fn take_merged(&mut self, out: &mut [u8]) -> Option<bool> {
        let m = self.merged.as_mut()?;
        let fresh = m.fresh.take()?;
        let len = usize::from(m.len).min(out.len());
        if fresh {
            out[..len].copy_from_slice(&m.data[..len]);
        }
        Some(fresh)
    }

    fn request_positions(&mut self, ids: &[u8]) -> Result<(), BusError> {
        let n = ids.len().min(crate::servo::MAX_SERVOS);
        // The board as one more Bulk Read entry, where the entries leave room for it.
        let merged = self.merged.is_some() && n < MAX_SERVOS;
        let sent = match (self.read, self.merged) {
            (mode, Some(m)) if merged => {
                // Different items from different devices: a Bulk Read, or a Fast Bulk Read
                // (one combined reply) where the profile reads fast.
                let mut entries = [(0u8, addr::PRESENT_POSITION, 4u16); MAX_SERVOS];
                for (e, &id) in entries.iter_mut().zip(&ids[..n]) {
                    e.0 = id;
                }
                entries[n] = (m.id, m.address, m.len);
                let inst = if matches!(mode, ReadMode::FastSync | ReadMode::FastBulk) {
                    instruction::FAST_BULK_READ
                } else {
                    instruction::BULK_READ
                };
                self.bulk_request(inst, &entries[..=n])?
            }
            (ReadMode::Sync, _) => self.sync_read_request(addr::PRESENT_POSITION, 4, &ids[..n])?,
            (ReadMode::FastSync, _) => self.fast_sync_request(addr::PRESENT_POSITION, 4, &ids[..n])?,
            (bulk, _) => {
                let mut entries = [(0u8, addr::PRESENT_POSITION, 4u16); MAX_SERVOS];
                for (e, &id) in entries.iter_mut().zip(&ids[..n]) {
                    e.0 = id;
                }
                let inst = if bulk == ReadMode::Bulk {
                    instruction::BULK_READ
                } else {
                    instruction::FAST_BULK_READ
                };
                self.bulk_request(inst, &entries[..n])?
            }
        };
        let mut p = PendingRead {
            ids: [0; crate::servo::MAX_SERVOS],
            n,
            sent,
            merged,
        };
        p.ids[..n].copy_from_slice(&ids[..n]);
        self.pending = Some(p);
        Ok(())
    }

    fn collect_positions(&mut self, ids: &[u8], out: &mut [i32]) -> Result<(), BusError> {
        if out.len() < ids.len() || ids.len() > crate::servo::MAX_SERVOS {
            return Err(invalid_request("more ids than outputs or servos"));
        }
        match self.pending.take() {
            Some(p) if p.ids[..p.n] == *ids => self.take_positions(&p, out),
            other => {
                // Nothing asked, or asked for other servos: read now.
                self.pending = other;
                self.settle();
                self.request_positions(ids)?;
                self.collect_positions(ids, out)
            }
        }
    }
}

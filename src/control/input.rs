//! Inputs of the loop over bounded crossbeam channels: frames (channel vectors) from the clip
//! player, effector targets from files, stdin or UDP.
//!
//! Every message carries the time it is due and the time it was made. The loop takes, without
//! blocking, the newest message already due ([`InputPort::take`]); paced producers (the player,
//! target files) run a few messages ahead, polling while the channel is full
//! ([`InputSender::send_wait`]: no receive has a blocked sender to wake), live producers (stdin,
//! UDP) never wait: when the channel is full the oldest message is dropped
//! ([`InputSender::send_newest`]).
//!
//! A message is sized for the largest frame (3.6 KB), but a target message uses a few hundred
//! bytes of it and a frame of the CMU skeleton an eighth. So messages travel boxed: the channel
//! moves a pointer, the loop reads only the bytes the message uses, and each box goes back to
//! the producers once the loop is done with it (a spare channel), so that neither the loop nor
//! a steady producer allocates.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender, TryRecvError, TrySendError};
use glam::DVec3;

use crate::skeleton::MAX_CHANNELS;

/// How often a paced producer tries again to send into a full channel.
pub const SEND_POLL: Duration = Duration::from_millis(1);

/// Most effectors one message or one follower holds.
pub const MAX_EFFECTORS: usize = 8;

/// One effector's goal.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Target {
    /// Index of the effector in the follower's list.
    pub effector: usize,
    /// Goal of the effector bone's tip, in the root's frame (file units).
    pub position: DVec3,
    /// Optional pointing direction of the next bone (hand, foot), unit or not.
    pub direction: Option<DVec3>,
}

impl Target {
    /// True when every component is a finite number.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.position.is_finite() && self.direction.is_none_or(|d| d.is_finite() && d.length() > 1e-12)
    }
}

/// What a message carries.
// Messages are plain values: a frame is copied into the channel's preallocated slot rather
// than boxed, so neither side allocates.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Payload {
    /// A full channel vector (radians for rotations, file units for translations).
    Frame {
        /// Channel values; `len` of them are used.
        channels: [f64; MAX_CHANNELS],
        /// Number of channels.
        len: usize,
        /// Clip time of the sample, seconds.
        clip_time: f64,
    },
    /// Goals for some effectors (the others keep theirs).
    Targets(heapless::Vec<Target, MAX_EFFECTORS>),
}

/// A message to the loop.
#[derive(Clone, Debug, PartialEq)]
pub struct Input {
    /// Sequence number from the producer.
    pub seq: u64,
    /// Loop-clock time (ns) from which it may be used; 0 for at once.
    pub due_ns: u64,
    /// Loop-clock time (ns) it was made: the input age is measured from here.
    pub made_ns: u64,
    /// The content.
    pub payload: Payload,
}

impl Input {
    /// A frame message from `channels`.
    #[must_use]
    pub fn frame(seq: u64, due_ns: u64, made_ns: u64, channels: &[f64], clip_time: f64) -> Input {
        let mut c = [0.0; MAX_CHANNELS];
        let len = channels.len().min(MAX_CHANNELS);
        c[..len].copy_from_slice(&channels[..len]);
        Input {
            seq,
            due_ns,
            made_ns,
            payload: Payload::Frame {
                channels: c,
                len,
                clip_time,
            },
        }
    }
}

/// The producer's end of an input channel.
#[derive(Clone, Debug)]
pub struct InputSender {
    tx: Sender<Box<Input>>,
    /// The same channel's receiving end, to drop the oldest message when full.
    rx: Receiver<Box<Input>>,
    /// Boxes the loop is done with, to send the next messages in.
    spares: Receiver<Box<Input>>,
    /// The spare channel's sending end, for the boxes of dropped messages.
    spare_tx: Sender<Box<Input>>,
    stop: Arc<AtomicBool>,
}

/// Why a send did not happen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SendError {
    /// The loop stopped (or asked producers to stop).
    Stopped,
}

impl InputSender {
    /// `msg` in a spare box (a new one when none is spare).
    fn boxed(&self, msg: Input) -> Box<Input> {
        match self.spares.try_recv() {
            Ok(mut b) => {
                *b = msg;
                b
            }
            Err(_) => Box::new(msg),
        }
    }

    /// Sends, dropping the oldest queued message when the channel is full (live sources).
    /// Never blocks. Returns whether a message was dropped.
    ///
    /// # Errors
    /// [`SendError::Stopped`] when the loop has stopped.
    pub fn send_newest(&self, msg: Input) -> Result<bool, SendError> {
        let mut msg = self.boxed(msg);
        let mut dropped = false;
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Err(SendError::Stopped);
            }
            match self.tx.try_send(msg) {
                Ok(()) => return Ok(dropped),
                Err(TrySendError::Full(m)) => {
                    msg = m;
                    if let Ok(oldest) = self.rx.try_recv() {
                        dropped = true;
                        let _ = self.spare_tx.try_send(oldest);
                    }
                }
                Err(TrySendError::Disconnected(_)) => return Err(SendError::Stopped),
            }
        }
    }

    /// Sends, waiting while the channel is full (paced sources running ahead of the loop).
    /// It waits by polling every [`SEND_POLL`], not blocked on the channel: a blocked sender is
    /// woken by the receiver, and that wake-up (a system call) would fall in the loop's tick.
    ///
    /// # Errors
    /// [`SendError::Stopped`] when the loop has stopped.
    pub fn send_wait(&self, msg: Input) -> Result<(), SendError> {
        let mut msg = self.boxed(msg);
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Err(SendError::Stopped);
            }
            match self.tx.try_send(msg) {
                Ok(()) => return Ok(()),
                Err(TrySendError::Full(m)) => {
                    msg = m;
                    std::thread::sleep(SEND_POLL);
                }
                Err(TrySendError::Disconnected(_)) => return Err(SendError::Stopped),
            }
        }
    }

    /// True once the loop asked producers to stop.
    #[must_use]
    pub fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// The flag [`InputSender::stopped`] reads, for a thread that waits on something else.
    #[must_use]
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.stop)
    }
}

/// The loop's end of an input channel.
#[derive(Debug)]
pub struct InputPort {
    rx: Receiver<Box<Input>>,
    /// Where the boxes of messages done with go back to the producers.
    spares: Sender<Box<Input>>,
    /// Messages received and not yet taken, in order (the next one first): the next one, and
    /// the one after it when [`InputPort::prefetch`] received it ahead.
    ahead: heapless::Deque<Box<Input>, 2>,
    /// The message in use.
    current: Option<Box<Input>>,
    stop: Arc<AtomicBool>,
    disconnected: bool,
    /// Messages received and passed over for a newer due one.
    pub superseded: u64,
}

/// Boxes in circulation beyond the channel's capacity that the spare channel has room for: the
/// loop's three (two received ahead, one in use) and one being filled by each of up to five producers. With
/// more producers, a box that finds no room is freed.
const SPARE_ROOM: usize = 8;

/// A bounded input channel of `capacity` messages (≥ 1): the producer's and the loop's ends.
/// The producer's end may be cloned for several producers.
#[must_use]
pub fn input_channel(capacity: usize) -> (InputSender, InputPort) {
    let (tx, rx) = crossbeam_channel::bounded(capacity.max(1));
    let (spare_tx, spares) = crossbeam_channel::bounded(capacity.max(1) + SPARE_ROOM);
    let stop = Arc::new(AtomicBool::new(false));
    (
        InputSender {
            tx,
            rx: rx.clone(),
            spares,
            spare_tx: spare_tx.clone(),
            stop: Arc::clone(&stop),
        },
        InputPort {
            rx,
            spares: spare_tx,
            ahead: heapless::Deque::new(),
            current: None,
            stop,
            disconnected: false,
            superseded: 0,
        },
    )
}

impl InputPort {
    /// Takes the newest message due at `now_ns`, if one arrived since the last call; never
    /// blocks, never allocates. A message not yet due is kept for a later tick.
    pub fn take(&mut self, now_ns: u64) -> Option<&Input> {
        let mut fresh = false;
        loop {
            self.fill();
            match self.ahead.front() {
                Some(m) if m.due_ns <= now_ns => {
                    if fresh {
                        self.superseded += 1;
                    }
                    self.use_pending();
                    fresh = true;
                }
                _ => break,
            }
        }
        if fresh {
            self.current()
        } else {
            None
        }
    }

    /// The next message in order if it is due by `due_by` (a look-ahead horizon), taken: it
    /// becomes the message in use ([`InputPort::current`]). Never blocks, never allocates.
    pub fn next_due(&mut self, due_by: u64) -> Option<&Input> {
        self.fill();
        if self.ahead.front().is_some_and(|m| m.due_ns <= due_by) {
            self.use_pending();
            self.current()
        } else {
            None
        }
    }

    /// The next message becomes the one in use; the box of the one before goes back.
    fn use_pending(&mut self) {
        if let Some(done) = std::mem::replace(&mut self.current, self.ahead.pop_front()) {
            // Full only with more producers than the room allows: then the box is freed.
            let _ = self.spares.try_send(done);
        }
    }

    /// Whether the message after the last one taken is also due by `due_by` (so that one is
    /// already superseded, for inputs that only the newest counts of).
    pub fn next_is_due(&mut self, due_by: u64) -> bool {
        self.fill();
        self.ahead.front().is_some_and(|m| m.due_ns <= due_by)
    }

    /// The next message in order, left where it is (whether due or not); never blocks, never
    /// allocates.
    pub fn peek(&mut self) -> Option<&Input> {
        self.fill();
        self.ahead.front().map(|m| &**m)
    }

    /// Receives the next message if none is waiting.
    fn fill(&mut self) {
        if self.ahead.is_empty() {
            self.receive();
        }
    }

    /// Receives the message after the next one too, if it has come: called while the loop
    /// waits, so that the tick that takes the next message finds the one after it (whether it
    /// is due too) without reading the channel. Never blocks, never allocates.
    pub fn prefetch(&mut self) {
        while !self.ahead.is_full() && self.receive() {}
    }

    /// One message from the channel into `ahead` (which has room); whether one came.
    fn receive(&mut self) -> bool {
        match self.rx.try_recv() {
            Ok(m) => {
                // `ahead` has room: every caller checks.
                let _ = self.ahead.push_back(m);
                true
            }
            Err(TryRecvError::Empty) => false,
            Err(TryRecvError::Disconnected) => {
                // Every producer is gone.
                self.disconnected = true;
                false
            }
        }
    }

    /// The message in use (the last one taken).
    #[must_use]
    pub fn current(&self) -> Option<&Input> {
        self.current.as_deref()
    }

    /// True when every producer has gone and nothing is left to take.
    #[must_use]
    pub fn finished(&self) -> bool {
        self.disconnected && self.ahead.is_empty() && self.rx.is_empty()
    }

    /// Asks the producers to stop.
    pub fn stop_producers(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }

    /// A flag producers watch (set by [`InputPort::stop_producers`]).
    #[must_use]
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.stop)
    }
}

impl Drop for InputPort {
    fn drop(&mut self) {
        self.stop_producers();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn targets(due_ns: u64, x: f64) -> Input {
        let mut t = heapless::Vec::new();
        let _ = t.push(Target {
            effector: 0,
            position: DVec3::new(x, 0.0, 0.0),
            direction: None,
        });
        Input {
            seq: due_ns,
            due_ns,
            made_ns: 1,
            payload: Payload::Targets(t),
        }
    }

    fn x(m: &Input) -> f64 {
        match &m.payload {
            Payload::Targets(t) => t[0].position.x,
            Payload::Frame { .. } => f64::NAN,
        }
    }

    #[test]
    fn messages_come_in_order_and_their_boxes_go_back_to_the_producer() {
        let (tx, mut port) = input_channel(4);
        for k in 1..=3 {
            tx.send_wait(targets(k * 10, k as f64)).unwrap();
        }
        // Received ahead, nothing taken: the next one is 10, and 20 is known to be due by 25.
        port.prefetch();
        assert_eq!(port.peek().map(x), Some(1.0));
        assert!(port.current().is_none());
        assert_eq!(port.next_due(5).map(x), None);
        assert_eq!(port.next_due(15).map(x), Some(1.0));
        assert!(port.next_is_due(25));
        assert!(!port.next_is_due(15));
        let first: *const Input = port.current().unwrap();
        assert_eq!(port.next_due(100).map(x), Some(2.0));
        // The first message's box went back: the next message sent travels in it.
        tx.send_wait(targets(40, 4.0)).unwrap();
        assert_eq!(port.next_due(100).map(x), Some(3.0));
        assert_eq!(port.next_due(100).map(x), Some(4.0));
        assert!(std::ptr::eq(port.current().unwrap(), first));
        assert_eq!(port.next_due(100).map(x), None);
        drop(tx);
        assert!(port.next_due(100).is_none());
        assert!(port.finished());
    }

    #[test]
    fn take_keeps_the_newest_due_and_counts_the_ones_passed_over() {
        let (tx, mut port) = input_channel(8);
        for k in 1..=4 {
            tx.send_newest(targets(k * 10, k as f64)).unwrap();
        }
        assert_eq!(port.take(35).map(x), Some(3.0));
        assert_eq!(port.superseded, 2);
        assert!(port.take(35).is_none());
        assert_eq!(port.take(40).map(x), Some(4.0));
        // A full channel drops its oldest for a live producer.
        let (tx, mut port) = input_channel(2);
        for k in 1..=3 {
            tx.send_newest(targets(k * 10, k as f64)).unwrap();
        }
        port.prefetch();
        assert_eq!(port.next_due(100).map(x), Some(2.0));
        assert_eq!(port.next_due(100).map(x), Some(3.0));
    }
}

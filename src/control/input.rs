//! Inputs of the loop over bounded crossbeam channels: frames (channel vectors) from the clip
//! player, effector targets from files, stdin or UDP.
//!
//! Every message carries the time it is due and the time it was made. The loop takes, without
//! blocking, the newest message already due ([`InputPort::take`]); paced producers (the player,
//! target files) run a few messages ahead with a blocking send, live producers (stdin, UDP)
//! never wait: when the channel is full the oldest message is dropped ([`InputSender::send_newest`]).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use crossbeam_channel::{Receiver, SendTimeoutError, Sender, TryRecvError, TrySendError};
use glam::DVec3;

use crate::skeleton::MAX_CHANNELS;

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
    tx: Sender<Input>,
    /// The same channel's receiving end, to drop the oldest message when full.
    rx: Receiver<Input>,
    stop: Arc<AtomicBool>,
}

/// Why a send did not happen.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SendError {
    /// The loop stopped (or asked producers to stop).
    Stopped,
}

impl InputSender {
    /// Sends, dropping the oldest queued message when the channel is full (live sources).
    /// Never blocks. Returns whether a message was dropped.
    ///
    /// # Errors
    /// [`SendError::Stopped`] when the loop has stopped.
    pub fn send_newest(&self, mut msg: Input) -> Result<bool, SendError> {
        let mut dropped = false;
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Err(SendError::Stopped);
            }
            match self.tx.try_send(msg) {
                Ok(()) => return Ok(dropped),
                Err(TrySendError::Full(m)) => {
                    msg = m;
                    dropped |= self.rx.try_recv().is_ok();
                }
                Err(TrySendError::Disconnected(_)) => return Err(SendError::Stopped),
            }
        }
    }

    /// Sends, waiting while the channel is full (paced sources running ahead of the loop).
    ///
    /// # Errors
    /// [`SendError::Stopped`] when the loop has stopped.
    pub fn send_wait(&self, mut msg: Input) -> Result<(), SendError> {
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Err(SendError::Stopped);
            }
            match self.tx.send_timeout(msg, Duration::from_millis(20)) {
                Ok(()) => return Ok(()),
                Err(SendTimeoutError::Timeout(m)) => msg = m,
                Err(SendTimeoutError::Disconnected(_)) => return Err(SendError::Stopped),
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
    rx: Receiver<Input>,
    /// A message received but not yet due.
    pending: Option<Input>,
    /// The message in use.
    current: Option<Input>,
    stop: Arc<AtomicBool>,
    disconnected: bool,
    /// Messages received and passed over for a newer due one.
    pub superseded: u64,
}

/// A bounded input channel of `capacity` messages (≥ 1): the producer's and the loop's ends.
/// The producer's end may be cloned for several producers.
#[must_use]
pub fn input_channel(capacity: usize) -> (InputSender, InputPort) {
    let (tx, rx) = crossbeam_channel::bounded(capacity.max(1));
    let stop = Arc::new(AtomicBool::new(false));
    (
        InputSender {
            tx,
            rx: rx.clone(),
            stop: Arc::clone(&stop),
        },
        InputPort {
            rx,
            pending: None,
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
            if self.pending.is_none() {
                match self.rx.try_recv() {
                    Ok(m) => self.pending = Some(m),
                    Err(TryRecvError::Empty) => break,
                    Err(TryRecvError::Disconnected) => {
                        // Every producer is gone.
                        self.disconnected = true;
                        break;
                    }
                }
            }
            match &self.pending {
                Some(m) if m.due_ns <= now_ns => {
                    if fresh {
                        self.superseded += 1;
                    }
                    self.current = self.pending.take();
                    fresh = true;
                }
                _ => break,
            }
        }
        if fresh {
            self.current.as_ref()
        } else {
            None
        }
    }

    /// The next message in order if it is due by `due_by` (a look-ahead horizon), moved out;
    /// never blocks, never allocates.
    pub fn next_due(&mut self, due_by: u64) -> Option<Input> {
        self.fill();
        if self.pending.as_ref().is_some_and(|m| m.due_ns <= due_by) {
            self.pending.take()
        } else {
            None
        }
    }

    /// Whether the message after the last one taken is also due by `due_by` (so that one is
    /// already superseded, for inputs that only the newest counts of).
    pub fn next_is_due(&mut self, due_by: u64) -> bool {
        self.fill();
        self.pending.as_ref().is_some_and(|m| m.due_ns <= due_by)
    }

    fn fill(&mut self) {
        if self.pending.is_none() {
            match self.rx.try_recv() {
                Ok(m) => self.pending = Some(m),
                Err(TryRecvError::Empty) => {}
                Err(TryRecvError::Disconnected) => self.disconnected = true,
            }
        }
    }

    /// The message in use (the last one taken).
    #[must_use]
    pub fn current(&self) -> Option<&Input> {
        self.current.as_ref()
    }

    /// True when every producer has gone and nothing is left to take.
    #[must_use]
    pub fn finished(&self) -> bool {
        self.disconnected && self.pending.is_none() && self.rx.is_empty()
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

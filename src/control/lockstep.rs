//! The loop in lockstep with a simulated rig: time is the simulation's, and inputs are sent
//! just in time instead of by producer threads.
//!
//! [`FeedingClock`] wraps a virtual clock (a [`crate::bus::virtual_chain::VirtualRig`] or the
//! MuJoCo bus): before it lets time pass up to a deadline it sends every input due by then, so
//! [`super::Controller::run`] runs unchanged — the same ticks, ramp and torque-off as on a
//! real bus — and the same inputs give the same run, every time.

use std::sync::Arc;

use super::input::{Input, InputSender, Payload};
use super::sources::{ClipPlayer, ProducerReport, TargetTrack};
use crate::schedule::Clock;
use crate::skeleton::MAX_CHANNELS;

/// Something that produces the loop's inputs in virtual time.
pub trait LockstepSource {
    /// Sends every input due at or before `until_ns` (the first tick is due at `start_ns`).
    /// Returns false once the source has ended.
    fn feed(&mut self, start_ns: u64, until_ns: u64, now_ns: u64, tx: &InputSender) -> bool;

    /// What was sent.
    fn report(&self) -> ProducerReport;
}

/// A clip played at the loop rate: sample k is due at tick k.
#[derive(Debug)]
pub struct PlayerFeed {
    player: ClipPlayer,
    period_ns: u64,
    next: u64,
    channels: usize,
    report: ProducerReport,
}

impl PlayerFeed {
    /// Feeds `player`'s samples, one per period of `period_ns`, over a skeleton of `channels`.
    #[must_use]
    pub fn new(player: ClipPlayer, period_ns: u64, channels: usize) -> PlayerFeed {
        PlayerFeed {
            player,
            period_ns,
            next: 0,
            channels: channels.min(MAX_CHANNELS),
            report: ProducerReport::default(),
        }
    }
}

impl LockstepSource for PlayerFeed {
    fn feed(&mut self, start_ns: u64, until_ns: u64, now_ns: u64, tx: &InputSender) -> bool {
        let mut buf = [0.0; MAX_CHANNELS];
        loop {
            let due = start_ns + self.next * self.period_ns;
            if due > until_ns {
                return true;
            }
            let Some(t) = self.player.next_sample(&mut buf[..self.channels]) else {
                return false;
            };
            match tx.send_newest(Input::frame(self.next, due, now_ns, &buf[..self.channels], t)) {
                Ok(dropped) => self.report.dropped += u64::from(dropped),
                Err(_) => return false,
            }
            self.report.sent += 1;
            self.next += 1;
        }
    }

    fn report(&self) -> ProducerReport {
        self.report
    }
}

/// Targets from a file, each due at its time stamp after the first tick.
#[derive(Debug)]
pub struct TrackFeed {
    track: Arc<TargetTrack>,
    next: usize,
    report: ProducerReport,
}

impl TrackFeed {
    /// Feeds `track` once.
    #[must_use]
    pub fn new(track: TargetTrack) -> TrackFeed {
        TrackFeed {
            track: Arc::new(track),
            next: 0,
            report: ProducerReport::default(),
        }
    }
}

impl LockstepSource for TrackFeed {
    fn feed(&mut self, start_ns: u64, until_ns: u64, now_ns: u64, tx: &InputSender) -> bool {
        let t0 = self.track.samples.first().map_or(0.0, |s| s.0);
        while let Some((t, targets)) = self.track.samples.get(self.next) {
            let due = start_ns + ((t - t0) * 1e9) as u64;
            if due > until_ns {
                return true;
            }
            let msg = Input {
                seq: self.next as u64,
                due_ns: due,
                made_ns: now_ns,
                payload: Payload::Targets(targets.clone()),
            };
            match tx.send_newest(msg) {
                Ok(dropped) => self.report.dropped += u64::from(dropped),
                Err(_) => return false,
            }
            self.report.sent += 1;
            self.next += 1;
        }
        false
    }

    fn report(&self) -> ProducerReport {
        self.report
    }
}

/// A virtual clock that feeds the loop's input channel just in time (module documentation).
/// When the source ends the sender is dropped, which the loop reads as the end of input.
pub struct FeedingClock<C: Clock, S: LockstepSource> {
    clock: C,
    source: S,
    tx: Option<InputSender>,
    start_ns: u64,
    half_period_ns: u64,
    preview_ns: u64,
}

impl<C: Clock, S: LockstepSource> std::fmt::Debug for FeedingClock<C, S> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeedingClock")
            .field("start_ns", &self.start_ns)
            .field("feeding", &self.tx.is_some())
            .finish_non_exhaustive()
    }
}

impl<C: Clock, S: LockstepSource> FeedingClock<C, S> {
    /// Feeds `source` into `tx` for a loop whose first tick is at `start_ns` with `period_ns`.
    pub fn new(clock: C, source: S, tx: InputSender, start_ns: u64, period_ns: u64) -> Self {
        FeedingClock {
            clock,
            source,
            tx: Some(tx),
            start_ns,
            half_period_ns: period_ns / 2,
            preview_ns: 0,
        }
    }

    /// Feeds inputs `preview_ns` ahead of their tick (the loop's look-ahead).
    #[must_use]
    pub fn with_preview(mut self, preview_ns: u64) -> Self {
        self.preview_ns = preview_ns;
        self
    }

    /// What the source sent.
    pub fn report(&self) -> ProducerReport {
        self.source.report()
    }
}

impl<C: Clock, S: LockstepSource> Clock for FeedingClock<C, S> {
    fn now_ns(&mut self) -> u64 {
        self.clock.now_ns()
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        if let Some(tx) = &self.tx {
            let now = self.clock.now_ns();
            // Everything the tick at this deadline may take (it looks half a period ahead, and
            // the look-ahead's preview further).
            if !self.source.feed(
                self.start_ns,
                deadline_ns + self.half_period_ns + self.preview_ns,
                now,
                tx,
            ) {
                self.tx = None;
            }
        }
        self.clock.wait_until(deadline_ns);
    }
}

impl<S: LockstepSource + ?Sized> LockstepSource for Box<S> {
    fn feed(&mut self, start_ns: u64, until_ns: u64, now_ns: u64, tx: &InputSender) -> bool {
        (**self).feed(start_ns, until_ns, now_ns, tx)
    }

    fn report(&self) -> ProducerReport {
        (**self).report()
    }
}

//! The loop in lockstep with a simulated rig: time is the simulation's, and inputs are sent
//! just in time instead of by producer threads.
//!
//! [`FeedingClock`] wraps a virtual clock (a [`crate::bus::virtual_chain::VirtualRig`] or the
//! MuJoCo bus): before it lets time pass up to a deadline it sends every input due by then, so
//! [`super::Controller::run`] runs unchanged — the same ticks, ramp and torque-off as on a
//! real bus — and the same inputs give the same run, every time.

use super::input::InputSender;
use super::source::{lockstep_feed, Grid, Source};
use super::sources::ProducerReport;
use crate::schedule::Clock;

/// A virtual clock that feeds the loop's input channel just in time (module documentation).
/// When the source ends the sender is dropped, which the loop reads as the end of input.
pub struct FeedingClock<C: Clock> {
    clock: C,
    source: Box<dyn Source>,
    tx: Option<InputSender>,
    grid: Grid,
    preview_ns: u64,
}

impl<C: Clock> std::fmt::Debug for FeedingClock<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FeedingClock")
            .field("grid", &self.grid)
            .field("feeding", &self.tx.is_some())
            .finish_non_exhaustive()
    }
}

impl<C: Clock> FeedingClock<C> {
    /// Feeds `source` into `tx` for a loop on `grid`.
    pub fn new(clock: C, source: Box<dyn Source>, tx: InputSender, grid: Grid) -> Self {
        FeedingClock {
            clock,
            source,
            tx: Some(tx),
            grid,
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

impl<C: Clock> Clock for FeedingClock<C> {
    fn now_ns(&mut self) -> u64 {
        self.clock.now_ns()
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        if let Some(tx) = &self.tx {
            let now = self.clock.now_ns();
            // Everything the tick at this deadline may take (it looks half a period ahead, and
            // the look-ahead's preview further).
            let until = deadline_ns + self.grid.period_ns / 2 + self.preview_ns;
            if !lockstep_feed(self.source.as_mut(), self.grid, until, now, tx) {
                self.tx = None;
            }
        }
        self.clock.wait_until(deadline_ns);
    }
}

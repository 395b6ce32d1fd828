//! Fixed-rate scheduling on absolute deadlines: tick `k` is due at
//! `start + k·period`, computed from integers in nanoseconds, so lateness never accumulates
//! into drift. Time comes from a [`Clock`], so the loop runs on a fake clock in tests.

/// A monotonic time source, nanoseconds from an arbitrary origin.
pub trait Clock {
    /// Now.
    fn now_ns(&mut self) -> u64;
    /// Blocks until `deadline` or later (a fake clock jumps there); returns at once when it
    /// has passed. [`Schedule::wait`] calls it for every tick, a late one too, so a clock that
    /// does work at each deadline (feeding inputs in lockstep) sees every tick.
    fn wait_until(&mut self, deadline_ns: u64);
}

/// What one wait for a tick found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Index of the tick (deadline `start + index·period`).
    pub index: u64,
    /// When it was due.
    pub deadline_ns: u64,
    /// When the wait returned (≥ deadline).
    pub woke_ns: u64,
    /// Deadlines passed over because the previous tick overran (0 normally).
    pub skipped: u64,
}

impl Tick {
    /// Lateness of the wake-up, nanoseconds.
    #[must_use]
    pub fn lateness_ns(&self) -> u64 {
        self.woke_ns.saturating_sub(self.deadline_ns)
    }
}

/// Deadlines of a fixed-rate loop.
#[derive(Clone, Copy, Debug)]
pub struct Schedule {
    start_ns: u64,
    period_ns: u64,
    next: u64,
}

impl Schedule {
    /// A schedule whose tick 0 is due at `start_ns`, one tick every `period_ns` (≥ 1).
    #[must_use]
    pub fn new(start_ns: u64, period_ns: u64) -> Schedule {
        Schedule {
            start_ns,
            period_ns: period_ns.max(1),
            next: 0,
        }
    }

    /// The period, nanoseconds.
    #[must_use]
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// Deadline of tick `k`.
    #[must_use]
    pub fn deadline(&self, k: u64) -> u64 {
        self.start_ns.saturating_add(k.saturating_mul(self.period_ns))
    }

    /// The deadline of the next tick [`Schedule::wait`] waits for, unless the caller is a
    /// whole period behind by then.
    #[must_use]
    pub fn next_deadline(&self) -> u64 {
        self.deadline(self.next)
    }

    /// Waits for the next tick. When the caller overran one or more whole periods, the
    /// deadlines already past are skipped (counted in [`Tick::skipped`]) rather than run back
    /// to back; the grid stays `start + k·period` either way.
    pub fn wait(&mut self, clock: &mut dyn Clock) -> Tick {
        let now = clock.now_ns();
        let mut k = self.next;
        let mut skipped = 0;
        // A tick is missed (not run late) only once its successor is due too.
        if now > self.deadline(k) {
            let behind = (now - self.deadline(k)) / self.period_ns;
            k += behind;
            skipped = behind;
        }
        let deadline = self.deadline(k);
        clock.wait_until(deadline);
        let woke = clock.now_ns();
        self.next = k + 1;
        Tick {
            index: k,
            deadline_ns: deadline,
            woke_ns: woke,
            skipped,
        }
    }
}

//! A live view of the running loop for a viewer in another thread (the studio): each servo's
//! commanded and present angle, the loop's timing, and when each new input reached the bus.
//!
//! The tick updates it with `try_lock` on fixed arrays: it never waits for a reader and
//! allocates nothing; a reader holding the lock costs the view one tick's update, never the loop.

use std::sync::{Mutex, MutexGuard, PoisonError};

use crate::servo::MAX_SERVOS;

/// Compute times kept for the percentile.
pub const COMPUTE_WINDOW: usize = 1024;
/// Inputs' journeys to the bus kept until a reader drains them.
pub const CARRIED_WINDOW: usize = 256;

/// An input carried to the bus: when it was made and when the Sync Write with the goals planned
/// from it started (both on the loop clock, ns).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Carried {
    /// The input's `made_ns`.
    pub made_ns: u64,
    /// The first Sync Write that carried it.
    pub write_ns: u64,
}

/// What the loop last did.
#[derive(Clone, Debug)]
pub struct LiveState {
    /// Ticks run.
    pub ticks: u64,
    /// Ticks that ended after the next deadline.
    pub misses: u64,
    /// Loop clock at the last tick, ns.
    pub last_tick_ns: u64,
    /// Commanded angle per servo (the goal written), radians; `len` used.
    pub goal_rad: [f64; MAX_SERVOS],
    /// Present angle per servo as last read, radians (NaN before a read).
    pub present_rad: [f64; MAX_SERVOS],
    /// Servos.
    pub len: usize,
    compute_ns: [u64; COMPUTE_WINDOW],
    compute_count: u64,
    carried: [Carried; CARRIED_WINDOW],
    carried_count: u64,
    /// The `made_ns` of the input last carried (so each input is counted once).
    last_made_ns: u64,
}

impl Default for LiveState {
    fn default() -> Self {
        LiveState {
            ticks: 0,
            misses: 0,
            last_tick_ns: 0,
            goal_rad: [f64::NAN; MAX_SERVOS],
            present_rad: [f64::NAN; MAX_SERVOS],
            len: 0,
            compute_ns: [0; COMPUTE_WINDOW],
            compute_count: 0,
            carried: [Carried::default(); CARRIED_WINDOW],
            carried_count: 0,
            last_made_ns: 0,
        }
    }
}

impl LiveState {
    /// Records one tick's compute time and whether it missed its deadline.
    pub fn record_tick(&mut self, now_ns: u64, compute_ns: u64, missed: bool) {
        self.ticks += 1;
        self.misses += u64::from(missed);
        self.last_tick_ns = now_ns;
        self.compute_ns[(self.compute_count % COMPUTE_WINDOW as u64) as usize] = compute_ns;
        self.compute_count += 1;
    }

    /// Records the input a Sync Write carried; an input already recorded is not again.
    pub fn record_carried(&mut self, made_ns: u64, write_ns: u64) {
        if made_ns == 0 || made_ns == self.last_made_ns {
            return;
        }
        self.last_made_ns = made_ns;
        self.carried[(self.carried_count % CARRIED_WINDOW as u64) as usize] = Carried { made_ns, write_ns };
        self.carried_count += 1;
    }

    /// The `q` quantile (0..=1) of the last [`COMPUTE_WINDOW`] compute times, ns (sorts a copy
    /// on the stack: for readers, not the tick).
    #[must_use]
    pub fn compute_quantile_ns(&self, q: f64) -> u64 {
        let n = self.compute_count.min(COMPUTE_WINDOW as u64) as usize;
        if n == 0 {
            return 0;
        }
        let mut v = self.compute_ns;
        let v = &mut v[..n];
        v.sort_unstable();
        let k = ((q.clamp(0.0, 1.0) * (n - 1) as f64).round() as usize).min(n - 1);
        v[k]
    }

    /// The carried inputs recorded after the `seen`-th one (a reader's cursor); returns the new
    /// cursor. Entries the ring overwrote before they were read are skipped.
    pub fn carried_since(&self, seen: u64, mut each: impl FnMut(Carried)) -> u64 {
        let first = seen.max(self.carried_count.saturating_sub(CARRIED_WINDOW as u64));
        for k in first..self.carried_count {
            each(self.carried[(k % CARRIED_WINDOW as u64) as usize]);
        }
        self.carried_count
    }
}

/// The shared view.
#[derive(Debug, Default)]
pub struct LiveView {
    state: Mutex<LiveState>,
}

impl LiveView {
    /// The state for the tick, unless a reader holds it right now.
    pub fn try_update(&self) -> Option<MutexGuard<'_, LiveState>> {
        match self.state.try_lock() {
            Ok(g) => Some(g),
            Err(std::sync::TryLockError::Poisoned(p)) => Some(p.into_inner()),
            Err(std::sync::TryLockError::WouldBlock) => None,
        }
    }

    /// The state for a reader (waits at most for one tick's update).
    pub fn read(&self) -> MutexGuard<'_, LiveState> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_and_carried_inputs_are_kept_in_rings() {
        let mut s = LiveState::default();
        for k in 0..2000u64 {
            s.record_tick(k, k, k % 100 == 0);
        }
        assert_eq!(s.ticks, 2000);
        assert_eq!(s.misses, 20);
        // The window holds the last 1024: 976..=1999.
        assert_eq!(s.compute_quantile_ns(0.0), 976);
        assert_eq!(s.compute_quantile_ns(1.0), 1999);
        s.record_carried(5, 10);
        s.record_carried(5, 11);
        s.record_carried(7, 12);
        let mut got = Vec::new();
        let cursor = s.carried_since(0, |c| got.push(c));
        assert_eq!(
            got,
            [
                Carried {
                    made_ns: 5,
                    write_ns: 10
                },
                Carried {
                    made_ns: 7,
                    write_ns: 12
                }
            ]
        );
        assert_eq!(s.carried_since(cursor, |_| panic!("nothing new")), 2);
        for k in 0..300 {
            s.record_carried(100 + k, 1000 + k);
        }
        let mut n = 0;
        s.carried_since(cursor, |_| n += 1);
        assert_eq!(n, CARRIED_WINDOW, "the ring keeps the newest");
    }
}

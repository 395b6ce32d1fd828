//! The fixed-rate schedule on a fake clock: no drift over 10⁶ ticks with random wake-up
//! lateness and occasional overruns, and overruns skip whole periods.

use marionette::bus::faults::Rng;
use marionette::schedule::{Clock, Schedule};

/// A clock that jumps to each deadline plus a random wake-up lateness, and that the "tick
/// work" advances.
struct FakeClock {
    now: u64,
    rng: Rng,
    max_late_ns: u64,
}

impl Clock for FakeClock {
    fn now_ns(&mut self) -> u64 {
        self.now
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        // Late by up to `max_late_ns` after a wait (none when the deadline has passed).
        if deadline_ns > self.now {
            self.now = deadline_ns + self.rng.below(self.max_late_ns + 1);
        }
    }
}

#[test]
fn no_drift_over_a_million_ticks() {
    let period = 2_000_000; // 500 Hz
    let start = 1_000_000_000;
    let mut clock = FakeClock {
        now: start - 5_000,
        rng: Rng::new(6),
        max_late_ns: 80_000,
    };
    let mut schedule = Schedule::new(start, period);
    let mut rng = Rng::new(7);
    let (mut ran, mut skipped, mut worst_late) = (0u64, 0u64, 0u64);
    let n = 1_000_000u64;
    while ran + skipped < n {
        let tick = schedule.wait(&mut clock);
        assert_eq!(tick.deadline_ns, start + tick.index * period, "off the grid");
        assert!(tick.woke_ns >= tick.deadline_ns);
        worst_late = worst_late.max(tick.lateness_ns());
        skipped += tick.skipped;
        ran += 1;
        // The tick's work: usually 300 µs, one in 10,000 overruns by 1–3 periods.
        clock.now += if rng.chance(1e-4) {
            period * (1 + rng.below(3)) + 1
        } else {
            300_000
        };
    }
    let last = schedule.wait(&mut clock);
    println!(
        "{ran} ticks run, {skipped} skipped, worst lateness {worst_late} ns; last tick {} due at {}",
        last.index, last.deadline_ns
    );
    // Drift would show as tick n's deadline off start + n·period; lateness never adds up.
    assert_eq!(last.index, ran + skipped);
    assert_eq!(last.deadline_ns, start + last.index * period);
    assert!(worst_late <= 80_000);
    assert!(skipped > 0 && skipped < 400);
}

#[test]
fn overrun_skips_whole_periods() {
    let mut clock = FakeClock {
        now: 0,
        rng: Rng::new(1),
        max_late_ns: 0,
    };
    let mut s = Schedule::new(0, 1000);
    assert_eq!(s.wait(&mut clock).index, 0);
    clock.now = 500; // within the period: tick 1 waits
    let t = s.wait(&mut clock);
    assert_eq!((t.index, t.woke_ns, t.skipped), (1, 1000, 0));
    clock.now = 3500; // overran: tick 2 is missed, tick 3 (due 3000) runs at once, 500 ns late
    let t = s.wait(&mut clock);
    assert_eq!((t.index, t.deadline_ns, t.woke_ns, t.skipped), (3, 3000, 3500, 1));
    clock.now = 4000; // exactly on time
    let t = s.wait(&mut clock);
    assert_eq!((t.index, t.woke_ns, t.skipped), (4, 4000, 0));
}

/// The system clock honours deadlines (never early) on a short real run; lateness is measured,
/// not asserted (machines are noisy).
#[test]
fn system_clock_never_wakes_early() {
    use marionette::clock::SystemClock;
    let mut clock = SystemClock::new(200_000);
    let start = clock.now_ns() + 1_000_000;
    let mut s = Schedule::new(start, 1_000_000);
    let mut late = Vec::new();
    for _ in 0..50 {
        let t = s.wait(&mut clock);
        assert!(t.woke_ns >= t.deadline_ns);
        late.push(t.lateness_ns());
    }
    late.sort_unstable();
    println!(
        "1 kHz, 50 ticks: lateness p50 {} ns, max {} ns",
        late[25], late[49]
    );
}

//! The machine's clock for the core's [`Schedule`](crate::schedule::Schedule).

use crate::schedule::Clock;

/// How long before each deadline the loop's clock stops sleeping and spins, ns.
pub const LOOP_SPIN_NS: u64 = 200_000;

/// The machine's monotonic clock: sleeps until `spin_ns` before a deadline, then spins, so the
/// wake-up does not inherit the sleep's granularity (typically 50–100 µs late on Linux).
#[derive(Clone, Copy, Debug)]
pub struct SystemClock {
    origin: std::time::Instant,
    spin_ns: u64,
}

impl SystemClock {
    /// A clock whose zero is now, spinning for the last `spin_ns` of each wait.
    #[must_use]
    pub fn new(spin_ns: u64) -> SystemClock {
        SystemClock {
            origin: std::time::Instant::now(),
            spin_ns,
        }
    }
}

impl Clock for SystemClock {
    fn now_ns(&mut self) -> u64 {
        u64::try_from(self.origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
    }

    fn wait_until(&mut self, deadline_ns: u64) {
        let now = self.now_ns();
        if deadline_ns > now + self.spin_ns {
            std::thread::sleep(std::time::Duration::from_nanos(deadline_ns - now - self.spin_ns));
        }
        while self.now_ns() < deadline_ns {
            core::hint::spin_loop();
        }
    }
}

//! Loop jitter: the control loop's schedule (absolute deadlines, sleep then spin) and
//! a naive `thread::sleep(period)` loop, run one after the other in the same process at the same
//! rate with the same work per tick, and their timing printed side by side:
//!
//! * period error — |interval between tick starts − period|;
//! * drift — how far the last tick started from `start + n·period`.
//!
//! `cargo bench --bench jitter` (env `MARIONETTE_JITTER_SECONDS`, default 3;
//! `MARIONETTE_JITTER_HZ`, default 1000).

use marionette::clock::SystemClock;
use marionette::control::stats::Histogram;
use marionette::schedule::{Clock, Schedule};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// About 20 µs of arithmetic, standing in for a tick's work.
fn work() -> f64 {
    let mut x = 0.0f64;
    for i in 0..4000 {
        x += black_box(f64::from(i)).sqrt();
    }
    x
}

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn report(name: &str, h: &Histogram, drift_us: f64, ticks: u64) {
    let q = h.summary_us();
    println!(
        "{name:<28} {ticks:>6} ticks  period error p50 {:>8.1}  p99 {:>8.1}  p99.9 {:>8.1}  max {:>8.1} µs   drift {drift_us:>10.1} µs",
        q.p50, q.p99, q.p999, q.max
    );
}

fn main() {
    // `cargo bench` passes `--bench`; nothing else to parse.
    let seconds = env("MARIONETTE_JITTER_SECONDS", 3.0);
    let rate = env("MARIONETTE_JITTER_HZ", 1000.0);
    let period_ns = (1e9 / rate) as u64;
    let ticks = (seconds * rate) as u64;
    println!("loop jitter at {rate} Hz over {seconds} s, ~20 µs of work per tick");

    // The control loop's schedule.
    let mut clock = SystemClock::new(200_000);
    let start = clock.now_ns() + period_ns;
    let mut schedule = Schedule::new(start, period_ns);
    let mut h = Histogram::new();
    let mut last: Option<(u64, u64)> = None;
    let mut first_start = 0;
    let mut final_start = 0;
    for _ in 0..ticks {
        let t = schedule.wait(&mut clock);
        let now = clock.now_ns();
        if let Some((i, at)) = last {
            h.record((now - at).abs_diff((t.index - i) * period_ns));
        } else {
            first_start = now;
        }
        last = Some((t.index, now));
        final_start = now;
        black_box(work());
    }
    let n = last.map_or(0, |l| l.0);
    let drift = final_start as f64 - (first_start as f64 + n as f64 * period_ns as f64);
    report("absolute deadlines + spin", &h, drift / 1000.0, ticks);

    // The naive loop.
    let origin = Instant::now();
    let mut h = Histogram::new();
    let mut prev: Option<Instant> = None;
    let mut first = origin;
    let mut final_at = origin;
    for _ in 0..ticks {
        let now = Instant::now();
        if let Some(p) = prev {
            h.record(((now - p).as_nanos() as u64).abs_diff(period_ns));
        } else {
            first = now;
        }
        prev = Some(now);
        final_at = now;
        black_box(work());
        std::thread::sleep(Duration::from_nanos(period_ns));
    }
    let drift = (final_at - first).as_nanos() as f64 - (ticks - 1) as f64 * period_ns as f64;
    report("naive thread::sleep(period)", &h, drift / 1000.0, ticks);
}

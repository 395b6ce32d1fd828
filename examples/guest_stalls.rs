//! How often the machine takes the CPU away from a real-time thread that never sleeps: the
//! thread spins on the monotonic clock at `SCHED_FIFO` priority 80 (when allowed) and counts
//! the gaps between consecutive readings, per second, by size. With `--touch-mb N` it also
//! reads and writes one byte in each 4 KB page of an N MB buffer in turn, as a loop with a
//! large working set would; on a virtual machine whose host ages or reclaims guest memory,
//! those touches stall too. The loop's own tick can be no steadier than this.
//!
//! `cargo run --release --example guest_stalls -- [--seconds S] [--touch-mb N]`

use std::hint::black_box;
use std::time::{Duration, Instant};

use marionette::rt::RealTime;

/// The gap sizes counted, µs.
const BOUNDS_US: [u64; 4] = [20, 50, 100, 300];

fn main() {
    let mut seconds = 10.0f64;
    let mut touch_mb = 0usize;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let value = args.next().and_then(|v| v.parse::<f64>().ok());
        match (a.as_str(), value) {
            ("--seconds", Some(v)) if v > 0.0 => seconds = v,
            ("--touch-mb", Some(v)) if v >= 0.0 => touch_mb = v as usize,
            _ => {
                eprintln!("usage: guest_stalls [--seconds S (> 0)] [--touch-mb N]");
                std::process::exit(2);
            }
        }
    }
    for warning in (RealTime {
        priority: Some(80),
        ..RealTime::default()
    })
    .apply()
    {
        eprintln!("{warning}");
    }
    const PAGE: usize = 4096;
    let mut buffer = vec![1u8; touch_mb << 20];
    let mut at = 0usize;
    let mut counts = [0u64; BOUNDS_US.len()];
    let mut lost = Duration::ZERO;
    let start = Instant::now();
    let end = start + Duration::from_secs_f64(seconds);
    let mut last = start;
    loop {
        if !buffer.is_empty() {
            // The next page, a cache line further in each pass so that every line is met.
            buffer[at] = black_box(buffer[at]).wrapping_add(1);
            at += PAGE + 64;
            if at >= buffer.len() {
                at -= buffer.len();
            }
        }
        let now = Instant::now();
        if now >= end {
            break;
        }
        let gap = now - last;
        last = now;
        if gap >= Duration::from_micros(BOUNDS_US[0]) {
            lost += gap;
        }
        for (count, bound) in counts.iter_mut().zip(BOUNDS_US) {
            if gap >= Duration::from_micros(bound) {
                *count += 1;
            }
        }
    }
    let per_second: Vec<String> = counts
        .iter()
        .zip(BOUNDS_US)
        .map(|(c, b)| format!("> {b} µs: {:.1}", *c as f64 / seconds))
        .collect();
    println!(
        "spinning {seconds} s, touching {touch_mb} MB: gaps per second {}; {:.2} % of the time in gaps of 20 µs or more",
        per_second.join(", "),
        100.0 * lost.as_secs_f64() / seconds
    );
}

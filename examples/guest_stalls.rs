//! What the machine does to a real-time thread, in two measurements.
//!
//! **Gaps.** A thread that never sleeps spins on the monotonic clock at `SCHED_FIFO` priority
//! 80 (when allowed) and counts the gaps between consecutive readings, per second, by size.
//! With `--touch-mb N` it also reads and writes one byte in each 4 KB page of an N MB buffer in
//! turn, as a loop with a large working set would; on a virtual machine whose host ages or
//! reclaims guest memory, those touches stall too.
//!
//! **Constant ticks** (`--tick-us W`). Ticks at `--rate` Hz (1,000 unless given) on the
//! loop's absolute-deadline schedule and clock, which sleeps until `--spin-us` (200 unless
//! given, as the loop) before each deadline and spins the rest. Every tick does the same work,
//! sized at the start to take about W µs: a dependent chain of multiply–adds, or with
//! `--solves` the project's limb solve of one fixed target repeated (the tick's own mix of
//! instructions), and with `--tick-kb K` a read of each cache line of a K KB buffer. With
//! `--rehearse` the same work also runs 40 µs before each deadline, unmeasured, as the loop
//! rehearses its next solve. With `--wake-other` each tick first writes a byte to a socket
//! that a thread on CPU 0 waits on (as the loop's write wakes the virtual chain's thread), so
//! that CPU is woken just before the work (the ticks run on the last CPU). It prints the
//! work's p50 / p99 / p99.9 and p99 ÷ p50: how steady a tick whose instructions never change
//! is on this machine. The loop's own tick can be no steadier than this.
//!
//! ```text
//! cargo run --release --example guest_stalls -- [--seconds S] [--touch-mb N]
//! cargo run --release --example guest_stalls -- --tick-us W [--solves] [--tick-kb K] [--rehearse] [--wake-other] [--spin-us U] [--rate HZ] [--seconds S]
//! ```

use std::hint::black_box;
use std::io::{Read, Write};
use std::os::unix::net::UnixStream;
use std::time::{Duration, Instant};

use glam::DVec3;
use marionette::clock::{SystemClock, LOOP_SPIN_NS};
use marionette::control::REHEARSAL_LEAD_NS;
use marionette::fk::{fk64, Pose64};
use marionette::formats::asf;
use marionette::ik::{Limb, Swivel};
use marionette::rt::RealTime;
use marionette::schedule::{Clock, Schedule};
use marionette::skeleton::Skeleton;

/// The gap sizes counted, µs.
const BOUNDS_US: [u64; 7] = [2, 5, 10, 20, 50, 100, 300];

fn main() {
    let mut seconds = 10.0f64;
    let mut touch_mb = 0usize;
    let mut ticks = TickSettings {
        work_us: 0.0,
        kb: 0,
        rate: 1000.0,
        seconds: 0.0,
        spin_ns: LOOP_SPIN_NS,
        rehearse: false,
        wake_other: false,
    };
    let (mut tick_us, mut solves) = (None, false);
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--solves" => {
                solves = true;
                continue;
            }
            "--rehearse" => {
                ticks.rehearse = true;
                continue;
            }
            "--wake-other" => {
                ticks.wake_other = true;
                continue;
            }
            _ => {}
        }
        let value = args.next().and_then(|v| v.parse::<f64>().ok());
        match (a.as_str(), value) {
            ("--seconds", Some(v)) if v > 0.0 => seconds = v,
            ("--touch-mb", Some(v)) if v >= 0.0 => touch_mb = v as usize,
            ("--tick-us", Some(v)) if v > 0.0 && v < 500.0 => tick_us = Some(v),
            ("--tick-kb", Some(v)) if (0.0..=4096.0).contains(&v) => ticks.kb = v as usize,
            ("--rate", Some(v)) if (1.0..=2000.0).contains(&v) => ticks.rate = v,
            ("--spin-us", Some(v)) if (0.0..=1e6).contains(&v) => ticks.spin_ns = (v * 1e3) as u64,
            _ => {
                eprintln!(
                    "usage: guest_stalls [--seconds S (> 0)] [--touch-mb N] | --tick-us W (0 < W < 500) [--solves] [--tick-kb K (≤ 4096)] [--rehearse] [--wake-other] [--spin-us U (≤ 10⁶)] [--rate HZ (1 … 2000)] [--seconds S]"
                );
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
    if let Some(w) = tick_us {
        let unit = if solves { Unit::solve() } else { Unit::Chain };
        ticks.work_us = w;
        ticks.seconds = seconds;
        constant_ticks(unit, &ticks);
        return;
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
        if gap >= Duration::from_micros(20) {
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

/// A dependent chain of `n` multiply–adds: the same instructions every call.
#[inline(never)]
fn chain(n: u64, x: f64) -> f64 {
    let mut y = x;
    for _ in 0..n {
        y = y * 0.999_999_9 + 1e-9;
    }
    y
}

/// One word of each 64-byte line of `buffer`, summed.
#[inline(never)]
fn read_lines(buffer: &[u64]) -> u64 {
    buffer.iter().step_by(8).fold(0, |a, &w| a.wrapping_add(w))
}

/// The p-th quantile of sorted `v`.
fn quantile(v: &[u64], p: f64) -> u64 {
    v[((v.len() - 1) as f64 * p).round() as usize]
}

/// The unit of a constant tick's work, repeated to fill it.
enum Unit {
    /// 100 steps of [`chain`]: latency-bound arithmetic, one operation at a time.
    Chain,
    /// The project's limb solve (the left arm of the bundled walk's skeleton, one fixed target,
    /// from the rest pose): the tick's own mix of instructions, about three a cycle.
    Solve(Box<FixedSolve>),
}

/// One limb solve, always the same.
struct FixedSolve {
    skeleton: Skeleton,
    limb: Limb,
    target: DVec3,
    channels: Vec<f64>,
}

impl Unit {
    fn solve() -> Unit {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu/16.asf");
        let skeleton = asf::load(&path).expect("the bundled 16.asf").skeleton;
        let (upper, lower) = (
            skeleton.find("lhumerus").unwrap(),
            skeleton.find("lradius").unwrap(),
        );
        let limb = Limb::new(&skeleton, upper, lower, None).expect("the left arm is a limb");
        // A reachable target: the wrist with the elbow bent and the shoulder turned.
        let mut channels = vec![0.0; skeleton.channel_count()];
        let bone = &skeleton.bones()[lower];
        channels[bone.first_channel()] = 0.9;
        channels[skeleton.bones()[upper].first_channel()] = -0.4;
        let mut pose = Pose64::default();
        fk64(&skeleton, &channels, &mut pose);
        let target = pose.tip[lower];
        let mut from_rest = vec![0.0; channels.len()];
        let s = limb.solve(&skeleton, &mut from_rest, target, Swivel::Auto { previous: None });
        assert!(
            s.reachable && s.error < 1e-9 && s.violation == 0.0,
            "the fixed target is solved within the limits: {s:?}"
        );
        Unit::Solve(Box::new(FixedSolve {
            skeleton,
            limb,
            target,
            channels: vec![0.0; channels.len()],
        }))
    }

    #[inline(never)]
    fn run(&mut self) -> f64 {
        match self {
            Unit::Chain => chain(100, black_box(1.0)),
            Unit::Solve(f) => {
                f.channels.fill(0.0);
                let s = f.limb.solve(
                    &f.skeleton,
                    &mut f.channels,
                    black_box(f.target),
                    Swivel::Auto { previous: None },
                );
                black_box(s);
                f.channels[0]
            }
        }
    }

    fn name(&self) -> &'static str {
        match self {
            Unit::Chain => "100 dependent multiply-adds",
            Unit::Solve(_) => "arm solves",
        }
    }
}

/// How [`constant_ticks`] runs.
struct TickSettings {
    /// The work a tick, µs (on a warm loop).
    work_us: f64,
    /// The buffer read a tick, KB.
    kb: usize,
    /// Ticks a second.
    rate: f64,
    /// How long, s.
    seconds: f64,
    /// The clock's spin before each deadline, ns.
    spin_ns: u64,
    /// The work also made 40 µs before each deadline, unmeasured.
    rehearse: bool,
    /// A byte written before each tick's work to a socket read by a thread on another CPU.
    wake_other: bool,
}

/// A socket whose reader waits on CPU 0, for its writer (pinned to the last CPU) to wake.
fn wake_other_cpu() -> UnixStream {
    let cpus = std::thread::available_parallelism().map_or(1, usize::from);
    if cpus < 2 {
        eprintln!("--wake-other needs two CPUs; this machine has one");
        std::process::exit(2);
    }
    let pin = |cpu| {
        RealTime {
            cpu: Some(cpu),
            ..RealTime::default()
        }
        .apply()
    };
    for warning in pin(cpus - 1) {
        eprintln!("{warning}");
    }
    let (writer, mut reader) = UnixStream::pair().expect("a socket pair");
    std::thread::spawn(move || {
        for warning in pin(0) {
            eprintln!("{warning}");
        }
        let mut buf = [0u8; 64];
        while reader.read(&mut buf).is_ok_and(|n| n > 0) {}
    });
    writer
}

/// Runs ticks of constant work (`unit` repeated to take about `work_us`, and one read of each
/// line of a `kb` KB buffer) and prints the work's quantiles.
fn constant_ticks(mut unit: Unit, settings: &TickSettings) {
    let buffer = vec![1u64; settings.kb * 1024 / 8];
    // Size the work on a warm loop: the median of 200 batches of 20 units.
    let mut times: Vec<u64> = (0..200)
        .map(|_| {
            let t = Instant::now();
            for _ in 0..20 {
                black_box(unit.run());
            }
            t.elapsed().as_nanos() as u64
        })
        .collect();
    times.sort_unstable();
    let unit_ns = quantile(&times, 0.5) as f64 / 20.0;
    let n = ((settings.work_us * 1e3 / unit_ns).round() as u64).max(1);
    let work_once = |unit: &mut Unit| {
        let mut sink = 0.0;
        for _ in 0..n {
            sink += unit.run();
        }
        sink + read_lines(black_box(&buffer)) as f64
    };
    let mut clock = SystemClock::new(settings.spin_ns);
    let period = (1e9 / settings.rate) as u64;
    let mut schedule = Schedule::new(clock.now_ns() + period, period);
    let ticks = ((settings.seconds * settings.rate) as usize).max(1);
    let mut work = Vec::with_capacity(ticks);
    let mut sink = 0.0;
    let mut waker = settings.wake_other.then(wake_other_cpu);
    for _ in 0..ticks {
        if settings.rehearse {
            clock.wait_until(schedule.next_deadline().saturating_sub(REHEARSAL_LEAD_NS));
            sink += work_once(&mut unit);
        }
        schedule.wait(&mut clock);
        if let Some(w) = &mut waker {
            w.write_all(&[1]).expect("the waiting thread reads");
        }
        let t0 = clock.now_ns();
        sink += work_once(&mut unit);
        work.push(clock.now_ns() - t0);
    }
    black_box(sink);
    work.sort_unstable();
    let us = |p: f64| quantile(&work, p) as f64 / 1e3;
    println!(
        "constant ticks ({n} × {}, {} KB read{}{}, spinning the last {} µs) at {} Hz, {ticks} ticks: p50 {:.2} µs, p99 {:.2} µs, p99.9 {:.2} µs, max {:.1} µs; p99 ÷ p50 {:.2}",
        unit.name(),
        settings.kb,
        if settings.rehearse { ", rehearsed" } else { "" },
        if settings.wake_other { ", another CPU woken first" } else { "" },
        settings.spin_ns / 1000,
        settings.rate,
        us(0.5),
        us(0.99),
        us(0.999),
        us(1.0),
        us(0.99) / us(0.5)
    );
}

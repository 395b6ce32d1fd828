//! One whole control-loop tick: newest input → 4-limb analytic IK (windowed swivel
//! search) + FK → rig mapping → command limits → Sync Write packet encoded (CRC, stuffing) →
//! present positions read back, on a bus that only encodes (no I/O), so the figure is the
//! loop's own work. Also the AMC playback tick. `cargo bench --bench control`
//!
//! With the look-ahead the same ticks plan every servo's goal path; `lookahead`
//! times the planning of the puppet's 28 servos alone. The same ticks' instruction counts are
//! in `benches/instructions.rs`.
//!
//! The jitter comparison with a naive `thread::sleep` loop is `cargo bench --bench jitter`.

use criterion::{criterion_group, criterion_main, Criterion};
use marionette::clock::SystemClock;
use marionette::formats::{amc, asf};
use marionette::profile::Profile;
use std::path::Path;
use std::sync::Arc;

#[path = "support/planner.rs"]
mod planner;
#[path = "support/tick.rs"]
mod tick;

use tick::{Kind, TickBench};

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu").join(name)
}

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("control_tick");
    for (kind, lookahead, name) in [
        (Kind::Play, false, "play"),
        (Kind::Follow, false, "follow_4_limbs"),
        (Kind::Play, true, "play_lookahead"),
        (Kind::Follow, true, "follow_4_limbs_lookahead"),
    ] {
        // As a real-time run: the fidelity accumulated on a thread of its own.
        let mut t = TickBench::new(kind, lookahead, true);
        let mut clock = SystemClock::new(0);
        // Inputs prepared outside the measurement: one per tick, the walk over and over.
        let inputs = t.take_inputs(1000);
        let next = std::cell::Cell::new(0usize);
        g.bench_function(name, |b| {
            b.iter_batched(
                || {
                    next.set(next.get() + 1);
                    inputs[next.get() % inputs.len()].clone()
                },
                |input| t.tick(input, &mut clock),
                criterion::BatchSize::SmallInput,
            );
        });
        assert!(next.get() == 0 || t.bus.bytes > 0, "the ticks wrote goals");
    }
    g.finish();

    let skel = Arc::new(asf::load(&data("16.asf")).unwrap().skeleton);
    let motion = Arc::new(amc::load(&skel, &data("16_15.amc")).unwrap());
    let profile =
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml"))
            .unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    // The planner alone: 28 servos over a full preview of the walk.
    let (mut look, mut stage, preview) = planner::walk_planner(&skel, &motion, &profile, &rig);
    // Following the walk: each iteration is the next tick, its targets commanded (every 100
    // ticks the time starts over, the stage where it was).
    let mut tick = 0u64;
    c.bench_function("lookahead/plan_28_servos", |b| {
        b.iter(|| {
            tick = (tick + 1) % 100;
            let now = 2_000_000 * (tick + 1);
            let targets = look.targets(&rig, &stage, &preview, now, 0.002, None);
            let first = targets[0];
            let _ = stage.command_planned(&rig, targets, 0.002);
            first
        });
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

//! Forward kinematics of the whole 31-bone CMU skeleton, one frame per iteration, cycling
//! through the 471 frames of the bundled walk. `cargo bench --bench fk`
//!
//! Also: the frame conversion from file values (degrees, f64) that precedes FK when playing a
//! clip, and the core ASF reader.

use criterion::{criterion_group, criterion_main, Criterion};
use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf};
use marionette::skeleton::MAX_CHANNELS;
use std::hint::black_box;
use std::path::Path;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu").join(name)
}

fn bench_fk(c: &mut Criterion) {
    let file = asf::load(&data("16.asf")).unwrap();
    let s = &file.skeleton;
    let motion = amc::load(s, &data("16_15.amc")).unwrap();
    let frames: Vec<[f32; MAX_CHANNELS]> = (0..motion.len())
        .map(|i| {
            let mut c = [0.0f32; MAX_CHANNELS];
            motion.channels_into(s, i, &mut c);
            c
        })
        .collect();
    let mut pose = Pose::new();
    let mut i = 0;
    c.bench_function("fk", |b| {
        b.iter(|| {
            i = (i + 1) % frames.len();
            forward_kinematics(s, black_box(&frames[i]), &mut pose).unwrap();
            black_box(&pose.tip);
        })
    });
    let mut channels = [0.0f32; MAX_CHANNELS];
    c.bench_function("fk_from_amc_frame", |b| {
        b.iter(|| {
            i = (i + 1) % motion.len();
            motion.channels_into(s, i, &mut channels);
            forward_kinematics(s, &channels, &mut pose).unwrap();
            black_box(&pose.tip);
        })
    });
    let text = std::fs::read_to_string(data("16.asf")).unwrap();
    c.bench_function("parse_asf", |b| {
        b.iter(|| black_box(marionette::asf::parse_asf(black_box(&text)).is_ok()))
    });
}

criterion_group!(benches, bench_fk);
criterion_main!(benches);

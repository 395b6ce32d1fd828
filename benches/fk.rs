//! Forward kinematics of the whole 31-bone CMU skeleton, one frame per iteration, cycling
//! through the 471 frames of the bundled walk. `cargo bench --bench fk`
//!
//! In one run: the f32 FK (`fk`), the f64 FK (`fk64`) and `k`'s `Chain<f64>` of the same tree
//! on the same frames (`fk_k`), so that the ratios against `k` come from one machine at one
//! time. Also: the frame conversion from file values (degrees, f64) that precedes FK when
//! playing a clip, and the core ASF reader.

#[path = "support/k_model.rs"]
mod k_model;

use criterion::{criterion_group, criterion_main, Criterion};
use marionette::fk::{fk64, forward_kinematics, Pose, Pose64};
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
    let radians: Vec<Vec<f64>> = frames
        .iter()
        .map(|f| f[..s.channel_count()].iter().map(|&v| f64::from(v)).collect())
        .collect();
    let mut pose64 = Pose64::default();
    c.bench_function("fk64", |b| {
        b.iter(|| {
            i = (i + 1) % radians.len();
            fk64(s, black_box(&radians[i]), &mut pose64);
            black_box(&pose64.tip);
        })
    });
    let (chain, chain_channels, _) = k_model::skeleton_chain(s);
    let positions: Vec<Vec<f64>> = radians
        .iter()
        .map(|f| chain_channels.iter().map(|&c| f[c]).collect())
        .collect();
    c.bench_function("fk_k", |b| {
        b.iter(|| {
            i = (i + 1) % positions.len();
            chain.set_joint_positions_unchecked(black_box(&positions[i]));
            black_box(chain.update_transforms());
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

//! Retargeting onto the ROBOTIS OP3, one frame per iteration (the human's f64 forward
//! kinematics included), cycling through the bundled clips. `cargo bench --bench retarget`
//!
//! `retarget_walk` and `retarget_playground`: whole body (arms, closed-form legs with planted
//! feet and balance, head). `retarget_upper_body`: arms and head with the legs in a stance.
//! `leg_ik`: one closed-form leg.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DQuat, DVec3};
use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, asf};
use marionette::motion::frame_to_radians;
use marionette::profile::Profile;
use marionette::retarget::{floor_of_clip, Options, RetargetFrame, Setup};
use std::hint::black_box;
use std::path::Path;

fn path(p: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn bench_retarget(c: &mut Criterion) {
    let profile = Profile::load(&path("firmware-profile/robotis-op3.toml")).unwrap();
    for (name, a, m, options) in [
        ("retarget_walk", "16.asf", "16_15.amc", Options::default()),
        ("retarget_playground", "01.asf", "01_01.amc", Options::default()),
        (
            "retarget_upper_body",
            "16.asf",
            "16_15.amc",
            Options {
                upper_body: true,
                ..Options::default()
            },
        ),
    ] {
        let s = asf::load(&path(&format!("data/cmu/{a}"))).unwrap().skeleton;
        let motion = amc::load(&s, &path(&format!("data/cmu/{m}"))).unwrap();
        let setup = Setup::new(&profile, &s).unwrap();
        let mut r = setup.retargeter(&s, floor_of_clip(&s, &motion, &setup.map.human), options);
        let frames: Vec<Vec<f64>> = motion.frames().map(|f| frame_to_radians(&s, f)).collect();
        let mut pose = Pose64::default();
        let mut out = RetargetFrame::default();
        let mut i = 0;
        c.bench_function(name, |b| {
            b.iter(|| {
                i = (i + 1) % frames.len();
                if i == 0 {
                    r.reset();
                }
                fk64(&s, black_box(&frames[i]), &mut pose);
                r.step(&setup.robot, &pose, 1.0 / 120.0, &mut out);
                black_box(&out.q);
            })
        });
        if name == "retarget_walk" {
            let ankle = DVec3::new(-0.01, 0.045, -0.25);
            c.bench_function("leg_ik", |b| {
                b.iter(|| black_box(r.leg_ik(0, black_box(DQuat::IDENTITY), black_box(ankle))))
            });
        }
    }
}

criterion_group!(benches, bench_retarget);
criterion_main!(benches);

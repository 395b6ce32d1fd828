//! IK benches: `limb_ik` — the analytic arm solver with the swivel search, with a
//! fixed swivel, warm-started along the bundled walk's wrist path, and along it with the
//! windowed search the loop uses (`windowed_stream`) — and `numeric_ik` — each
//! numerical method on the same arm targets from the rest pose (100-iteration cap), plus a
//! two-constraint (hand + foot) DLS solve. `cargo bench --bench ik`
//!
//! The same-run comparison with the `k` crate is `cargo run --release --example ik_compare`.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use marionette::bus::faults::Rng;
use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, asf};
use marionette::ik::{Limb, Swivel};
use marionette::ik_numeric::{chain_mask, Constraint, Method, Settings, Solver};
use marionette::skeleton::Skeleton;
use std::hint::black_box;
use std::path::Path;

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu").join(name)
}

/// Reachable arm targets: FK of random angles inside the ASF limits.
fn targets(skel: &Skeleton, bones: [usize; 2], n: usize) -> Vec<DVec3> {
    let mut rng = Rng::new(42);
    let mut pose = Pose64::default();
    (0..n)
        .map(|_| {
            let mut ch = vec![0.0; skel.channel_count()];
            for b in bones {
                let bone = &skel.bones()[b];
                for (k, d) in bone.dofs().iter().enumerate() {
                    if d.is_rotation() {
                        let l = bone.limits()[k];
                        let t = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
                        ch[bone.first_channel() + k] = f64::from(l.min) + t * f64::from(l.max - l.min);
                    }
                }
            }
            fk64(skel, &ch, &mut pose);
            pose.tip[bones[1]]
        })
        .collect()
}

fn bench_limb(c: &mut Criterion) {
    let skel = asf::load(&data("16.asf")).unwrap().skeleton;
    let (u, l) = (skel.find("lhumerus").unwrap(), skel.find("lradius").unwrap());
    let limb = Limb::new(&skel, u, l, None).unwrap();
    let goals = targets(&skel, [u, l], 1000);
    let mut ch = vec![0.0; skel.channel_count()];
    let mut i = 0;
    let mut group = c.benchmark_group("limb_ik");
    group.bench_function("swivel_search", |b| {
        b.iter(|| {
            i = (i + 1) % goals.len();
            black_box(limb.solve(
                &skel,
                &mut ch,
                black_box(goals[i]),
                Swivel::Auto { previous: None },
            ))
        })
    });
    group.bench_function("fixed_swivel", |b| {
        b.iter(|| {
            i = (i + 1) % goals.len();
            black_box(limb.solve(&skel, &mut ch, black_box(goals[i]), Swivel::Fixed(0.3)))
        })
    });
    // A stream: the walk's own wrist positions, warm-started from the previous solution.
    let motion = amc::load(&skel, &data("16_15.amc")).unwrap();
    let mut pose = Pose64::default();
    let path: Vec<(Vec<f64>, DVec3)> = (0..motion.len())
        .map(|f| {
            let frame = marionette::motion::frame_to_radians(&skel, motion.frame(f));
            fk64(&skel, &frame, &mut pose);
            (frame, pose.tip[l])
        })
        .collect();
    let mut previous = None;
    let mut f = 0;
    group.bench_function("walk_stream", |b| {
        b.iter(|| {
            f = (f + 1) % path.len();
            let mut frame = path[f].0.clone();
            let s = limb.solve(&skel, &mut frame, path[f].1, Swivel::Auto { previous });
            previous = Some(s.swivel);
            black_box(frame)
        })
    });
    // The loop's stream: the swivel searched within 40° of the previous one (Swivel::Track).
    let mut previous: Option<f64> = None;
    let mut f = 0;
    let mut frame = path[0].0.clone();
    group.bench_function("windowed_stream", |b| {
        b.iter(|| {
            f = (f + 1) % path.len();
            frame.copy_from_slice(&path[f].0);
            let swivel = match previous {
                Some(p) => Swivel::Track {
                    previous: p,
                    window: 40f64.to_radians(),
                },
                None => Swivel::Auto { previous: None },
            };
            let s = limb.solve(&skel, &mut frame, path[f].1, swivel);
            previous = Some(s.swivel);
            black_box(s)
        })
    });
    group.finish();
}

fn bench_numeric(c: &mut Criterion) {
    let skel = asf::load(&data("16.asf")).unwrap().skeleton;
    let (u, l) = (skel.find("lhumerus").unwrap(), skel.find("lradius").unwrap());
    let goals = targets(&skel, [u, l], 1000);
    let mut solver = Solver::new(&skel, &chain_mask(&skel, u, l), false);
    let mut ch = vec![0.0; skel.channel_count()];
    let mut group = c.benchmark_group("numeric_ik");
    for (name, method) in [
        ("ccd", Method::Ccd),
        ("jacobian_transpose", Method::Transpose),
        ("pseudoinverse", Method::Pseudoinverse),
        ("dls", Method::DampedLeastSquares),
        ("cg", Method::ConjugateGradient),
    ] {
        let settings = Settings {
            method,
            max_iterations: 100,
            ..Settings::default()
        };
        let mut i = 0;
        group.bench_function(name, |b| {
            b.iter(|| {
                i = (i + 1) % goals.len();
                ch.iter_mut().for_each(|x| *x = 0.0);
                let goal = [Constraint {
                    bone: l,
                    position: black_box(goals[i]),
                    axes: None,
                }];
                black_box(solver.solve(&skel, &goal, &mut ch, &settings))
            })
        });
    }
    // Hand and foot together from a walk frame, the whole body free (root fixed).
    let motion = amc::load(&skel, &data("16_15.amc")).unwrap();
    let frame = marionette::motion::frame_to_radians(&skel, motion.frame(200));
    let mut pose = Pose64::default();
    fk64(&skel, &frame, &mut pose);
    let foot = skel.find("rtibia").unwrap();
    let goals = [
        Constraint {
            bone: l,
            position: pose.tip[l] + DVec3::new(0.0, 2.0, 1.0),
            axes: None,
        },
        Constraint {
            bone: foot,
            position: pose.tip[foot],
            axes: None,
        },
    ];
    let mut body = Solver::new(&skel, &[true; marionette::skeleton::MAX_BONES], false);
    let settings = Settings {
        restarts: 0,
        ..Settings::default()
    };
    group.bench_function("dls_hand_and_foot_whole_body", |b| {
        b.iter(|| {
            ch.copy_from_slice(&frame);
            black_box(body.solve(&skel, &goals, &mut ch, &settings))
        })
    });
    group.finish();
}

criterion_group!(benches, bench_limb, bench_numeric);
criterion_main!(benches);

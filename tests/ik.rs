//! Inverse kinematics: f64 FK, Jacobians, the analytic limb solver, the numerical solvers.

mod common;

use glam::DVec3;
use marionette::bus::faults::Rng;
use marionette::fk::{fk64, fk64_step, fk64_tip, Pose64};
use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf};
use marionette::ik::{Limb, Swivel};
use marionette::ik_numeric::{chain_mask, Constraint, JacobianKind, Method, Settings, Solver};
use marionette::skeleton::{dof_rotation, Skeleton, MAX_CHANNELS};

fn skeleton() -> Skeleton {
    asf::load(&common::data("16.asf")).unwrap().skeleton
}

fn uniform(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// A random offset, each of x and z uniform in `±xz`, y in `±y`.
fn offset(rng: &mut Rng, xz: f64, y: f64) -> DVec3 {
    DVec3::new(uniform(rng, -xz, xz), uniform(rng, -y, y), uniform(rng, -xz, xz))
}

/// Random angles within the ASF limits for the given bones' rotation DOFs.
fn random_pose(skel: &Skeleton, bones: &[usize], rng: &mut Rng, channels: &mut [f64]) {
    for &b in bones {
        let bone = &skel.bones()[b];
        for (k, d) in bone.dofs().iter().enumerate() {
            if d.is_rotation() {
                let l = bone.limits()[k];
                channels[bone.first_channel() + k] = uniform(rng, f64::from(l.min), f64::from(l.max));
            }
        }
    }
}

fn walk_frames(skel: &Skeleton) -> Vec<Vec<f64>> {
    let motion = amc::load(skel, &common::data("16_15.amc")).unwrap();
    (0..motion.len())
        .map(|f| marionette::motion::frame_to_radians(skel, motion.frame(f)))
        .collect()
}

#[test]
fn fk64_matches_the_f32_fk() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let mut p64 = Pose64::default();
    let mut p32 = Pose::new();
    let (mut worst, mut worst_rotation) = (0.0f64, 0.0f64);
    for f in frames.iter().step_by(10) {
        fk64(&skel, f, &mut p64);
        let mut c = [0.0f32; MAX_CHANNELS];
        for (i, v) in f.iter().enumerate() {
            c[i] = *v as f32;
        }
        forward_kinematics(&skel, &c, &mut p32).unwrap();
        for b in 0..skel.len() {
            worst = worst.max((p64.tip[b] - p32.tip[b].as_dvec3()).length());
            // Both precisions' frames and world rotations, within f32's rounding.
            let pairs = [
                (p64.frame[b], glam::Mat3::from(p32.frame[b])),
                (p64.world(&skel, b), glam::Mat3::from(p32.world(&skel, b))),
            ];
            for (m64, m32) in pairs {
                let far = m64
                    .to_cols_array()
                    .iter()
                    .zip(m32.to_cols_array())
                    .map(|(x, y)| (x - f64::from(y)).abs())
                    .fold(0.0, f64::max);
                worst_rotation = worst_rotation.max(far);
            }
        }
    }
    assert!(worst < 1e-3, "{worst}");
    assert!(worst_rotation < 1e-5, "{worst_rotation:e}");
}

/// Every bone's frame is eq. (1) composed directly, `Fᵢ = Wₚ·Cᵢ·Mᵢ` with `Wₚ = Fₚ·Cₚᵀ` (the
/// root's `W = F`) and `M` from the bone's channels, and `Pose64::world` is `Fᵢ·Cᵢᵀ`: taking a
/// bone's axes from its parent's frame through `K = Cₚᵀ·C` (the identity where an axis is its
/// parent's to the file's rounding) changes the pose by rounding only.
#[test]
fn fk64_frames_are_eq1_composed_directly() {
    let skel = skeleton();
    let mut pose = Pose64::default();
    let (mut worst_frame, mut worst_world) = (0.0f64, 0.0f64);
    let diff = |a: glam::DMat3, b: glam::DMat3| {
        let (a, b) = (a.to_cols_array(), b.to_cols_array());
        a.iter().zip(&b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
    };
    for f in walk_frames(&skel).iter().step_by(13) {
        fk64(&skel, f, &mut pose);
        let mut world = vec![glam::DMat3::IDENTITY; skel.len()];
        for (b, bone) in skel.bones().iter().enumerate() {
            let c = bone.axis_rotation_f64();
            let m = dof_rotation(bone.dofs(), bone.channels().map(|k| f[k]));
            let (frame, w) = match bone.parent() {
                None => (c * m, c * m),
                Some(p) => (world[p] * c * m, world[p] * c * m * c.transpose()),
            };
            world[b] = w;
            worst_frame = worst_frame.max(diff(pose.frame[b], frame));
            worst_world = worst_world.max(diff(pose.world(&skel, b), w));
        }
    }
    assert!(
        worst_frame < 1e-12 && worst_world < 1e-12,
        "{worst_frame:e} {worst_world:e}"
    );
}

/// A bone's tip found by turning its vector (`fk64_tip`) is the full step's, on every bone of
/// the walk, the root's translation included.
#[test]
fn fk64_tip_is_the_steps_tip() {
    let skel = skeleton();
    let mut pose = Pose64::default();
    let mut worst = 0.0f64;
    for f in walk_frames(&skel).iter().step_by(7) {
        fk64(&skel, f, &mut pose);
        for (b, bone) in skel.bones().iter().enumerate() {
            let parent = bone.parent().map(|p| (&pose.frame[p], pose.tip[p]));
            worst = worst.max((fk64_tip(&skel, f, b, parent) - pose.tip[b]).length());
        }
    }
    assert!(worst < 1e-12, "{worst:e}");
}

/// The whole frame's FK, whose sines and cosines are computed in lanes a window of channels at
/// a time, is the bone-by-bone step's bit for bit; a frame shorter than the skeleton's
/// channels (or empty) is that frame padded with zeros.
#[test]
fn fk64_is_its_steps_bit_for_bit_short_frames_too() {
    let skel = skeleton();
    let n = skel.channel_count();
    let frames = walk_frames(&skel);
    let mut cases: Vec<Vec<f64>> = frames.iter().step_by(11).cloned().collect();
    cases.extend([frames[3][..n / 2].to_vec(), frames[5][..1].to_vec(), Vec::new()]);
    for f in &cases {
        let mut pose = Pose64::default();
        fk64(&skel, f, &mut pose);
        let mut padded = f.clone();
        padded.resize(n, 0.0);
        let mut full = Pose64::default();
        fk64(&skel, &padded, &mut full);
        for (b, bone) in skel.bones().iter().enumerate() {
            let parent = bone.parent().map(|p| (&pose.frame[p], pose.tip[p]));
            let (frame, start, tip) = fk64_step(&skel, &padded, b, parent);
            for (got, want) in [(pose.tip[b], tip), (pose.start[b], start), (full.tip[b], tip)] {
                assert_eq!(
                    got.to_array().map(f64::to_bits),
                    want.to_array().map(f64::to_bits),
                    "bone {b}"
                );
            }
            for (got, want) in [(pose.frame[b], frame), (full.frame[b], frame)] {
                assert_eq!(
                    got.to_cols_array().map(f64::to_bits),
                    want.to_cols_array().map(f64::to_bits),
                    "bone {b}"
                );
            }
        }
    }
}

/// The analytic Jacobian (eq. 43–47) equals central differences.
#[test]
fn analytic_jacobian_matches_finite_differences() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let hand = skel.find("lhand").unwrap();
    let mask = chain_mask(&skel, 0, hand);
    let mut rng = Rng::new(3);
    for f in frames.iter().step_by(47) {
        let mut pose = Pose64::default();
        fk64(&skel, f, &mut pose);
        let target =
            pose.tip[hand] + DVec3::new(uniform(&mut rng, -3.0, 3.0), uniform(&mut rng, -3.0, 3.0), 1.0);
        let c = [Constraint {
            bone: hand,
            position: target,
            axes: Some((DVec3::X, DVec3::Y)),
        }];
        let mut ch = f.clone();
        let mut solver = Solver::new(&skel, &mask, true);
        let rows = solver.jacobian_at(&skel, &c, &mut ch, 10.0, JacobianKind::Analytic);
        let analytic: Vec<Vec<f64>> = (0..rows).map(|r| solver.jacobian_row(r).to_vec()).collect();
        solver.jacobian_at(&skel, &c, &mut ch, 10.0, JacobianKind::FiniteDifference);
        let scale = analytic.iter().flatten().fold(0.0f64, |m, x| m.max(x.abs()));
        for (r, row) in analytic.iter().enumerate() {
            for (a, b) in row.iter().zip(solver.jacobian_row(r)) {
                assert!(
                    (a - b).abs() <= 1e-6 * scale,
                    "row {r}: analytic {a} vs finite difference {b}"
                );
            }
        }
        assert_eq!(rows, 9);
        assert_eq!(analytic[0].len(), solver.variables());
    }
}

/// Targets made by FK of random within-limit angles are reached by the limb solver, with the
/// shoulder inside its limits, for an arm and a leg.
#[test]
fn limb_reaches_random_reachable_targets_within_limits() {
    let skel = skeleton();
    let mut rng = Rng::new(5);
    for (upper, lower) in [("lhumerus", "lradius"), ("rfemur", "rtibia")] {
        let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
        let limb = Limb::new(&skel, u, l, None).unwrap();
        let n = 2000;
        let (mut ok, mut legal, mut worst) = (0, 0, 0.0f64);
        for _ in 0..n {
            let mut goal = vec![0.0; skel.channel_count()];
            random_pose(&skel, &[u, l], &mut rng, &mut goal);
            let mut pose = Pose64::default();
            fk64(&skel, &goal, &mut pose);
            let target = pose.tip[l];
            let mut ch = vec![0.0; skel.channel_count()];
            let s = limb.solve(&skel, &mut ch, target, Swivel::Auto { previous: None });
            assert!(ch.iter().all(|x| x.is_finite()));
            assert!(s.reachable);
            worst = worst.max(s.error);
            ok += usize::from(s.error < 1e-6);
            legal += usize::from(s.upper_within_limits && s.elbow_within_limits);
        }
        println!("{upper}/{lower}: {ok}/{n} within 1e-6 (worst {worst:.1e}), {legal}/{n} within limits");
        assert_eq!(ok, n);
        assert_eq!(legal, n, "{legal}/{n} within limits");
    }
}

/// Out of reach: stretched towards the target, flagged, never NaN; degenerate targets too.
#[test]
fn limb_handles_unreachable_and_degenerate_targets() {
    let skel = skeleton();
    let (u, l) = (skel.find("lhumerus").unwrap(), skel.find("lradius").unwrap());
    let limb = Limb::new(&skel, u, l, None).unwrap();
    let mut ch = vec![0.0; skel.channel_count()];
    let mut pose = Pose64::default();
    fk64(&skel, &ch, &mut pose);
    let s0 = pose.start[u];
    let (_, reach) = limb.reach();
    let far = s0 + DVec3::new(100.0, 50.0, -30.0);
    let sol = limb.solve(&skel, &mut ch, far, Swivel::Auto { previous: None });
    assert!(!sol.reachable);
    fk64(&skel, &ch, &mut pose);
    let dir = (pose.tip[l] - s0).normalize();
    assert!(
        dir.dot((far - s0).normalize()) > 1.0 - 1e-9,
        "not stretched towards the target"
    );
    assert!(((pose.tip[l] - s0).length() - reach).abs() < 1e-6);
    for target in [
        s0,
        DVec3::NAN,
        DVec3::splat(f64::INFINITY),
        s0 + DVec3::new(0.0, 1e-12, 0.0),
    ] {
        let mut ch = vec![0.0; skel.channel_count()];
        let sol = limb.solve(&skel, &mut ch, target, Swivel::Auto { previous: None });
        assert!(ch.iter().all(|x| x.is_finite()), "{target:?}");
        assert!(!sol.error.is_nan());
    }
    assert!(Limb::new(&skel, l, u, None).is_err());
}

/// Streaming the walk's left wrist path through the limb solver with warm starts: the wrist
/// follows, the swivel and joints move smoothly.
#[test]
fn limb_stream_is_continuous() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    // The whole-circle search with a continuity term, and the windowed search of streams.
    for (upper, lower, windowed) in [
        ("lhumerus", "lradius", false),
        ("rfemur", "rtibia", false),
        ("lhumerus", "lradius", true),
        ("rfemur", "rtibia", true),
    ] {
        let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
        let limb = Limb::new(&skel, u, l, None).unwrap();
        let mut previous: Option<f64> = None;
        let mut last: Option<Vec<f64>> = None;
        let (mut worst_err, mut worst_step, mut worst_swivel) = (0.0f64, 0.0f64, 0.0f64);
        let mut pose = Pose64::default();
        // From frame 3: frames 0–1 are the capture's arm dropout.
        for f in &frames[3..] {
            fk64(&skel, f, &mut pose);
            let target = pose.tip[l];
            let mut ch = last.clone().unwrap_or_else(|| f.clone());
            for b in 0..skel.bones().len() {
                if b != u && b != l {
                    for c in skel.bones()[b].channels() {
                        ch[c] = f[c];
                    }
                }
            }
            let swivel = match previous {
                Some(p) if windowed => Swivel::Track {
                    previous: p,
                    window: 40f64.to_radians(),
                },
                _ => Swivel::Auto { previous },
            };
            let s = limb.solve(&skel, &mut ch, target, swivel);
            if let Some(p) = previous {
                let step = (marionette::math::wrap_near(s.swivel, p) - p).abs();
                worst_swivel = worst_swivel.max(step);
            }
            previous = Some(s.swivel);
            worst_err = worst_err.max(s.error);
            assert!(s.upper_within_limits && s.elbow_within_limits);
            if let Some(p) = &last {
                for c in skel.bones()[u].channels().chain(skel.bones()[l].channels()) {
                    worst_step = worst_step.max((ch[c] - p[c]).abs());
                }
            }
            last = Some(ch);
        }
        println!(
            "walk {lower} path ({}): worst error {worst_err:.1e}, largest swivel step {:.2}°, largest joint step {:.2}°",
            if windowed { "windowed search" } else { "whole circle" },
            worst_swivel.to_degrees(),
            worst_step.to_degrees()
        );
        assert!(worst_err < 1e-6);
        assert!(
            worst_swivel.to_degrees() <= 5.0,
            "{lower}: swivel jumped {:.2}°",
            worst_swivel.to_degrees()
        );
        assert!(worst_step.to_degrees() < 10.0);
    }
}

/// 10⁶ random inputs to the analytic solver — reachable, unreachable, at and near the
/// shoulder, NaN/∞/huge components, garbage in the limb's own channels, NaN or wild previous
/// swivels and fixed swivels — never give a NaN channel or a NaN error, on an arm and a leg.
/// `MARIONETTE_IK_INPUTS=N` changes the count.
#[test]
fn limb_never_returns_nan() {
    let skel = skeleton();
    let count: usize = std::env::var("MARIONETTE_IK_INPUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let mut rng = Rng::new(11);
    let weird = [
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e300,
        -1e300,
        0.0,
        1e-300,
    ];
    let mut ch = vec![0.0; skel.channel_count()];
    let mut pose = Pose64::default();
    for (upper, lower) in [("lhumerus", "lradius"), ("rfemur", "rtibia")] {
        let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
        let limb = Limb::new(&skel, u, l, None).unwrap();
        fk64(&skel, &ch, &mut pose);
        let shoulder = pose.start[u];
        for i in 0..count / 2 {
            ch.iter_mut().for_each(|x| *x = 0.0);
            let kind = rng.below(6);
            let target = match kind {
                0 => shoulder + offset(&mut rng, 30.0, 30.0),
                1 => shoulder + offset(&mut rng, 1e6, 1e6),
                2 => shoulder + offset(&mut rng, 1e-9, 0.0),
                3 => DVec3::new(
                    weird[rng.below(7) as usize],
                    uniform(&mut rng, -10.0, 10.0),
                    weird[rng.below(7) as usize],
                ),
                4 => shoulder,
                _ => {
                    random_pose(&skel, &[u, l], &mut rng, &mut ch);
                    fk64(&skel, &ch, &mut pose);
                    pose.tip[l]
                }
            };
            // Garbage in the limb's own channels (outputs, but the present elbow is read).
            if rng.chance(0.2) {
                for b in [u, l] {
                    for c in skel.bones()[b].channels() {
                        ch[c] = if rng.chance(0.5) {
                            weird[rng.below(7) as usize]
                        } else {
                            uniform(&mut rng, -20.0, 20.0)
                        };
                    }
                }
            }
            let swivel = match rng.below(5) {
                0 => Swivel::Auto { previous: None },
                4 => Swivel::Track {
                    previous: if rng.chance(0.5) {
                        weird[rng.below(7) as usize]
                    } else {
                        uniform(&mut rng, -1e3, 1e3)
                    },
                    window: if rng.chance(0.2) {
                        weird[rng.below(7) as usize]
                    } else {
                        uniform(&mut rng, 0.0, 4.0)
                    },
                },
                1 => Swivel::Auto {
                    previous: Some(if rng.chance(0.5) {
                        weird[rng.below(7) as usize]
                    } else {
                        uniform(&mut rng, -1e3, 1e3)
                    }),
                },
                2 => Swivel::Fixed(weird[rng.below(7) as usize]),
                _ => Swivel::Fixed(uniform(&mut rng, -10.0, 10.0)),
            };
            let sol = limb.solve(&skel, &mut ch, target, swivel);
            assert!(
                skel.bones()[u]
                    .channels()
                    .chain(skel.bones()[l].channels())
                    .all(|c| ch[c].is_finite()),
                "input {i} kind {kind}: {target:?} {swivel:?} gave {sol:?}"
            );
            assert!(
                !sol.error.is_nan() && sol.swivel.is_finite() && !sol.violation.is_nan(),
                "{target:?} {swivel:?} {sol:?}"
            );
            if kind == 5 {
                assert!(
                    sol.reachable && sol.error < 1e-6,
                    "reachable target missed: {swivel:?} {sol:?}"
                );
            }
        }
    }
}

/// Each numerical method reaches random reachable targets (arm: humerus + radius, leg: femur +
/// tibia, 4 DOFs each) from the rest pose within 100 iterations, restarts included; limits are
/// respected in every result. DLS and CG must reach 99.5 %; the full 10,000-target
/// table is `cargo run --release --example ik_compare`.
#[test]
fn numerical_methods_reach_random_targets() {
    let skel = skeleton();
    for (upper, lower, seed) in [("lhumerus", "lradius", 8), ("lfemur", "ltibia", 9)] {
        let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
        let mask = chain_mask(&skel, u, l);
        let mut rng = Rng::new(seed);
        let n = 2000;
        let mut goals = Vec::new();
        for _ in 0..n {
            let mut goal = vec![0.0; skel.channel_count()];
            random_pose(&skel, &[u, l], &mut rng, &mut goal);
            let mut pose = Pose64::default();
            fk64(&skel, &goal, &mut pose);
            goals.push(pose.tip[l]);
        }
        for method in Method::ALL {
            let mut solver = Solver::new(&skel, &mask, false);
            assert_eq!(solver.variables(), 4);
            let settings = Settings {
                method,
                max_iterations: 100,
                ..Settings::default()
            };
            let mut ok = 0;
            for &goal in &goals {
                let mut ch = vec![0.0; skel.channel_count()];
                let out = solver.solve(
                    &skel,
                    &[Constraint {
                        bone: l,
                        position: goal,
                        axes: None,
                    }],
                    &mut ch,
                    &settings,
                );
                assert!(solver.within_limits(&ch), "{method:?} left the limits");
                assert!(out.position_error.is_finite() && out.iterations <= 100);
                let mut pose = Pose64::default();
                fk64(&skel, &ch, &mut pose);
                let e = (pose.tip[l] - goal).length();
                assert!(
                    (e - out.position_error).abs() < 1e-9,
                    "reported {out:?}, actual {e}"
                );
                ok += usize::from(out.converged);
            }
            println!("{upper}/{lower} {method:?}: {ok}/{n}");
            let floor = match method {
                Method::Ccd | Method::Transpose => 0.6,
                Method::Pseudoinverse => 0.99,
                Method::DampedLeastSquares | Method::ConjugateGradient => 0.995,
            };
            assert!(ok as f64 >= floor * n as f64, "{upper} {method:?}: {ok}/{n}");
        }
    }
}

/// The swivel score's polynomial arctangent agrees with libm's to 1e-7 rad.
#[test]
fn fast_quaternion_distance_matches_libm() {
    use glam::DQuat;
    use marionette::math::{quat_distance_f64, quat_distance_fast};
    let mut rng = Rng::new(3);
    let mut worst = 0.0f64;
    for _ in 0..100_000 {
        let mut q = || {
            let v = [0; 4].map(|_| uniform(&mut rng, -1.0, 1.0));
            DQuat::from_xyzw(v[0], v[1], v[2], v[3]).normalize()
        };
        let (a, b) = (q(), q());
        worst = worst.max((quat_distance_fast(a, b) - quat_distance_f64(a, b)).abs());
    }
    assert_eq!(quat_distance_fast(DQuat::IDENTITY, DQuat::IDENTITY), 0.0);
    println!("worst {worst:.1e}");
    assert!(worst < 1e-7, "{worst}");
}

/// Several constraints at once: both feet and a hand, from a walk frame.
#[test]
fn numerical_ik_with_several_constraints() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let (lf, rf, lh) = (
        skel.find("ltibia").unwrap(),
        skel.find("rtibia").unwrap(),
        skel.find("lradius").unwrap(),
    );
    let mut pose = Pose64::default();
    fk64(&skel, &frames[200], &mut pose);
    let targets = [
        Constraint {
            bone: lf,
            position: pose.tip[lf],
            axes: None,
        },
        Constraint {
            bone: rf,
            position: pose.tip[rf],
            axes: None,
        },
        Constraint {
            bone: lh,
            position: pose.tip[lh] + DVec3::new(0.0, 2.0, 1.0),
            axes: None,
        },
    ];
    let mut mask = [true; marionette::skeleton::MAX_BONES];
    mask[0] = true;
    let mut solver = Solver::new(&skel, &mask, false);
    let mut ch = frames[200].clone();
    let out = solver.solve(
        &skel,
        &targets,
        &mut ch,
        &Settings {
            max_iterations: 1000,
            damping: 0.1,
            ..Settings::default()
        },
    );
    println!("{out:?}");
    assert!(out.converged, "{out:?}");
    assert!(solver.within_limits(&ch));
}

/// `marionette ik` end to end: a reachable wrist target from a walk frame is met by every
/// method, the pose file reproduces it, and bad input gets a clear error.
#[test]
fn ik_command_line() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let l = skel.find("lradius").unwrap();
    let mut pose = Pose64::default();
    fk64(&skel, &frames[99], &mut pose);
    // Bring the wrist 30 % closer to the shoulder and a little forward (the elbow bends).
    let s = pose.start[skel.find("lhumerus").unwrap()];
    let t = pose.tip[l] + (s - pose.tip[l]) * 0.3 + DVec3::new(0.0, 0.0, 0.5);
    let target = format!("{},{},{}", t.x, t.y, t.z);
    let dir = std::env::temp_dir().join(format!("marionette-ik-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for method in ["analytic", "ccd", "jt", "pinv", "dls", "cg"] {
        let out_path = dir.join(format!("{method}.amc"));
        let out = common::bin()
            .args([
                "ik",
                common::data("16.asf").to_str().unwrap(),
                "--amc",
                common::data("16_15.amc").to_str().unwrap(),
            ])
            .args([
                "--frame",
                "100",
                "--effector",
                "lradius",
                "--target",
                &target,
                "--method",
                method,
                "-o",
            ])
            .arg(&out_path)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "{method}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let residual: f64 = stdout
            .split("residual ")
            .nth(1)
            .unwrap()
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap();
        assert!(residual < 1e-3, "{method}: {stdout}");
        assert!(stdout.contains("joint limits met"), "{method}: {stdout}");
        // The written pose puts the wrist on the target.
        let m = amc::load(&skel, &out_path).unwrap();
        let mut p = Pose64::default();
        let ch: Vec<f64> = marionette::motion::frame_to_radians(&skel, m.frame(0));
        fk64(&skel, &ch, &mut p);
        assert!((p.tip[l] - t).length() < 1e-3, "{method}");
    }
    for (args, words) in [
        (vec!["--effector", "lfoo", "--target", "1,2,3"], "unknown bone"),
        (vec!["--effector", "lradius", "--target", "1,2"], "X,Y,Z"),
        (vec!["--effector", "lradius", "--target", "1,nan,3"], "finite"),
        (
            vec![
                "--effector",
                "lfingers",
                "--target",
                "1,2,3",
                "--method",
                "analytic",
            ],
            "2-bone limb",
        ),
    ] {
        let out = common::bin()
            .args(["ik", common::data("16.asf").to_str().unwrap()])
            .args(&args)
            .output()
            .unwrap();
        assert!(!out.status.success());
        assert!(
            String::from_utf8_lossy(&out.stderr).contains(words),
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
}

/// `ik-edit` plants the left foot (ankle = ltibia's tip) of the walk over its stance frames
/// 150..170: the ankle holds the pinned position, frames outside the blend are untouched, only
/// the leg's channels change, and the leg moves smoothly. Also the swivel read back from a pose
/// reproduces it, and bad arguments are refused with a message.
#[test]
fn ik_edit_plants_a_foot() {
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let (fe, ti) = (skel.find("lfemur").unwrap(), skel.find("ltibia").unwrap());
    let limb = Limb::new(&skel, fe, ti, Some(&frames[0])).unwrap();
    let mut pose = Pose64::default();
    for f in &frames {
        let mut ch = f.clone();
        fk64(&skel, f, &mut pose);
        let s = limb.solve(
            &skel,
            &mut ch,
            pose.tip[ti],
            Swivel::Fixed(limb.swivel_of(&skel, f)),
        );
        for c in skel.bones()[fe].channels().chain(skel.bones()[ti].channels()) {
            assert!(
                (ch[c] - f[c]).abs() < 1e-7,
                "swivel_of does not reproduce the pose: {s:?}"
            );
        }
    }

    let dir = std::env::temp_dir().join(format!("marionette-ik-edit-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out_path = dir.join("planted.amc");
    let run = |extra: &[&str]| {
        common::bin()
            .args([
                "ik-edit",
                common::data("16.asf").to_str().unwrap(),
                common::data("16_15.amc").to_str().unwrap(),
            ])
            .args(extra)
            .output()
            .unwrap()
    };
    let out = run(&[
        "--pin",
        "ltibia@160",
        "--frames",
        "150..170",
        "-o",
        out_path.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    println!("{stdout}");
    assert!(stdout.contains("pin ltibia@160") && stdout.contains("target missed on 0 frames"));
    let input = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let edited = amc::load(&skel, &out_path).unwrap();
    assert_eq!(edited.len(), input.len());
    fk64(&skel, &frames[159], &mut pose);
    let pin = pose.tip[ti];
    let leg: Vec<usize> = skel.bones()[fe]
        .channels()
        .chain(skel.bones()[ti].channels())
        .collect();
    let mut largest_step = 0.0f64;
    for i in 0..input.len() {
        let f = i as i64 + 1;
        for c in 0..skel.channel_count() {
            if !(138..=182).contains(&f) || !leg.contains(&c) {
                assert_eq!(
                    edited.frame(i)[c],
                    input.frame(i)[c],
                    "frame {f} channel {c} changed"
                );
            }
        }
        if (150..=170).contains(&f) {
            let ch = marionette::motion::frame_to_radians(&skel, edited.frame(i));
            fk64(&skel, &ch, &mut pose);
            let drift = (pose.tip[ti] - pin).length();
            assert!(drift < 1e-6, "frame {f}: ankle {drift} from the pin");
        }
        if i > 0 {
            for &c in &leg {
                largest_step = largest_step.max((edited.frame(i)[c] - edited.frame(i - 1)[c]).abs());
            }
        }
    }
    println!("largest leg step {largest_step:.2}°");
    assert!(largest_step < 5.0, "{largest_step}°");

    for (args, expect) in [
        (vec!["--pin", "ltibia@160", "--frames", "170..150"], "A ≤ B"),
        (
            vec!["--pin", "ltibia@160", "--frames", "1..9999"],
            "not inside the clip",
        ),
        (
            vec!["--pin", "nose@160", "--frames", "150..170"],
            "unknown bone 'nose'",
        ),
        (vec!["--pin", "ltibia", "--frames", "150..170"], "BONE@FRAME"),
        (
            vec!["--pin", "ltibia@0", "--frames", "150..170"],
            "frame 0 is not in the clip",
        ),
    ] {
        let mut a = args.clone();
        a.extend(["-o", out_path.to_str().unwrap()]);
        let out = run(&a);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && stderr.contains(expect),
            "{args:?}: {stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Eq. (31)–(34) on the 3-DOF bones of the CMU skeleton (humerus, upper neck, lower back):
/// for random legal poses, pointing the bone along its posed direction with the posed roll
/// gives back the same frame; the direction error stays below 0.01° (it is ~1e-14 rad).
#[test]
fn closed_form_pointing_with_roll() {
    use glam::{DMat3, DQuat};
    use marionette::ik::{point_bone, PointError};
    let skel = skeleton();
    let frames = walk_frames(&skel);
    let mut rng = Rng::new(21);
    let mut worst_dir = 0.0f64;
    let mut worst_frame = 0.0f64;
    for name in ["lhumerus", "upperneck", "lowerback", "rfemur"] {
        let b = skel.find(name).unwrap();
        let v_h = skel.bones()[b].local_direction().as_dvec3().normalize();
        for i in 0..2000 {
            let mut goal = frames[i % frames.len()].clone();
            random_pose(&skel, &[b], &mut rng, &mut goal);
            let mut pose = Pose64::default();
            fk64(&skel, &goal, &mut pose);
            let dir = pose.tip[b] - pose.start[b];
            let goal_frame = pose.frame[b];
            // Roll 0 first, then the roll that the goal has relative to it.
            let mut ch = frames[i % frames.len()].clone();
            point_bone(&skel, &mut ch, b, dir, 0.0).unwrap();
            fk64(&skel, &ch, &mut pose);
            let (axis, angle) = DQuat::from_mat3(&(pose.frame[b].transpose() * goal_frame)).to_axis_angle();
            let roll = if axis.dot(v_h) < 0.0 { -angle } else { angle };
            let p = point_bone(&skel, &mut ch, b, dir * 3.7, roll).unwrap();
            fk64(&skel, &ch, &mut pose);
            worst_dir = worst_dir.max(p.direction_error);
            let diff: DMat3 = pose.frame[b] - goal_frame;
            let e = diff.x_axis.length() + diff.y_axis.length() + diff.z_axis.length();
            worst_frame = worst_frame.max(e);
            assert!(
                p.violation < 1e-9,
                "{name}: a legal pose came back outside the limits by {}",
                p.violation
            );
        }
    }
    println!(
        "pointing: worst direction error {:.1e}°, worst frame difference {worst_frame:.1e}",
        worst_dir.to_degrees()
    );
    assert!(worst_dir.to_degrees() <= 0.01);
    assert!(worst_frame < 1e-9);
    let mut ch = vec![0.0; skel.channel_count()];
    let radius = skel.find("lradius").unwrap();
    assert_eq!(
        point_bone(&skel, &mut ch, radius, DVec3::X, 0.0),
        Err(PointError::Needs3Dofs)
    );
    let hum = skel.find("lhumerus").unwrap();
    assert_eq!(
        point_bone(&skel, &mut ch, hum, DVec3::ZERO, 0.0),
        Err(PointError::BadDirection)
    );
    assert_eq!(
        point_bone(&skel, &mut ch, hum, DVec3::NAN, 0.0),
        Err(PointError::BadDirection)
    );
}

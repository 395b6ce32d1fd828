//! Motion editing on real captures: matching against brute force, seam quality, the
//! transformation, interpolation identities, loops and resampling.

mod common;

use glam::{DMat3, DQuat, DVec3};
use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf};
use marionette::interp::{facing_angle, interpolate_frames, root_position, root_rotation};
use marionette::math::wrap_near;
use marionette::motion::clip::{bend, transform};
use marionette::motion::connect::{connect, loop_clip, ConnectParams, Direction, Method};
use marionette::motion::matching::{backward_match, forward_match, MatchParams, Metric};
use marionette::motion::seam::{seam_report, wrap_jump};
use marionette::motion::Motion;
use marionette::skeleton::{Skeleton, MAX_CHANNELS};
use std::sync::OnceLock;

struct Clips {
    skeleton: Skeleton,
    walk: Motion,
    play: Motion,
}

/// Both clips read with the subject-16 skeleton (same bones and DOFs as subject 1).
fn clips() -> &'static Clips {
    static C: OnceLock<Clips> = OnceLock::new();
    C.get_or_init(|| {
        let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
        let walk = amc::load(&skeleton, &common::data("16_15.amc")).unwrap();
        let play = amc::load(&skeleton, &common::data("01_01.amc")).unwrap();
        Clips { skeleton, walk, play }
    })
}

/// Eq. (11) computed the plain way: every window, every frame, every joint, from the raw
/// channel values (own Euler → quaternion conversion, own position normalisation).
fn brute_force(
    s: &Skeleton,
    reference: &Motion,
    ref_start: usize,
    cand: &Motion,
    n: usize,
    metric: Metric,
) -> Vec<f64> {
    let rest_height = {
        let mut p = Pose::new();
        forward_kinematics(s, &[0.0; MAX_CHANNELS], &mut p).unwrap();
        let ys: Vec<f32> = p.tip[..s.len()].iter().map(|v| v.y).collect();
        f64::from(ys.iter().cloned().fold(f32::MIN, f32::max) - ys.iter().cloned().fold(f32::MAX, f32::min))
    };
    let positions = |m: &Motion, i: usize| -> Vec<DVec3> {
        let mut c = [0.0f32; MAX_CHANNELS];
        let mut p = Pose::new();
        m.channels_into(s, i, &mut c);
        forward_kinematics(s, &c, &mut p).unwrap();
        let f = m.frame(i);
        let r = root_rotation(s, f);
        let yaw = r.col(2).x.atan2(r.col(2).z);
        let root = root_position(s, f);
        (0..s.len())
            .map(|b| DMat3::from_rotation_y(-yaw) * (p.tip[b].as_dvec3() - root) / rest_height)
            .collect()
    };
    let quat = |f: &[f64], b: usize| -> DQuat {
        let bone = &s.bones()[b];
        let mut q = DQuat::IDENTITY;
        for (d, c) in bone.dofs().iter().zip(bone.channels()) {
            if let (true, Some(axis)) = (d.is_rotation(), d.axis()) {
                q = DQuat::from_axis_angle(axis.unit().as_dvec3(), f[c].to_radians()) * q;
            }
        }
        q
    };
    let mut out = Vec::new();
    for j in 0..=cand.len() - n {
        let mut total = 0.0;
        for f in 0..n {
            let (fa, fb) = (reference.frame(ref_start + f), cand.frame(j + f));
            let (pa, pb) = if metric == Metric::Position {
                (positions(reference, ref_start + f), positions(cand, j + f))
            } else {
                (Vec::new(), Vec::new())
            };
            for b in 1..s.len() {
                let bone = &s.bones()[b];
                if !bone.dofs().iter().any(|d| d.is_rotation()) {
                    continue;
                }
                total += match metric {
                    Metric::Euler => bone
                        .channels()
                        .map(|c| (fa[c] - fb[c]).to_radians().powi(2))
                        .sum::<f64>()
                        .sqrt(),
                    Metric::Quat => {
                        let d = quat(fa, b).conjugate() * quat(fb, b);
                        DVec3::new(d.x, d.y, d.z).length().atan2(d.w.abs())
                    }
                    Metric::Position => (pa[b] - pb[b]).length(),
                };
            }
        }
        out.push(total);
    }
    out
}

#[test]
fn matching_finds_the_global_minimum_for_every_metric() {
    let c = clips();
    let s = &c.skeleton;
    // Every 4th frame of the playground clip keeps the brute force quick.
    let play = {
        let mut m = Motion::new(s.channel_count(), 30.0);
        for i in (0..c.play.len()).step_by(4) {
            m.push_frame(c.play.frame(i));
        }
        m
    };
    for metric in [Metric::Euler, Metric::Quat, Metric::Position] {
        let n = 12;
        let params = MatchParams::new(n, metric);
        let fwd = forward_match(s, &c.walk, &play, &params).unwrap();
        let want = brute_force(s, &c.walk, c.walk.len() - n, &play, n, metric);
        assert_eq!(fwd.distances.len(), want.len());
        for (g, w) in fwd.distances.iter().zip(&want) {
            assert!((g - w).abs() <= 1e-6 * w.max(1.0), "{metric:?}: {g} vs {w}");
        }
        let brute_best = want
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!(fwd.best, brute_best, "{metric:?} forward");
        assert_eq!(
            fwd.best_distance,
            fwd.distances.iter().cloned().fold(f64::INFINITY, f64::min)
        );

        let bwd = backward_match(s, &play, &c.walk, &params).unwrap();
        let want = brute_force(s, &c.walk, 0, &play, n, metric);
        let brute_best = want
            .iter()
            .enumerate()
            .min_by(|a, b| a.1.total_cmp(b.1))
            .unwrap()
            .0;
        assert_eq!(bwd.best, brute_best, "{metric:?} backward");
    }
}

/// `connect` with both methods and both matchings on every pair of bundled clips
/// (the walk, the playground, the generated squat and weight shift, each with itself too):
/// no bone, and not the root, moves per frame across the seam more than 1.5× its own
/// 99th-percentile speed in the inputs + 1° — measured again here from the output.
#[test]
fn seams_on_real_captures_stay_within_each_bones_speeds() {
    use marionette::motion::dropouts::repair;
    use marionette::motion::seam::{bone_seam, BoneLimits};
    let c = clips();
    let s = &c.skeleton;
    let generated = |name: &str| {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("data/generated")
            .join(name);
        amc::load(s, &path).unwrap()
    };
    let mut walk = c.walk.clone();
    repair(s, &mut walk);
    let clips: [(&str, Motion); 4] = [
        ("walk", walk),
        ("playground", c.play.clone()),
        ("squat", generated("squat.amc")),
        ("weight shift", generated("weight_shift.amc")),
    ];
    let mut worst = (0.0f64, String::new());
    let mut checked = 0;
    for (an, a) in &clips {
        for (bn, b) in &clips {
            for method in [Method::Interpolate, Method::Blend] {
                for direction in [Direction::Forward, Direction::Backward] {
                    let params = ConnectParams {
                        method,
                        direction,
                        matching: MatchParams::new(30, Metric::Quat),
                        insert: None,
                        blend: None,
                    };
                    let conn = connect(s, a, b, &params).unwrap();
                    let limits = BoneLimits::of(s, &[a, b]);
                    let bones = bone_seam(s, &conn.motion, conn.seam.clone(), &limits);
                    let name = format!("{an}→{bn} {method:?}/{direction:?}");
                    assert_eq!(bones, conn.bones, "{name}: the connection reports what it made");
                    eprintln!(
                        "{name:<40} seam {:>3} frames, worst {} {:.2}",
                        conn.seam.len(),
                        bones[0].name,
                        bones[0].ratio
                    );
                    assert!(bones[0].ratio <= 1.0, "{name}: {:?}", &bones[..3]);
                    if bones[0].ratio > worst.0 {
                        worst = (bones[0].ratio, name.clone());
                    }
                    // B really continues after the seam (no empty or trivial connection).
                    assert!(!conn.b_kept.is_empty(), "{name}");
                    assert!(conn.motion.len() > conn.seam.end, "{name}");
                    checked += 1;
                }
            }
        }
    }
    println!(
        "{checked} connections, worst per-bone ratio {:.3} ({})",
        worst.0, worst.1
    );
    assert_eq!(checked, 64);
}

fn facings(s: &Skeleton, m: &Motion) -> Vec<f64> {
    (0..m.len())
        .map(|i| facing_angle(&root_rotation(s, m.frame(i))))
        .collect()
}

#[test]
fn transformation_sets_facing_and_keeps_relative_headings() {
    let c = clips();
    let s = &c.skeleton;
    for clip in [&c.walk, &c.play] {
        let before = facings(s, clip);
        for target_deg in [0.0f64, 37.5, 90.0, 180.0, -180.0, -135.0, 270.0] {
            let target = target_deg.to_radians();
            let out = transform(s, clip, target, Some((3.0, -7.0)));
            let after = facings(s, &out);
            for i in 0..clip.len() {
                let want = target + (before[i] - before[0]);
                let err = (wrap_near(after[i], want) - want).abs();
                assert!(err < 1e-6, "frame {i} target {target_deg}: {err}");
            }
            let p = root_position(s, out.frame(0));
            assert!((p.x - 3.0).abs() < 1e-9 && (p.z + 7.0).abs() < 1e-9);
            assert!(
                (p.y - root_position(s, clip.frame(0)).y).abs() < 1e-9,
                "height kept"
            );
        }
        // A full turn brings the clip back.
        let turned = transform(s, clip, before[0] + std::f64::consts::TAU, None);
        let mut worst = 0.0f64;
        for (x, y) in clip.frames().zip(turned.frames()) {
            for (a, b) in x.iter().zip(y) {
                worst = worst.max((a - b).abs());
            }
        }
        assert!(worst < 1e-9, "360° turn: {worst}");
    }
}

/// `bend` (`transform --turn`): each frame turned by its share of the turn — the facing goes
/// from the clip's own to it plus the turn, evenly — each step over the ground turned with its
/// frame (the same length, heights kept), the first frame where it was; a straight walk bent
/// 90° ends walking at right angles to how it started.
#[test]
fn bending_a_walk_turns_its_facing_and_its_path() {
    let c = clips();
    let s = &c.skeleton;
    let walk = &c.walk;
    let n = walk.len();
    for turn_deg in [45.0f64, -90.0] {
        let turn = turn_deg.to_radians();
        let out = bend(s, walk, turn);
        let (before, after) = (facings(s, walk), facings(s, &out));
        for i in 0..n {
            let want = before[i] + turn * i as f64 / (n - 1) as f64;
            let err = (wrap_near(after[i], want) - want).abs();
            assert!(err < 1e-6, "{turn_deg}°, frame {i}: facing off by {err}");
            let (p, q) = (root_position(s, walk.frame(i)), root_position(s, out.frame(i)));
            assert!((p.y - q.y).abs() < 1e-9, "height kept");
            if i > 0 {
                let ground = |m: &Motion| {
                    let d = root_position(s, m.frame(i)) - root_position(s, m.frame(i - 1));
                    DVec3::new(d.x, 0.0, d.z).length()
                };
                assert!((ground(walk) - ground(&out)).abs() < 1e-9, "step length kept");
            }
        }
        let start = root_position(s, out.frame(0)) - root_position(s, walk.frame(0));
        assert!(start.length() < 1e-12, "the first frame stays");
        // The path's last stretch (half a second) against its first, in the ground plane.
        let heading = |m: &Motion, a: usize, b: usize| {
            let d = root_position(s, m.frame(b)) - root_position(s, m.frame(a));
            d.x.atan2(d.z)
        };
        let k = 60;
        let straight = heading(walk, n - 1 - k, n - 1) - heading(walk, 0, k);
        let bent = heading(&out, n - 1 - k, n - 1) - heading(&out, 0, k);
        // The two stretches' middles are (n − 1 − k) frames apart: that share of the turn.
        let want = turn * (n - 1 - k) as f64 / (n - 1) as f64;
        let got = wrap_near(bent - straight, want);
        assert!(
            (got - want).abs() < 3f64.to_radians(),
            "{turn_deg}°: path turned {}°, {}° wanted",
            got.to_degrees(),
            want.to_degrees()
        );
    }
}

#[test]
fn interpolating_a_frame_with_itself_returns_it_exactly() {
    let c = clips();
    let s = &c.skeleton;
    let mut out = vec![0.0; s.channel_count()];
    for clip in [&c.walk, &c.play] {
        for i in (0..clip.len()).step_by(7) {
            for u in [0.0, 0.3, 0.5, 1.0] {
                interpolate_frames(s, clip.frame(i), clip.frame(i), u, &mut out);
                assert_eq!(out.as_slice(), clip.frame(i));
            }
        }
    }
}

#[test]
fn interpolation_takes_the_short_arc_and_hits_the_ends() {
    let c = clips();
    let s = &c.skeleton;
    let (a, b) = (c.walk.frame(10), c.walk.frame(60));
    let mut out = vec![0.0; s.channel_count()];
    for (u, want) in [(0.0, a), (1.0, b)] {
        interpolate_frames(s, a, b, u, &mut out);
        for bone in s.bones() {
            let q = |f: &[f64]| DQuat::from_mat3(&marionette::interp::channel_rotation(bone, f));
            assert!(
                q(&out).dot(q(want)).abs() > 1.0 - 1e-12,
                "{} at u={u}",
                bone.name()
            );
        }
    }
    // Halfway, each 3-DOF joint is halfway along the geodesic.
    interpolate_frames(s, a, b, 0.5, &mut out);
    for bone in s.bones().iter().filter(|b| b.dofs().len() == 3) {
        let q = |f: &[f64]| DQuat::from_mat3(&marionette::interp::channel_rotation(bone, f));
        let (qa, qb, qm) = (q(a), q(b), q(&out));
        let half = marionette::math::quat_distance_f64(qa, qb);
        assert!(
            (marionette::math::quat_distance_f64(qa, qm) - half / 2.0).abs() < 1e-9,
            "{}",
            bone.name()
        );
    }
}

#[test]
fn loop_wraps_seamlessly_and_carries_the_root_on() {
    let c = clips();
    let s = &c.skeleton;
    let l = loop_clip(s, &c.walk, &MatchParams::new(30, Metric::Quat), 3).unwrap();
    assert_eq!(l.motion.len(), 3 * l.period);
    assert!(l.period >= 60);
    for wrap in [l.period, 2 * l.period] {
        let r = seam_report(s, &[&c.walk], &l.motion, wrap..wrap);
        eprintln!("loop wrap at {wrap}: {r}");
        assert!(r.within(1.5), "{r:?}");
    }
    // Played over and over, the cycle's wrap is a step like its others; the captured walk's
    // is not.
    let cycle = l.motion.slice(0..l.period);
    let seamless = wrap_jump(s, &cycle).unwrap();
    assert!(seamless.is_seamless(), "{seamless:?}");
    let walk = wrap_jump(s, &c.walk).unwrap();
    assert!(!walk.is_seamless(), "{walk:?}");
    assert!(walk.rotation > 10f64.to_radians(), "{walk:?}");
    // The walk goes on: the third cycle ends farther from the start than the first.
    let p0 = root_position(s, l.motion.frame(0));
    let d1 = (root_position(s, l.motion.frame(l.period - 1)) - p0).length();
    let d3 = (root_position(s, l.motion.frame(3 * l.period - 1)) - p0).length();
    assert!(d3 > 2.5 * d1, "{d1} {d3}");
}

#[test]
fn resampling_keeps_shared_frames_and_duration() {
    let c = clips();
    let s = &c.skeleton;
    let half = c.walk.resampled(s, 60.0);
    assert_eq!(half.len(), 236);
    assert_eq!(half.frame_rate, 60.0);
    for k in 0..half.len() {
        assert_eq!(half.frame(k), c.walk.frame(2 * k));
    }
    let up = c.walk.resampled(s, 500.0);
    assert!((up.duration() - c.walk.duration()).abs() < 1.0 / 500.0);
    // 500 Hz frame 25 is 0.05 s = 120 Hz frame 6 exactly.
    assert_eq!(up.frame(25), c.walk.frame(6));
    let back = c.walk.reversed().reversed();
    assert_eq!(back, c.walk);
}

/// Capture dropouts: 16_15's left arm reads 0 in frames 1–2 (humerus, radius, wrist; its hand
/// and thumb in frames 1–7) next to far-away frames; they are found, filled from the valid
/// side, and nothing else in the clip changes. 01_01 has none, and a bone resting at zero is no dropout.
#[test]
fn capture_dropouts_are_found_and_filled() {
    use marionette::motion::dropouts::{find, repair};
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let found = find(&skel, &motion);
    let names: Vec<(&str, (usize, usize))> = found.iter().map(|d| (d.bone.as_str(), d.frames)).collect();
    assert_eq!(
        names,
        [
            ("lhumerus", (0, 1)),
            ("lradius", (0, 1)),
            ("lwrist", (0, 1)),
            ("lhand", (0, 6)),
            ("lthumb", (0, 6))
        ],
        "{found:?}"
    );
    assert!(found[0].speed_dps > 9000.0, "{}", found[0]);
    assert_eq!(
        found[0].to_string(),
        "lhumerus frames 1–2 read zero (9141°/s to the next valid frame)"
    );
    let mut repaired = motion.clone();
    assert_eq!(repair(&skel, &mut repaired), found);
    let humerus = skel.find("lhumerus").unwrap();
    let channels: Vec<usize> = skel.bones()[humerus].channels().collect();
    for i in 0..motion.len() {
        for c in 0..motion.channel_count() {
            let (was, now) = (motion.frame(i)[c], repaired.frame(i)[c]);
            if i < 2 && channels.contains(&c) {
                // Held at the first valid frame (the dropout opens the clip).
                assert_eq!(now, motion.frame(2)[c]);
            } else if !(i < 7 && now != was) {
                assert_eq!(now, was, "frame {i} channel {c}");
            }
        }
    }
    assert!(find(&skel, &repaired).is_empty());
    let skel01 = asf::load(&common::data("01.asf")).unwrap().skeleton;
    let m01 = amc::load(&skel01, &common::data("01_01.amc")).unwrap();
    assert!(find(&skel01, &m01).is_empty());
    // A dropout inside a clip is filled linearly between its sides.
    let mut inner = repaired.clone();
    for i in 100..103 {
        for &c in &channels {
            inner.frame_mut(i)[c] = 0.0;
        }
    }
    let holes = repair(&skel, &mut inner);
    assert_eq!(holes.len(), 1);
    assert_eq!(holes[0].frames, (100, 102));
    for &c in &channels {
        let (a, b) = (repaired.frame(99)[c], repaired.frame(103)[c]);
        assert!((inner.frame(101)[c] - (a + b) / 2.0).abs() < 1e-12);
    }
    // The root's rotation reading zero in the first frame (a BVH conversion's T-pose, facing
    // elsewhere than the captured body) is one too; its position is left as recorded.
    let root = skel.bones().iter().position(|b| b.parent().is_none()).unwrap();
    let bone = &skel.bones()[root];
    let (rotations, positions): (Vec<_>, Vec<_>) = bone
        .channels()
        .zip(bone.dofs())
        .partition(|(_, d)| d.is_rotation());
    // The capture turned 60° about each axis, so that zero is far from every frame.
    let mut facing = repaired.clone();
    for i in 0..facing.len() {
        for (c, _) in &rotations {
            facing.frame_mut(i)[*c] += 60.0;
        }
    }
    let mut turned = facing.clone();
    for (c, _) in &rotations {
        turned.frame_mut(0)[*c] = 0.0;
    }
    let found = repair(&skel, &mut turned);
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!((found[0].bone.as_str(), found[0].frames), (bone.name(), (0, 0)));
    for (c, _) in &rotations {
        assert_eq!(turned.frame(0)[*c], facing.frame(1)[*c]);
    }
    for (c, _) in &positions {
        assert_eq!(turned.frame(0)[*c], facing.frame(0)[*c]);
    }
}

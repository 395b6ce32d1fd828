//! Rig profiles, angle ↔ tick mapping, Euler re-decomposition, the command stage, the budget.

mod common;

use std::path::{Path, PathBuf};

use marionette::budget::plan;
use marionette::command::{CommandError, CommandStage};
use marionette::formats::{amc, asf};
use marionette::math::EulerOrder;
use marionette::profile::{Drive, Profile};
use marionette::rig::{bone_rotation, redecompose, JointSource, Rig, ServoMap};
use marionette::servo::{model_by_name, MODELS};
use proptest::prelude::*;

fn profile_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("firmware-profile")
        .join(name)
}

fn servo(direction: f64, zero: f64, gear: f64) -> ServoMap {
    ServoMap {
        id: 1,
        model: &MODELS[2],
        source: JointSource::Joint(0),
        direction,
        zero_tick: zero,
        gear,
        min_tick: 0,
        max_tick: 4095,
        max_velocity: 1e9,
        max_acceleration: 0.0,
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(5000))]

    /// angle → ticks (rounded) → angle lands within half a tick of the angle.
    #[test]
    fn mapping_round_trip_within_half_a_tick(
        angle in -3.0f64..3.0,
        dir in prop_oneof![Just(1.0), Just(-1.0)],
        zero in 0.0f64..4095.0,
        gear in 0.25f64..4.0,
    ) {
        let s = servo(dir, zero, gear);
        let ticks = s.angle_to_ticks(angle);
        let back = s.ticks_to_angle(f64::from(ticks));
        let half_tick = 0.5 / s.ticks_per_radian().abs();
        prop_assert!((back - angle).abs() <= half_tick * (1.0 + 1e-12), "{angle} -> {ticks} -> {back}");
        // And ticks → angle → ticks is the identity.
        prop_assert_eq!(s.angle_to_ticks(s.ticks_to_angle(f64::from(ticks))), ticks);
    }
}

/// Re-decomposition between every pair of the 12 orders gives the same rotation to 1e-9, and
/// going back gives the original angles to 1e-9 (away from gimbal lock).
#[test]
fn euler_redecomposition_exact_for_all_orders() {
    let mut rng = marionette::bus::faults::Rng::new(7);
    let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let mut worst_matrix = 0.0f64;
    let mut worst_angles = 0.0f64;
    let mut checked = 0;
    for from in EulerOrder::ALL {
        for to in EulerOrder::ALL {
            for _ in 0..500 {
                let mid = if from.is_proper() {
                    uniform(0.05, 3.09)
                } else {
                    uniform(-1.52, 1.52)
                };
                let a = [uniform(-3.1, 3.1), mid, uniform(-3.1, 3.1)];
                let b = redecompose(from, a, to, [0.0; 3]);
                let (ma, mb) = (from.to_mat3_f64(a), to.to_mat3_f64(b));
                let diff = (ma - mb)
                    .to_cols_array()
                    .iter()
                    .fold(0.0f64, |m, x| m.max(x.abs()));
                worst_matrix = worst_matrix.max(diff);
                // Back to `from`, choosing the solution next to the original angles.
                let back = redecompose(to, b, from, a);
                let near_lock = if to.is_proper() {
                    b[1].sin().abs() < 0.05
                } else {
                    b[1].cos().abs() < 0.05
                };
                if !near_lock {
                    let d = (0..3).map(|k| (back[k] - a[k]).abs()).fold(0.0, f64::max);
                    worst_angles = worst_angles.max(d);
                }
                checked += 1;
            }
        }
    }
    println!("{checked} conversions: worst matrix difference {worst_matrix:.2e}, worst angle round trip {worst_angles:.2e} rad");
    assert!(worst_matrix < 1e-9, "matrix difference {worst_matrix}");
    assert!(worst_angles < 1e-9, "angle round trip {worst_angles}");
}

/// The shipped profiles load and say what the issue asks.
#[test]
fn shipped_profiles_load() {
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let puppet = Profile::load(&profile_path("cmu-puppet.toml")).unwrap();
    assert!(
        (24..=32).contains(&puppet.servos.len()),
        "{} servos",
        puppet.servos.len()
    );
    let rig = puppet.rig(Some(&skel)).unwrap();
    assert_eq!(rig.len(), puppet.servos.len());
    for m in MODELS.iter() {
        assert!(
            puppet.servos.iter().any(|s| s.model.name == m.name),
            "puppet uses {}",
            m.name
        );
    }
    for part in [
        "lowerback",
        "lowerneck",
        "humerus",
        "radius",
        "femur",
        "tibia",
        "foot",
    ] {
        assert!(
            puppet
                .servos
                .iter()
                .any(|s| matches!(&s.drive, Drive::Bone { bone, .. } if bone.contains(part))),
            "{part}"
        );
    }
    assert!(rig
        .servos
        .iter()
        .any(|s| matches!(s.source, JointSource::Redecomposed { .. })));

    let op3 = Profile::load(&profile_path("robotis-op3.toml")).unwrap();
    assert_eq!(op3.bus.baud, 2_000_000);
    assert_eq!(op3.servos.len(), 20);
    let names = [
        "r_sho_pitch",
        "l_sho_pitch",
        "r_sho_roll",
        "l_sho_roll",
        "r_el",
        "l_el",
        "r_hip_yaw",
        "l_hip_yaw",
        "r_hip_roll",
        "l_hip_roll",
        "r_hip_pitch",
        "l_hip_pitch",
        "r_knee",
        "l_knee",
        "r_ank_pitch",
        "l_ank_pitch",
        "r_ank_roll",
        "l_ank_roll",
        "head_pan",
        "head_tilt",
    ];
    for (k, s) in op3.servos.iter().enumerate() {
        assert_eq!(s.id as usize, k + 1);
        assert_eq!(s.name, names[k]);
        assert_eq!(s.model.name, "XM430-W350");
        assert_eq!(s.drive, Drive::Joint(names[k].to_string()));
    }
    let rig = op3.rig(None).unwrap();
    assert_eq!(rig.servos[4].source, JointSource::Joint(4));
}

/// On a real clip, the puppet's re-decomposed shoulder angles rebuild the humerus rotation
/// exactly and stay continuous from frame to frame.
#[test]
fn puppet_shoulders_follow_the_walk() {
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let profile = Profile::load(&profile_path("cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let humerus = skel.find("lhumerus").unwrap();
    let shoulder: Vec<usize> = (0..rig.len())
        .filter(
            |&k| matches!(rig.servos[k].source, JointSource::Redecomposed { bone, .. } if bone == humerus),
        )
        .collect();
    assert_eq!(shoulder.len(), 3);
    let mut angles = vec![0.0; rig.len()];
    let mut previous: Option<Vec<f64>> = None;
    let mut worst = 0.0f64;
    let mut biggest_step = 0.0f64;
    for f in 0..motion.len() {
        let channels = marionette::motion::frame_to_radians(&skel, motion.frame(f));
        rig.joint_angles(&skel, &channels, &[], &mut angles);
        let mut zyx = [0.0; 3];
        for &k in &shoulder {
            let JointSource::Redecomposed { slot, .. } = rig.servos[k].source else {
                unreachable!()
            };
            zyx[slot] = angles[k];
        }
        let rebuilt = EulerOrder::ZYX.to_mat3_f64(zyx);
        let want = bone_rotation(&skel, humerus, &channels).unwrap();
        worst = worst.max(
            (rebuilt - want)
                .to_cols_array()
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs())),
        );
        // Frames 0–1 of 16_15 are a left-arm dropout (all zeros; docs/motion-and-ik.md, BVH): the
        // capture itself jumps into frame 2, so steps are measured from frame 3 on.
        if let (Some(p), true) = (&previous, f >= 3) {
            for &k in &shoulder {
                biggest_step = biggest_step.max((angles[k] - p[k]).abs());
            }
        }
        previous = Some(angles.clone());
    }
    println!(
        "lhumerus ZYX over {} frames: worst rebuild {worst:.2e}, largest step {:.2}°",
        motion.len(),
        biggest_step.to_degrees()
    );
    assert!(worst < 1e-9);
    assert!(
        biggest_step.to_degrees() < 10.0,
        "a jump of {}°",
        biggest_step.to_degrees()
    );
}

fn one_servo_rig(max_velocity: f64, max_acceleration: f64) -> Rig {
    let mut rig = Rig::default();
    let mut s = servo(1.0, 2048.0, 1.0);
    s.min_tick = 1024;
    s.max_tick = 3072;
    s.max_velocity = max_velocity;
    s.max_acceleration = max_acceleration;
    rig.servos.push(s).unwrap();
    rig
}

#[test]
fn command_stage_rejects_non_finite_and_keeps_the_last_command() {
    let rig = one_servo_rig(4096.0, 0.0);
    let mut stage = CommandStage::new(1);
    stage.start_from(&rig, &[2048]);
    let (t, _) = stage.command(&rig, &[0.1], 0.01).unwrap();
    let before = t.to_vec();
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        assert_eq!(
            stage.command(&rig, &[bad], 0.01).unwrap_err(),
            CommandError::NotFinite { servo: 0 }
        );
        assert_eq!(stage.last(), &before[..]);
    }
    assert_eq!(
        stage.command(&rig, &[0.1, 0.2], 0.01).unwrap_err(),
        CommandError::WrongLength { got: 2, want: 1 }
    );
    assert_eq!(
        stage.command(&rig, &[0.1], f64::NAN).unwrap_err(),
        CommandError::BadTimeStep
    );
}

#[test]
fn command_stage_clamps_and_limits_velocity_and_acceleration() {
    // Position limits.
    let rig = one_servo_rig(1e9, 0.0);
    let mut stage = CommandStage::new(1);
    stage.start_from(&rig, &[2048]);
    let (t, lim) = stage.command(&rig, &[10.0], 0.01).unwrap();
    assert_eq!((t[0], lim.clamped), (3072, 1));
    let (t, _) = stage.command(&rig, &[-10.0], 0.01).unwrap();
    assert_eq!(t[0], 1024);

    // Velocity: 1000 ticks/s at 100 Hz is 10 ticks per tick.
    let rig = one_servo_rig(1000.0, 0.0);
    let mut stage = CommandStage::new(1);
    stage.start_from(&rig, &[2048]);
    let target = rig.servos[0].ticks_to_angle(2548.0);
    let mut last = 2048;
    let mut ticks = 0;
    while last != 2548 {
        let (t, _) = stage.command(&rig, &[target], 0.01).unwrap();
        assert!((t[0] - last).abs() <= 10, "{} -> {}", last, t[0]);
        last = t[0];
        ticks += 1;
        assert!(ticks < 1000);
    }
    assert_eq!(ticks, 50);

    // Acceleration: speeds change by at most a·dt per tick, and it stops at the target
    // without overshoot.
    let rig = one_servo_rig(2000.0, 10_000.0);
    let mut stage = CommandStage::new(1);
    stage.start_from(&rig, &[1100]);
    let target = rig.servos[0].ticks_to_angle(3000.0);
    let (dt, mut prev_p, mut prev_v) = (0.002, 1100.0f64, 0.0f64);
    let mut peak = 0.0f64;
    for _ in 0..5000 {
        let (t, _) = stage.command(&rig, &[target], dt).unwrap();
        let p = f64::from(t[0]);
        let v = (p - prev_p) / dt;
        assert!(
            (v - prev_v).abs() <= 10_000.0 * dt + 2.0 / dt,
            "acceleration {}",
            (v - prev_v) / dt
        );
        assert!(p <= 3000.0, "overshoot to {p}");
        peak = peak.max(v);
        prev_p = p;
        prev_v = v;
    }
    assert_eq!(prev_p, 3000.0);
    assert!(peak <= 2000.0 + 1.0 / dt, "peak velocity {peak}");
}

/// A correction (IMU feedback) rides on the goals sent: the path the stage keeps, which a
/// planner continues from, is the same with and without it; what is sent keeps within the
/// position limits and moves no faster than the velocity limit; taken away, it fades out at
/// that speed.
#[test]
fn a_correction_rides_on_the_goals_sent_within_the_limits_and_stays_out_of_the_path() {
    // 1000 ticks/s at 100 Hz: 10 ticks per tick.
    let rig = one_servo_rig(1000.0, 0.0);
    let (mut plain, mut corrected) = (CommandStage::new(1), CommandStage::new(1));
    plain.start_from(&rig, &[2000]);
    corrected.start_from(&rig, &[2000]);
    let mut previous = 2000;
    let mut path = 2000.0;
    for k in 0..230 {
        // A path climbing 5 ticks a tick towards the upper limit, and a correction that
        // swings ±40 ticks, faster than the servo.
        path += 5.0;
        let correction = if (k / 3) % 2 == 0 { 40.0 } else { -40.0 };
        corrected.set_correction(&[correction]);
        let (sent, _) = corrected.command_planned(&rig, &[path], 0.01).unwrap();
        let sent = sent[0];
        let (unc, _) = plain.command_planned(&rig, &[path], 0.01).unwrap();
        let unc = unc[0];
        assert_eq!(corrected.state(0), plain.state(0), "tick {k}: the path moved");
        assert!((1024..=3072).contains(&sent), "tick {k}: {sent}");
        assert!((sent - previous).abs() <= 10, "tick {k}: {previous} → {sent}");
        assert!((sent - unc).abs() <= 41, "tick {k}: {sent} against {unc}");
        previous = sent;
    }
    // At the upper limit the path stands at 3072 and the correction cannot push past it.
    assert_eq!(plain.last()[0], 3072);
    corrected.set_correction(&[40.0]);
    for _ in 0..10 {
        let (sent, _) = corrected.command_planned(&rig, &[3072.0], 0.01).unwrap();
        assert!(sent[0] <= 3072);
    }
    assert_eq!(corrected.last()[0], 3072);
    // Taken away: back on the path within the velocity limit.
    corrected.set_correction(&[-40.0]);
    for _ in 0..10 {
        corrected.command_planned(&rig, &[3072.0], 0.01).unwrap();
    }
    assert_eq!(corrected.last()[0], 3032);
    corrected.set_correction(&[]);
    let (sent, _) = corrected.command_planned(&rig, &[3072.0], 0.01).unwrap();
    assert_eq!(sent[0], 3042);
    for _ in 0..3 {
        corrected.command_planned(&rig, &[3072.0], 0.01).unwrap();
    }
    assert_eq!(
        (corrected.last()[0], corrected.applied_correction()[0]),
        (3072, 0.0)
    );
}

/// Each kind of profile error is reported with its line and what was expected.
#[test]
fn profile_errors_name_the_line() {
    let good = std::fs::read_to_string(profile_path("robotis-op3.toml")).unwrap();
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let servo_line = |text: &str, n: usize| -> u32 {
        text.lines()
            .enumerate()
            .filter(|(_, l)| l.trim() == "[[servo]]")
            .nth(n)
            .map(|(i, _)| i as u32 + 1)
            .unwrap()
    };
    // (description, edited text, expected line, words in the message)
    let mut cases: Vec<(&str, String, u32, &str)> = Vec::new();
    let first = servo_line(&good, 0);
    let second = servo_line(&good, 1);
    cases.push((
        "syntax",
        good.replacen("baud = 2_000_000", "baud = = 2", 1),
        line_of(&good, "baud ="),
        "expected",
    ));
    cases.push((
        "unknown key",
        good.replacen("usb_latency_us", "usb_latency", 1),
        line_of(&good, "usb_latency_us"),
        "unknown field",
    ));
    cases.push((
        "bad baud",
        good.replacen("baud = 2_000_000", "baud = 2_500_000", 1),
        line_of(&good, "baud ="),
        "baud rate",
    ));
    cases.push((
        "unknown model",
        good.replacen("model = \"XM430-W350\"", "model = \"XM999\"", 1),
        first + 3,
        "unknown servo model",
    ));
    cases.push((
        "duplicate id",
        good.replacen("id = 2\n", "id = 1\n", 1),
        second + 1,
        "duplicate id 1",
    ));
    cases.push((
        "id range",
        good.replacen("id = 2\n", "id = 253\n", 1),
        second + 1,
        "0…252",
    ));
    cases.push((
        "duplicate name",
        good.replacen("name = \"l_sho_pitch\"", "name = \"r_sho_pitch\"", 1),
        second + 2,
        "duplicate servo name",
    ));
    cases.push((
        "limit outside range",
        good.replacen("min_deg = -179", "min_deg = -200", 1),
        first + 6,
        "outside the servo's range",
    ));
    cases.push((
        "max below min",
        good.replacen("max_deg = 179", "max_deg = -179.5", 1),
        first + 7,
        "max_deg > min_deg",
    ));
    cases.push((
        "direction",
        good.replacen("zero = 2048\n", "zero = 2048\ndirection = 2\n", 1),
        first + 6,
        "direction 1 or -1",
    ));
    cases.push((
        "too fast",
        good.replacen("max_velocity_dps = 270", "max_velocity_dps = 900", 1),
        first + 8,
        "reaches at most",
    ));
    cases.push((
        "no drive",
        good.replacen("joint = \"r_sho_pitch\"\n", "", 1),
        first,
        "needs `bone",
    ));
    cases.push((
        "both drives",
        good.replacen(
            "joint = \"r_sho_pitch\"",
            "joint = \"r_sho_pitch\"\nbone = \"lfemur.rx\"",
            1,
        ),
        first + 4,
        "either",
    ));
    cases.push((
        "same joint twice",
        good.replacen("joint = \"l_sho_pitch\"", "joint = \"r_sho_pitch\"", 1),
        second + 4,
        "already drives",
    ));
    cases.push((
        "bad dof",
        good.replacen("joint = \"r_sho_pitch\"", "bone = \"lfemur.tx\"", 1),
        first + 4,
        "bone.rx|ry|rz",
    ));
    for (what, text, line, words) in &cases {
        let err = Profile::parse(text, Path::new("op3.toml")).expect_err(what);
        assert_eq!(err.line, *line, "{what}: {err:?}");
        assert!(err.message.contains(words), "{what}: {}", err.message);
    }
    // Bones are checked against the skeleton, at the servo's line.
    let puppet = std::fs::read_to_string(profile_path("cmu-puppet.toml")).unwrap();
    let p1 = servo_line(&puppet, 0);
    for (edit, words) in [
        (
            puppet.replacen("bone = \"lowerback.rx\"", "bone = \"lowerbak.rx\"", 1),
            "unknown bone `lowerbak`",
        ),
        (
            puppet.replacen("bone = \"ltibia.rx\"", "bone = \"ltibia.rz\"", 1),
            "has no DOF `rz`",
        ),
    ] {
        let p = Profile::parse(&edit, Path::new("puppet.toml")).unwrap();
        let err = p.rig(Some(&skel)).unwrap_err().to_string();
        assert!(err.contains(words), "{err}");
        if words.starts_with("unknown") {
            assert!(err.starts_with(&format!("puppet.toml:{p1}:")), "{err}");
        }
    }
    // Through the CLI: file:line: message, exit code 1.
    let dir = std::env::temp_dir().join(format!("marionette-profile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    std::fs::write(&bad, good.replacen("id = 2\n", "id = 1\n", 1)).unwrap();
    let out = common::bin()
        .args(["profile", bad.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains(&format!("bad.toml:{}:", second + 1)) && stderr.contains("duplicate id"),
        "{stderr}"
    );
    assert!(model_by_name("XM430-W350-R").is_some());
}

fn line_of(text: &str, needle: &str) -> u32 {
    text.lines().position(|l| l.contains(needle)).unwrap() as u32 + 1
}

/// `marionette budget robotis-op3.toml --json` against a hand computation:
/// Sync Write 14 + 5·20 = 114 B, Sync Read request 14 + 20 = 34 B, replies 20 · 15 = 300 B;
/// 448 B · 10 bit / 2 Mbit/s = 2240 µs; return delay 0; USB latency 1000 µs → 3240 µs, 308.6 Hz.
#[test]
fn budget_matches_hand_computation() {
    let out = common::bin()
        .args([
            "budget",
            profile_path("robotis-op3.toml").to_str().unwrap(),
            "--json",
            "--rate",
            "125",
        ])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["servos"], 20);
    assert_eq!(v["bytes_per_cycle"], 114 + 34 + 300);
    assert!((v["wire_time_us"].as_f64().unwrap() - 2240.0).abs() < 1e-9);
    assert!((v["max_rate_hz"].as_f64().unwrap() - 1e6 / 3240.0).abs() < 1e-9);
    assert_eq!(v["feasible"], true);

    // FACTS.md figures: N = 20 at 4.5 Mbps, RDT 0, no USB latency → 1.00 ms; N = 31 → 1.51 ms;
    // with the default 500 µs return delay N = 20 stays below ~90 Hz.
    let mut bus = Profile::load(&profile_path("robotis-op3.toml")).unwrap().bus;
    bus.baud = 4_500_000;
    bus.usb_latency_us = 0;
    assert!((plan(&bus, 20, None).wire_time_us - 995.6).abs() < 0.1);
    assert!((plan(&bus, 31, None).wire_time_us - 1508.9).abs() < 0.1);
    bus.return_delay_us = 500;
    bus.usb_latency_us = 1000;
    let b = plan(&bus, 20, Some(125.0));
    assert!(b.max_rate_hz < 90.0 && b.max_rate_hz > 80.0, "{}", b.max_rate_hz);
    assert_eq!(b.feasible, Some(false));
}

/// `budget --measure` serves the chain with line time and times the loop's bus work through
/// the real client; `serve` serves it until its duration. (The figures are printed, not
/// judged: the machine is shared.)
#[test]
fn budget_measures_cycles_on_the_line_timed_chain_and_serve_serves_it() {
    let measure = || {
        common::bin()
            .args([
                "budget",
                profile_path("robotis-op3.toml").to_str().unwrap(),
                "--measure",
                "50",
                "--json",
            ])
            .output()
            .unwrap()
    };
    // The start-up's pings go through a pty served by a thread: on a loaded machine (tests run
    // in parallel on two cores) a reply can miss its margin once (seen in CI). Asked again
    // then; a second miss fails.
    let mut out = measure();
    if !out.status.success() && String::from_utf8_lossy(&out.stderr).contains("no reply in time") {
        out = measure();
    }
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    println!("{v}");
    assert_eq!(v["cycles"].as_u64().unwrap() + v["failed"].as_u64().unwrap(), 50);
    assert!((v["planned_cycle_us"].as_f64().unwrap() - 3240.0).abs() < 1e-9);
    // Never faster than the wire, served or in process.
    assert!(v["measured_p50_us"].as_f64().unwrap() >= 0.99 * 3240.0);
    assert_eq!(
        v["in_process"]["cycles"].as_u64().unwrap() + v["in_process"]["failed"].as_u64().unwrap(),
        50
    );
    assert!(v["in_process"]["measured_p50_us"].as_f64().unwrap() >= 0.99 * 3240.0);

    // A profile that reads with Fast Sync Read: the loop's bus is then the project's own host
    // over the port (dynamixel2 0.9.1 has no Fast Sync Read); measured, and played.
    let dir = common::tempdir("fast-sync-profile");
    let fast = dir.join("puppet-fast.toml");
    let text = std::fs::read_to_string(profile_path("cmu-puppet.toml")).unwrap();
    assert!(text.contains("read = \"sync\""));
    std::fs::write(&fast, text.replace("read = \"sync\"", "read = \"fast-sync\"")).unwrap();
    let out = common::bin()
        .args(["budget", fast.to_str().unwrap(), "--measure", "50", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    println!("{v}");
    // The write 14 + 5 · 28, the request 14 + 28, one reply of 8 + 8 · 28: 428 B at 4 Mbps
    // (1070 µs) + 1 ms USB latency.
    assert!(
        (v["planned_cycle_us"].as_f64().unwrap() - 2070.0).abs() < 1e-9,
        "{v}"
    );
    assert!(v["cycles"].as_u64().unwrap() >= 45, "{v}");
    assert!(v["measured_p50_us"].as_f64().unwrap() >= 0.99 * 2070.0);
    let out = common::bin()
        .args(["play", fast.to_str().unwrap()])
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--rate", "200", "--duration", "1", "-q"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("torque off, acknowledged by 28 servos"), "{text}");

    let out = common::bin()
        .args([
            "serve",
            profile_path("cmu-puppet.toml").to_str().unwrap(),
            "--duration",
            "0.2",
        ])
        .output()
        .unwrap();
    assert!(out.status.success());
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("28 virtual servos on /dev/pts/"), "{text}");
    assert!(
        text.contains("line time of 4000000 bit/s and a 1000 µs USB latency"),
        "{text}"
    );
    let out = common::bin()
        .args([
            "serve",
            profile_path("cmu-puppet.toml").to_str().unwrap(),
            "--duration",
            "-1",
        ])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
}

/// The inverse mapping (the effector fidelity): servo angles back to a skeleton frame.
/// For every frame of the walk on the puppet (direct channels and re-decomposed bones), the
/// frame the servos' angles stand for poses every bone the servos move exactly as the source.
#[test]
fn servo_angles_map_back_to_the_frame_they_came_from() {
    use marionette::fk::{fk64, Pose64};
    let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skeleton, &common::data("16_15.amc")).unwrap();
    let profile = Profile::load(&profile_path("cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skeleton)).unwrap();
    assert!(rig
        .servos
        .iter()
        .any(|s| matches!(s.source, JointSource::Redecomposed { .. })));
    let mut angles = vec![0.0; rig.len()];
    let mut back = vec![0.0; skeleton.channel_count()];
    let (mut a, mut b) = (Pose64::default(), Pose64::default());
    let mut worst = 0.0f64;
    for frame in motion.frames() {
        let source = marionette::motion::frame_to_radians(&skeleton, frame);
        rig.joint_angles(&skeleton, &source, &[], &mut angles);
        rig.channels_from_angles(&skeleton, &angles, &source, &mut back);
        fk64(&skeleton, &source, &mut a);
        fk64(&skeleton, &back, &mut b);
        for i in 0..skeleton.len() {
            worst = worst.max((a.tip[i] - b.tip[i]).length());
        }
        // A servo turned by 0.1 rad moves the frame: the inverse is not just the source.
        let mut turned = angles.clone();
        turned[0] += 0.1;
        rig.channels_from_angles(&skeleton, &turned, &source, &mut back);
        assert_ne!(back, source);
    }
    assert!(worst < 1e-9, "tips moved by {worst} units");
}

/// The look-ahead's plans through the command stage under 10⁶ random source angles —
/// a random walk, jumps, NaN, infinities, ±1e300 and angles far outside the limits, with and
/// without extrapolation, leads from none to 100 ms, at 500 Hz and 1 kHz (each servo replanned
/// every second tick, and every fourth or, with the default 0.19 s window, every eighth, going
/// on at its plan in between): no command outside
/// the limits, none faster than the velocity limit, none accelerating harder than the
/// acceleration limit (a tick of rounding aside).
#[test]
fn planned_commands_keep_every_limit_under_random_input() {
    use marionette::control::lookahead::LookaheadSettings;
    let every_fourth = LookaheadSettings {
        min_window_s: 0.0,
        ..LookaheadSettings::default()
    };
    for (rate, settings) in [
        (500.0, LookaheadSettings::default()),
        (1000.0, every_fourth),
        // The default window (0.19 s) at 1 kHz: replanned every eighth tick.
        (1000.0, LookaheadSettings::default()),
    ] {
        planned_commands_keep_every_limit(rate, settings, 1_000_000 / 2);
    }
}

fn planned_commands_keep_every_limit(
    rate: f64,
    settings: marionette::control::lookahead::LookaheadSettings,
    angles: usize,
) {
    use marionette::control::lookahead::{Lookahead, Preview, SampleHead};
    let mut rng = marionette::bus::faults::Rng::new(17);
    let mut uniform = |lo: f64, hi: f64| lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
    let limited = |direction: f64, gear: f64, lo: i32, hi: i32, v: f64, a: f64| ServoMap {
        min_tick: lo,
        max_tick: hi,
        max_velocity: v,
        max_acceleration: a,
        ..servo(direction, 2048.0, gear)
    };
    let mut rig = Rig::default();
    for s in [
        limited(1.0, 1.0, 1024, 3072, 3000.0, 30_000.0),
        limited(-1.0, 2.0, 1900, 2600, 500.0, 2_000.0),
        limited(1.0, 0.5, 0, 4095, 6000.0, 200_000.0),
    ] {
        rig.servos.push(s).unwrap();
    }
    let dt = 1.0 / rate;
    let period = (1e9 / rate) as u64;
    let look = Lookahead::new(&rig, rate, &[0.0, 0.02, 0.1], settings);
    let ahead = look.preview_ns() / period + 1;
    let mut look = look;
    let mut preview = Preview::new(ahead as usize + 8, rig.len(), 0);
    let mut stage = CommandStage::new(3);
    let rest: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    stage.start_from(&rig, &rest);
    let mut walk = [0.0f64; 3];
    let (mut before, mut last) = (rest.clone(), rest.clone());
    let inputs = angles / 3 + 1;
    let mut commands = 0u64;
    let (mut at_limit, mut fastest) = (0u64, [0.0f64; 3]);
    for k in 0..inputs as u64 {
        let head = SampleHead {
            due_ns: (k + ahead) * period,
            ..SampleHead::default()
        };
        let mut angles = [0.0; 3];
        for (s, w) in walk.iter_mut().enumerate() {
            *w = match (rng_pick(&mut uniform), k % 5000 < 2500) {
                (p, _) if p < 0.01 => f64::NAN,
                (p, _) if p < 0.015 => f64::INFINITY,
                (p, _) if p < 0.02 => f64::NEG_INFINITY,
                (p, _) if p < 0.025 => 1e300 * uniform(-1.0, 1.0),
                (p, _) if p < 0.05 => uniform(-10.0, 10.0),
                (_, true) => (*w + uniform(-0.05, 0.05)).clamp(-2.0, 2.0),
                (_, false) => 0.6 * (k as f64 * 0.01 + s as f64).sin(),
            };
            // Non-finite values stay in the sample; the walk goes on from a finite one.
            angles[s] = *w;
            if !w.is_finite() || w.abs() > 10.0 {
                *w = 0.0;
            }
        }
        preview.push(head, &angles, &[], &[]);
        preview.advance(k * period + period / 2);
        preview.live = k % 3 == 0;
        let targets = look
            .targets(&rig, &stage, &preview, k * period, dt, None)
            .to_vec();
        let (goals, _) = stage.command_planned(&rig, &targets, dt).expect("finite targets");
        commands += 1;
        for (j, (servo, &g)) in rig.servos.iter().zip(goals).enumerate() {
            assert!(
                (servo.min_tick..=servo.max_tick).contains(&g),
                "input {k}, servo {j}: goal {g} outside {}…{}",
                servo.min_tick,
                servo.max_tick
            );
            let step = f64::from(g - last[j]);
            let previous = f64::from(last[j] - before[j]);
            at_limit += u64::from(g == servo.min_tick || g == servo.max_tick);
            fastest[j] = fastest[j].max(step.abs() / (servo.max_velocity * dt));
            assert!(
                step.abs() <= servo.max_velocity * dt + 1.0,
                "input {k}, servo {j}: {step} ticks in one tick"
            );
            assert!(
                (step - previous).abs() <= servo.max_acceleration * dt * dt + 2.0,
                "input {k}, servo {j}: step {previous} → {step}"
            );
        }
        before = std::mem::replace(&mut last, goals.to_vec());
    }
    assert_eq!(commands * 3, inputs as u64 * 3);
    assert!(inputs * 3 >= angles);
    // The input did push the plans against the limits.
    println!(
        "{rate} Hz, {settings:?}: goals at a position limit: {at_limit}; fastest step / velocity limit: {fastest:?}"
    );
    // (Planning over the longer window, the goals stop just short of the limits.)
    assert!(at_limit > 50 || settings.min_window_s > 0.1, "{at_limit}");
    assert!(fastest.iter().all(|&f| f > 0.9), "{fastest:?}");
}

/// A number in 0…1 from the test's generator.
fn rng_pick(uniform: &mut impl FnMut(f64, f64) -> f64) -> f64 {
    uniform(0.0, 1.0)
}

/// `identify --write`: `lag_ms` replaced where it is, added at the end of an entry where it is
/// not, only in the entries named; comments and layout kept; the result loads.
#[test]
fn lags_are_written_into_a_profile_keeping_its_text() {
    use marionette::profile::set_servo_lags;
    // The shipped profile without its lags.
    let shipped = std::fs::read_to_string(profile_path("cmu-puppet.toml")).unwrap();
    let mut text: String = shipped
        .lines()
        .filter(|l| !l.starts_with("lag_ms"))
        .collect::<Vec<_>>()
        .join("\n");
    text.push('\n');
    assert!(text.len() < shipped.len(), "the shipped profile has lags");
    let once = set_servo_lags(&text, &[("ltibia_rx".into(), 21.5), ("head_rx".into(), 3.0)]);
    let twice = set_servo_lags(&once, &[("ltibia_rx".into(), 30.0)]);
    assert_eq!(once.lines().count(), text.lines().count() + 2);
    assert_eq!(twice.lines().count(), once.lines().count());
    assert!(twice.contains("lag_ms = 30\n") && twice.contains("lag_ms = 3\n"));
    assert!(!twice.contains("lag_ms = 21.5"));
    // Every other line is as it was, comments included.
    let kept: Vec<&str> = twice.lines().filter(|l| !l.starts_with("lag_ms")).collect();
    assert_eq!(kept, text.lines().collect::<Vec<_>>());
    let dir = common::tempdir("lags");
    let path = dir.join("cmu-puppet.toml");
    std::fs::write(&path, &twice).unwrap();
    let p = Profile::load(&path).unwrap();
    let lag = |n: &str| p.servos.iter().find(|s| s.name == n).unwrap().lag_ms;
    assert_eq!(
        (lag("ltibia_rx"), lag("head_rx"), lag("rtibia_rx")),
        (Some(30.0), Some(3.0), None)
    );
    // A lag out of range is an error with its line.
    std::fs::write(&path, set_servo_lags(&text, &[("ltibia_rx".into(), -1.0)])).unwrap();
    let e = Profile::load(&path).unwrap_err().to_string();
    assert!(e.contains("expected a lag in 0…1000 ms, found -1"), "{e}");
    // So is a supply the model cannot take (an XM430 at 24 V), and a speed above the model's
    // no-load speed at its supply (the W210 knee at 12 V: 462°/s).
    let e_v = text.replacen("supply_v = 14.8", "supply_v = 24", 1);
    std::fs::write(&path, e_v).unwrap();
    let e = Profile::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("expected a supply of 10…14.8 V for the XM430-W210, found 24"),
        "{e}"
    );
    let fast = text.replacen("supply_v = 14.8\n", "", 1).replacen(
        "max_velocity_dps = 440",
        "max_velocity_dps = 500",
        1,
    );
    std::fs::write(&path, fast).unwrap();
    let e = Profile::load(&path).unwrap_err().to_string();
    assert!(
        e.contains("XM430-W210 reaches at most 462 joint °/s at gear 1 and 12 V, found 500"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

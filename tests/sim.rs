//! The MuJoCo simulator in the loop (built with `--features sim`, MuJoCo from
//! `sim/fetch-mujoco.sh`): the generated puppet against forward kinematics, the CMU walk
//! streamed in lockstep (tracking, determinism), the ROBOTIS OP3 standing and moving its arms,
//! and `play` over a pseudo-terminal served by `marionette sim serve`.
#![cfg(feature = "sim")]

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::Stdio;
use std::sync::Arc;

use glam::{DQuat, DVec3};
use marionette::bus::{start_up, ServoBus};
use marionette::control::input::input_channel;
use marionette::control::lockstep::FeedingClock;
use marionette::control::source::{ClipSource, Grid};
use marionette::control::sources::ClipPlayer;
use marionette::control::{Controller, LoopConfig, RunEnd, Solve, StopMode, StopRequests};
use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, asf};
use marionette::profile::Profile;
use marionette::rig::JointSource;
use marionette::schedule::{Clock, Schedule};
use marionette::sim::mjcf::{puppet, PuppetOptions};
use marionette::sim::plant::{sim_bus, SimBus};
use marionette::sim::report::TrackingReport;
use marionette_sim::World;

fn repo(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn report(bus: &SimBus, profile: &Profile) -> TrackingReport {
    let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
    bus.with(|t| {
        let p = t.plant();
        TrackingReport::new(
            p.samples(),
            &names,
            p.saturated_steps(),
            &p.site_names(),
            p.steps(),
        )
    })
}

/// The generated model's hinges reproduce the skeleton's forward kinematics: at a walk frame
/// (DOFs without a servo at 0), every leaf bone's tip site sits where `fk64` puts that tip.
#[test]
fn generated_puppet_matches_forward_kinematics() {
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let profile = Profile::load(&repo("firmware-profile/cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let options = PuppetOptions::default();
    let xml = puppet(&skel, &profile, &rig, &options).unwrap();
    let mut world = World::from_xml_str(&xml).unwrap();
    // Keep only the DOFs the puppet has: channels of served bones' DOFs, all of a re-decomposed bone.
    let mut served = vec![false; skel.channel_count()];
    for m in &rig.servos {
        match m.source {
            JointSource::Channel(c) => served[c] = true,
            JointSource::Redecomposed { bone, .. } => {
                for c in skel.bones()[bone].channels() {
                    served[c] = true;
                }
            }
            JointSource::Joint(_) => unreachable!(),
        }
    }
    let unit = f64::from(skel.units().meters_per_unit()) * options.scale;
    let up = DQuat::from_rotation_x(core::f64::consts::FRAC_PI_2);
    let mut worst = 0.0f64;
    for frame in [0, 150, 300, 470] {
        let channels: Vec<f64> = motion
            .frame(frame)
            .iter()
            .enumerate()
            .map(|(c, v)| if served[c] { v.to_radians() } else { 0.0 })
            .collect();
        let mut angles = vec![0.0; rig.len()];
        rig.joint_angles(&skel, &channels, &[], &mut angles);
        for (spec, a) in profile.servos.iter().zip(&angles) {
            let j = world.joint(&spec.name).unwrap();
            world.set_joint_position(j, *a);
        }
        world.forward();
        let mut pose = Pose64::default();
        fk64(&skel, &channels, &mut pose);
        let root = DVec3::from(world.body_position(world.body("root").unwrap()));
        for s in 0..world.site_count() {
            let name = world.site_name(s).unwrap().to_string();
            let b = skel.find(&name).unwrap();
            let want = root + up * ((pose.tip[b] - pose.start[0]) * unit);
            let got = DVec3::from(world.site_position(s));
            worst = worst.max((got - want).length());
        }
    }
    println!("largest tip difference, MuJoCo vs fk64: {:.2e} m", worst);
    assert!(worst < 1e-5, "{worst}");
}

/// Streams the bundled 16_15 walk at 120 Hz through the loop into the simulated puppet in
/// lockstep; returns the tracking report, the final joint state and the loop's statistics.
fn walk_in_lockstep() -> (TrackingReport, Vec<f64>, u64, RunEnd) {
    let skel = Arc::new(asf::load(&common::data("16.asf")).unwrap().skeleton);
    let motion = Arc::new(amc::load(&skel, &common::data("16_15.amc")).unwrap());
    let profile = Profile::load(&repo("firmware-profile/cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let xml = puppet(&skel, &profile, &rig, &PuppetOptions::default()).unwrap();
    let mut bus = sim_bus(World::from_xml_str(&xml).unwrap(), &profile, &rig).unwrap();
    let present = start_up(&mut bus, profile.bus_section()).unwrap();
    bus.with(|t| t.plant_mut().record(true));
    let (tx, port) = input_channel(16);
    let config = LoopConfig {
        rate_hz: 120.0,
        stop: StopMode::Hold { hold_s: 0.0 },
        ..LoopConfig::default()
    };
    let mut c = Controller::new(
        Arc::clone(&skel),
        rig,
        profile.ids(),
        &present,
        port,
        Solve::Frames,
        config,
    );
    let period = c.period_ns();
    let start = bus.now_ns() + period;
    let player = ClipPlayer::new(Arc::clone(&skel), motion, 120.0, false);
    let feed = Box::new(ClipSource::new(player, None));
    let grid = Grid {
        start_ns: start,
        period_ns: period,
    };
    let mut clock = FeedingClock::new(bus.clone(), feed, tx, grid);
    let mut schedule = Schedule::new(start, period);
    let end = c.run(&mut schedule, &mut bus, &mut clock, &StopRequests::new());
    assert_eq!(clock.report().sent, 471);
    let qpos = bus.with(|t| t.plant().world().qpos().to_vec());
    (report(&bus, &profile), qpos, c.stats.inputs_used, end)
}

#[test]
fn puppet_tracks_the_walk_in_lockstep_within_3_degrees_and_repeats_exactly() {
    let (a, qpos_a, used, end) = walk_in_lockstep();
    print!("{a}");
    assert_eq!(end, RunEnd::InputEnded);
    assert_eq!(used, 471, "every sample of the walk reached the servos");
    assert!(
        a.samples > 3800,
        "{} samples (1 kHz over the 3.92 s clip)",
        a.samples
    );
    assert!(a.rms_deg <= 3.0, "tracking RMS over all servos {:.2}°", a.rms_deg);
    // The servos really moved with the walk (knees through tens of degrees).
    let knee = a.servos.iter().find(|s| s.name == "ltibia_rx").unwrap();
    assert!(knee.commanded_range_deg > 50.0, "{}", knee.commanded_range_deg);
    let (b, qpos_b, _, _) = walk_in_lockstep();
    assert_eq!(
        qpos_a, qpos_b,
        "the same run twice ends in the same state, bit for bit"
    );
    assert_eq!(a.rms_deg.to_bits(), b.rms_deg.to_bits());
    assert_eq!(a.saturated_steps, b.saturated_steps);
    for (x, y) in a.servos.iter().zip(&b.servos) {
        assert_eq!(x.rms_deg.to_bits(), y.rms_deg.to_bits(), "{}", x.name);
    }
}

/// The OP3 on the floor, every servo up through the real start-up sequence, goals sent at the
/// OP3's own 125 Hz: `script(t)` gives the joint angles (radians, profile order) at time t.
fn op3_run(seconds: f64, script: impl Fn(f64, &str) -> f64) -> (SimBus, Profile, Vec<(f64, f64, f64)>) {
    let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
    let rig = profile.rig(None).unwrap();
    let world = World::from_file(&repo("sim/models/robotis_op3/scene.xml")).unwrap();
    let mut bus = sim_bus(world, &profile, &rig).unwrap();
    start_up(&mut bus, profile.bus_section()).unwrap();
    bus.with(|t| t.plant_mut().record(true));
    let ids = profile.ids();
    let torso = bus.with(|t| t.plant().world().site("torso").unwrap());
    let body = bus.with(|t| t.plant().world().body("body_link").unwrap());
    let period = 8_000_000u64;
    let start = bus.now_ns() + period;
    let mut trace = Vec::new();
    let mut present = vec![0i32; ids.len()];
    for k in 0..(seconds * 125.0) as u64 {
        bus.wait_until(start + k * period);
        let t = k as f64 * 0.008;
        let goals: Vec<i32> = profile
            .servos
            .iter()
            .zip(&rig.servos)
            .map(|(s, m)| m.angle_to_ticks(script(t, &s.name)).clamp(m.min_tick, m.max_tick))
            .collect();
        bus.write_goals(&ids, &goals).unwrap();
        bus.read_positions(&ids, &mut present).unwrap();
        let (height, tilt) = bus.with(|tr| {
            let w = tr.plant().world();
            let r = w.body_rotation(body);
            // The body's z axis against the world's: r is row-major, column 2 is (r[2], r[5], r[8]).
            (
                w.site_position(torso)[2],
                r[8].clamp(-1.0, 1.0).acos().to_degrees(),
            )
        });
        trace.push((t, height, tilt));
    }
    (bus, profile, trace)
}

/// The simulated robot is held until the controller first turns a torque on (as a real one is
/// held while its controller starts): two seconds of limp servos leave it where it stood; with
/// torque on it stands on its servos; torque off again, it folds.
#[test]
fn a_simulated_robot_is_held_until_the_first_torque_on() {
    let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
    let rig = profile.rig(None).unwrap();
    let world = World::from_file(&repo("sim/models/robotis_op3/scene.xml")).unwrap();
    let mut bus = sim_bus(world, &profile, &rig).unwrap();
    let torso = bus.with(|t| t.plant().world().site("torso").unwrap());
    let height = |bus: &SimBus| bus.with(|t| t.plant().world().site_position(torso)[2]);
    let stood = height(&bus);
    let now = bus.now_ns();
    bus.wait_until(now + 2_000_000_000);
    assert_eq!(height(&bus), stood, "limp servos before any torque-on: held");
    start_up(&mut bus, profile.bus_section()).unwrap();
    let now = bus.now_ns();
    bus.wait_until(now + 1_000_000_000);
    let standing = height(&bus);
    // It settles from where the model places it onto the floor, on straight legs.
    assert!(
        (standing - stood).abs() < 0.03,
        "on its servos: {stood} → {standing} m"
    );
    for id in profile.ids() {
        bus.set_torque(id, false).unwrap();
    }
    let now = bus.now_ns();
    bus.wait_until(now + 2_000_000_000);
    let folded = height(&bus);
    assert!(
        folded < standing - 0.05,
        "limp after torque off: {standing} → {folded} m"
    );
}

#[test]
fn op3_stands_upright_for_5_seconds() {
    let (_, _, trace) = op3_run(5.0, |_, _| 0.0);
    let (min_h, max_tilt) = trace
        .iter()
        .skip(63) // after half a second of settling onto the floor
        .fold((f64::INFINITY, 0.0f64), |(h, a), x| (h.min(x.1), a.max(x.2)));
    let last = trace.last().unwrap();
    println!(
        "OP3 standing 5 s: torso height min {min_h:.3} m, last {:.3} m; tilt max {max_tilt:.2}°, last {:.2}°",
        last.1, last.2
    );
    assert!(min_h > 0.25, "torso height {min_h}");
    assert!(max_tilt < 5.0, "tilt {max_tilt}°");
}

#[test]
fn op3_tracks_a_scripted_arm_motion_within_3_degrees() {
    // Shoulders and elbows wave (0.25 Hz), legs hold the standing pose.
    let wave = |t: f64, name: &str| {
        let s = (core::f64::consts::TAU * 0.25 * t).sin();
        let ramp = (t / 1.0).min(1.0);
        ramp * match name {
            "r_sho_pitch" | "l_sho_pitch" => 0.7 * s,
            "r_sho_roll" => -0.3 - 0.3 * s,
            "l_sho_roll" => 0.3 + 0.3 * s,
            "r_el" | "l_el" => 0.5 * s,
            _ => 0.0,
        }
    };
    let (bus, profile, trace) = op3_run(8.0, wave);
    let r = report(&bus, &profile);
    print!("{r}");
    let arms = [
        "r_sho_pitch",
        "l_sho_pitch",
        "r_sho_roll",
        "l_sho_roll",
        "r_el",
        "l_el",
    ];
    let arm: Vec<_> = r
        .servos
        .iter()
        .filter(|s| arms.contains(&s.name.as_str()))
        .collect();
    assert_eq!(arm.len(), 6);
    let rms = (arm.iter().map(|s| s.rms_deg * s.rms_deg).sum::<f64>() / 6.0).sqrt();
    println!("arm tracking RMS {rms:.2}°");
    for s in &arm {
        assert!(
            s.commanded_range_deg > 30.0,
            "{} moved {}°",
            s.name,
            s.commanded_range_deg
        );
    }
    assert!(rms <= 3.0, "arm tracking RMS {rms:.2}°");
    let max_tilt = trace.iter().skip(63).map(|x| x.2).fold(0.0f64, f64::max);
    assert!(
        max_tilt < 10.0,
        "the robot stayed up while waving: tilt {max_tilt}°"
    );
}

/// `marionette sim serve` puts the simulated puppet on a pseudo-terminal; `marionette play`
/// drives it there through `dynamixel2`, in real time, and prints the loop's statistics.
#[test]
fn play_drives_the_simulator_served_on_a_pty() {
    let mut serve = common::bin()
        .args(["sim", "serve"])
        .arg(repo("firmware-profile/cmu-puppet.toml"))
        .arg(common::data("16.asf"))
        .args(["--duration", "30"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(serve.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    assert!(first.contains("28 simulated servos"), "{first}");
    let path = lines.next().unwrap().unwrap();
    assert!(path.starts_with("/dev/"), "{path}");
    let out = common::bin()
        .arg("play")
        .arg(repo("firmware-profile/cmu-puppet.toml"))
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--bus", &path, "--rate", "120", "-q", "--ramp", "0.2"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let _ = serve.kill();
    let _ = serve.wait();
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(text.contains("28 servos up, torque on"), "{text}");
    assert!(text.contains("tick compute"), "{text}");
    assert!(text.contains("tracking        rms"), "{text}");
    assert!(text.contains("ended: end of input; torque off"), "{text}");
}

/// `play --bus sim`: lockstep from the command line, with the tracking report and the picture.
#[test]
fn play_bus_sim_writes_the_report_and_the_picture() {
    let dir = std::env::temp_dir().join(format!("marionette-sim-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("tracking.json");
    let svg = dir.join("tracking.svg");
    let out = common::bin()
        .arg("play")
        .arg(repo("firmware-profile/cmu-puppet.toml"))
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--bus", "sim", "--rate", "120", "-q"])
        .arg("--sim-report")
        .arg(&json)
        .arg("--sim-plot")
        .arg(&svg)
        .args(["--plot-servos", "ltibia_rx,lfemur_rx"])
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(text.contains("lockstep on simulated time"), "{text}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["servos"].as_array().unwrap().len(), 28);
    assert!(v["rms_deg"].as_f64().unwrap() <= 3.0);
    // The loop's end-to-end figures per servo, beside the simulator's own.
    for servo in v["servos"].as_array().unwrap() {
        let rms = servo["source_rms_deg"].as_f64().expect("source_rms_deg");
        assert!(
            rms.is_finite() && servo["source_lag_ms"].as_f64().is_some(),
            "{servo}"
        );
    }
    let picture = std::fs::read_to_string(&svg).unwrap();
    assert!(picture.contains("ltibia_rx") && picture.contains("RMS tracking error per servo"));
    assert!(
        picture.contains("source (the clip through the rig)"),
        "the source curve"
    );
    // A profile of robot joints with a model it does not fit: a one-line error, exit 1.
    let bad = common::bin()
        .arg("play")
        .arg(repo("firmware-profile/cmu-puppet.toml"))
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--bus", "sim", "--model"])
        .arg(repo("sim/models/robotis_op3/scene.xml"))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(1), "{err}");
    assert!(err.contains("has no actuator in the model"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The OP3's kinematic tree read from its MJCF: every body's frame and the centre
/// of mass equal MuJoCo's own kinematics to 1e-6 m on random joint angles (scene.xml, through
/// its include), the floating base where the model puts it.
#[test]
fn op3_kinematics_from_mjcf_equal_mujocos() {
    use marionette::bus::faults::Rng;
    use marionette::formats::mjcf;
    use marionette::robot::RobotPose;

    let path = repo("sim/models/robotis_op3/scene.xml");
    let model = mjcf::load(&path).unwrap();
    let robot = &model.robot;
    assert!(model.floating);
    assert_eq!(robot.joints().len(), 20);
    assert!(model.without_inertial.is_empty(), "{:?}", model.without_inertial);
    let mut world = World::from_file(&path).unwrap();
    assert!(
        (robot.mass() - world.total_mass()).abs() < 1e-9,
        "{} vs {}",
        robot.mass(),
        world.total_mass()
    );
    let joints: Vec<usize> = robot
        .joints()
        .iter()
        .map(|j| {
            world
                .joint(&j.name)
                .unwrap_or_else(|| panic!("MuJoCo has no joint {}", j.name))
        })
        .collect();
    let bodies: Vec<usize> = robot
        .bodies()
        .iter()
        .map(|b| world.body(&b.name).unwrap())
        .collect();
    let sites: Vec<usize> = robot
        .sites()
        .iter()
        .map(|s| world.site(&s.name).unwrap())
        .collect();
    assert_eq!(sites.len(), 5, "the OP3 model's named sites");
    let mut worst_site = 0.0f64;
    let mut rng = Rng::new(16);
    let mut pose = RobotPose::default();
    let (mut worst_pos, mut worst_com, mut worst_rot) = (0.0f64, 0.0f64, 0.0f64);
    for _ in 0..200 {
        let q: Vec<f64> = robot
            .joints()
            .iter()
            .map(|j| {
                let (lo, hi) = j.range.unwrap_or((-std::f64::consts::PI, std::f64::consts::PI));
                lo + (hi - lo) * (rng.below(1 << 30) as f64 / f64::from(1u32 << 30))
            })
            .collect();
        world.reset();
        for (&mj, &a) in joints.iter().zip(&q) {
            world.set_joint_position(mj, a);
        }
        world.forward();
        robot.forward(DVec3::ZERO, DQuat::IDENTITY, &q, &mut pose);
        for (k, &mj) in sites.iter().enumerate() {
            let p = DVec3::from_array(world.site_position(mj));
            worst_site = worst_site.max((p - robot.site_position(&pose, k)).length());
        }
        for (i, &mj) in bodies.iter().enumerate() {
            let p = DVec3::from_array(world.body_position(mj));
            worst_pos = worst_pos.max((p - pose.pos[i]).length());
            let m = world.body_rotation(mj);
            let ours = glam::DMat3::from_quat(pose.rot[i]);
            for r in 0..3 {
                for c in 0..3 {
                    worst_rot = worst_rot.max((m[3 * r + c] - ours.col(c)[r]).abs());
                }
            }
        }
        let com = DVec3::from_array(world.subtree_com(bodies[0]));
        worst_com = worst_com.max((com - robot.centre_of_mass(&pose)).length());
    }
    println!("OP3 vs MuJoCo, 200 random configurations: body position {worst_pos:.2e} m, rotation {worst_rot:.2e}, centre of mass {worst_com:.2e} m");
    println!("sites: {worst_site:.1e} m");
    assert!(worst_pos < 1e-6 && worst_com < 1e-6 && worst_rot < 1e-9 && worst_site < 1e-6);
}

/// Runs `play` on the OP3 in MuJoCo (lockstep, `scene.xml` with its floor) and returns the
/// simulator's report and the stats JSON.
fn op3_on_the_floor(
    asf_name: &str,
    amc: &std::path::Path,
    extra: &[&str],
) -> (serde_json::Value, serde_json::Value) {
    let dir = common::tempdir("op3-floor");
    let (sim_json, stats_json) = (dir.join("sim.json"), dir.join("stats.json"));
    let out = common::bin()
        .arg("play")
        .arg(repo("firmware-profile/robotis-op3.toml"))
        .arg(common::data(asf_name))
        .arg(amc)
        .args(["--bus", "sim", "--model"])
        .arg(repo("sim/models/robotis_op3/scene.xml"))
        .args(["-q", "--sim-report"])
        .arg(&sim_json)
        .arg("--stats-json")
        .arg(&stats_json)
        .args(extra)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read = |p: &std::path::Path| serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap();
    let r = (read(&sim_json), read(&stats_json));
    let _ = std::fs::remove_dir_all(&dir);
    r
}

/// `--upper-body` on the floor — the legs in a stance, arms and head retargeted — with the
/// default flags keeps the OP3 up through the walk and the playground clip, every joint inside
/// its limits; the present position follows the retargeted clip (source → present) within 1°
/// RMS, 10 ms of lag and 10 mm at the hands (the clip planned within the servos' speeds, the
/// look-ahead leading the profile's identified lags); no servo at its torque limit in the
/// first second (the pre-roll's move to the first pose); two runs give the same figures.
#[test]
fn op3_upper_body_on_the_floor_does_not_fall() {
    for (a, m) in [("16.asf", "16_15.amc"), ("01.asf", "01_01.amc")] {
        let (sim, stats) = op3_on_the_floor(a, &common::data(m), &["--upper-body"]);
        println!(
            "{m}: torso {} m, tilt {}°, retarget {}",
            sim["torso_min_height_m"],
            sim["torso_max_tilt_deg"],
            stats["retarget"]["limb_direction_error_deg"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{m}: {sim}");
        assert!(sim["torso_max_tilt_deg"].as_f64().unwrap() <= 15.0, "{m}");
        assert!(sim["fell_at_s"].is_null(), "{m}: {sim}");
        // Standing in place: the torso stays where it stood, the floor's centre of pressure
        // inside the feet's contacts.
        assert!(sim["torso_travel_m"].as_f64().unwrap() < 0.02, "{m}: {sim}");
        assert!(
            sim["zmp_margin_mm"]["measured_min"].as_f64().unwrap() >= -1e-6,
            "{m}: {sim}"
        );
        assert_eq!(stats["commands_refused"].as_u64(), Some(0));
        assert_eq!(stats["retarget"]["foot_slide_mm"]["max"].as_f64(), Some(0.0));
        let f = &stats["fidelity"];
        println!(
            "{m}: fidelity {f}, first second at a torque limit {}",
            sim["saturated_steps_first_s"]
        );
        assert!(f["joint_rms_deg"].as_f64().unwrap() <= 1.0, "{m}: {f}");
        assert!(f["lag_ms"].as_f64().unwrap().abs() <= 10.0, "{m}: {f}");
        assert!(f["effector_rms_mm"].as_f64().unwrap() <= 10.0, "{m}: {f}");
        assert_eq!(sim["saturated_steps_first_s"].as_u64(), Some(0), "{m}: {sim}");
        if m == "16_15.amc" {
            let (again, stats2) = op3_on_the_floor(a, &common::data(m), &["--upper-body"]);
            assert_eq!(sim, again, "two runs differ");
            assert_eq!(stats["retarget"], stats2["retarget"]);
        }
    }
}

/// The whole body on the floor through slow motions — a squat and a weight shift —
/// without falling, the centre of mass inside the support polygon throughout.
#[test]
fn op3_whole_body_squats_and_shifts_its_weight_on_the_floor() {
    for name in ["squat.amc", "weight_shift.amc"] {
        let (sim, stats) = op3_on_the_floor("16.asf", &repo("data/generated").join(name), &[]);
        println!(
            "{name}: torso {} m, tilt {}°, margin {}",
            sim["torso_min_height_m"], sim["torso_max_tilt_deg"], stats["retarget"]["com_margin_mm"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{name}: {sim}");
        assert!(
            stats["retarget"]["com_margin_mm"]["min"].as_f64().unwrap() >= 0.0,
            "{name}"
        );
    }
}

/// Every standing stretch of the playground clip (both feet planted for a second or
/// more, as `retarget` lists them: the crouches before the jumps), whole body on the floor,
/// eased in over 0.5 s from the standing robot and held at the end: no fall, the centre of mass
/// inside the support polygon throughout.
#[test]
fn op3_whole_body_stands_through_the_standing_stretches() {
    use marionette::retarget::{retarget_clip, Options, Setup};
    let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
    let skeleton = asf::load(&common::data("01.asf")).unwrap().skeleton;
    let motion = amc::load(&skeleton, &common::data("01_01.amc")).unwrap();
    let setup = Setup::new(&profile, &skeleton).unwrap();
    let stretches = retarget_clip(&setup, &skeleton, &motion, Options::default())
        .report
        .standing_s;
    assert!(stretches.len() >= 8, "{stretches:?}");
    for [from, to] in stretches {
        let (start, length) = (format!("{from:.3}"), format!("{:.3}", to - from));
        let (sim, stats) = op3_on_the_floor(
            "01.asf",
            &common::data("01_01.amc"),
            &[
                "--start",
                &start,
                "--duration",
                &length,
                "--ease-in",
                "0.5",
                "--on-stop",
                "hold",
                "--ramp",
                "0.01",
            ],
        );
        println!(
            "01_01 {start}+{length}: torso {} m, tilt {}°, margin {}",
            sim["torso_min_height_m"], sim["torso_max_tilt_deg"], stats["retarget"]["com_margin_mm"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{start}: {sim}");
        assert!(
            stats["retarget"]["com_margin_mm"]["min"].as_f64().unwrap() >= 0.0,
            "{start}"
        );
    }
}

/// Plays `amc` walking on its plan on the OP3 in MuJoCo at `rate` Hz, eased in and held at the
/// end, with `extra` options; returns the simulator's report and the stats JSON.
fn op3_walks(
    asf_name: &str,
    amc: &std::path::Path,
    rate: &str,
    extra: &[&str],
) -> (serde_json::Value, serde_json::Value) {
    let mut args = vec![
        "--walk",
        "--rate",
        rate,
        "--ease-in",
        "1",
        "--pre-roll",
        "1",
        "--on-stop",
        "hold",
    ];
    args.extend_from_slice(extra);
    op3_on_the_floor(asf_name, amc, &args)
}

/// The bundled walk on its plan, whole body on the floor, at the OP3 framework's 125 Hz and at
/// 250 Hz: no fall, the torso within 15° of upright, every foot within 20 mm (RMS) of its
/// planned footprint, the torso travelling at least 80 % of the plan's travel, the arms as
/// close to the human's as the kinematic retargeting's (within 2°); two runs identical.
#[test]
fn op3_walks_the_bundled_walk_on_its_plan_in_mujoco() {
    let kinematic = {
        use marionette::retarget::{retarget_clip, Options, Setup};
        let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
        let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
        let motion = amc::load(&skeleton, &common::data("16_15.amc")).unwrap();
        let setup = Setup::new(&profile, &skeleton).unwrap();
        let r = retarget_clip(&setup, &skeleton, &motion, Options::default()).report;
        [
            r.limb_direction_error_deg.left_arm,
            r.limb_direction_error_deg.right_arm,
        ]
        .map(|e| e.map_or(f64::NAN, |e| e.rms))
    };
    for rate in ["125", "250"] {
        let (sim, stats) = op3_walks("16.asf", &common::data("16_15.amc"), rate, &[]);
        println!(
            "16_15 at {rate} Hz: tilt {}°, travel {} of {} m, footsteps {}, zmp {}",
            sim["torso_max_tilt_deg"],
            sim["torso_travel_m"],
            sim["planned_travel_m"],
            sim["footstep_error_mm"],
            sim["zmp_margin_mm"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{rate} Hz: {sim}");
        assert!(sim["torso_max_tilt_deg"].as_f64().unwrap() <= 15.0, "{rate} Hz");
        let steps = &sim["footstep_error_mm"];
        assert!(steps["rms"].as_f64().unwrap() <= 20.0, "{rate} Hz: {steps}");
        assert_eq!(
            steps["matched"].as_u64(),
            sim["footsteps"].as_u64(),
            "{rate} Hz: {steps}"
        );
        let (travel, planned) = (
            sim["torso_travel_m"].as_f64().unwrap(),
            sim["planned_travel_m"].as_f64().unwrap(),
        );
        assert!(
            planned > 0.4 && travel >= 0.8 * planned,
            "{rate} Hz: {travel} of {planned}"
        );
        assert!(sim["zmp_margin_mm"]["planned_min"].as_f64().unwrap() > 25.0);
        assert_eq!(stats["sim"], sim, "the stats JSON carries the simulator's report");
        let arms = &stats["retarget"]["limb_direction_error_deg"];
        for (side, k) in ["left_arm", "right_arm"].iter().zip(kinematic) {
            let walked = arms[side]["rms"].as_f64().unwrap();
            assert!(
                (walked - k).abs() <= 2.0,
                "{side}: {walked}° walking, {k}° kinematic"
            );
        }
        if rate == "125" {
            let (again, _) = op3_walks("16.asf", &common::data("16_15.amc"), rate, &[]);
            assert_eq!(sim, again, "two runs differ");
        }
    }
}

/// Pushed (`--sim-push`): the walking OP3 survives 0.3 N·s sideways in single support and
/// 1 N·s forward standing after the walk; a 3 N·s shove topples it, and the report says when.
#[test]
fn op3_walking_survives_a_push_and_a_shove_topples_it() {
    for (push, falls) in [
        ("2.17,0.3,-90", false),
        ("5.6,1.0,0", false),
        ("2.5,3.0,90", true),
    ] {
        let (sim, _) = op3_walks("16.asf", &common::data("16_15.amc"), "125", &["--sim-push", push]);
        println!(
            "push {push}: tilt {}°, fell {}",
            sim["torso_max_tilt_deg"], sim["fell_at_s"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(falls), "{push}: {sim}");
        if falls {
            // Counted from the first sample (0.26 s of settling before it).
            assert!(sim["fell_at_s"].as_f64().unwrap() > 2.0, "{push}: {sim}");
        }
    }
}

/// A jumping clip (01_01: its flights replaced, a foot kept down through each) and the walk
/// bent into a 45° turn to either side (`transform --turn`), on their plans in MuJoCo at
/// 125 Hz: no fall, the torso within 15° of upright; the turns' feet within 20 mm (RMS) of
/// their footprints.
#[test]
fn op3_walks_a_turn_and_plays_a_jumping_clip_without_falling() {
    let dir = common::tempdir("op3-turns");
    let mut clips = vec![("01.asf", common::data("01_01.amc"))];
    for turn in ["45", "-45"] {
        let path = dir.join(format!("turn{turn}.amc"));
        let out = common::bin()
            .arg("transform")
            .arg(common::data("16.asf"))
            .arg(common::data("16_15.amc"))
            .args(["--turn", turn, "-o"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        clips.push(("16.asf", path));
    }
    for (asf_name, amc) in &clips {
        let (sim, stats) = op3_walks(asf_name, amc, "125", &[]);
        let walk = &stats["retarget"]["walk"];
        println!(
            "{}: tilt {}°, footsteps {} ({} substituted), {}",
            amc.display(),
            sim["torso_max_tilt_deg"],
            walk["footsteps"],
            walk["substituted_steps"],
            sim["footstep_error_mm"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{}: {sim}", amc.display());
        assert!(
            sim["torso_max_tilt_deg"].as_f64().unwrap() <= 15.0,
            "{}",
            amc.display()
        );
        if asf_name == &"16.asf" {
            let steps = &sim["footstep_error_mm"];
            assert!(
                steps["rms"].as_f64().unwrap() <= 20.0,
                "{}: {steps}",
                amc.display()
            );
            assert_eq!(steps["matched"], sim["footsteps"], "{}: {steps}", amc.display());
        }
        if asf_name == &"01.asf" {
            let flights = walk["footstep_plan"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|s| {
                    s["changed"]
                        .as_array()
                        .is_some_and(|c| c.iter().any(|c| c == "flight"))
                })
                .count();
            // A jump's flight: the foot that would lift into it stays down, its landing left
            // out (dropped) or the other foot's next step marked.
            assert!(
                flights > 0 || walk["dropped_steps"].as_u64().unwrap() > 0,
                "{walk}"
            );
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Servos unlike the profile in MuJoCo: the walk on its plan at 125 Hz stands (no fall, the
/// torso within 15° of upright) with every servo 50 % slower (joint damping × 1.5) or 20 %
/// weaker (torque limits × 0.8) than the profile says. On the slower servos the IMU's gyro
/// feedback, read in the servos' Bulk Read with the MPU-9250's offsets and noise on it, puts
/// the feet closer to their footprints than open loop does (on the weaker ones the legs, led
/// by their lags, already land within about 6 mm open loop).
#[test]
fn op3_walks_on_servos_unlike_its_profile_and_the_imu_feedback_helps() {
    let clip = common::data("16_15.amc");
    for extra in [["--sim-lag-scale", "1.5"], ["--sim-torque-scale", "0.8"]] {
        let (sim, _) = op3_walks("16.asf", &clip, "125", &extra);
        println!(
            "{extra:?}: tilt {}°, footsteps {}",
            sim["torso_max_tilt_deg"], sim["footstep_error_mm"]
        );
        assert_eq!(sim["fell"].as_bool(), Some(false), "{extra:?}: {sim}");
        assert!(sim["torso_max_tilt_deg"].as_f64().unwrap() <= 15.0, "{extra:?}");
    }
    let slower = ["--sim-lag-scale", "1.5"];
    let (open, _) = op3_walks("16.asf", &clip, "125", &slower);
    let mut closed_args = slower.to_vec();
    closed_args.extend(["--imu", "feedback", "--sim-imu-errors", "1,3"]);
    let (closed, stats) = op3_walks("16.asf", &clip, "125", &closed_args);
    let imu = &stats["imu"];
    println!(
        "slower servos: footsteps open loop {}, with feedback {}; imu {imu}",
        open["footstep_error_mm"], closed["footstep_error_mm"]
    );
    assert_eq!(closed["fell"].as_bool(), Some(false), "{closed}");
    assert_eq!(imu["merged"].as_bool(), Some(true), "{imu}");
    assert_eq!(imu["reads_failed"].as_u64(), Some(0), "{imu}");
    assert_eq!(imu["stale_ticks"].as_u64(), Some(0), "{imu}");
    assert!(imu["max_offset_deg"].as_f64().unwrap() > 0.1, "{imu}");
    let rms = |r: &serde_json::Value| r["footstep_error_mm"]["rms"].as_f64().unwrap();
    assert!(
        rms(&closed) < rms(&open),
        "{} against {}",
        rms(&closed),
        rms(&open)
    );
}

/// Stopped in the middle of a step (`--duration`), the walking OP3 ramps to its plan's
/// standing stance (`--on-stop rest`) and stands there: no fall, the torso within 10° of
/// upright throughout.
#[test]
fn op3_stopped_mid_walk_ramps_to_a_stance_it_stands_in() {
    let (sim, stats) = op3_on_the_floor(
        "16.asf",
        &common::data("16_15.amc"),
        &[
            "--walk",
            "--rate",
            "125",
            "--ease-in",
            "1",
            "--pre-roll",
            "1",
            "--on-stop",
            "rest",
            "--duration",
            "3.2",
        ],
    );
    println!(
        "stopped mid-walk: tilt {}°, fell {}",
        sim["torso_max_tilt_deg"], sim["fell"]
    );
    assert_eq!(
        stats["end"].as_str(),
        Some("duration reached"),
        "{}",
        stats["end"]
    );
    assert_eq!(sim["fell"].as_bool(), Some(false), "{sim}");
    // The swinging foot is put down first (the plan goes on to its double support), then the
    // ramp: no more tilt than the walk itself has (4.4°).
    assert!(sim["torso_max_tilt_deg"].as_f64().unwrap() <= 6.0, "{sim}");
}

/// Plays the walk on the simulated puppet through the command line (`--bus sim --rate 120
/// --pre-roll 0.5`, plus `extra`); returns the statistics' `fidelity` block.
fn walk_fidelity_in_mujoco(extra: &[&str]) -> serde_json::Value {
    let dir = common::tempdir("fidelity-sim");
    let stats = dir.join("stats.json");
    let out = common::bin()
        .args([
            "play",
            "firmware-profile/cmu-puppet.toml",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
        ])
        .args([
            "--bus",
            "sim",
            "--rate",
            "120",
            "--pre-roll",
            "0.5",
            "-q",
            "--stats-json",
        ])
        .arg(&stats)
        .args(extra)
        .current_dir(repo(""))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("capture dropout: lhumerus frames 1–2"), "{text}");
    let s: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    s["fidelity"].clone()
}

/// Source → present on the simulated puppet at 120 Hz, with the look-ahead and the
/// profile's identified lags: joint RMS ≤ 1.5°, best-aligned lag ≤ 10 ms either way, effector
/// RMS ≤ 10 mm — better than the greedy limiter on every figure — and two runs identical.
#[test]
fn the_walk_in_mujoco_follows_the_source_within_the_fidelity_targets() {
    let planned = walk_fidelity_in_mujoco(&[]);
    let greedy = walk_fidelity_in_mujoco(&["--no-lookahead"]);
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap();
    println!(
        "look-ahead: rms {:.3}°, lag {} ms, effectors {:.1} mm; greedy: rms {:.3}°, lag {} ms, effectors {:.1} mm",
        f(&planned, "joint_rms_deg"),
        f(&planned, "lag_ms"),
        f(&planned, "effector_rms_mm"),
        f(&greedy, "joint_rms_deg"),
        f(&greedy, "lag_ms"),
        f(&greedy, "effector_rms_mm")
    );
    assert!(f(&planned, "joint_rms_deg") <= 1.5, "{planned}");
    assert!(f(&planned, "lag_ms").abs() <= 10.0, "{planned}");
    assert!(f(&planned, "effector_rms_mm") <= 10.0, "{planned}");
    assert!(f(&planned, "samples") > 400.0);
    for k in ["joint_rms_deg", "effector_rms_mm", "joint_max_deg"] {
        assert!(f(&planned, k) < f(&greedy, k), "{k}: {planned} vs {greedy}");
    }
    assert!(f(&greedy, "lag_ms") > 20.0, "{greedy}");
    assert_eq!(
        planned,
        walk_fidelity_in_mujoco(&[]),
        "two runs, the same figures"
    );
}

/// `identify` on the simulated puppet finds each servo's lag over the band of human
/// motion — the values the shipped profile carries — and a bandwidth; the same every run.
#[test]
fn identify_in_mujoco_reproduces_the_profiles_lags() {
    let dir = common::tempdir("identify-sim");
    let json = dir.join("id.json");
    let run = || {
        let out = common::bin()
            .args(["identify", "firmware-profile/cmu-puppet.toml", "data/cmu/16.asf"])
            .args([
                "--bus",
                "sim",
                "--rate",
                "120",
                "--servos",
                "ltibia_rx,lhumerus_rx,head_rx",
                "--json",
            ])
            .arg(&json)
            .current_dir(repo(""))
            .stdin(Stdio::null())
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        v
    };
    let a = run();
    let profile = Profile::load(&repo("firmware-profile/cmu-puppet.toml")).unwrap();
    for r in a.as_array().unwrap() {
        let name = r["name"].as_str().unwrap();
        let lag = r["lag_ms"].as_f64().unwrap();
        let shipped = profile
            .servos
            .iter()
            .find(|s| s.name == name)
            .unwrap()
            .lag_ms
            .unwrap();
        println!(
            "{name}: lag {lag:.1} ms (profile {shipped}), bandwidth {}",
            r["bandwidth_hz"]
        );
        assert!((5.0..60.0).contains(&lag), "{r}");
        assert!((lag - shipped).abs() <= 0.05 + 1e-9, "{name}: {lag} vs {shipped}");
        // Below the −3 dB point within the chirp, or beyond its 8 Hz; low frequencies pass whole.
        assert!(
            r["bandwidth_hz"].as_f64().is_none_or(|b| (2.0..8.0).contains(&b)),
            "{r}"
        );
        let first = &r["frequency_response"][0];
        assert!((first["gain"].as_f64().unwrap() - 1.0).abs() < 0.1, "{r}");
        // The position servo overshoots its step (an underdamped P-controlled hinge).
        assert!(r["overshoot_pct"].as_f64().unwrap() > 5.0, "{r}");
    }
    assert_eq!(a, run(), "the same identification twice");
    let _ = std::fs::remove_dir_all(&dir);
}

/// `sim size` on the walk. With the puppet's knees and ankles on XL430-W250s (the
/// profile before its fix) those four saturate; on XM430-W210s at 12 V the right knee still
/// does; on the shipped XM430-W210s at 14.8 V none does.
#[test]
fn sizing_the_walk_names_the_servos_that_saturate() {
    let shipped = std::fs::read_to_string(repo("firmware-profile/cmu-puppet.toml")).unwrap();
    let at_12_v = shipped.replace("supply_v = 14.8\n", "");
    // The profile before the fix: XL430-W250 knees and ankles at the old limits.
    let before = at_12_v
        .replace("model = \"XM430-W210\"", "model = \"XL430-W250\"")
        .replace("max_velocity_dps = 440", "max_velocity_dps = 300")
        .replace("max_acceleration_dps2 = 9000", "max_acceleration_dps2 = 3000");
    let dir = common::tempdir("size");
    let before_path = dir.join("before.toml");
    std::fs::write(&before_path, before).unwrap();
    let at_12_v_path = dir.join("at-12-v.toml");
    std::fs::write(&at_12_v_path, at_12_v).unwrap();
    let size = |profile: &std::path::Path| {
        let json = dir.join("size.json");
        let out = common::bin()
            .args(["sim", "size"])
            .arg(profile)
            .args([repo("data/cmu/16.asf"), repo("data/cmu/16_15.amc")])
            .arg("--json")
            .arg(&json)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "{text}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        (text, v)
    };
    let saturating = |v: &serde_json::Value| -> Vec<String> {
        v["servos"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|s| s["saturates"].as_bool().unwrap())
            .map(|s| s["name"].as_str().unwrap().to_string())
            .collect()
    };
    let (text, b) = size(&before_path);
    print!("{text}");
    assert_eq!(saturating(&b), ["ltibia_rx", "lfoot_rx", "rtibia_rx", "rfoot_rx"]);
    assert!(
        text.contains("saturating: ltibia_rx, lfoot_rx, rtibia_rx, rfoot_rx"),
        "{text}"
    );
    let (text, twelve) = size(&at_12_v_path);
    print!("{text}");
    assert_eq!(saturating(&twelve), ["rtibia_rx"]);
    let (text, a) = size(&repo("firmware-profile/cmu-puppet.toml"));
    print!("{text}");
    assert!(saturating(&a).is_empty(), "{text}");
    assert!(text.contains("no servo saturates over the 471 frames"), "{text}");
    // Every servo the fix changed uses less of its line than before.
    for (x, y) in b["servos"]
        .as_array()
        .unwrap()
        .iter()
        .zip(a["servos"].as_array().unwrap())
    {
        if x["model"] != y["model"] {
            assert!(y["line_share"].as_f64() < x["line_share"].as_f64(), "{x} → {y}");
        }
        assert!(y["peak_torque_nm"].as_f64().unwrap() < 10.0 && y["rms_torque_nm"].as_f64().unwrap() > 0.0);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The OP3's IMU read over the bus from its OpenCR board in MuJoCo: the torso's tilt it reports
/// is MuJoCo's own (standing through the ease-in and the pre-roll of the walk on its plan).
#[test]
fn the_op3_imu_read_over_the_bus_gives_mujocos_torso_tilt() {
    let (sim, stats) = op3_on_the_floor(
        "16.asf",
        &common::data("16_15.amc"),
        &[
            "--walk",
            "--imu",
            "read",
            "--ease-in",
            "1",
            "--pre-roll",
            "1",
            "--duration",
            "1.5",
            "--on-stop",
            "hold",
        ],
    );
    let imu = &stats["imu"];
    println!("IMU {imu}; MuJoCo's torso tilt {}", sim["torso_max_tilt_deg"]);
    assert_eq!(imu["reads_failed"].as_u64(), Some(0), "{imu}");
    assert!(imu["reads_ok"].as_u64().unwrap() > 100, "{imu}");
    let read = imu["max_tilt_deg"].as_f64().unwrap();
    let simulated = sim["torso_max_tilt_deg"].as_f64().unwrap();
    assert!(
        read > 0.5 && (read - simulated).abs() < 0.5,
        "{read} against {simulated}"
    );
}

/// A long heavy clip heats the servos that carry the load (the thermal model, from the current
/// each draws in MuJoCo): the bundled walk looped for 47 s on the puppet, its servos warm from
/// an earlier run (62 °C). The loaded leg servos heat, the light ones cool towards the air;
/// the health watch ends the run before any servo reaches its Temperature Limit (no
/// overheating error), eases it to rest and turns torque off, naming the servo and why.
#[test]
fn a_long_walk_heats_the_loaded_servos_and_the_health_watch_eases_to_rest_in_time() {
    let dir = common::tempdir("sim-heat");
    let walk = dir.join("walk40.amc");
    let looped = common::bin()
        .arg("loop")
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .arg("-o")
        .arg(&walk)
        .args(["--cycles", "40"])
        .output()
        .unwrap();
    assert!(
        looped.status.success(),
        "{}",
        String::from_utf8_lossy(&looped.stderr)
    );
    let stats_json = dir.join("stats.json");
    let out = common::bin()
        .arg("play")
        .arg(repo("firmware-profile/cmu-puppet.toml"))
        .arg(common::data("16.asf"))
        .arg(&walk)
        .args(["--bus", "sim", "-q", "--sim-servo-temp", "62", "--stats-json"])
        .arg(&stats_json)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let (text, err) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    println!("{text}{err}");
    assert_eq!(out.status.code(), Some(1));
    assert!(
        err.contains("Temperature Limit") && err.contains("eased to rest"),
        "{err}"
    );
    let stats: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&stats_json).unwrap()).unwrap();
    assert_eq!(stats["end"], "servo health");
    assert!(text.contains("torque off, acknowledged by 28 servos"), "{text}");
    let health = &stats["health"];
    let stopped = health["stopped"].as_str().unwrap();
    let servos = health["servos"].as_array().unwrap();
    let named = |s: &serde_json::Value| {
        stopped.starts_with(&format!("id {} {}:", s["id"], s["name"].as_str().unwrap()))
    };
    let culprit = servos.iter().find(|s| named(s)).unwrap();
    let leg = ["femur", "tibia", "foot"];
    assert!(
        leg.iter().any(|b| culprit["name"].as_str().unwrap().contains(b)),
        "{stopped}"
    );
    // Before the clip's end (47 s at 120 Hz), and before the servo's own shutdown.
    assert!(stats["ticks"].as_u64().unwrap() < 5600, "{}", stats["ticks"]);
    assert!(servos.iter().all(|s| s["hardware_error"] == 0));
    // The legs heated; the head and neck, nearly idle, cooled.
    let hottest = |name: &str| {
        servos.iter().find(|s| s["name"] == name).unwrap()["hottest_c"]
            .as_u64()
            .unwrap()
    };
    let last = |name: &str| {
        servos.iter().find(|s| s["name"] == name).unwrap()["temperature_c"]
            .as_u64()
            .unwrap()
    };
    assert!(hottest("rtibia_rx") >= 66, "{}", hottest("rtibia_rx"));
    assert!(last("head_rx") <= 55 && last("lowerneck_rx") <= 55, "{health}");
    let _ = std::fs::remove_dir_all(&dir);
}

//! `calibrate`: a rig whose servos are mounted unlike its profile says (`serve --miscalibrate`,
//! served on a pseudo-terminal with line time) is calibrated from the command line, the test
//! answering as the operator who sees the rig; the zeros, directions and Homing Offsets it
//! writes are the rig's, and the calibrated profile then drives the rig.

mod common;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};

use marionette::bus::virtual_chain::miscalibration;
use marionette::bus::{open, Registers, ServoBus, Wire};
use marionette::calibrate::wrap_safe_zero;
use marionette::profile::Profile;
use marionette::servo::addr;

const SEED: u64 = 7;

fn puppet_copy(dir: &Path) -> PathBuf {
    let path = dir.join("cmu-puppet.toml");
    std::fs::copy(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml"),
        &path,
    )
    .unwrap();
    path
}

/// One served chain at a time: each keeps line time, and two on a two-core machine beside
/// the seeded rigs' test starve each other.
fn one_served() -> std::sync::MutexGuard<'static, ()> {
    static SERVED: std::sync::Mutex<()> = std::sync::Mutex::new(());
    SERVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `serve PROFILE --miscalibrate SEED` and its device path.
fn serve(profile: &Path, seconds: u32) -> (Child, String) {
    serve_with(profile, seconds, &["--miscalibrate", &SEED.to_string()])
}

/// `serve PROFILE EXTRA…` and its device path.
fn serve_with(profile: &Path, seconds: u32, extra: &[&str]) -> (Child, String) {
    let mut child = common::bin()
        .arg("serve")
        .arg(profile)
        .args(extra)
        .args(["--duration", &seconds.to_string()])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    assert!(first.contains("28 virtual servos"), "{first}");
    let path = lines.next().unwrap().unwrap();
    assert!(path.starts_with("/dev/"), "{path}");
    (child, path)
}

/// Servo `id`'s control table in one read, tried again on a busy machine (the served chain is
/// another process). One read for all the items looked at: a late reply to a 4-byte read
/// would pass for the next 4-byte read's.
fn registers(bus: &mut dyn ServoBus, id: u8) -> Registers {
    let mut last = None;
    for _ in 0..10 {
        match Registers::read(bus, id) {
            Ok(r) => return r,
            Err(e) => last = Some(e),
        }
    }
    panic!("id {id}: {last:?}");
}

/// `doctor PROFILE --port PORT`: exit code and report.
fn doctor(profile: &Path, port: &str) -> (Option<i32>, String) {
    let out = common::bin()
        .arg("doctor")
        .arg(profile)
        .args(["--port", port])
        .output()
        .unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
    )
}

fn calibrate(profile: &Path, port: &str, answers: &str, extra: &[&str]) -> std::process::Output {
    let mut child = common::bin()
        .arg("calibrate")
        .arg(profile)
        .args(["--port", port])
        .args(extra)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(answers.as_bytes()).unwrap();
    child.wait_with_output().unwrap()
}

#[test]
fn calibrate_recovers_the_zeros_and_directions_of_a_miscalibrated_rig_and_the_result_drives_it() {
    let _one = one_served();
    let dir = common::tempdir("calibrate");
    let path = puppet_copy(&dir);
    let before = Profile::load(&path).unwrap();
    let truth = miscalibration(SEED, before.servos.len());
    let (mut served, port) = serve(&path, 120);

    // As it was, the profile does not fit the rig: doctor says which servos stand outside
    // their range and the rig cannot run it.
    let (code, text) = doctor(&path, &port);
    assert_eq!(code, Some(1), "{text}");
    assert!(
        text.contains("outside its") && text.contains("marionette calibrate"),
        "{text}"
    );

    // The operator poses the rig (Enter), then watches each joint's move: out the positive
    // way when the servo is mounted turning positive with rising ticks.
    let mut answers = String::from("\n");
    for (_, direction, _) in &truth {
        answers.push_str(if *direction > 0 { "y\n" } else { "n\n" });
    }
    let json = dir.join("calibration.json");
    let out = calibrate(&path, &port, &answers, &["--json", json.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    assert!(text.contains("written into"), "{text}");

    let found: Vec<serde_json::Value> =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let after = Profile::load(&path).unwrap();
    let mut offsets = 0;
    for ((s, c), (horn, direction, _)) in after.servos.iter().zip(&found).zip(&truth) {
        // The horn's tick in the reference pose, whatever Homing Offset was left in it.
        assert_eq!(c["horn"].as_i64(), Some(i64::from(*horn)), "{}", s.name);
        assert_eq!(s.direction, f64::from(*direction), "{}", s.name);
        let homing = s.homing_offset.unwrap_or(0);
        assert_eq!(
            s.zero as i32 - homing,
            *horn,
            "{}: zero less the offset is the horn",
            s.name
        );
        offsets += usize::from(homing != 0);
    }
    // Seed 7 puts some horns where the range would wrap past 0/4095: those get an offset.
    assert!(offsets >= 3, "{offsets} Homing Offsets");
    // Comments and layout stay: only the calibrated keys changed.
    let old = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml"),
    )
    .unwrap();
    let new = std::fs::read_to_string(&path).unwrap();
    let comments = |t: &str| t.lines().filter(|l| l.trim_start().starts_with('#')).count();
    assert_eq!(comments(&old), comments(&new));
    assert_eq!(new.lines().count(), old.lines().count() + offsets);

    // On the rig: every servo is back in the reference pose, reading its new zero (its
    // offset written), torque off.
    {
        let mut bus = open(Wire::Port(port.clone()), &after.bus, after.servos.len()).unwrap();
        for s in &after.servos {
            let r = registers(bus.as_mut(), s.id);
            let at = r.signed(addr::PRESENT_POSITION);
            assert!(
                (at - s.zero as i32).abs() <= 3,
                "{}: at {at}, zero {}",
                s.name,
                s.zero
            );
            assert_eq!(r.value(addr::TORQUE_ENABLE, 1), 0, "{}", s.name);
            let homing = r.signed(addr::HOMING_OFFSET);
            assert_eq!(homing, s.homing_offset.unwrap_or(0), "{}", s.name);
        }
    }

    // The calibrated profile passes doctor and plays the walk on the rig.
    let (code, text) = doctor(&path, &port);
    assert_eq!(code, Some(0), "{text}");
    assert!(!text.contains("Homing Offset"), "{text}");
    // The walk, whole, on the calibrated rig and on a rig as the stock profile says: the same
    // fidelity (source against present).
    let play = |profile: &Path, port: &str, json: &Path| {
        let out = common::bin()
            .arg("play")
            .arg(profile)
            .arg(common::data("16.asf"))
            .arg(common::data("16_15.amc"))
            .args(["--bus", port, "--rate", "120", "-q", "--stats-json"])
            .arg(json)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        println!("{text}{}", String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success());
        assert!(text.contains("28 servos up, torque on"), "{text}");
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap();
        v["fidelity"]["joint_rms_deg"].as_f64().unwrap()
    };
    let calibrated = play(&path, &port, &dir.join("calibrated.json"));
    let _ = served.kill();
    let _ = served.wait();
    let stock = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let (mut served, port) = serve_with(&stock, 60, &[]);
    let usual = play(&stock, &port, &dir.join("usual.json"));
    let _ = served.kill();
    let _ = served.wait();
    println!("source → present RMS: {calibrated:.3}° calibrated, {usual:.3}° on a rig as the profile says");
    // Both runs keep real time on a pseudo-terminal: the margin is the machine's noise (a
    // loaded CI machine moved one by 0.09°). That the calibrated profile turns each joint as
    // the rig is mounted is checked exactly, in the chain's own time, below.
    assert!(calibrated <= 1.5 * usual + 0.2, "{calibrated}° against {usual}°");
}

#[test]
fn calibrate_stopped_by_the_operator_leaves_the_profile_unchanged_and_torque_off() {
    let _one = one_served();
    let dir = common::tempdir("calibrate-stop");
    let path = puppet_copy(&dir);
    let text_before = std::fs::read_to_string(&path).unwrap();
    let profile = Profile::load(&path).unwrap();
    let (mut served, port) = serve(&path, 60);
    // Posed, three joints watched, then stdin closes (nobody at the rig any more).
    let out = calibrate(&path, &port, "\ny\nn\ny\n", &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("calibration stopped") && err.contains("stdin closed"),
        "{err}"
    );
    assert_eq!(std::fs::read_to_string(&path).unwrap(), text_before);
    // "q" stops too.
    let out = calibrate(&path, &port, "\ny\nq\n", &[]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("stopped by the operator"), "{err}");
    assert_eq!(std::fs::read_to_string(&path).unwrap(), text_before);
    // The servos as they were: torque off, the Homing Offsets left in them, horns where they
    // stood.
    let truth = miscalibration(SEED, profile.servos.len());
    let mut bus = open(Wire::Port(port), &profile.bus, profile.servos.len()).unwrap();
    for (s, (horn, _, homing)) in profile.servos.iter().zip(&truth) {
        let r = registers(bus.as_mut(), s.id);
        assert_eq!(r.value(addr::TORQUE_ENABLE, 1), 0, "{}", s.name);
        assert_eq!(r.signed(addr::HOMING_OFFSET), *homing, "{}", s.name);
        let at = r.signed(addr::PRESENT_POSITION);
        assert!((at - homing - horn).abs() <= 3, "{}: at {at}", s.name);
    }
    let _ = served.kill();
    let _ = served.wait();
}

#[test]
fn a_zero_near_the_seam_gets_a_homing_offset_that_centres_the_range() {
    let profile =
        Profile::load(&PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/robotis-op3.toml"))
            .unwrap();
    for s in &profile.servos {
        for direction in [1.0, -1.0] {
            // Mid-turn: the profile's zero alone, no offset.
            assert_eq!(
                wrap_safe_zero(s, 2048, direction).unwrap(),
                (0, 2048),
                "{}",
                s.name
            );
            // At the seam, either side: an offset, and the range then inside 0…4095.
            for horn in [0, 30, 4065, 4095] {
                let (offset, zero) = wrap_safe_zero(s, horn, direction).unwrap();
                assert_eq!(zero - offset, horn);
                let mut spec = s.clone();
                spec.zero = f64::from(zero);
                spec.direction = direction;
                let (lo, hi) = spec.tick_limits();
                assert!(lo >= 0 && hi <= 4095, "{}: {lo}…{hi}", s.name);
                if offset == 0 {
                    // Only a joint whose range lies all on one side of 0° fits there.
                    assert!(s.min_deg >= 0.0 || s.max_deg <= 0.0, "{} at {horn}", s.name);
                }
            }
        }
    }
}

/// The operator of a virtual rig who knows how it is really mounted (the seed's truth): says
/// which way a joint turned, and turns one by hand the positive way (its horn moves by the
/// true direction).
struct KnowingOperator {
    rig: marionette::bus::virtual_chain::VirtualRig,
    ids: Vec<u8>,
    truth: Vec<(i32, i8, i32)>,
}

impl KnowingOperator {
    fn direction(&self, id: u8) -> i8 {
        self.truth[self.ids.iter().position(|&i| i == id).unwrap()].1
    }
}

impl marionette::calibrate::Operator for KnowingOperator {
    fn hold_reference_pose(&mut self, _: &str) -> Result<(), marionette::calibrate::CalibrationError> {
        Ok(())
    }
    fn turned_positive(
        &mut self,
        servo: &marionette::profile::ServoSpec,
        _: &str,
    ) -> Result<bool, marionette::calibrate::CalibrationError> {
        Ok(self.direction(servo.id) > 0)
    }
    fn turn_by_hand(
        &mut self,
        servo: &marionette::profile::ServoSpec,
        _: &str,
    ) -> Result<(), marionette::calibrate::CalibrationError> {
        // A few degrees (40 ticks) the positive way: the horn turns as the servo is mounted.
        let d = f64::from(self.direction(servo.id)) * 40.0;
        self.rig.with(|t| {
            let s = t.chain_mut().servo_mut(servo.id).unwrap();
            let at = s.present_tick();
            s.set_position(f64::from(at) + d);
        });
        Ok(())
    }
}

/// The chain's own time passes while a servo moves.
struct ChainTime(marionette::bus::virtual_chain::VirtualRig);

impl marionette::calibrate::Wait for ChainTime {
    fn wait(&mut self, d: std::time::Duration) {
        self.0.with(|t| t.advance(d));
    }
}

/// 100 seeded rigs of each shipped profile, every servo mounted unknown to the profile (its
/// horn anywhere in the turn, either direction, some with a Homing Offset left in them),
/// calibrated in the chain's own time: every horn to the tick, every direction right, by the
/// watched move and (one rig in ten) by hand; afterwards every servo reads its new zero (plus
/// where the hand turned it).
#[test]
fn calibrate_recovers_a_hundred_seeded_rigs_of_both_profiles() {
    use marionette::bus::virtual_chain::{chain_for, miscalibrate, VirtualRig};
    use marionette::calibrate::{calibrate, Directions};
    for name in ["cmu-puppet.toml", "robotis-op3.toml"] {
        let profile = Profile::load(
            &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("firmware-profile")
                .join(name),
        )
        .unwrap();
        let ids = profile.ids();
        let (mut offsets, mut by_hand) = (0, 0);
        for seed in 0..100u64 {
            let truth = miscalibration(seed, ids.len());
            let mut chain = chain_for(profile.bus_section(), |_| 2048);
            miscalibrate(&mut chain, &ids, &truth);
            let rig = VirtualRig::new(chain, profile.bus.baud, std::time::Duration::from_millis(5));
            let mut operator = KnowingOperator {
                rig: rig.clone(),
                ids: ids.clone(),
                truth: truth.clone(),
            };
            let how = if seed % 10 == 9 {
                by_hand += 1;
                Directions::ByHand
            } else {
                Directions::Step
            };
            let mut bus = rig.clone();
            let done = calibrate(
                &mut bus,
                &profile,
                how,
                &mut operator,
                &mut ChainTime(rig.clone()),
            )
            .unwrap_or_else(|e| panic!("{name} seed {seed}: {e}"));
            for (c, (horn, direction, _)) in done.iter().zip(&truth) {
                assert!(
                    (c.horn - horn).abs() <= 1,
                    "{name} seed {seed} {}: horn {} for {horn}",
                    c.name,
                    c.horn
                );
                assert_eq!(c.direction, *direction, "{name} seed {seed} {}", c.name);
                assert_eq!(c.zero - c.homing_offset, c.horn);
                // Every angle in the joint's range lands where the rig as mounted puts it: the
                // calibrated map (ticks less the Homing Offset) is the true one, to a tick.
                let mut spec = profile.servos.iter().find(|s| s.id == c.id).unwrap().clone();
                spec.zero = f64::from(c.zero);
                spec.direction = f64::from(c.direction);
                let map = spec.map(marionette::rig::JointSource::Joint(0));
                for k in 0..=8 {
                    let deg = spec.min_deg + (spec.max_deg - spec.min_deg) * f64::from(k) / 8.0;
                    let ticks = map.angle_to_ticks_exact(deg.to_radians()) - f64::from(c.homing_offset);
                    let truly = f64::from(*horn)
                        + f64::from(*direction) * spec.gear * deg.to_radians() * 4096.0
                            / std::f64::consts::TAU;
                    assert!(
                        (ticks - truly).abs() <= 1.0,
                        "{name} seed {seed} {} at {deg}°: {ticks} for {truly}",
                        c.name
                    );
                }
                offsets += usize::from(c.homing_offset != 0);
                // Back at the reference pose after a watched move; where the hand left it (40
                // ticks the positive way) after one by hand.
                let moved = if how == Directions::ByHand {
                    40 * i32::from(*direction)
                } else {
                    0
                };
                let at = registers(&mut bus, c.id).signed(addr::PRESENT_POSITION);
                assert!(
                    (at - c.zero - moved).abs() <= 1,
                    "{name} seed {seed} {}: at {at}, zero {}",
                    c.name,
                    c.zero
                );
            }
        }
        println!("{name}: 100 rigs, {by_hand} by hand, {offsets} Homing Offsets");
        assert!(offsets > 0);
    }
}

/// The chain's own time passes, and servo `id` overloads at the first wait (as it starts its
/// direction check's move, against a blocked joint): its Hardware Error Status gets `bits`,
/// which turns its torque off.
struct OverloadAtFirstWait {
    rig: marionette::bus::virtual_chain::VirtualRig,
    id: u8,
    waits: u32,
}

impl marionette::calibrate::Wait for OverloadAtFirstWait {
    fn wait(&mut self, d: std::time::Duration) {
        self.waits += 1;
        if self.waits == 1 {
            let id = self.id;
            self.rig
                .with(|t| t.chain_mut().servo_mut(id).unwrap().raise_hardware_error(0x20));
        }
        self.rig.with(|t| t.advance(d));
    }
}

/// [`KnowingOperator`], with servo `overheats` (if any) shutting down with an overheating error
/// while the reference pose is held (`posed`), or else while the operator watches another servo
/// turn.
struct Overheats {
    operator: KnowingOperator,
    overheats: Option<u8>,
    posed: bool,
}

impl Overheats {
    fn overheat(&mut self) {
        if let Some(id) = self.overheats.take() {
            self.operator
                .rig
                .with(|t| t.chain_mut().servo_mut(id).unwrap().raise_hardware_error(0x04));
        }
    }
}

impl marionette::calibrate::Operator for Overheats {
    fn hold_reference_pose(&mut self, pose: &str) -> Result<(), marionette::calibrate::CalibrationError> {
        if self.posed {
            self.overheat();
        }
        self.operator.hold_reference_pose(pose)
    }
    fn turned_positive(
        &mut self,
        servo: &marionette::profile::ServoSpec,
        positive: &str,
    ) -> Result<bool, marionette::calibrate::CalibrationError> {
        if !self.posed {
            self.overheat();
        }
        self.operator.turned_positive(servo, positive)
    }
    fn turn_by_hand(
        &mut self,
        servo: &marionette::profile::ServoSpec,
        positive: &str,
    ) -> Result<(), marionette::calibrate::CalibrationError> {
        self.operator.turn_by_hand(servo, positive)
    }
}

/// A servo that shuts itself down with a hardware error stops calibration with an error
/// naming it, its error and when it was seen (not "it did not move"), every torque off and
/// every servo's offsets and limits as they were: one already shut down before anything moves,
/// one that overheats while the pose is held (named before the first move, though it is not the
/// servo about to move), one that overheats while another is checked (named before it moves),
/// one that overloads while its direction is checked.
#[test]
fn calibrate_stops_on_a_servos_hardware_error_naming_it() {
    use marionette::bus::virtual_chain::{chain_for, VirtualRig};
    use marionette::calibrate::{calibrate, CalibrationError, Directions};
    let profile = Profile::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("firmware-profile")
            .join("cmu-puppet.toml"),
    )
    .unwrap();
    let ids = profile.ids();
    let truth = miscalibration(SEED, ids.len());
    for when in [
        "before calibration",
        "while the reference pose was held",
        "before it moved",
        "while it moved",
    ] {
        let mut chain = chain_for(profile.bus_section(), |_| 2048);
        marionette::bus::virtual_chain::miscalibrate(&mut chain, &ids, &truth);
        let rig = VirtualRig::new(chain, profile.bus.baud, std::time::Duration::from_millis(5));
        let mut bus = rig.clone();
        let before: Vec<(i32, i32, i32)> = ids
            .iter()
            .map(|&id| {
                let r = registers(&mut bus, id);
                (
                    r.signed(addr::HOMING_OFFSET),
                    r.signed(addr::MAX_POSITION_LIMIT),
                    r.signed(addr::MIN_POSITION_LIMIT),
                )
            })
            .collect();
        // The servo at fault: the first one moved for its direction check, or another.
        let id = match when {
            "before calibration" => ids[2],
            "while the reference pose was held" => ids[5],
            "before it moved" => ids[3],
            _ => ids[0],
        };
        if when == "before calibration" {
            rig.with(|t| t.chain_mut().servo_mut(id).unwrap().raise_hardware_error(0x04));
        }
        let mut operator = Overheats {
            operator: KnowingOperator {
                rig: rig.clone(),
                ids: ids.clone(),
                truth: truth.clone(),
            },
            overheats: matches!(when, "while the reference pose was held" | "before it moved").then_some(id),
            posed: when == "while the reference pose was held",
        };
        let mut clock = OverloadAtFirstWait {
            rig: rig.clone(),
            id,
            waits: if when == "while it moved" { 0 } else { 1 },
        };
        let e = calibrate(&mut bus, &profile, Directions::Step, &mut operator, &mut clock).unwrap_err();
        println!("{e}");
        let CalibrationError::HardwareError {
            id: named,
            ref name,
            bits,
            when: seen,
        } = e
        else {
            panic!("{e}");
        };
        let spec = profile.servos.iter().find(|s| s.id == id).unwrap();
        let (want_bits, want_text) = if when == "while it moved" {
            (0x20, "hardware error 0x20 (overload)")
        } else {
            (0x04, "hardware error 0x04 (overheating)")
        };
        assert_eq!(
            (named, name, bits, seen),
            (id, &spec.name, want_bits, when),
            "{e}"
        );
        assert!(e.to_string().contains(want_text), "{e}");
        assert!(e.to_string().contains(when), "{e}");
        assert!(e.to_string().contains("doctor PROFILE --fix"), "{e}");
        assert!(rig.with(|t| t.chain().servos().iter().all(|v| !v.torque_on())));
        for (&id, saved) in ids.iter().zip(&before) {
            let r = registers(&mut bus, id);
            let now = (
                r.signed(addr::HOMING_OFFSET),
                r.signed(addr::MAX_POSITION_LIMIT),
                r.signed(addr::MIN_POSITION_LIMIT),
            );
            assert_eq!(&now, saved, "id {id}");
        }
    }
}

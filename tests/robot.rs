//! A robot's kinematic tree from MJCF (`marionette::formats::mjcf`) and its FK and centre of
//! mass (`marionette::robot`). Against MuJoCo itself: `tests/sim.rs`.

mod common;

use glam::{DQuat, DVec3};
use marionette::formats::mjcf;
use marionette::robot::RobotPose;

fn write(dir: &std::path::Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

/// Defaults and childclass, degrees, euler sequences, and an include, resolved as MuJoCo does.
#[test]
fn defaults_angles_and_includes_resolve_as_mujoco_does() {
    let dir = common::tempdir("mjcf");
    write(
        &dir,
        "arm.xml",
        r#"<mujoco><worldbody>
  <body name="base" pos="0 0 1" euler="0 0 90">
    <inertial pos="0 0 0.1" mass="2"/>
    <body name="upper" pos="0.1 0 0" childclass="arm">
      <inertial pos="0.2 0 0" mass="1"/>
      <joint name="shoulder"/>
      <body name="lower" pos="0.4 0 0">
        <inertial pos="0.1 0 0" mass="0.5"/>
        <joint name="elbow" class="elbow" pos="0 0 0"/>
      </body>
    </body>
  </body>
</worldbody></mujoco>"#,
    );
    let main = write(
        &dir,
        "robot.xml",
        r#"<mujoco model="test">
  <compiler angle="degree" eulerseq="XYZ"/>
  <default>
    <joint axis="0 1 0"/>
    <default class="arm">
      <joint range="-90 45"/>
      <default class="elbow"><joint axis="0 0 1" range="0 150"/></default>
    </default>
  </default>
  <include file="arm.xml"/>
</mujoco>"#,
    );
    let m = mjcf::load(&main).unwrap();
    let r = &m.robot;
    assert!(!m.floating);
    assert_eq!(r.bodies().len(), 3);
    let shoulder = &r.joints()[r.joint("shoulder").unwrap()];
    assert_eq!(shoulder.axis, DVec3::Y, "the main class's axis");
    let (lo, hi) = shoulder.range.unwrap();
    assert!((lo + 90f64.to_radians()).abs() < 1e-12 && (hi - 45f64.to_radians()).abs() < 1e-12);
    let elbow = &r.joints()[r.joint("elbow").unwrap()];
    assert_eq!(elbow.axis, DVec3::Z, "the nested class's axis");
    assert!((elbow.range.unwrap().1 - 150f64.to_radians()).abs() < 1e-12);
    assert!((r.mass() - 3.5).abs() < 1e-12);
    // The base turned 90° about z: the arm points along y; the shoulder (about y) at 0.
    let mut pose = RobotPose::default();
    r.forward(DVec3::ZERO, DQuat::IDENTITY, &[0.0, 0.0], &mut pose);
    let lower = r.body("lower").unwrap();
    assert!(
        (pose.pos[lower] - DVec3::new(0.0, 0.5, 1.0)).length() < 1e-12,
        "{}",
        pose.pos[lower]
    );
    // The elbow at 90° about the arm's own z turns the forearm's centre by 90°.
    r.forward(
        DVec3::ZERO,
        DQuat::IDENTITY,
        &[0.0, std::f64::consts::FRAC_PI_2],
        &mut pose,
    );
    let com_lower = pose.pos[lower] + pose.rot[lower] * DVec3::new(0.1, 0.0, 0.0);
    assert!(
        (com_lower - DVec3::new(-0.1, 0.5, 1.0)).length() < 1e-12,
        "{com_lower}"
    );
}

/// What a kinematic tree cannot hold, and files that cannot be read: one error naming the
/// file, the line and the element.
#[test]
fn bad_models_name_file_line_and_element() {
    let dir = common::tempdir("mjcf-bad");
    let cases = [
        ("slide.xml", "<mujoco><worldbody>\n<body name=\"a\">\n<joint name=\"j\" type=\"slide\"/>\n</body></worldbody></mujoco>", "slide.xml:3:1: <joint>: joint \"j\": expected a hinge, found type \"slide\""),
        ("broken.xml", "<mujoco><worldbody>\n<body name=\"a\">\n</worldbody></mujoco>", "broken.xml:3:1: expected well-formed XML: expected 'body' tag, not 'worldbody'"),
        ("class.xml", "<mujoco><worldbody>\n<body name=\"a\" childclass=\"nope\"/>\n</worldbody></mujoco>", "class.xml:2:1: <body>: expected a defined class"),
        ("empty.xml", "<mujoco/>", "empty.xml:1: expected a <worldbody> with at least one <body>"),
        ("include.xml", "<mujoco>\n<include file=\"missing.xml\"/>\n</mujoco>", "missing.xml: No such file"),
        ("pos.xml", "<mujoco><worldbody>\n  <body name=\"a\" pos=\"1 2\"/>\n</worldbody></mujoco>", "pos.xml:2:3: <body>: expected pos=\"x y z\", found \"1 2\""),
    ];
    for (name, text, want) in cases {
        let p = write(&dir, name, text);
        let e = mjcf::load(&p).unwrap_err().to_string();
        assert!(e.contains(want), "{name}: {e}\n(wanted {want})");
    }
}

/// The bundled OP3 model without MuJoCo: its 20 servo joints and 21 bodies, all with masses.
#[test]
fn the_op3_model_reads() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sim/models/robotis_op3/op3.xml");
    let m = mjcf::load(&path).unwrap();
    assert!(m.floating);
    assert_eq!(m.robot.bodies().len(), 21);
    assert_eq!(m.robot.joints().len(), 20);
    assert!(m.without_inertial.is_empty());
    for name in ["head_pan", "l_sho_pitch", "r_el", "l_hip_yaw", "r_ank_roll"] {
        assert!(m.robot.joint(name).is_some(), "{name}");
    }
    assert!((m.robot.mass() - 3.0).abs() < 0.5, "OP3 mass {}", m.robot.mass());
}

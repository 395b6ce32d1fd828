//! Readers and writers: round trips, the exact BVH mapping, and the errors bad files get.

mod common;

use marionette::fk::{fk64, forward_kinematics, Pose, Pose64};
use marionette::formats::{amc, asf, bvh, FileError};
use marionette::math::EulerOrder;
use marionette::motion::Motion;
use marionette::skeleton::{Dof, Skeleton, MAX_CHANNELS};
use std::path::Path;

fn load(asf_name: &str, amc_name: &str) -> (asf::AsfFile, Motion) {
    let a = asf::load(&common::data(asf_name)).unwrap();
    let m = amc::load(&a.skeleton, &common::data(amc_name)).unwrap();
    (a, m)
}

fn close(a: f32, b: f32) -> bool {
    a == b || (a - b).abs() < 1e-6
}

fn tips(s: &Skeleton, m: &Motion, frame: usize) -> Pose {
    let mut c = [0.0f32; MAX_CHANNELS];
    let mut p = Pose::new();
    m.channels_into(s, frame, &mut c);
    forward_kinematics(s, &c, &mut p).unwrap();
    p
}

#[test]
fn amc_round_trip_is_identical() {
    for (a, m) in [("16.asf", "16_15.amc"), ("01.asf", "01_01.amc")] {
        let (file, motion) = load(a, m);
        let mut out = Vec::new();
        amc::write(&file.skeleton, &motion, &mut out).unwrap();
        let again = amc::parse(&file.skeleton, std::str::from_utf8(&out).unwrap()).unwrap();
        assert_eq!(again.len(), motion.len());
        assert_eq!(again.first_frame, motion.first_frame);
        let mut worst = 0.0f64;
        for (x, y) in motion.frames().zip(again.frames()) {
            for (a, b) in x.iter().zip(y) {
                worst = worst.max((a - b).abs());
            }
        }
        assert!(worst <= 1e-9, "{m}: {worst}");
        // Written once more, the text is the same byte for byte.
        let mut out2 = Vec::new();
        amc::write(&file.skeleton, &again, &mut out2).unwrap();
        assert_eq!(out, out2);
    }
}

#[test]
fn amc_in_radians_reads_as_the_same_motion() {
    let (file, motion) = load("16.asf", "16_15.amc");
    let text = common::read("16_15.amc");
    let s = &file.skeleton;
    // Rewrite the first 5 frames in radians.
    let mut rad = String::from(":FULLY-SPECIFIED\n:RADIANS\n");
    for i in 0..5 {
        rad.push_str(&format!("{}\n", i + 1));
        for b in s.bones() {
            if b.dofs().is_empty() {
                continue;
            }
            rad.push_str(b.name());
            for (k, d) in b.dofs().iter().enumerate() {
                let v = motion.frame(i)[b.first_channel() + k];
                let v = if d.is_rotation() { v.to_radians() } else { v };
                rad.push_str(&format!(" {v}"));
            }
            rad.push('\n');
        }
    }
    let m2 = amc::parse(s, &rad).unwrap();
    for i in 0..5 {
        for (a, b) in motion.frame(i).iter().zip(m2.frame(i)) {
            assert!((a - b).abs() < 1e-9);
        }
    }
    assert!(text.contains(":DEGREES"));
}

#[test]
fn amc_bones_in_any_order_and_absent_bones_rest() {
    let file = asf::load(&common::data("16.asf")).unwrap();
    let s = &file.skeleton;
    let text = "1\nlfemur 10 20 30\nroot 1 2 3 4 5 6\n2\nroot 0 0 0 0 0 0\n";
    let m = amc::parse(s, text).unwrap();
    assert_eq!(m.len(), 2);
    let f = s.bones()[s.find("lfemur").unwrap()].first_channel();
    assert_eq!(&m.frame(0)[f..f + 3], &[10.0, 20.0, 30.0]);
    assert_eq!(&m.frame(0)[..6], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
    assert!(m.frame(1).iter().all(|v| *v == 0.0), "absent bones are at rest");
}

#[test]
fn asf_write_read_gives_the_same_skeleton() {
    for name in ["16.asf", "01.asf"] {
        let file = asf::load(&common::data(name)).unwrap();
        let mut out = Vec::new();
        asf::write(&file, &mut out).unwrap();
        let again = asf::parse(std::str::from_utf8(&out).unwrap()).unwrap();
        let (a, b) = (&file.skeleton, &again.skeleton);
        assert_eq!(a.len(), b.len());
        for (x, y) in a.bones().iter().zip(b.bones()) {
            assert_eq!(x.name(), y.name());
            assert_eq!(x.parent(), y.parent());
            assert_eq!(x.dofs(), y.dofs());
            assert!(x.direction().abs_diff_eq(y.direction(), 1e-6));
            assert_eq!(x.length(), y.length());
            assert!(x.axis_rotation().abs_diff_eq(y.axis_rotation(), 1e-6));
            for (l, m) in x.limits().iter().zip(y.limits()) {
                assert!(close(l.min, m.min) && close(l.max, m.max));
            }
        }
        assert_eq!(file.name, again.name);
        assert_eq!(file.documentation, again.documentation);
    }
}

/// ASF/AMC → BVH → import: the same pose, bone by bone, to 1e-4 units, on every frame.
#[test]
fn bvh_export_then_import_is_pose_exact() {
    for (a, m) in [("16.asf", "16_15.amc"), ("01.asf", "01_01.amc")] {
        let (file, motion) = load(a, m);
        let s = &file.skeleton;
        let mut out = Vec::new();
        bvh::write(s, &motion, &mut out).unwrap();
        let inches = 1.0 / f64::from(s.units().length);
        let (bfile, bmotion) = bvh::parse(std::str::from_utf8(&out).unwrap(), inches).unwrap();
        let bs = &bfile.skeleton;
        assert_eq!(bmotion.len(), motion.len());
        assert!((bmotion.frame_rate - motion.frame_rate).abs() < 1e-9);
        assert!((bs.units().length - s.units().length).abs() < 1e-6);
        let mut worst = 0.0f32;
        for f in 0..motion.len() {
            let p = tips(s, &motion, f);
            let q = tips(bs, &bmotion, f);
            for (i, b) in s.bones().iter().enumerate() {
                let j = bs.find(b.name()).expect("every bone is a joint");
                worst = worst.max((p.start[i] - q.start[j]).length());
                worst = worst.max((p.tip[i] - q.tip[j]).length());
            }
        }
        assert!(worst < 1e-4, "{m}: {worst}");
    }
}

/// The third-party BVH of the walk has the same skeleton (lengths × 2.54/0.45 cm) and agrees
/// with the AMC pose to millimetres on most frames; it deviates where the converter smoothed
/// capture glitches (frames 2–8: the AMC's left arm is all zeros for two frames).
#[test]
fn third_party_bvh_agrees_with_amc_to_a_few_centimetres() {
    let (file, motion) = load("16.asf", "16_15.amc");
    let s = &file.skeleton;
    let (bfile, bmotion) = bvh::load(&common::data("16_15.bvh"), 1.0 / 2.54).unwrap();
    let bs = &bfile.skeleton;
    let cm = f64::from(s.units().meters_per_unit()) * 100.0;
    for b in s.bones().iter().skip(1) {
        // The BVH has no hip-joint bones: its femurs hang from the root at an offset.
        let Some(j) = bs.find(b.name()) else { continue };
        let len = f64::from(b.length()) * cm;
        assert!(
            (f64::from(bs.bones()[j].length()) - len).abs() < 0.01,
            "{}",
            b.name()
        );
    }
    let mut per_frame = Vec::new();
    for f in 0..motion.len() {
        let p = tips(s, &motion, f);
        let q = tips(bs, &bmotion, f);
        let worst = s
            .bones()
            .iter()
            .enumerate()
            .skip(1)
            .filter_map(|(i, b)| bs.find(b.name()).map(|j| (i, j)))
            .map(|(i, j)| (p.start[i].as_dvec3() * cm - q.start[j].as_dvec3()).length())
            .fold(0.0, f64::max);
        per_frame.push(worst);
    }
    let mut sorted = per_frame.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    assert!(median < 0.5, "median per-frame worst joint {median} cm");
    assert!(per_frame[2] > 10.0, "the smoothed dropout at frame 3 shows");
}

#[test]
fn bvh_import_keeps_channel_values_and_reverses_rotation_order() {
    let text = "HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\n JOINT Arm\n {\n  OFFSET 1 0 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n  End Site\n  {\n   OFFSET 0 2 0\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.01\n1 2 3 10 20 30 40 50 60\n";
    let (file, m) = bvh::parse(text, 1.0).unwrap();
    let s = &file.skeleton;
    assert_eq!(m.frame_rate, 100.0);
    assert_eq!(
        &s.root().order[..],
        &[Dof::Tx, Dof::Ty, Dof::Tz, Dof::Ry, Dof::Rx, Dof::Rz]
    );
    let arm = &s.bones()[s.find("Arm").unwrap()];
    assert_eq!(arm.dofs(), &[Dof::Ry, Dof::Rx, Dof::Rz]);
    assert_eq!(&m.frame(0)[..6], &[1.0, 2.0, 3.0, 30.0, 20.0, 10.0]);
    assert_eq!(&m.frame(0)[arm.channels()], &[60.0, 50.0, 40.0]);
    // The arm's tip: root at (1,2,3) rotated by Rz(10)Rx(20)Ry(30), offset (1,0,0), then
    // Rz(40)Rx(50)Ry(60) applied to the end site (0,2,0).
    let r = |o: EulerOrder, a: [f64; 3]| o.to_mat3_f64(a.map(f64::to_radians));
    let root = r(EulerOrder::YXZ, [30.0, 20.0, 10.0]);
    let joint = root * r(EulerOrder::YXZ, [60.0, 50.0, 40.0]);
    let want =
        glam::DVec3::new(1.0, 2.0, 3.0) + root * glam::DVec3::X + joint * glam::DVec3::new(0.0, 2.0, 0.0);
    let p = tips(s, &m, 0);
    let connector = s
        .find("root_to_Arm")
        .expect("nonzero offset from the root becomes a connector");
    assert!(
        (p.tip[connector].as_dvec3() - (glam::DVec3::new(1.0, 2.0, 3.0) + root * glam::DVec3::X)).length()
            < 1e-5
    );
    assert!((p.tip[s.find("Arm").unwrap()].as_dvec3() - want).length() < 1e-5);
}

fn parse_err(asf_text: &str) -> String {
    match asf::parse(asf_text) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

const MINI: &str = ":version 1.10\r\n:name mini\r\n:units\r\n  mass 1.0\r\n  length 0.45\r\n  angle deg\r\n:root\r\n  order TX TY TZ RX RY RZ\r\n  axis XYZ\r\n  position 0 0 0\r\n  orientation 0 0 0\r\n:bonedata\r\n  begin\r\n    id 1\r\n    name a\r\n    direction 0 1 0\r\n    length 2\r\n    axis 0 0 0 XYZ\r\n    dof rx ry rz\r\n    limits (-10 10)\r\n           (-20 20)\r\n           (-inf inf)\r\n  end\r\n  begin\r\n    id 2\r\n    name b\r\n    direction 1 0 0\r\n    length 1.5e0\r\n    axis 0 0 90 XYZ\r\n    dof rx\r\n    limits (0.0 170.0)\r\n  end\r\n:hierarchy\r\n  begin\r\n    root a\r\n    a b\r\n  end\r\n";

#[test]
fn asf_reads_crlf_limits_over_lines_and_inf() {
    let f = asf::parse(MINI).unwrap();
    let s = &f.skeleton;
    assert_eq!(s.len(), 3);
    let a = &s.bones()[1];
    assert_eq!(a.limits()[0].min, (-10.0f32).to_radians());
    assert_eq!(a.limits()[2].max, f32::INFINITY);
    assert_eq!(s.bones()[2].length(), 1.5);
}

#[test]
fn asf_errors_name_line_column_and_what_was_expected() {
    let cases: &[(&str, &str, &str)] = &[
        (
            "    root a\r\n",
            "    root a\r\n    b a\r\n",
            "36:7: bone 'a' is given a second parent",
        ),
        (
            "    a b\r\n",
            "    a zz\r\n",
            "36:7: unknown bone 'zz' in :hierarchy",
        ),
        (
            "    a b\r\n",
            "    a b\r\n    b a\r\n",
            "37:7: bone 'a' is given a second parent",
        ),
        (
            "    root a\r\n    a b\r\n",
            "    a b\r\n    b a\r\n",
            "is not connected to the root",
        ),
        (
            "    name b\r\n",
            "    name a\r\n",
            "26:10: bone 'a' is defined twice",
        ),
        (
            "    length 1.5e0\r\n",
            "    length abc\r\n",
            "28:12: expected a bone length from 0 to 1e9, found 'abc'",
        ),
        (
            "    length 1.5e0\r\n",
            "    length 1e40\r\n",
            "28:12: expected a bone length from 0 to 1e9, found '1e40'",
        ),
        ("    length 1.5e0\r\n", "", "24:3: bone 'b' has no 'length'"),
        (
            "    limits (0.0 170.0)\r\n",
            "    limits (0.0 170.0) (1 2)\r\n",
            "the number of limits differs",
        ),
        (
            "    limits (0.0 170.0)\r\n",
            "    limits (0.0 NaN)\r\n",
            "31:17: expected a limit (number between -1e9 and 1e9, or inf), found 'NaN'",
        ),
        (
            "    axis 0 0 90 XYZ\r\n",
            "    axis 0 0 90 XYQ\r\n",
            "29:17: expected an Euler order such as XYZ, found 'XYQ'",
        ),
        (
            "    dof rx\r\n",
            "    dof rx qq\r\n",
            "30:12: expected a DOF (rx ry rz tx ty tz l), each once, found 'qq'",
        ),
        (
            "  angle deg\r\n",
            "  angle grad\r\n",
            "6:9: expected deg or rad, found 'grad'",
        ),
        (":name mini\r\n", ":nmae mini\r\n", "2:1: expected an ASF section"),
    ];
    for (from, to, want) in cases {
        assert!(MINI.contains(from), "{from}");
        let text = MINI.replacen(from, to, 1);
        let got = parse_err(&text);
        assert!(
            got.contains(want),
            "replacing {from:?} by {to:?}: got '{got}', want '{want}'"
        );
    }
    assert!(parse_err("").contains("the file is empty"));
}

#[test]
fn asf_honours_axis_orders_units_and_root_section() {
    // Bone b's axis given as XYZ (0, 0, 90) and as the same rotation in ZYX order; radians too.
    let base = asf::parse(MINI).unwrap().skeleton;
    let c = EulerOrder::XYZ.to_mat3_f64([0.0, 0.0, 90f64.to_radians()]);
    for order in EulerOrder::ALL {
        let a = order.from_mat3_f64(&c).map(f64::to_degrees);
        let text = MINI.replacen(
            "axis 0 0 90 XYZ",
            &format!("axis {} {} {} {}", a[0], a[1], a[2], order.name()),
            1,
        );
        let s = asf::parse(&text).unwrap().skeleton;
        assert!(
            s.bones()[2]
                .axis_rotation()
                .abs_diff_eq(base.bones()[2].axis_rotation(), 1e-5),
            "{order:?}"
        );
    }
    let rad = MINI
        .replacen("angle deg", "angle rad", 1)
        .replacen("(0.0 170.0)", "(0.0 2.9670597)", 1)
        .replacen("axis 0 0 90 XYZ", "axis 0 0 1.5707963 XYZ", 1)
        .replacen("(-10 10)", "(-0.17453292 0.17453292)", 1)
        .replacen("(-20 20)", "(-0.34906585 0.34906585)", 1);
    let s = asf::parse(&rad).unwrap().skeleton;
    for (x, y) in s.bones().iter().zip(base.bones()) {
        assert!(x.axis_rotation().abs_diff_eq(y.axis_rotation(), 1e-6));
        for (l, m) in x.limits().iter().zip(y.limits()) {
            assert!(close(l.min, m.min) && close(l.max, m.max));
        }
    }
    // The root's position offset and channel order.
    let moved = MINI.replacen("position 0 0 0", "position 1 2 3", 1).replacen(
        "order TX TY TZ RX RY RZ",
        "order RZ TX TY TZ",
        1,
    );
    let s = asf::parse(&moved).unwrap().skeleton;
    assert_eq!(&s.root().order[..], &[Dof::Rz, Dof::Tx, Dof::Ty, Dof::Tz]);
    let m = amc::parse(&s, "1\nroot 90 10 0 0\n").unwrap();
    let p = tips(&s, &m, 0);
    assert!((p.tip[0] - glam::Vec3A::new(11.0, 2.0, 3.0)).length() < 1e-5);
    // Bone a points along +y at rest; the root's 90° about z turns it to −x.
    assert!((p.tip[1] - glam::Vec3A::new(9.0, 2.0, 3.0)).length() < 1e-5);
}

/// The root is a point: its tip is its position whatever its rotation channels hold, and a
/// bone's translation and length channels move its start and its tip (eq. 2).
#[test]
fn fk_reads_translation_and_length_channels_and_keeps_the_root_a_point() {
    let stretchy = MINI.replacen(
        "    dof rx\r\n    limits (0.0 170.0)\r\n",
        "    dof tx l rz\r\n    limits (-inf inf)\r\n           (-inf inf)\r\n           (-inf inf)\r\n",
        1,
    );
    let s = asf::parse(&stretchy).unwrap().skeleton;
    assert_eq!(s.bones()[2].dofs(), &[Dof::Tx, Dof::L, Dof::Rz]);
    let mut c = [0.0f32; MAX_CHANNELS];
    let mut p = Pose::new();
    // Root at (1, 2, 3), a at rest (tip (1, 4, 3)); b moved 0.5 along its own x (its `C`, 90°
    // about z, takes that to the world's y), 1 longer.
    c[..3].copy_from_slice(&[1.0, 2.0, 3.0]);
    c[9..12].copy_from_slice(&[0.5, 1.0, 0.0]);
    forward_kinematics(&s, &c, &mut p).unwrap();
    assert_eq!(p.start[0], p.tip[0]);
    assert!((p.tip[1] - glam::Vec3A::new(1.0, 4.0, 3.0)).length() < 1e-6);
    assert!(
        (p.start[2] - glam::Vec3A::new(1.0, 4.5, 3.0)).length() < 1e-6,
        "{}",
        p.start[2]
    );
    // b points along +x, 1.5 + 1 long.
    assert!(
        (p.tip[2] - glam::Vec3A::new(3.5, 4.5, 3.0)).length() < 1e-6,
        "{}",
        p.tip[2]
    );
    // The f64 FK agrees.
    let c64: Vec<f64> = c[..s.channel_count()].iter().map(|&v| f64::from(v)).collect();
    let mut p64 = Pose64::default();
    fk64(&s, &c64, &mut p64);
    for b in 0..s.len() {
        let (start, tip) = (p64.start[b].as_vec3(), p64.tip[b].as_vec3());
        assert!((glam::Vec3A::from(start) - p.start[b]).length() < 1e-6);
        assert!((glam::Vec3A::from(tip) - p.tip[b]).length() < 1e-6);
    }
    // A rotation channel that is not a number spoils the orientation, not the root's point.
    c[3] = f32::NAN;
    forward_kinematics(&s, &c, &mut p).unwrap();
    assert_eq!(p.tip[0], glam::Vec3A::new(1.0, 2.0, 3.0));
    assert_eq!(p.start[0], p.tip[0]);
    assert!(p.tip[2].is_nan());
}

fn amc_err(text: &str) -> String {
    let file = asf::load(&common::data("16.asf")).unwrap();
    let e = amc::parse(&file.skeleton, text).unwrap_err();
    FileError::parse(Path::new("16_15.amc"), e).to_string()
}

#[test]
fn amc_errors_name_file_line_and_what_was_expected() {
    let real = common::read("16_15.amc");
    let line = real.lines().position(|l| l.starts_with("lfemur")).unwrap();
    let broken: String = real
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == line {
                "lfemur -28.6707 -0.503906\r".to_string()
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let e = amc_err(&broken);
    assert_eq!(
        e,
        format!("16_15.amc:{}:1: bone 'lfemur' has 3 DOFs but 2 values", line + 1)
    );
    assert_eq!(
        amc_err("1\nroot 0 0 0 0 0 x\n"),
        "16_15.amc:2:16: expected a number, found 'x'"
    );
    assert_eq!(
        amc_err("1\nroot 0 0 0 0 0 NaN\n"),
        "16_15.amc:2:16: expected a value between -1e9 and 1e9, found 'NaN'"
    );
    assert_eq!(
        amc_err("1\nroot 0 0 0 0 0 1e300\n"),
        "16_15.amc:2:16: expected a value between -1e9 and 1e9, found '1e300'"
    );
    assert_eq!(
        amc_err("1\nnose 0\n"),
        "16_15.amc:2:1: unknown bone 'nose' (not in the skeleton)"
    );
    assert_eq!(
        amc_err("1\nltibia 1\nltibia 2\n"),
        "16_15.amc:3:1: bone 'ltibia' appears twice in frame 1"
    );
    assert_eq!(
        amc_err("1\n3\n"),
        "16_15.amc:2:1: expected frame 2, found frame 3"
    );
    assert_eq!(
        amc_err("ltibia 1\n"),
        "16_15.amc:1:1: expected a frame number, found 'ltibia'"
    );
    assert_eq!(
        amc_err(":DEGREES\n"),
        "16_15.amc:1: expected at least one frame (a frame number, then a line per bone), found none"
    );
    assert_eq!(
        amc_err(":FOO\n"),
        "16_15.amc:1:1: expected :FULLY-SPECIFIED, :DEGREES or :RADIANS, found ':FOO'"
    );
}

#[test]
fn bvh_errors_name_line_and_what_was_expected() {
    let e = |t: &str| bvh::parse(t, 1.0).unwrap_err().to_string();
    assert_eq!(
        e("HIERARCHY\nROOT a\n{\nOFFSET 0 0\n}\n"),
        "5:1: expected a number, found '}'"
    );
    assert_eq!(
        e("HIERARCHY\nROOT a\n{\nCHANNELS 1 Wrotation\n}\n"),
        "4:12: expected a channel (Xposition … Zrotation), found 'Wrotation'"
    );
    assert_eq!(
        e("HIERARCHY\nROOT a\n{\nCHANNELS 1 Xrotation\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1\n"),
        "9:0: expected 2 frames (Frames:), found 1"
    );
    assert_eq!(
        e("HIERARCHY\nROOT a\n{\nCHANNELS 1 Xrotation\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n1 2\n"),
        "9:3: expected 1 values on a frame line, found more"
    );
    assert!(
        e("HIERARCHY\nROOT a\n{\nJOINT b\n{\nCHANNELS 3 Xposition Yposition Zposition\n}\n}\n")
            .contains("only the root may")
    );
}

/// Found by the `asf` fuzz target: a byte-order mark shifted the documentation's offsets
/// (a panic when a line of it held a multi-byte character).
#[test]
fn asf_with_a_byte_order_mark_keeps_its_documentation() {
    let text = format!("\u{feff}{}", common::read("16.asf"));
    let plain = asf::parse(&common::read("16.asf")).unwrap();
    let with_bom = asf::parse(&text).unwrap();
    assert_eq!(with_bom.documentation, plain.documentation);
    let accented = text.replacen(":documentation\r\n", ":documentation\r\n  Señor Ωmega\r\n", 1);
    assert_ne!(accented, text, "16.asf has a :documentation line");
    let doc = asf::parse(&accented).unwrap().documentation;
    assert!(doc.starts_with("Señor Ωmega\n"), "{doc:?}");
}

/// Found by the `asf` fuzz target: a documentation line whose first token, once its control
/// characters are read as spaces, starts like a section keyword was written back as one.
#[test]
fn asf_documentation_that_looks_like_a_section_writes_back_as_documentation() {
    let text = common::read("16.asf").replacen(
        ":documentation\r\n",
        ":documentation\r\n\u{b}:\r:hierarchy\rbonedata (c)\r\n",
        1,
    );
    let file = asf::parse(&text).unwrap();
    let mut out = Vec::new();
    asf::write(&file, &mut out).unwrap();
    let back = asf::parse(std::str::from_utf8(&out).unwrap()).unwrap();
    assert_eq!(back.skeleton.len(), file.skeleton.len());
    assert!(
        back.documentation.starts_with("hierarchy bonedata (c)\n"),
        "{:?}",
        back.documentation
    );
}

/// Found by the `asf` fuzz target after the fix above: two byte-order marks (one is removed, the
/// second is text) must not shift the documentation's offsets either.
#[test]
fn asf_with_two_byte_order_marks_is_an_error_not_a_panic() {
    let text = "\u{feff}\u{feff}\r\n:documentation\r\n  é\r\n:root\r\n";
    let e = asf::parse(text).unwrap_err();
    assert_eq!(e.line, 1, "{e:?}");
    let fuzzed = b"\xef\xbb\xbf\xef\xbb\xbf\r\n# weg\r\n:documentation\r\n01.):bonedata\x0c\x18\r\n    \x00:\x01\x00\x0c\xef\xbb\xbf\r\x00\n";
    let text = marionette::formats::text_from_bytes(fuzzed.to_vec()).unwrap();
    assert!(asf::parse(&text).is_err());
}

//! The `marionette` command as a user runs it: output, exit codes, one-line errors.

mod common;

use std::io::Read;
use std::process::{Output, Stdio};

use common::run;

fn stdout(o: &Output) -> String {
    String::from_utf8(o.stdout.clone()).unwrap()
}

fn one_line_error(o: &Output, contains: &str) {
    assert!(!o.status.success(), "should fail");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    assert!(err.starts_with("marionette: error: "), "{err}");
    assert!(err.contains(contains), "'{err}' should contain '{contains}'");
}

#[test]
fn info_describes_skeleton_and_motion() {
    let o = run(&["info", "data/cmu/16.asf", "data/cmu/16_15.amc"]);
    assert!(o.status.success());
    let s = stdout(&o);
    assert!(s.contains("31 (root included), 62 DOFs"), "{s}");
    assert!(s.contains("length 0.45"), "{s}");
    assert!(s.contains("lfemur") && s.contains("rx[-160.0,20.0]"), "{s}");
    assert!(s.contains("471 frames (1..471) at 120 Hz = 3.917 s"), "{s}");
    let o = run(&["info", "data/cmu/01_01.bvh", "--bvh-unit", "cmu"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("2752 frames"), "{}", stdout(&o));
    // A BVH frame time of 0.0083333 s prints as the rate it stands for.
    assert!(stdout(&o).contains("at 120 Hz"), "{}", stdout(&o));
}

#[test]
fn info_of_an_amc_alone_finds_its_skeleton_beside_it() {
    let o = run(&["info", "data/cmu/16_15.amc"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = stdout(&o);
    assert!(s.starts_with("skeleton  data/cmu/16.asf"), "{s}");
    assert!(s.contains("471 frames (1..471) at 120 Hz"), "{s}");
    // No ASF beside it: say what to give, not that the AMC is a broken ASF.
    let lone = common::tempdir("info-amc-alone").join("99_01.amc");
    std::fs::copy("data/cmu/16_15.amc", &lone).unwrap();
    let o = run(&["info", lone.to_str().unwrap()]);
    one_line_error(&o, "an AMC file is a motion; give its skeleton first");
}

#[test]
fn fk_every_frames_meters_and_json() {
    let o = run(&[
        "fk",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--every",
        "100",
        "--frames",
        "1..300",
    ]);
    assert!(o.status.success());
    let s = stdout(&o);
    let frames: std::collections::BTreeSet<&str> =
        s.lines().skip(1).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(frames.into_iter().collect::<Vec<_>>(), vec!["1", "101", "201"]);
    assert_eq!(s.lines().count(), 1 + 3 * 31);
    let root_units: Vec<f64> = s
        .lines()
        .nth(1)
        .unwrap()
        .split(',')
        .skip(2)
        .map(|v| v.parse().unwrap())
        .collect();

    let o = run(&[
        "fk",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--frames",
        "1..1",
        "--meters",
        "--format",
        "json",
    ]);
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("valid JSON");
    assert_eq!(v["units"], "m");
    assert_eq!(v["bones"].as_array().unwrap().len(), 31);
    assert_eq!(v["frames"][0]["frame"], 1);
    let root_m = v["frames"][0]["tips"][0][1].as_f64().unwrap();
    let want = root_units[1] / 0.45 * 0.0254;
    assert!((root_m - want).abs() < 1e-5, "{root_m} vs {want}");
}

/// Angles as large as the AMC loader accepts (±10⁹ degrees, where f32 cannot tell angles half a
/// radian apart) still give finite positions and valid JSON.
#[test]
fn fk_of_angles_at_the_loaders_bound_is_finite() {
    let walk = std::fs::read_to_string("data/cmu/16_15.amc").unwrap();
    let mut frame = 0;
    let huge: Vec<String> = walk
        .lines()
        .map(|l| {
            let t = l.trim();
            if let Ok(n) = t.parse::<u32>() {
                frame = n;
            }
            match (frame, t.split_whitespace().next()) {
                (1, Some("lhumerus")) => "lhumerus 9e8 -1e9 5.5e8".to_string(),
                _ => l.to_string(),
            }
        })
        .collect();
    let amc = common::tempdir("cli").join("huge.amc");
    std::fs::write(&amc, huge.join("\n")).unwrap();
    let o = run(&[
        "fk",
        "data/cmu/16.asf",
        amc.to_str().unwrap(),
        "--frames",
        "1..1",
        "--format",
        "json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("valid JSON");
    let tips = v["frames"][0]["tips"].as_array().unwrap();
    assert_eq!(tips.len(), 31);
    for tip in tips {
        assert!(
            tip.as_array()
                .unwrap()
                .iter()
                .all(|c| c.as_f64().is_some_and(f64::is_finite)),
            "{tip}"
        );
    }
}

#[test]
fn bad_input_gives_one_line_errors_and_nonzero_exit() {
    one_line_error(&run(&["info", "data/cmu/nope.asf"]), "data/cmu/nope.asf");
    // A profile of the ASF's bones against a BVH skeleton: the line, and the names it has.
    one_line_error(
        &run(&[
            "play",
            "firmware-profile/cmu-puppet.toml",
            "data/cmu/01_01.bvh",
            "--bvh-unit",
            "cmu",
        ]),
        "cmu-puppet.toml:36: unknown bone `lhumerus` in [[bone]]; the skeleton has: root LHipJoint LeftUpLeg",
    );
    // A motion where the skeleton should be.
    let misnamed = common::tempdir("info-misnamed").join("walk.asf");
    std::fs::copy("data/cmu/16_15.amc", &misnamed).unwrap();
    one_line_error(
        &run(&["info", misnamed.to_str().unwrap()]),
        "walk.asf:2:1: expected an ASF section",
    );
    one_line_error(
        &run(&[
            "fk",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "--frames",
            "400..900",
        ]),
        "not inside the clip's frames 1..471",
    );
    one_line_error(
        &run(&["fk", "data/cmu/16.asf", "data/cmu/16_15.amc", "--frames", "x"]),
        "--frames must look like",
    );
    one_line_error(
        &run(&["convert", "data/cmu/16.asf", "/tmp/x.txt"]),
        "unknown output type",
    );
    let dir = common::tempdir("cli");
    let bad = dir.join("bad.amc");
    std::fs::write(&bad, "1\nroot 0 0 0 0 0\n").unwrap();
    one_line_error(
        &run(&["fk", "data/cmu/16.asf", bad.to_str().unwrap()]),
        "bad.amc:2:1: bone 'root' has 6 DOFs but 5 values",
    );
    // Usage errors come from clap, also with a non-zero exit.
    assert!(!run(&["fk", "data/cmu/16.asf"]).status.success());
    assert!(
        !run(&["fk", "data/cmu/16.asf", "data/cmu/16_15.amc", "--every", "0"])
            .status
            .success()
    );
}

#[test]
fn convert_bvh_to_asf_amc_and_back() {
    let d = common::tempdir("cli");
    let amc_out = d.join("walk.amc");
    let o = run(&["convert", "data/cmu/16_15.bvh", amc_out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let asf_out = d.join("walk.asf");
    assert!(asf_out.is_file(), "skeleton written beside the AMC");
    let o = run(&["info", asf_out.to_str().unwrap(), amc_out.to_str().unwrap()]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("471 frames"));
    // And AMC (skeleton found from the CMU subject number) to BVH.
    let bvh_out = d.join("walk.bvh");
    let o = run(&["convert", "data/cmu/16_15.amc", bvh_out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["info", bvh_out.to_str().unwrap(), "--bvh-unit", "cmu"]);
    assert!(o.status.success());
    assert!(stdout(&o).contains("471 frames"));
}

#[test]
fn closed_pipe_is_not_an_error() {
    let mut child = common::bin()
        .args(["fk", "data/cmu/01.asf", "data/cmu/01_01.amc"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = child.stdout.take().unwrap();
    let mut first = [0u8; 64];
    out.read_exact(&mut first).unwrap();
    drop(out);
    let status = child.wait().unwrap();
    let mut err = String::new();
    child.stderr.take().unwrap().read_to_string(&mut err).unwrap();
    assert!(status.success(), "exit {status:?}, stderr {err}");
    assert!(err.is_empty(), "{err}");
}

fn tmp(name: &str) -> std::path::PathBuf {
    common::tempdir("cli").join(name)
}

fn frames_of(amc_path: &std::path::Path) -> usize {
    let skel = marionette::formats::asf::load(&common::data("16.asf"))
        .unwrap()
        .skeleton;
    marionette::formats::amc::load(&skel, amc_path).unwrap().len()
}

#[test]
fn connect_writes_a_readable_clip_and_both_picture_kinds() {
    let out = tmp("connect.amc");
    let svg = tmp("connect.svg");
    let o = run(&[
        "connect",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "data/cmu/01_01.amc",
        "--method",
        "blend",
        "--match",
        "backward",
        "--metric",
        "euler",
        "--window",
        "20",
        "-o",
        out.to_str().unwrap(),
        "--plot",
        svg.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = stdout(&o);
    assert!(
        s.contains("Backward matching, window 20 frames, metric Euler"),
        "{s}"
    );
    assert!(s.contains("seam      joint change"), "{s}");
    assert!(frames_of(&out) > 100);
    let svg_text = std::fs::read_to_string(&svg).unwrap();
    assert!(svg_text.starts_with("<svg") && svg_text.contains("matching window distance"));

    let png = tmp("connect.png");
    let o = run(&[
        "connect",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "data/cmu/16_15.amc",
        "--insert",
        "5",
        "-o",
        out.to_str().unwrap(),
        "--plot",
        png.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("5 interpolated"), "{}", stdout(&o));
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
}

#[test]
fn loop_transform_and_blend_commands() {
    let out = tmp("loop.amc");
    let o = run(&[
        "loop",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--cycles",
        "3",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("3 cycles"), "{}", stdout(&o));
    assert!(frames_of(&out) > 300);

    let moved = tmp("moved.amc");
    let o = run(&[
        "transform",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--facing",
        "-90",
        "--start",
        "-5,2.5",
        "-o",
        moved.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout(&o).contains("→ -90.000°"), "{}", stdout(&o));
    assert!(stdout(&o).contains("(-5.0000,"), "{}", stdout(&o));
    assert_eq!(frames_of(&moved), 471);

    let mix = tmp("mix.amc");
    let o = run(&[
        "blend",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "data/cmu/01_01.amc",
        "--weight",
        "0.25",
        "-o",
        mix.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(frames_of(&mix), 471);

    one_line_error(
        &run(&[
            "blend",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "data/cmu/01_01.amc",
            "--weight",
            "2",
            "-o",
            mix.to_str().unwrap(),
        ]),
        "--weight must be between 0 and 1",
    );
    one_line_error(
        &run(&[
            "connect",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "data/cmu/01_01.amc",
            "--window",
            "5000",
            "-o",
            mix.to_str().unwrap(),
        ]),
        "window of 5000 frames does not fit",
    );
    one_line_error(
        &run(&[
            "transform",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "--facing",
            "10",
            "--start",
            "1",
            "-o",
            mix.to_str().unwrap(),
        ]),
        "--start must look like X,Z",
    );
    one_line_error(
        &run(&[
            "connect",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "data/cmu/01_01.amc",
            "-o",
            mix.to_str().unwrap(),
            "--plot",
            "/tmp/x.gif",
        ]),
        "must be .svg or .png",
    );
}

/// `identify` on the virtual chain (virtual time): a row per chosen servo with its lag, the
/// figures as JSON, one-line errors for bad options.
#[test]
fn identify_measures_each_servo_on_the_virtual_chain() {
    let dir = common::tempdir("identify-cli");
    let json = dir.join("id.json");
    let o = run(&[
        "identify",
        "firmware-profile/cmu-puppet.toml",
        "data/cmu/16.asf",
        "--rate",
        "250",
        "--servos",
        "ltibia_rx,head_rx",
        "--json",
        json.to_str().unwrap(),
    ]);
    let s = stdout(&o);
    assert!(o.status.success(), "{s}{}", String::from_utf8_lossy(&o.stderr));
    assert!(s.contains("identifying 2 servo(s) at 250 Hz"), "{s}");
    let rows: Vec<&str> = s
        .lines()
        .filter(|l| l.starts_with("ltibia_rx") || l.starts_with("head_rx"))
        .collect();
    assert_eq!(rows.len(), 2, "{s}");
    let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for servo in r.as_array().unwrap() {
        let lag = servo["lag_ms"].as_f64().unwrap();
        // The virtual servo follows at its no-load speed: a few milliseconds.
        assert!((0.0..20.0).contains(&lag), "{servo}");
        assert!(servo["rms_after_lag_deg"].as_f64().unwrap() < 1.0, "{servo}");
        assert!(servo["frequency_response"].as_array().unwrap().len() > 10);
    }
    one_line_error(
        &run(&[
            "identify",
            "firmware-profile/cmu-puppet.toml",
            "data/cmu/16.asf",
            "--servos",
            "elbow",
        ]),
        "--servos: no servo named `elbow` in the profile",
    );
    one_line_error(
        &run(&[
            "identify",
            "firmware-profile/cmu-puppet.toml",
            "data/cmu/16.asf",
            "--amplitude-deg",
            "0",
        ]),
        "--amplitude-deg must be above 0",
    );
    let _ = std::fs::remove_dir_all(&dir);
}

//! `marionette play`, `follow` and `targets` as a user runs them: over the virtual chain on a
//! pseudo-terminal through `dynamixel2`, in real time. Timing figures are printed, not asserted
//! (machines are noisy); what is asserted is what must hold anywhere.

mod common;

use std::io::Write;
use std::net::UdpSocket;
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

const PROFILE: &str = "firmware-profile/cmu-puppet.toml";
const ASF: &str = "data/cmu/16.asf";
const AMC: &str = "data/cmu/16_15.amc";

/// The real-time runs one at a time: on a 2-core machine parallel loops would measure each
/// other.
static REAL_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

fn serial() -> std::sync::MutexGuard<'static, ()> {
    REAL_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

use common::{run, tempdir};
use marionette::control::sources::MAX_DATAGRAM_BYTES;

fn json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn ok(o: &Output) -> String {
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    assert!(
        o.status.success(),
        "failed: {out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    out
}

/// The fields `--stats-json` promises, with sane values.
fn check_stats(v: &serde_json::Value, rate: f64) {
    assert_eq!(v["rate_hz"].as_f64(), Some(rate));
    assert!(v["ticks"].as_u64().unwrap() > 0);
    assert!(v["deadline_misses"].is_u64());
    for key in ["tick_compute_us", "period_error_us"] {
        for q in ["p50", "p99", "p999", "max"] {
            let x = v[key][q].as_f64().unwrap_or(f64::NAN);
            assert!(x.is_finite() && x >= 0.0, "{key}.{q} = {x}");
        }
        assert!(v[key]["p50"].as_f64() <= v[key]["p99"].as_f64());
        assert!(v[key]["p99"].as_f64() <= v[key]["max"].as_f64());
    }
    assert_eq!(v["bus_errors"].as_u64(), Some(0));
    assert_eq!(
        v["allocations_in_tick"].as_u64(),
        Some(0),
        "the counting allocator saw none"
    );
    if cfg!(target_os = "linux") {
        // The loop's storage, stack and code are mapped before it starts.
        assert_eq!(v["page_faults_in_loop"].as_u64(), Some(0), "{v}");
    }
    let t = v["tracking_rms_deg"].as_f64().unwrap();
    assert!(t.is_finite() && t < 5.0, "tracking {t}");
    // End to end: the source mapped through the rig against the present positions read back.
    let f = &v["fidelity"];
    for key in [
        "joint_rms_deg",
        "joint_max_deg",
        "rms_after_lag_deg",
        "effector_rms_mm",
    ] {
        let x = f[key].as_f64().unwrap_or(f64::NAN);
        assert!(x.is_finite() && x >= 0.0, "fidelity.{key} = {x}: {f}");
    }
    // The lag is negative where the servos run ahead of the source (a lead beyond their lag).
    assert!(f["lag_ms"].as_f64().is_some_and(f64::is_finite), "{f}");
    assert!(f["rms_after_lag_deg"].as_f64() <= f["joint_rms_deg"].as_f64());
    assert!(f["joint_rms_deg"].as_f64() <= f["joint_max_deg"].as_f64());
    let samples = f["samples"].as_u64().unwrap();
    assert!(samples > 0 && samples <= v["reads_ok"].as_u64().unwrap(), "{f}");
    assert_eq!(f["servos"].as_array().unwrap().len(), 28);
}

/// `follow … --targets TARGETS --ramp 0.1 --duration SECONDS --stats-json STATS` as a child
/// process with piped stdout/stderr and the given stdin.
fn spawn_follow(targets: &str, seconds: &str, stats: &std::path::Path, stdin: Stdio) -> std::process::Child {
    common::bin()
        .args([
            "follow",
            PROFILE,
            ASF,
            "--targets",
            targets,
            "--ramp",
            "0.1",
            "--duration",
            seconds,
            "--stats-json",
            stats.to_str().unwrap(),
        ])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(stdin)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Whether the run kept its schedule. A loaded machine can overrun ticks (the deadlines passed
/// over are counted as skipped); a sample due in a skipped tick is superseded by the next, and
/// the servos catch up at their speed, so "every sample sent" and the largest error are asserted
/// only when no tick was skipped or overran — the virtual-time tests in `tests/control.rs`
/// assert them unconditionally, stalls included.
fn kept_time(v: &serde_json::Value) -> bool {
    let kept = v["skipped_ticks"].as_u64() == Some(0) && v["deadline_misses"].as_u64() == Some(0);
    if !kept {
        println!(
            "this machine did not keep time ({} skipped, {} misses): sample coverage and the largest error not asserted",
            v["skipped_ticks"], v["deadline_misses"]
        );
    }
    kept
}

#[test]
fn play_streams_the_whole_clip_over_the_virtual_chain() {
    let _serial = serial();
    let dir = tempdir("play");
    // Both within the puppet's wire limit (393 Hz: `marionette budget`), as the virtual chain
    // keeps line time.
    for rate in ["120", "250"] {
        let stats = dir.join(format!("stats-{rate}.json"));
        let out = ok(&run(&[
            "play",
            PROFILE,
            ASF,
            AMC,
            "--rate",
            rate,
            "--ramp",
            "0.2",
            "--stats-json",
            stats.to_str().unwrap(),
        ]));
        println!("{out}");
        assert!(out.contains("ended: end of input; torque off"));
        // The chain's servos stand at their zero angle, far from the clip's first pose: the
        // pre-roll is made longer than its 1 s, and the first pass with it.
        assert!(out.contains("moving to the first pose over"), "{out}");
        let v = json(&stats);
        check_stats(&v, rate.parse().unwrap());
        let hz: f64 = rate.parse().unwrap();
        let pass = (3.916 * hz) as u64;
        assert!(v["samples_per_pass"].as_u64().unwrap() > pass + hz as u64, "{v}");
        assert!(v["inputs_used"].as_u64() <= v["samples_per_pass"].as_u64());
        if kept_time(&v) {
            assert_eq!(v["all_samples_sent"].as_bool(), Some(true));
            assert_eq!(v["inputs_used"], v["samples_per_pass"]);
        }
        assert_eq!(v["commands_sent"], v["ticks"]);
        let period_us = 1e6 / rate.parse::<f64>().unwrap();
        println!(
            "{rate} Hz: tick compute p99 {} µs = {:.2} % of the period",
            v["tick_compute_us"]["p99"],
            100.0 * v["tick_compute_us"]["p99"].as_f64().unwrap() / period_us
        );
    }
}

/// A clip looped as captured jumps from its last pose to its first at each pass, and `play`
/// says so, as `follow` does for its targets; the cycle that `marionette loop` makes of it,
/// and the targets of that cycle, play without the warning.
#[test]
fn play_and_follow_warn_when_a_looped_input_is_not_a_cycle() {
    let _serial = serial();
    let dir = tempdir("play-loop");
    let path = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (cycle, walk_targets, cycle_targets) = (path("cycle.amc"), path("walk.csv"), path("cycle.csv"));
    ok(&run(&["loop", ASF, AMC, "-o", &cycle, "--cycles", "1"]));
    ok(&run(&["targets", ASF, AMC, "-o", &walk_targets]));
    ok(&run(&["targets", ASF, &cycle, "-o", &cycle_targets]));
    let brief = ["--loop", "--duration", "0.3", "--ramp", "0.1", "-q"];
    let play = |clip: &str| ok(&run(&[&["play", PROFILE, ASF, clip][..], &brief[..]].concat()));
    let follow = |targets: &str| {
        ok(&run(&[
            &["follow", PROFILE, ASF, "--targets", targets][..],
            &brief[..],
        ]
        .concat()))
    };
    let out = play(AMC);
    assert!(
        out.contains(
            "warning: --loop: the clip is not a cycle: from its last frame to its first, `rfemur` turns 46°"
        ),
        "{out}"
    );
    assert!(out.contains("`marionette loop` makes a seamless cycle"), "{out}");
    let out = follow(&walk_targets);
    assert!(
        out.contains("warning: --loop: the targets are not a cycle: from the last sample to the first, rtibia's target moves"),
        "{out}"
    );
    for out in [play(&cycle), follow(&cycle_targets)] {
        assert!(!out.contains("not a cycle"), "{out}");
    }
}

#[test]
fn follow_drives_the_puppet_from_a_clips_wrist_and_ankle_paths() {
    let _serial = serial();
    let dir = tempdir("follow");
    let csv = dir.join("walk.csv");
    let jsonl = dir.join("walk.jsonl");
    let made = ok(&run(&["targets", ASF, AMC, "-o", csv.to_str().unwrap()]));
    // The capture's left-arm dropout (frames 1–2) is filled, as `play` fills it.
    assert!(
        made.contains("capture dropout: lhumerus frames 1–2 read zero"),
        "{made}"
    );
    ok(&run(&[
        "targets",
        ASF,
        AMC,
        "--format",
        "jsonl",
        "-o",
        jsonl.to_str().unwrap(),
    ]));
    let text = std::fs::read_to_string(&csv).unwrap();
    assert!(text.starts_with("t,effector,x,y,z\n"));
    assert_eq!(text.lines().count(), 1 + 4 * 471);
    // The second run asks for an ease-in longer than the move the servos need (2.08 s): the
    // file's first targets are held through it.
    for (file, rate, ease_in) in [(&csv, "120", "0"), (&jsonl, "250", "2.5")] {
        let stats = dir.join(format!("follow-{rate}.json"));
        let out = ok(&run(&[
            "follow",
            PROFILE,
            ASF,
            "--targets",
            file.to_str().unwrap(),
            "--rate",
            rate,
            "--ease-in",
            ease_in,
            "--ramp",
            "0.2",
            "--stats-json",
            stats.to_str().unwrap(),
        ]));
        println!("{out}");
        let v = json(&stats);
        let seconds = (v["ticks"].as_f64().unwrap() + v["skipped_ticks"].as_f64().unwrap())
            / rate.parse::<f64>().unwrap();
        if ease_in == "0" {
            // The first targets are solved before the run and held while the servos move there
            // (the humerus twists are 80–90° from rest), out of the fidelity.
            assert!(out.contains("moving to the first pose over"), "{out}");
            assert!(seconds > 5.5, "{seconds} s: the move, then 3.92 s of targets");
            // The pose solved before the run is the loop's first: it asks for no longer a move.
            assert!(v["start_move_s"].is_null(), "{}", v["start_move_s"]);
        } else {
            assert!(seconds > 6.0, "{seconds} s: 2.5 s held, then 3.92 s of targets");
        }
        check_stats(&v, rate.parse().unwrap());
        if kept_time(&v) {
            // A stall ends in a catch-up at the servos' speed, which the fidelity counts.
            let max = v["fidelity"]["joint_max_deg"].as_f64().unwrap();
            assert!(max < 30.0, "fidelity max {max}°: the move from rest counted");
            assert_eq!(v["inputs_used"].as_u64(), Some(471), "every target sample used");
        }
        assert_eq!(v["inputs_rejected"].as_u64(), Some(0));
        assert_eq!(v["unreachable"].as_u64(), Some(0));
        assert!(v["ik_error_max"].as_f64().unwrap() < 1e-6);
    }
}

#[test]
fn follow_reads_targets_from_stdin_and_udp() {
    let _serial = serial();
    let dir = tempdir("live");
    let csv = dir.join("walk.csv");
    ok(&run(&["targets", ASF, AMC, "-o", csv.to_str().unwrap()]));
    let lines: Vec<String> = std::fs::read_to_string(&csv)
        .unwrap()
        .lines()
        .skip(1)
        .take(4 * 400)
        .map(str::to_string)
        .collect();
    // Stdin: the run ends when the input does; one garbage line is counted, not fatal.
    let stats = dir.join("stdin.json");
    let mut child = spawn_follow("-", "20", &stats, Stdio::piped());
    {
        let mut stdin = child.stdin.take().unwrap();
        for (k, l) in lines.iter().enumerate() {
            writeln!(stdin, "{l}").unwrap();
            if k == 50 {
                writeln!(stdin, "0,lradius,1,nan-ish,3").unwrap();
            }
            if k % 4 == 3 {
                std::thread::sleep(Duration::from_millis(8));
            }
        }
    }
    let out = child.wait_with_output().unwrap();
    let text = ok(&out);
    assert!(text.contains("1 unreadable lines"), "{text}");
    assert!(text.contains("ended: end of input"), "{text}");
    // Live: the loop sizes the move to the first pose when it arrives (about 2 s here).
    assert!(text.contains("start move "), "{text}");
    let v = json(&stats);
    check_stats(&v, 120.0);
    assert!(v["inputs_used"].as_u64().unwrap() > 10);

    // UDP on loopback: datagrams of four lines.
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let stats = dir.join("udp.json");
    let child = spawn_follow(&format!("udp://127.0.0.1:{port}"), "3.5", &stats, Stdio::null());
    let sender = UdpSocket::bind("127.0.0.1:0").unwrap();
    let t0 = Instant::now();
    // Among them, datagrams over the size limit (refused whole, counted) and a target a
    // kilometre off (refused by the loop: out of range).
    let oversized = format!("{}\n", lines[0]).repeat(1 + MAX_DATAGRAM_BYTES / lines[0].len());
    let mut sent_oversized = 0;
    let mut sent_far = false;
    for (k, chunk) in lines.chunks(4).cycle().enumerate() {
        if t0.elapsed() > Duration::from_millis(3300) {
            break;
        }
        let datagram = match k {
            20..=24 => {
                sent_oversized +=
                    u64::from(sender.send_to(oversized.as_bytes(), ("127.0.0.1", port)).is_ok());
                continue;
            }
            30 => {
                sent_far = true;
                "0,lradius,40000,0,0".to_string()
            }
            _ => chunk.join("\n"),
        };
        let _ = sender.send_to(datagram.as_bytes(), ("127.0.0.1", port));
        std::thread::sleep(Duration::from_millis(8));
    }
    let out = child.wait_with_output().unwrap();
    let text = ok(&out);
    println!("{text}");
    assert!(!text.contains("warning: not loopback"), "{text}");
    let v = json(&stats);
    check_stats(&v, 120.0);
    assert!(v["inputs_used"].as_u64().unwrap() > 20, "{}", v["inputs_used"]);
    assert_eq!(v["end"].as_str(), Some("duration reached"));
    assert!(oversized.len() > MAX_DATAGRAM_BYTES && sent_oversized == 5 && sent_far);
    assert_eq!(v["oversized_datagrams"].as_u64(), Some(5), "{text}");
    // The far target may be superseded before a tick takes it, but never used.
    assert!(v["inputs_rejected"].as_u64().unwrap() <= 1);
    assert!(v["ik_error_max"].as_f64().unwrap() < 1.0, "{}", v["ik_error_max"]);

    // Off loopback only when asked, and then said at start-up.
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let out = common::bin()
        .args([
            "follow",
            PROFILE,
            ASF,
            "--targets",
            &format!("udp://0.0.0.0:{port}"),
        ])
        .args(["--targets-from-network", "--ramp", "0.05", "--duration", "0.3"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = ok(&out);
    assert!(
        text.contains("warning: not loopback: any host that reaches this port moves the servos"),
        "{text}"
    );
}

#[test]
fn bad_loop_arguments_give_one_line_errors() {
    let dir = tempdir("bad");
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "t,effector,x,y,z\n0,lradius,1,2,3\n0.1,lhand,1,2,3\n").unwrap();
    // Exit codes: 2 for arguments that are wrong, 1 for what fails at run time.
    const USAGE: i32 = 2;
    const RUNTIME: i32 = 1;
    for (args, says, code) in [
        (
            vec!["play", PROFILE, ASF, AMC, "--rate", "0"],
            "--rate must be between",
            USAGE,
        ),
        // Without the simulator `--bus sim` says how to get it; with it, live input is refused.
        if cfg!(feature = "sim") {
            (
                vec![
                    "follow",
                    PROFILE,
                    ASF,
                    "--targets",
                    "udp://127.0.0.1:0",
                    "--bus",
                    "sim",
                ],
                "not live input",
                USAGE,
            )
        } else {
            (
                vec!["play", PROFILE, ASF, AMC, "--bus", "sim"],
                "--features sim",
                RUNTIME,
            )
        },
        (
            vec!["play", PROFILE, ASF, AMC, "--duration=-1"],
            "--duration",
            USAGE,
        ),
        (
            vec!["play", PROFILE, ASF, AMC, "--start", "99"],
            "--start must be within",
            USAGE,
        ),
        (
            vec![
                "follow",
                PROFILE,
                ASF,
                "--targets",
                "x.csv",
                "--effectors",
                "lradius,nose",
            ],
            "no bone named 'nose'",
            USAGE,
        ),
        (
            vec![
                "targets",
                ASF,
                "data/cmu/16_15.amc",
                "-o",
                "/dev/null",
                "--effectors",
                "lradius,nose",
            ],
            "--effectors: no bone named 'nose' in the skeleton; it has: root lhipjoint lfemur",
            USAGE,
        ),
        (
            vec!["follow", PROFILE, ASF, "--targets", "udp://10.1.2.3:5000"],
            "only a loopback address",
            USAGE,
        ),
        (
            vec!["follow", PROFILE, ASF, "--targets", bad.to_str().unwrap()],
            "bad.csv:3: effector 'lhand' is not one of",
            RUNTIME,
        ),
        (
            vec!["play", PROFILE, ASF, AMC, "--bus", "/dev/nonexistent-port"],
            "/dev/nonexistent-port",
            RUNTIME,
        ),
    ] {
        let o = run(&args);
        assert_eq!(
            o.status.code(),
            Some(code),
            "{args:?} should fail with exit code {code}"
        );
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(says), "{args:?}: '{err}' should contain '{says}'");
    }
}

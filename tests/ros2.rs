//! ROS 2 interoperability (the `ros2` feature): `marionette follow --targets ros2` against an
//! independent DDS implementation, Eclipse Cyclone DDS from PyPI (`tests/ros2/peer.py`), on
//! loopback in a domain of its own. The peer reads `rt/joint_states` and publishes the walk's
//! wrist and ankle paths on `rt/marionette/targets/<effector>`, then two messages the loop
//! must refuse. Latency is printed, not asserted.
#![cfg(feature = "ros2")]

mod common;

use std::process::{Command, Stdio};

use common::{run, tempdir};

const PROFILE: &str = "firmware-profile/cmu-puppet.toml";
const ASF: &str = "data/cmu/16.asf";
const AMC: &str = "data/cmu/16_15.amc";

fn json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() as f64 * q) as usize).min(sorted.len() - 1)]
}

/// The runs one at a time: two loops and two peers at once would measure each other.
static ONE_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// What a run with the peer gave: marionette's output, its statistics, the peer's report.
struct Run {
    out: String,
    stats: serde_json::Value,
    peer: serde_json::Value,
}

/// `follow --targets ros2` for 10 s at 250 Hz with the peer publishing the walk's paths
/// (`pose`: as PoseStamped, with the captured directions of the hands and feet).
fn run_with_peer(pose: bool) -> Run {
    common::needs_python("cyclonedds", "cyclonedds==11.0.1");
    let _one = ONE_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let dir = tempdir(if pose { "ros2-pose" } else { "ros2-point" });
    let targets = dir.join("walk.csv");
    let mut args = vec!["targets", ASF, AMC, "-o", targets.to_str().unwrap()];
    if pose {
        args.push("--directions");
    }
    let o = run(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The rig's metres per file unit: the default --scale 0.3 × the ASF's (length 0.45: one
    // unit is 1/0.45 inch).
    let metres_per_unit = 0.3 * 0.0254 / 0.45;
    // A domain of this run's own (ROS 2 allows 0–232).
    let domain = (100 + 2 * (std::process::id() % 50) + u32::from(pose)).to_string();
    let got = dir.join("got.json");
    let stats = dir.join("stats.json");
    let manifest = env!("CARGO_MANIFEST_DIR");
    let mut peer = Command::new("python3");
    peer.arg(format!("{manifest}/tests/ros2/peer.py"))
        .args(["--domain", &domain, "--out", got.to_str().unwrap()])
        .args(["--targets", targets.to_str().unwrap()])
        .args([
            "--metres-per-unit",
            &metres_per_unit.to_string(),
            "--timeout",
            "60",
        ])
        .stdin(Stdio::null());
    if pose {
        peer.arg("--pose");
    }
    let mut peer = peer.spawn().expect("python3 runs");
    let o = common::bin()
        .args([
            "follow",
            PROFILE,
            ASF,
            "--targets",
            "ros2",
            "--duration",
            "10",
            "--rate",
            "250",
        ])
        .args(["--ros2-targets", if pose { "pose" } else { "point" }])
        .args(["-q", "--stats-json", stats.to_str().unwrap()])
        .env("ROS_DOMAIN_ID", &domain)
        .env("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
        .current_dir(manifest)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout).to_string();
    let peer_ok = peer.wait().unwrap().success();
    assert!(
        o.status.success(),
        "{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(peer_ok, "the peer failed; marionette said:\n{out}");
    println!("{out}");
    let r = Run {
        out,
        stats: json(&stats),
        peer: json(&got),
    };
    let _ = std::fs::remove_dir_all(&dir);
    r
}

/// The largest range over the received joint states of each servo whose name passes `pick`.
fn sweep(states: &[serde_json::Value], names: &[&str], pick: impl Fn(&str) -> bool) -> f64 {
    (0..names.len())
        .filter(|k| pick(names[*k]))
        .map(|k| {
            let v: Vec<f64> = states
                .iter()
                .map(|m| m["position"][k].as_f64().unwrap())
                .collect();
            v.iter().copied().fold(f64::MIN, f64::max) - v.iter().copied().fold(f64::MAX, f64::min)
        })
        .fold(0.0, f64::max)
}

/// What both kinds of targets must show: the targets used, the two unreadable messages refused
/// by the reader and the out-of-range one by the loop, each solved to the IK's precision, no
/// allocation in the tick.
fn check_targets(r: &Run) -> f64 {
    let s = &r.stats;
    let sent = r.peer["sent"]["targets"].as_u64().unwrap();
    assert!(sent > 1000, "{}", r.peer["sent"]);
    assert!(r.out.contains("2 unreadable lines"), "{}", r.out);
    assert!(s["inputs_used"].as_u64().unwrap() > 300, "{}", s["inputs_used"]);
    assert_eq!(s["inputs_rejected"].as_u64().unwrap(), 1);
    assert_eq!(s["unreachable"].as_u64().unwrap(), 0);
    let residual = s["ik_error_max"].as_f64().unwrap();
    assert!(residual < 1e-3, "IK residual {residual} file units");
    assert_eq!(s["allocations_in_tick"].as_u64(), Some(0));
    residual
}

#[test]
fn a_cyclone_dds_peer_reads_the_joint_states_and_its_targets_move_the_rig() {
    let r = run_with_peer(false);
    let out = &r.out;
    let s = &r.stats;
    let published: usize = out
        .lines()
        .find_map(|l| {
            l.strip_prefix("ros2: ")?
                .split(" joint states published")
                .next()?
                .parse()
                .ok()
        })
        .expect("the publisher's report");
    let states = r.peer["joint_states"].as_array().unwrap();
    let final_present = s["final_present"].as_array().unwrap();
    let names: Vec<&str> = final_present
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 28);
    assert_eq!(names[0], "lowerback_rx");

    // Every message published once the peer's reader had matched arrived (reliable; volatile:
    // those before discovery ended were for nobody): 100 a second over the span received.
    assert!(published >= 900, "{published} published in 10 s at 100 Hz");
    assert!(
        states.len() <= published,
        "published {published}, received {}",
        states.len()
    );
    let span_s = (states.last().unwrap()["stamp_ns"].as_f64().unwrap()
        - states[0]["stamp_ns"].as_f64().unwrap())
        * 1e-9;
    // The states come from the loop's tick records: a tick a loaded host skipped has none, so
    // 100 a second of the ticks that ran.
    let ticks = s["ticks"].as_f64().unwrap();
    let ran = ticks / (ticks + s["skipped_ticks"].as_f64().unwrap());
    assert!(
        states.len() as f64 >= 0.97 * span_s * 100.0 * ran && span_s > 8.0,
        "{} joint states over {span_s:.2} s, {:.1} % of the ticks ran",
        states.len(),
        100.0 * ran
    );
    let mut stamps = Vec::new();
    for m in states {
        let n: Vec<&str> = m["name"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_str().unwrap())
            .collect();
        assert_eq!(n, names);
        assert_eq!(m["position"].as_array().unwrap().len(), names.len());
        assert_eq!(m["velocity"].as_array().unwrap().len(), names.len());
        assert!(m["position"]
            .as_array()
            .unwrap()
            .iter()
            .all(|v| v.as_f64().unwrap().is_finite()));
        stamps.push(m["stamp_ns"].as_u64().unwrap());
    }
    assert!(stamps.windows(2).all(|w| w[0] < w[1]), "stamps must increase");
    // The last message is the run's last read: the statistics' present positions exactly.
    let last = states.last().unwrap()["position"].as_array().unwrap();
    for (p, want) in last.iter().zip(final_present) {
        assert_eq!(p.as_f64().unwrap(), want["rad"].as_f64().unwrap(), "{want}");
    }
    // The rig moved while the targets came: some joint swept more than 0.3 rad; the feet,
    // with no direction given, stayed at rest.
    let moved = sweep(states, &names, |_| true);
    assert!(moved > 0.3, "largest sweep {moved} rad");
    let feet = sweep(states, &names, |n| n.contains("foot"));
    assert!(feet < 0.01, "feet swept {feet} rad without directions");
    let residual = check_targets(&r);
    // The ROS 2 graph (what `ros2 node list` reads) has the node, its writer and its readers.
    let node = &r.peer["nodes"]["/marionette"];
    assert!(node["writers"].as_u64().unwrap() >= 1, "{}", r.peer["nodes"]);
    assert!(node["readers"].as_u64().unwrap() >= 4, "{}", r.peer["nodes"]);

    let mut latency: Vec<f64> = states
        .iter()
        .map(|m| (m["arrived_ns"].as_f64().unwrap() - m["stamp_ns"].as_f64().unwrap()) * 1e-3)
        .collect();
    latency.sort_by(f64::total_cmp);
    println!(
        "{} of {published} joint states received; read → peer: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs; IK residual max {residual:.1e}; tick compute p99 {} µs; graph {}",
        states.len(),
        quantile(&latency, 0.5),
        quantile(&latency, 0.99),
        latency.last().unwrap(),
        s["tick_compute_us"]["p99"],
        r.peer["nodes"]
    );
}

/// PoseStamped targets: the orientation turns the root's +x to the captured direction of the
/// hand or foot, and `follow` turns those bones: the feet's servos now move.
#[test]
fn pose_targets_from_the_peer_turn_the_feet() {
    let r = run_with_peer(true);
    let states = r.peer["joint_states"].as_array().unwrap();
    let names: Vec<&str> = r.stats["final_present"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    let residual = check_targets(&r);
    let feet = sweep(states, &names, |n| n.contains("foot"));
    assert!(feet > 0.1, "feet swept {feet} rad");
    println!("PoseStamped: feet swept {feet:.2} rad; IK residual max {residual:.1e}");
}

#[test]
fn a_bad_domain_id_is_refused_clearly() {
    let o = common::bin()
        .args(["follow", PROFILE, ASF, "--targets", "ros2", "--duration", "1"])
        .env("ROS_DOMAIN_ID", "300")
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .output()
        .unwrap();
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("ROS_DOMAIN_ID='300'") && err.contains("0 to 232"),
        "{err}"
    );
}

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

#[test]
fn a_cyclone_dds_peer_reads_the_joint_states_and_its_targets_move_the_rig() {
    let dir = tempdir("ros2");
    let targets = dir.join("walk.csv");
    let o = run(&["targets", ASF, AMC, "-o", targets.to_str().unwrap()]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The rig's metres per file unit: the default --scale 0.3 × the ASF's (length 0.45: one
    // unit is 1/0.45 inch).
    let metres_per_unit = 0.3 * 0.0254 / 0.45;
    // A domain of this run's own (ROS 2 allows 0–232).
    let domain = (100 + std::process::id() % 100).to_string();
    let got = dir.join("got.json");
    let stats = dir.join("stats.json");
    let manifest = env!("CARGO_MANIFEST_DIR");
    let mut peer = Command::new("python3")
        .arg(format!("{manifest}/tests/ros2/peer.py"))
        .args(["--domain", &domain, "--out", got.to_str().unwrap()])
        .args(["--targets", targets.to_str().unwrap()])
        .args([
            "--metres-per-unit",
            &metres_per_unit.to_string(),
            "--timeout",
            "60",
        ])
        .stdin(Stdio::null())
        .spawn()
        .expect("python3 with cyclonedds (pip install cyclonedds==11.0.1; .ci/run installs it)");
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
    let report = json(&got);
    let states = report["joint_states"].as_array().unwrap();
    let s = json(&stats);
    let final_present = s["final_present"].as_array().unwrap();
    let names: Vec<&str> = final_present
        .iter()
        .map(|p| p["name"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 28);
    assert_eq!(names[0], "lowerback_rx");

    // Every message published once the peer's reader had matched arrived (reliable, volatile:
    // the first few, before discovery ended, are for nobody), about 100 a second.
    assert!(published >= 900, "{published} published in 10 s at 100 Hz");
    assert!(
        states.len() <= published && states.len() + 50 >= published,
        "published {published}, received {}",
        states.len()
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
    // The rig moved while the targets came: some joint swept more than 0.3 rad.
    let sweep = (0..names.len())
        .map(|k| {
            let v: Vec<f64> = states
                .iter()
                .map(|m| m["position"][k].as_f64().unwrap())
                .collect();
            v.iter().copied().fold(f64::MIN, f64::max) - v.iter().copied().fold(f64::MAX, f64::min)
        })
        .fold(0.0, f64::max);
    assert!(sweep > 0.3, "largest sweep {sweep} rad");

    // The targets: every one used or superseded, the two bad ones refused, each solved.
    let sent = report["sent"]["targets"].as_u64().unwrap();
    assert!(sent > 1000, "{report}");
    assert!(out.contains("2 unreadable lines"), "{out}");
    assert!(s["inputs_used"].as_u64().unwrap() > 300, "{}", s["inputs_used"]);
    assert_eq!(s["inputs_rejected"].as_u64().unwrap(), 0);
    assert_eq!(s["unreachable"].as_u64().unwrap(), 0);
    let residual = s["ik_error_max"].as_f64().unwrap();
    assert!(residual < 1e-3, "IK residual {residual} file units");
    assert_eq!(s["allocations_in_tick"].as_u64(), Some(0));

    let mut latency: Vec<f64> = states
        .iter()
        .map(|m| (m["arrived_ns"].as_f64().unwrap() - m["stamp_ns"].as_f64().unwrap()) * 1e-3)
        .collect();
    latency.sort_by(f64::total_cmp);
    println!(
        "{} of {published} joint states received; read → peer: p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs; IK residual max {residual:.1e}; tick compute p99 {} µs",
        states.len(),
        quantile(&latency, 0.5),
        quantile(&latency, 0.99),
        latency.last().unwrap(),
        s["tick_compute_us"]["p99"]
    );
    let _ = std::fs::remove_dir_all(&dir);
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

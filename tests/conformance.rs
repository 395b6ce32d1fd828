//! ROBOTIS's own Python SDK (`dynamixel-sdk` 4.1.0) as a client of `marionette serve` and
//! `marionette sim serve`, both shipped profiles: the checks of `tests/conformance/sdk_check.py` (model numbers, pings,
//! register ranges and access, error codes, sync/bulk/fast reads, Reg Write/Action, Status
//! Return Levels, reboot, watchdog, factory reset rules). Every check must hold; a difference is
//! printed by name.

mod common;

use std::io::{BufRead, BufReader};
use std::process::Stdio;

/// One served chain and its client at a time: the SDK waits 34 ms for a reply, and two chains
/// with their clients (one stepping MuJoCo) on a two-core machine can keep a server from
/// answering that soon.
static ONE_CHAIN_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Runs the SDK checks against a chain served by `marionette ARGS`; returns (passed, total,
/// the failed checks).
fn sdk_checks(args: &[&str], profile: &str, sim: bool) -> (u64, u64, serde_json::Value) {
    common::needs_python("dynamixel_sdk", "dynamixel-sdk==4.1.0");
    let _one = ONE_CHAIN_AT_A_TIME
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let mut serve = common::bin()
        .args(args)
        .args(["--duration", "180"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(serve.stdout.take().unwrap()).lines();
    // The path comes on a line of its own.
    let path = lines
        .by_ref()
        .map_while(Result::ok)
        .find(|l| l.starts_with("/dev/pts/"))
        .expect("the served chain's path");
    assert!(path.starts_with("/dev/pts/"), "{path}");
    let out = std::process::Command::new("python3")
        .arg("tests/conformance/sdk_check.py")
        .arg(&path)
        .arg(profile)
        .arg("--json")
        .args(sim.then_some("--sim"))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("python3 runs");
    let _ = serve.kill();
    let _ = serve.wait();
    let stdout = String::from_utf8_lossy(&out.stdout);
    println!("{args:?}:\n{stdout}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "the SDK checks did not run");
    let v: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    (
        v["passed"].as_u64().unwrap(),
        v["total"].as_u64().unwrap(),
        v["failed"].clone(),
    )
}

#[test]
fn robotis_sdk_finds_the_served_servos_as_the_e_manual_describes_them() {
    for profile in [
        "firmware-profile/cmu-puppet.toml",
        "firmware-profile/robotis-op3.toml",
    ] {
        // At real-time priority, as servos keep their own time: a reply later than the SDK's
        // timeout (34 ms) on a loaded machine would be the host's, not the servo's.
        let args = ["serve", profile, "--rt-priority", "50"];
        let (passed, total, failed) = sdk_checks(&args, profile, false);
        assert!(total >= 45, "{total} checks");
        // Every check: a difference from the e-manual is a defect, not a tolerance.
        assert_eq!(passed, total, "{profile}: different: {failed}");
    }
}

/// The same checks against the servos simulated in MuJoCo (`sim serve`, line time kept).
#[cfg(feature = "sim")]
#[test]
fn robotis_sdk_finds_the_simulated_servos_as_the_e_manual_describes_them() {
    for (profile, extra) in [
        ("firmware-profile/cmu-puppet.toml", Some("data/cmu/16.asf")),
        (
            "firmware-profile/robotis-op3.toml",
            Some("--model=sim/models/robotis_op3/op3.xml"),
        ),
    ] {
        let mut args = vec!["sim", "serve", profile];
        args.extend(extra);
        let (passed, total, failed) = sdk_checks(&args, profile, true);
        assert!(total >= 45, "{total} checks");
        assert_eq!(passed, total, "{profile} in MuJoCo: different: {failed}");
    }
}

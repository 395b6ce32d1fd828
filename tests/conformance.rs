//! ROBOTIS's own Python SDK (`dynamixel-sdk` 4.1.0) as a client of `marionette serve`, both
//! shipped profiles: the checks of `tests/conformance/sdk_check.py` (model numbers, pings,
//! register ranges and access, error codes, sync/bulk/fast reads, Reg Write/Action, Status
//! Return Levels, reboot, watchdog, factory reset rules). At least 95 % must hold; the rest are
//! printed by name.

mod common;

use std::io::{BufRead, BufReader};
use std::process::Stdio;

#[test]
fn robotis_sdk_finds_the_served_servos_as_the_e_manual_describes_them() {
    for profile in [
        "firmware-profile/cmu-puppet.toml",
        "firmware-profile/robotis-op3.toml",
    ] {
        let mut serve = common::bin()
            .args(["serve", profile, "--duration", "120"])
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(serve.stdout.take().unwrap()).lines();
        let _ = lines.next();
        let path = lines.next().unwrap().unwrap();
        assert!(path.starts_with("/dev/pts/"), "{path}");
        let out = std::process::Command::new("python3")
            .arg("tests/conformance/sdk_check.py")
            .arg(&path)
            .arg(profile)
            .arg("--json")
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .output()
            .expect("python3 with dynamixel-sdk 4.1.0 (see .ci/run)");
        let _ = serve.kill();
        let _ = serve.wait();
        let stdout = String::from_utf8_lossy(&out.stdout);
        println!("{profile}:\n{stdout}{}", String::from_utf8_lossy(&out.stderr));
        assert!(out.status.success(), "the SDK checks did not run");
        let v: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
        let (passed, total) = (v["passed"].as_u64().unwrap(), v["total"].as_u64().unwrap());
        assert!(total >= 45, "{total} checks");
        assert!(
            passed * 100 >= 95 * total,
            "{profile}: {passed} of {total}; different: {}",
            v["failed"]
        );
    }
}

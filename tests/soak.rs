//! The fault soak (`marionette soak`): a short one here, every fault kind through the whole
//! loop; the million-fault figures come from the command (docs/robustness.md).

mod common;

use std::sync::Arc;

use marionette::bus::faults::Fault;
use marionette::formats::{amc, asf};
use marionette::profile::Profile;
use marionette::session::soak::{soak, SoakConfig};

#[test]
fn a_short_soak_counts_no_violation_and_recovers_within_a_tick() {
    let skeleton = Arc::new(asf::load(&common::data("16.asf")).unwrap().skeleton);
    let motion = Arc::new(amc::load(&skeleton, &common::data("16_15.amc")).unwrap());
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let profile = Profile::load(&path).unwrap();
    let rig = profile.rig(Some(&skeleton)).unwrap();
    let config = SoakConfig {
        faults: 30_000,
        seed: 7,
        ..SoakConfig::default()
    };
    let mut progress = 0;
    let r = soak(&skeleton, &motion, &profile, &rig, &config, |_| progress += 1).unwrap();
    println!("{r}");
    assert!(r.faults >= 30_000);
    assert!(progress > 0);
    for (kind, n) in &r.faults_by_kind {
        assert!(*n > 0, "no {kind} fault applied");
    }
    assert_eq!(r.faults_by_kind.len(), Fault::ALL.len());
    assert_eq!(r.panics, 0);
    assert_eq!(r.corrupt_values_used, 0);
    assert_eq!(r.commands_outside_limits, 0);
    assert_eq!(r.goals_outside_limits, 0);
    assert_eq!(r.torque_left_on, 0);
    // The figures are of a loop that ran, failed, held, stopped and recovered.
    assert!(r.reads_used > 1000 && r.reads_failed > 100 && r.held_ticks > 0);
    assert!(
        r.torque_off_stops > 0,
        "no burst was long enough to stop the loop"
    );
    assert!(r.recovery_ticks.iter().sum::<u64>() > 100);
    assert!(r.recovery_max_ticks <= 1, "{}", r.recovery_max_ticks);
    // The same seed replays the same soak.
    let again = soak(&skeleton, &motion, &profile, &rig, &config, |_| {}).unwrap();
    assert_eq!(again.faults_by_kind, r.faults_by_kind);
    assert_eq!(again.ticks, r.ticks);
}

#[test]
fn the_soak_command_prints_its_figures() {
    let dir = common::tempdir("soak");
    let json = dir.join("soak.json");
    let out = common::run(&[
        "soak",
        "firmware-profile/cmu-puppet.toml",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--faults",
        "5000",
        "--json",
        json.to_str().unwrap(),
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}{}", String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success());
    for line in [
        "panics                 0",
        "corrupt values used    0",
        "goals outside limits   0",
        "recovery max",
    ] {
        assert!(text.contains(line), "{line}: {text}");
    }
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(v["faults"].as_u64().unwrap() >= 5000);
    let bad = common::run(&[
        "soak",
        "firmware-profile/cmu-puppet.toml",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--rate",
        "0",
    ]);
    assert_eq!(bad.status.code(), Some(2));
}

//! `doctor`: a rig made wrong on purpose (virtual chains served on a pseudo-terminal, line time
//! kept) is checked against its profile: every fault named, the exit code, and `--fix`.

mod common;

use marionette::bus::virtual_chain::{chain_for, LineTiming, PtyChain};
use marionette::bus::{open, Wire};
use marionette::device::{Chain, VirtualServo};
use marionette::doctor::{self, Level, Report};
use marionette::profile::Profile;
use marionette::servo::{addr, MODELS};

fn op3() -> Profile {
    Profile::load(
        &std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/robotis-op3.toml"),
    )
    .unwrap()
}

/// Serves `chain` and checks it against `profile` (and with `fix`, fixes, then checks again).
fn doctor_on(profile: &Profile, chain: Chain, fix: bool) -> (Report, Option<Report>, Vec<String>) {
    let pty = PtyChain::serve_timed(chain, LineTiming::of(&profile.bus)).unwrap();
    let as_found = doctor::bus_as_found(&profile.bus);
    let mut bus = open(
        Wire::Port(pty.path().to_string()),
        &as_found,
        profile.servos.len(),
    )
    .unwrap();
    let first = doctor::examine(bus.as_mut(), profile).unwrap();
    if !fix {
        return (first, None, Vec::new());
    }
    let fixed = doctor::apply_fixes(bus.as_mut(), &first).unwrap();
    let again = doctor::examine(bus.as_mut(), profile).unwrap();
    (first, Some(again), fixed)
}

/// `serve` of the OP3's chain made wrong by `misconfigure`, then `doctor` on its pseudo-terminal
/// with `extra` arguments: its output and stdout (printed).
fn doctor_on_served(misconfigure: &str, extra: &[&str]) -> (std::process::Output, String) {
    let mut serve = common::bin()
        .args(["serve", "firmware-profile/robotis-op3.toml", "--duration", "60"])
        .args(["--misconfigure", misconfigure])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufRead::lines(std::io::BufReader::new(serve.stdout.take().unwrap()));
    let first = lines.next().unwrap().unwrap();
    let path = first
        .split_whitespace()
        .find(|w| w.starts_with("/dev/pts/"))
        .unwrap()
        .trim_end_matches(',')
        .to_string();
    let mut args = vec!["doctor", "firmware-profile/robotis-op3.toml", "--port", &path];
    args.extend_from_slice(extra);
    let out = common::run(&args);
    let _ = serve.kill();
    let _ = serve.wait();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    println!("{text}");
    (out, text)
}

/// `doctor` exited 1 and its output has each of `lines`.
fn exits_1_naming((out, text): (std::process::Output, String), lines: &[&str]) {
    assert_eq!(
        out.status.code(),
        Some(1),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for words in lines {
        assert!(text.contains(words), "{words}: {text}");
    }
}

fn named(report: &Report, level: Level, id: Option<u8>, words: &str) -> bool {
    report
        .findings
        .iter()
        .any(|f| f.level == level && f.id == id && f.what.contains(words))
}

#[test]
fn a_rig_as_the_profile_says_is_ready() {
    let profile = op3();
    let mut chain = chain_for(profile.bus_section(), |_| 2048);
    // As start-up leaves it: the profile's Return Delay Time.
    for s in chain.servos_mut() {
        s.poke(addr::RETURN_DELAY_TIME, &[0]);
    }
    let (report, _, _) = doctor_on(&profile, chain, false);
    println!("{report:#?}");
    assert!(report.can_run());
    assert_eq!(report.at(Level::Fault).count(), 0);
    // No servo warns; the cycle's own line is a measured time, printed, not asserted.
    assert!(
        report
            .at(Level::Warn)
            .all(|f| f.id.is_none() && f.what.contains("cycle")),
        "{report:?}"
    );
    let measured = report.measured_cycle_us.unwrap();
    println!(
        "cycle {measured:.0} µs against {:.0} µs planned",
        report.planned_cycle_us
    );
    assert!(measured > 0.0);
}

#[test]
fn every_fault_is_named_and_what_can_be_written_is_fixed() {
    let profile = op3();
    let spec = |id: u8| profile.servos.iter().find(|s| s.id == id).unwrap();
    let mut chain = Chain::new();
    for s in &profile.servos {
        match s.id {
            // Missing.
            5 => continue,
            // Another model at the id.
            6 => chain.add(VirtualServo::new(6, &MODELS[0], 2048)).unwrap(),
            _ => chain.add(VirtualServo::new(s.id, s.model, 2048)).unwrap(),
        }
    }
    // An id the profile does not name.
    chain.add(VirtualServo::new(42, spec(1).model, 2048)).unwrap();
    chain.set_board(marionette::sensor_board::SensorBoard::new(200));
    chain.servo_mut(1).unwrap().raise_hardware_error(0x04);
    chain.servo_mut(2).unwrap().poke(addr::OPERATING_MODE, &[1]);
    chain
        .servo_mut(3)
        .unwrap()
        .poke(addr::MAX_POSITION_LIMIT, &2100u32.to_le_bytes());
    chain.servo_mut(4).unwrap().poke(addr::STATUS_RETURN_LEVEL, &[1]);
    chain
        .servo_mut(7)
        .unwrap()
        .poke(addr::VELOCITY_LIMIT, &100u32.to_le_bytes());
    chain
        .servo_mut(8)
        .unwrap()
        .poke(addr::PWM_LIMIT, &500u16.to_le_bytes());
    let (first, again, fixed) = doctor_on(&profile, chain, true);
    for f in &first.findings {
        println!(
            "{:?} {:?} {}: {} — {}",
            f.level,
            f.id,
            f.servo.as_deref().unwrap_or(""),
            f.what,
            f.todo
        );
    }
    assert!(!first.can_run());
    assert!(named(&first, Level::Fault, Some(5), "does not answer"));
    assert!(named(
        &first,
        Level::Fault,
        Some(6),
        "the profile says XM430-W350"
    ));
    assert!(named(&first, Level::Warn, Some(42), "does not name it"));
    assert!(named(&first, Level::Fault, Some(1), "overheating"));
    assert!(named(&first, Level::Fault, Some(2), "Operating Mode 1"));
    assert!(named(&first, Level::Warn, Some(3), "position limits"));
    assert!(named(&first, Level::Warn, Some(4), "Status Return Level 1"));
    assert!(named(&first, Level::Warn, Some(7), "Velocity Limit 100"));
    assert!(named(&first, Level::Warn, Some(8), "PWM Limit 500"));
    // The factory Return Delay Time (500 µs) on every servo present.
    assert!(named(&first, Level::Warn, Some(10), "Return Delay Time 500 µs"));
    // Every fixable one written, and gone when checked again; what cannot be written stays.
    println!("{fixed:#?}");
    assert!(fixed.len() >= 6);
    let again = again.unwrap();
    for f in &again.findings {
        println!("after --fix: {:?} {:?} {}", f.level, f.id, f.what);
    }
    assert!(!named(&again, Level::Fault, Some(2), "Operating Mode"));
    assert!(!named(&again, Level::Warn, Some(3), "position limits"));
    assert!(!named(&again, Level::Warn, Some(7), "Velocity Limit"));
    assert!(!named(&again, Level::Warn, Some(10), "Return Delay Time"));
    assert!(named(&again, Level::Fault, Some(5), "does not answer"));
    // The hardware error's servo rebooted, its error cleared (its cause was gone).
    assert!(!named(&again, Level::Fault, Some(1), "overheating"));
    assert!(
        fixed
            .iter()
            .any(|l| l == "id 1 r_sho_pitch: rebooted; the hardware error 0x04 (overheating) is cleared"),
        "{fixed:#?}"
    );
    assert!(!again.can_run());
}

#[test]
fn the_command_exits_1_with_faults_and_0_when_the_rig_can_run() {
    let out = common::run(&["doctor", "firmware-profile/robotis-op3.toml", "--bus", "virtual"]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    // Fresh virtual servos: the factory Return Delay Time is a warning, not a fault.
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("all 20 servos: Return Delay Time 500 µs"), "{text}");
    assert!(text.contains("the rig can run the profile"));
    let out = common::run(&[
        "doctor",
        "firmware-profile/cmu-puppet.toml",
        "--bus",
        "virtual",
        "--fix",
        "--json",
    ]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["fixed"].as_array().unwrap().len(), 28, "{v}");
    assert!(
        v["findings"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["level"] != "fault"),
        "{v}"
    );
    // The virtual servos are powered as the profile says (the puppet's knees and ankles at
    // 14.8 V): no supply finding.
    assert!(
        v["findings"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| !f["what"].as_str().unwrap().contains("supply")),
        "{v}"
    );
    // A chain made wrong from the command line (`serve --misconfigure`), checked over its
    // pseudo-terminal: every fault named, exit 1.
    exits_1_naming(
        doctor_on_served(
            "missing=5,model=6:XL330-M288,hwerror=1:4,max_limit=3:2100,extra=42",
            &[],
        ),
        &[
            "id 5 r_el: id 5 does not answer at 2000000 bit/s",
            "id 6 l_el: id 6 is model 1200 (XL330-M288)",
            "id 42 (XM430-W350) answers but the profile does not name it",
            "id 1 r_sho_pitch: hardware error 0x04 (overheating)",
            "id 3 r_sho_roll: position limits",
            "Return Delay Time 500 µs",
            "the rig cannot run the profile",
        ],
    );
    // A list it cannot read: a usage error naming the item.
    let out = common::run(&[
        "serve",
        "firmware-profile/robotis-op3.toml",
        "--misconfigure",
        "rdt=1",
    ]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("`rdt=1`"));
    // No way to reach a rig: a usage error.
    let out = common::run(&["doctor", "firmware-profile/robotis-op3.toml"]);
    assert_eq!(out.status.code(), Some(2));
}

/// Servos set to other bauds than the profile's are silent at its baud (the served chain keeps
/// to the baud the client sets): `doctor` finds each at its own baud, `--fix` sets it to the
/// profile's there, and the rig then starts.
#[test]
fn servos_at_other_bauds_are_found_and_moved_to_the_profiles() {
    use std::io::{BufRead, BufReader};
    let mut serve = common::bin()
        .args(["serve", "firmware-profile/robotis-op3.toml", "--misconfigure"])
        .arg("baud=5:57600,baud=6:1000000")
        .args(["--duration", "60"])
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(serve.stdout.take().unwrap()).lines();
    let _ = lines.next().unwrap().unwrap();
    let path = lines.next().unwrap().unwrap();
    // At the profile's baud they are silent: start-up refuses the rig.
    let play = |extra: &[&str]| {
        let mut args = vec![
            "play",
            "firmware-profile/robotis-op3.toml",
            "data/cmu/16.asf",
            "data/cmu/16_15.amc",
            "--upper-body",
            "--bus",
            &path,
            "-q",
        ];
        args.extend_from_slice(extra);
        common::run(&args)
    };
    let out = play(&["--duration", "0.5"]);
    assert_ne!(out.status.code(), Some(0));
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("5"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = common::run(&["doctor", "firmware-profile/robotis-op3.toml", "--port", &path]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text.contains("id 5 r_el: answers at 57600 bit/s (XM430-W350), not the profile's 2000000"),
        "{text}"
    );
    assert!(text.contains("id 6 l_el: answers at 1000000 bit/s"), "{text}");
    assert!(text.contains("18 of 20 servos answer at 2000000 bit/s"), "{text}");
    let out = common::run(&[
        "doctor",
        "firmware-profile/robotis-op3.toml",
        "--port",
        &path,
        "--fix",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    println!("{text}");
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(
        text.contains("fixed  id 5 r_el: Baud Rate set to 2000000 bit/s (written at 57600)"),
        "{text}"
    );
    assert!(
        text.contains("20 of 20 servos answer at 2000000 bit/s; 0 fault(s)"),
        "{text}"
    );
    let out = play(&["--duration", "0.5"]);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = serve.kill();
    let _ = serve.wait();
}

/// A read lost now and then while the cycle is timed (a busy host, a noisy line) is counted
/// and reported as a warning — the rig can still run — not taken for a broken bus.
#[test]
fn reads_lost_while_the_cycle_is_timed_are_counted_not_fatal() {
    use marionette::bus::faults::{Fault, FaultInjector};
    use marionette::bus::packet::PacketBus;
    use marionette::bus::virtual_chain::InProcess;
    let p = Profile::load(
        &std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml"),
    )
    .unwrap();
    let chain = chain_for(p.bus_section(), |k| p.servos[k].zero as i32);
    let mut bus = PacketBus::new(
        InProcess::new(chain, p.bus.baud),
        std::time::Duration::from_millis(2),
    );
    bus.link_mut().injector = Some(FaultInjector::new(3, 0.003, &[Fault::Drop], 0));
    let report = doctor::examine(&mut bus, &p).unwrap();
    let lost = report
        .findings
        .iter()
        .find(|f| f.what.contains("lost their read"));
    assert!(lost.is_some_and(|f| f.level == Level::Warn), "{report:#?}");
    assert!(report.measured_cycle_us.is_some());
    assert!(report.can_run(), "{report:#?}");
}

/// A hardware error whose cause is still there (a servo at 95 °C, past its 80 °C limit):
/// `--fix` reboots it, says the error came back, and the rig still cannot run.
#[test]
fn a_reboot_says_when_the_hardware_errors_cause_remains() {
    exits_1_naming(
        doctor_on_served("temp=1:95", &["--fix"]),
        &[
            "id 1 r_sho_pitch: rebooted, but hardware error 0x04 (overheating) again: its cause is still there",
            "id 1 r_sho_pitch: at 9",
            "the rig cannot run the profile",
        ],
    );
}

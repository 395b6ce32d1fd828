//! The loop's health watch over a served virtual chain (line time kept): a servo warm from
//! an earlier run, past its thresholds, or off its supply range, as `serve --misconfigure`
//! makes it; the run warns, or ends eased to rest with torque off and one line naming the
//! servo and why.

mod common;

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::Stdio;

use marionette::bus::virtual_chain::VirtualRig;
use marionette::control::health::HealthWatch;

fn puppet() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml")
}

/// One served chain and its run at a time: each pair keeps line time, and two pairs on a
/// two-core machine starve each other.
static SERVED: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// `serve --misconfigure SPEC`, then `play` of the bundled walk there: (exit code, stdout,
/// stderr, the stats JSON). The run turns torque off after a second without a valid read,
/// not the default 100 ms: a loaded machine pauses the serving process longer than that, and
/// what is tested here is the health watch.
fn play_on(spec: &str, extra: &[&str]) -> (Option<i32>, String, String, serde_json::Value) {
    let _one = SERVED.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let mut served = common::bin()
        .arg("serve")
        .arg(puppet())
        .args(["--misconfigure", spec, "--duration", "60"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(served.stdout.take().unwrap()).lines();
    let _ = lines.next().unwrap().unwrap();
    let port = lines.next().unwrap().unwrap();
    let dir = common::tempdir("health");
    let json = dir.join("stats.json");
    let out = common::bin()
        .arg("play")
        .arg(puppet())
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--bus", &port, "--rate", "120", "--torque-off-after", "1000"])
        .args(["-q", "--stats-json"])
        .arg(&json)
        .args(extra)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let _ = served.kill();
    let _ = served.wait();
    let (stdout, stderr) = (
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    );
    let text = std::fs::read_to_string(&json).unwrap_or_else(|e| {
        panic!(
            "no stats JSON ({e}); play exited {:?}:\n{stdout}{stderr}",
            out.status
        )
    });
    let stats = serde_json::from_str(&text).unwrap();
    (out.status.code(), stdout, stderr, stats)
}

#[test]
fn a_servo_near_its_temperature_limit_ends_the_run_eased_to_rest_naming_it() {
    // lowerneck_ry, an XM430-W350 (Temperature Limit 80 °C), at 79 °C.
    // Looped: a read that fails on a loaded machine leaves the servo to the next round.
    let (code, out, err, stats) = play_on("temp=5:79", &["--loop", "--duration", "30"]);
    println!("{out}{err}");
    assert_eq!(code, Some(1));
    // It cools a little (idle, torque on) during the move to the first pose before its read.
    assert!(
        err.contains("id 5 lowerneck_ry: 7")
            && err.contains("Temperature Limit of 80 °C")
            && err.contains("eased to rest"),
        "{err}"
    );
    assert_eq!(stats["end"], "servo health");
    assert!(
        out.contains("ended: servo health; torque off, acknowledged by"),
        "{out}"
    );
    let health = &stats["health"];
    assert!(health["stopped"]
        .as_str()
        .unwrap()
        .starts_with("id 5 lowerneck_ry"));
    // It stopped at the servo's first read: its turn comes after four servos' two reads. (A
    // read that failed on a busy machine is tried once more at once, or, failed again, leaves
    // its servo to the next round; the count then depends on which failed.)
    let (reads, failed) = (
        health["reads"].as_u64().unwrap(),
        health["reads_failed"].as_u64().unwrap(),
    );
    if failed == 0 {
        assert_eq!(reads, 9, "{health}");
    }
    assert_eq!(stats["allocations_in_tick"], 0, "{stats}");
}

#[test]
fn a_warm_servo_warns_and_the_run_goes_on() {
    // lowerback_rz, an XH540-W270 (80 °C): warned from 65 °C, eased to rest from 75 °C. Idle
    // with torque on it cools about 0.4 °C a second before its first read, which a loaded
    // machine makes later: 70 °C leaves room for that. Longer than a round of reads (5.6 s
    // at 120 Hz), as a read that fails on a loaded machine leaves the servo to the next.
    let (code, out, err, stats) = play_on("temp=3:70", &["--loop", "--duration", "7"]);
    assert_eq!(code, Some(0), "{out}{err}");
    let warned = out
        .split("health warning: id 3 lowerback_rz: ")
        .nth(1)
        .and_then(|rest| rest.split(" °C, warm (it eases to rest at 75 °C)").next())
        .and_then(|c| c.parse::<u32>().ok());
    assert!(warned.is_some_and(|c| (65..=70).contains(&c)), "{out}");
    assert_eq!(stats["end"], "duration reached");
    let servos = stats["health"]["servos"].as_array().unwrap();
    assert_eq!(servos[2]["warned"], true);
    assert!(servos
        .iter()
        .filter(|s| s["id"] != 3)
        .all(|s| s["warned"] == false));
    // The others read the air's temperature and the profile's supply.
    assert_eq!(servos[0]["temperature_c"], 25);
    assert_eq!(servos[0]["voltage_v"], 12.0);
}

#[test]
fn a_supply_off_the_models_range_ends_the_run() {
    let (code, _, err, stats) = play_on("supply=2:9.2", &["--loop", "--duration", "30"]);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("id 2 lowerback_ry: supply 9.2 V, outside the model's 10…14.8 V"),
        "{err}"
    );
    assert_eq!(stats["health"]["servos"][1]["lowest_v"], 9.2);
}

/// The puppet's chain in process, at rest, and a health watch over it at 120 Hz.
fn watched_puppet() -> (VirtualRig, HealthWatch) {
    use marionette::bus::virtual_chain::chain_for;
    use marionette::profile::Profile;
    let profile = Profile::load(&puppet()).unwrap();
    let chain = chain_for(profile.bus_section(), |_| 2048);
    let rig = VirtualRig::new(chain, profile.bus.baud, std::time::Duration::from_millis(5));
    let watch = HealthWatch::of_profile(&profile, 120.0);
    (rig, watch)
}

#[test]
fn a_hardware_error_raised_mid_run_is_read_at_the_servos_turn() {
    let (mut rig, mut watch) = watched_puppet();
    // At 120 Hz a read every 12 ticks.
    assert_eq!(watch.every(), 12);
    let mut ticks = 0;
    while ticks < 12 * 2 * 28 {
        assert!(!watch.read(&mut rig), "healthy servos never stop it");
        ticks += 1;
    }
    // Every servo read once, each twice (vitals, then errors).
    let report = watch.report();
    assert_eq!(report.reads, 56);
    assert!(report.servos.iter().all(|s| s.temperature_c == Some(25)));
    // Overload on servo 4 mid-run: found at its next error read, within one round.
    rig.with(|t| t.chain_mut().servo_mut(4).unwrap().raise_hardware_error(0x20));
    let mut stopped_after = None;
    for k in 1..=12 * 2 * 28 {
        if watch.read(&mut rig) {
            stopped_after = Some(k);
            break;
        }
    }
    assert!(stopped_after.is_some());
    assert_eq!(
        watch.stopped().unwrap(),
        "id 4 lowerneck_rx: hardware error 0x20 (overload)"
    );
    // It stays stopped.
    assert!(watch.read(&mut rig));
}

/// A reply's alert flag brings that servo's Hardware Error Status read to the next slot, out
/// of turn and without moving the rotation; one found clear is not read again for its flags
/// until its turn, and ids the watch does not have are passed over.
#[test]
fn an_alert_brings_the_servos_error_read_forward() {
    let (mut rig, mut watch) = watched_puppet();
    let reads = |w: &HealthWatch| (w.report().reads, w.report().alert_reads);
    // The IMU board's id, or any the watch does not have: nothing.
    watch.alert(200);
    assert!(!watch.read(&mut rig));
    assert_eq!(reads(&watch), (0, 0));
    // Servo 9 (no error: a flag the watch cannot confirm) is read at once, out of turn.
    watch.alert(9);
    assert!(!watch.read(&mut rig));
    assert_eq!(reads(&watch), (1, 1));
    // Found clear: its flags are passed over until its turn; the rotation's first read comes
    // at its tick as if nothing had happened (the 12th tick that is not a read out of turn).
    for tick in 2..12 {
        watch.alert(9);
        assert!(!watch.read(&mut rig));
        assert_eq!(reads(&watch), (1, 1), "tick {tick}");
    }
    watch.alert(9);
    assert!(!watch.read(&mut rig));
    assert_eq!(reads(&watch), (2, 1));
    assert_eq!(
        watch.report().servos[0].temperature_c,
        Some(25),
        "servo 1's vitals, in turn"
    );
    // A servo that shut itself down is found at the next slot.
    rig.with(|t| t.chain_mut().servo_mut(5).unwrap().raise_hardware_error(0x20));
    watch.alert(5);
    assert!(watch.read(&mut rig));
    assert_eq!(reads(&watch), (3, 2));
    assert_eq!(
        watch.stopped().unwrap(),
        "id 5 lowerneck_ry: hardware error 0x20 (overload)"
    );
}

#[test]
fn no_health_turns_the_watch_off() {
    // Without the watch, a warm servo is not read: the run plays to its end.
    let (code, out, err, stats) = play_on("temp=5:79", &["--no-health", "--duration", "1.5"]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(stats.get("health").is_none_or(serde_json::Value::is_null));
}

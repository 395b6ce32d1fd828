//! Stopping `play` and `follow` from outside, as users and service managers do: each
//! termination signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT) eases to rest and turns torque off on
//! every servo before the process exits — checked in the record of the virtual chain the
//! process drives, served here on a pseudo-terminal; a second signal cuts the ramp short; and
//! the port vanishing mid-run (the pty's other end closed: EIO) ends the run with one line that
//! names the port.

mod common;

use std::io::{BufRead, BufReader};
use std::process::{Child, ChildStdout, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use marionette::bus::virtual_chain::{chain_for, PtyChain, TorqueEvent};
use marionette::formats::asf;
use marionette::profile::Profile;
use marionette::rig::ServoMap;

const PROFILE: &str = "firmware-profile/cmu-puppet.toml";

/// One test at a time: a process that one test starts while another test's pseudo-terminal is
/// being opened could inherit its device end (the open and the close-on-exec flag are two
/// steps) and keep that line up after the chain closed it.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static ONE: std::sync::Mutex<()> = std::sync::Mutex::new(());
    ONE.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The puppet's 28 servos standing at their zero angle, served on a pseudo-terminal.
fn serve_puppet() -> (PtyChain, Profile) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(PROFILE);
    let profile = Profile::load(&path).unwrap();
    let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let rig = profile.rig(Some(&skeleton)).unwrap();
    let rest: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let chain = PtyChain::serve(chain_for(profile.bus_section(), |k| rest[k]), None).unwrap();
    (chain, profile)
}

/// Lines of the child's stdout as they come.
fn lines(stdout: ChildStdout) -> mpsc::Receiver<String> {
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    rx
}

/// Waits for a line containing `what`; returns every line read so far.
fn wait_for(rx: &mpsc::Receiver<String>, what: &str, child: &mut Child) -> Vec<String> {
    let mut seen = Vec::new();
    loop {
        match rx.recv_timeout(Duration::from_secs(60)) {
            Ok(l) => {
                let found = l.contains(what);
                seen.push(l);
                if found {
                    return seen;
                }
            }
            Err(_) => {
                let _ = child.kill();
                panic!("no line with `{what}`; read: {seen:?}");
            }
        }
    }
}

/// `play` (looping the clip, so only a stop ends it) on the chain at `port`.
fn spawn_play(port: &str, extra: &[&str]) -> Child {
    common::bin()
        .arg("play")
        .arg(PROFILE)
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--bus", port, "--rate", "100", "-q", "--loop"])
        .args(extra)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

fn signal(child: &Child, name: &str) {
    let ok = std::process::Command::new("kill")
        .args([format!("-{name}"), child.id().to_string()])
        .status()
        .unwrap()
        .success();
    assert!(ok, "kill -{name}");
}

/// Waits for the child to exit (killing it after a minute); returns its output and the moment
/// its exit was seen.
fn finish(
    mut child: Child,
    rx: &mpsc::Receiver<String>,
) -> (std::process::ExitStatus, String, String, Instant) {
    let began = Instant::now();
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if began.elapsed() > Duration::from_secs(60) {
            let _ = child.kill();
            panic!("the process did not exit within a minute of the signal");
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let exited = Instant::now();
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
    }
    let mut stdout = String::new();
    while let Ok(l) = rx.recv_timeout(Duration::from_millis(500)) {
        stdout.push_str(&l);
        stdout.push('\n');
    }
    (status, stdout, stderr, exited)
}

/// In the chain's record: every servo was turned on, then off, and off before `exited`.
fn assert_torque_went_off_before(log: &[TorqueEvent], profile: &Profile, exited: Instant) {
    for s in &profile.servos {
        let events: Vec<&TorqueEvent> = log.iter().filter(|e| e.id == s.id).collect();
        assert!(
            events.first().is_some_and(|e| e.on),
            "servo {}: never turned on: {events:?}",
            s.id
        );
        let last = events.last().unwrap();
        assert!(
            !last.on,
            "servo {} ({}): torque still on at the end",
            s.id, s.name
        );
        assert!(
            last.at < exited,
            "servo {}: torque off only after the process exited",
            s.id
        );
    }
}

#[test]
fn every_termination_signal_eases_to_rest_and_turns_torque_off() {
    let _one_at_a_time = serial();
    for sig in ["INT", "TERM", "HUP", "QUIT"] {
        let (chain, profile) = serve_puppet();
        let mut child = spawn_play(chain.path(), &["--ramp", "0.3"]);
        let rx = lines(child.stdout.take().unwrap());
        wait_for(&rx, "servos up", &mut child);
        // Let the clip move the servos away from rest first.
        std::thread::sleep(Duration::from_millis(700));
        let moved = chain.chain().servos().iter().any(|s| s.goal_writes() > 10);
        signal(&child, sig);
        let (status, stdout, stderr, exited) = finish(child, &rx);
        println!("SIG{sig}:\n{stdout}{stderr}");
        assert!(moved, "SIG{sig}: the loop ran before the signal");
        assert!(status.success(), "SIG{sig}: {status:?}\n{stderr}");
        assert!(
            stdout.contains("ended: interrupted; torque off, acknowledged by 28 servos"),
            "SIG{sig}: {stdout}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
        assert_torque_went_off_before(&chain.torque_log(), &profile, exited);
        // The ramp ran to its end: every servo's last goal is its rest position (±1 tick).
        let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
        let rig = profile.rig(Some(&skeleton)).unwrap();
        for (v, r) in chain.chain().servos().iter().zip(&rig.servos) {
            let rest = r.rest_tick();
            assert!(
                (v.goal_tick() - rest).abs() <= 1,
                "SIG{sig}: servo {} goal {} rest {rest}",
                v.id(),
                v.goal_tick()
            );
        }
    }
}

#[test]
fn a_second_signal_during_the_ramp_turns_torque_off_at_once() {
    let _one_at_a_time = serial();
    let (chain, profile) = serve_puppet();
    let dir = common::tempdir("second-signal");
    let stats = dir.join("stats.json");
    let mut child = spawn_play(
        chain.path(),
        &["--ramp", "30", "--stats-json", stats.to_str().unwrap()],
    );
    let rx = lines(child.stdout.take().unwrap());
    wait_for(&rx, "servos up", &mut child);
    std::thread::sleep(Duration::from_millis(700));
    signal(&child, "TERM");
    // Into the 30 s ramp, then the second signal.
    std::thread::sleep(Duration::from_millis(300));
    signal(&child, "TERM");
    let (status, stdout, stderr, exited) = finish(child, &rx);
    println!("{stdout}{stderr}");
    assert!(status.success(), "{status:?}\n{stderr}");
    assert_torque_went_off_before(&chain.torque_log(), &profile, exited);
    // The ramp was cut: a 30 s ramp at 100 Hz is 3000 ticks; the run's ticks are those before
    // the first signal, and the stats file was still written.
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    assert_eq!(v["end"], "interrupted");
    assert_eq!(v["torque_off_acknowledged"], 28);
    let writes: u32 = chain
        .chain()
        .servos()
        .iter()
        .map(|s| s.goal_writes())
        .max()
        .unwrap();
    let ticks = v["ticks"].as_u64().unwrap();
    assert!(
        u64::from(writes) < ticks + 1500,
        "{writes} goal writes: the ramp of 3000 ticks was not cut short ({ticks} loop ticks)"
    );
}

#[test]
fn follow_stops_on_sigterm_with_torque_off() {
    let _one_at_a_time = serial();
    let (chain, profile) = serve_puppet();
    let dir = common::tempdir("follow-term");
    let targets = dir.join("targets.csv");
    let made = common::run(&[
        "targets",
        "data/cmu/16.asf",
        "data/cmu/16_15.amc",
        "--output",
        targets.to_str().unwrap(),
    ]);
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let mut child = common::bin()
        .arg("follow")
        .arg(PROFILE)
        .arg(common::data("16.asf"))
        .args(["--targets", targets.to_str().unwrap(), "--loop"])
        .args(["--bus", chain.path(), "--rate", "100", "-q", "--ramp", "0.3"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let rx = lines(child.stdout.take().unwrap());
    wait_for(&rx, "servos up", &mut child);
    std::thread::sleep(Duration::from_millis(700));
    signal(&child, "TERM");
    let (status, stdout, stderr, exited) = finish(child, &rx);
    println!("{stdout}{stderr}");
    assert!(status.success(), "{status:?}\n{stderr}");
    assert!(
        stdout.contains("ended: interrupted; torque off, acknowledged by 28 servos"),
        "{stdout}"
    );
    assert_torque_went_off_before(&chain.torque_log(), &profile, exited);
}

#[test]
fn the_port_vanishing_mid_run_ends_with_one_line_naming_it() {
    let _one_at_a_time = serial();
    let (chain, _profile) = serve_puppet();
    let port = chain.path().to_string();
    let mut child = spawn_play(&port, &["--ramp", "0.3"]);
    let rx = lines(child.stdout.take().unwrap());
    wait_for(&rx, "servos up", &mut child);
    std::thread::sleep(Duration::from_millis(500));
    // The adapter is unplugged: the other end of the pseudo-terminal closes.
    drop(chain);
    let (status, stdout, stderr, _) = finish(child, &rx);
    println!("{stdout}---\n{stderr}");
    assert_eq!(status.code(), Some(1), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let errors: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(errors.len(), 1, "one line: {errors:?}");
    assert!(
        errors[0].starts_with(&format!("marionette: error: {port} went away mid-run (")),
        "{}",
        errors[0]
    );
    assert!(
        stdout.contains("ended: port lost; one torque-off Sync Write tried"),
        "{stdout}"
    );
}

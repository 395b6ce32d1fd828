//! `marionette studio`: the JSON API against the running loop on the virtual chain, and the page
//! in a real browser (headless Chromium through ChromeDriver and Selenium).
#![cfg(feature = "studio")]

mod common;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use glam::DVec3;
use marionette::fk::{fk64, Pose64};
use marionette::formats::asf;
use serde_json::{json, Value};

const PROFILE: &str = "firmware-profile/cmu-puppet.toml";

struct Studio {
    child: Child,
    addr: String,
    lines: mpsc::Receiver<String>,
}

impl Drop for Studio {
    /// A failed test must not leave the server running (it holds the test's output open).
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Studio {
    fn start(extra: &[&str]) -> Studio {
        let mut child = common::bin()
            .arg("studio")
            .arg(PROFILE)
            .arg(common::data("16.asf"))
            .args(["--port", "0", "-q", "--rate", "120"])
            .args(extra)
            .current_dir(env!("CARGO_MANIFEST_DIR"))
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap();
        let (tx, lines) = mpsc::channel();
        let out = child.stdout.take().unwrap();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
        let mut addr = None;
        let mut seen = Vec::new();
        while addr.is_none() {
            let l = lines
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("no URL printed: {seen:?}"));
            if let Some(rest) = l.strip_prefix("studio: http://") {
                addr = Some(rest.split('/').next().unwrap().to_string());
            }
            seen.push(l);
        }
        let s = Studio {
            child,
            addr: addr.unwrap(),
            lines,
        };
        // The loop is up once its goals are in the pose.
        for _ in 0..200 {
            if s.get("/api/pose").1["servos"][0]["goal_deg"].is_number() {
                return s;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!("the loop did not start");
    }

    fn request(&self, method: &str, path: &str, body: &str) -> (u16, String) {
        let mut s = TcpStream::connect(&self.addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        write!(
            s,
            "{method} {path} HTTP/1.1\r\nHost: {}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            self.addr,
            body.len()
        )
        .unwrap();
        let mut text = String::new();
        s.read_to_string(&mut text).unwrap();
        let status = text[9..12].parse().unwrap();
        let body = text.split_once("\r\n\r\n").map_or("", |(_, b)| b).to_string();
        (status, body)
    }

    fn get(&self, path: &str) -> (u16, Value) {
        let (s, b) = self.request("GET", path, "");
        (s, serde_json::from_str(&b).unwrap_or(Value::Null))
    }

    fn post(&self, path: &str, body: &Value) -> (u16, Value) {
        let (s, b) = self.request("POST", path, &body.to_string());
        assert_eq!(s, 200, "{path} {body}: {b}");
        (s, serde_json::from_str(&b).unwrap())
    }

    /// Ctrl-C: the usual stop; returns what it printed.
    fn stop(&mut self) -> String {
        let ok = std::process::Command::new("kill")
            .args(["-INT", &self.child.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok);
        let status = self.child.wait().unwrap();
        let mut out = String::new();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(5)) {
            out.push_str(&l);
            out.push('\n');
        }
        assert!(status.success(), "{status:?}\n{out}");
        out
    }
}

fn tip(pose: &Value, bone: &str) -> DVec3 {
    let t = &pose["tips"][bone];
    DVec3::new(
        t[0].as_f64().unwrap(),
        t[1].as_f64().unwrap(),
        t[2].as_f64().unwrap(),
    )
}

/// Reachable targets: the limb's tip at random angles inside its ASF limits, the rest of the
/// body at rest (the studio's base pose without a clip).
fn reachable_targets(limb: (&str, &str), count: usize, seed: u64) -> Vec<DVec3> {
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let mut rng = marionette::bus::faults::Rng::new(seed);
    let mut out = Vec::new();
    let mut pose = Pose64::default();
    while out.len() < count {
        let mut channels = vec![0.0; skel.channel_count()];
        for name in [limb.0, limb.1] {
            let b = &skel.bones()[skel.find(name).unwrap()];
            for ((d, c), l) in b.dofs().iter().zip(b.channels()).zip(b.limits()) {
                if d.is_rotation() {
                    // Inside the limits (radians) by 5 % of the range each side.
                    let (lo, hi) = (f64::from(l.min), f64::from(l.max));
                    let (lo, hi) = (lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo));
                    let u = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
                    channels[c] = lo + u * (hi - lo);
                }
            }
        }
        fk64(&skel, &channels, &mut pose);
        out.push(pose.tip[skel.find(limb.1).unwrap()]);
    }
    out
}

#[test]
fn the_api_reaches_random_targets_with_every_method_and_refuses_bad_requests() {
    let mut studio = Studio::start(&[]);
    let (status, pose) = studio.get("/api/pose");
    assert_eq!(status, 200);
    assert_eq!(pose["solver"], "analytic");
    assert_eq!(pose["servos"].as_array().unwrap().len(), 28);
    let rest_goals: Vec<f64> = pose["servos"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["goal_deg"].as_f64().unwrap())
        .collect();

    let limbs = [
        ("lhumerus", "lradius"),
        ("rhumerus", "rradius"),
        ("lfemur", "ltibia"),
        ("rfemur", "rtibia"),
    ];
    let mut table = Vec::new();
    let mut results = Vec::new();
    for method in ["analytic", "ccd", "jt", "pinv", "dls", "cg"] {
        studio.post("/api/solver", &json!({"method": method}));
        let mut reached = 0;
        let mut worst: f64 = 0.0;
        let mut total = 0;
        for (k, limb) in limbs.iter().enumerate() {
            // Release the others: each target is judged on its own limb.
            for other in limbs {
                studio.post("/api/target", &json!({"effector": other.1, "position": null}));
            }
            for t in reachable_targets(*limb, 6, 17 + k as u64) {
                let (_, p) = studio.post(
                    "/api/target",
                    &json!({"effector": limb.1, "position": t.to_array()}),
                );
                assert_eq!(p["solver"], method);
                let r = p["residual"].as_f64().expect("a finite residual");
                let got = tip(&p, limb.1);
                assert!(got.is_finite());
                assert!(
                    ((got - t).length() - r).abs() < 1e-6,
                    "the residual is the tip's distance"
                );
                total += 1;
                worst = worst.max(r);
                if r < 1e-3 {
                    reached += 1;
                }
            }
        }
        table.push(format!(
            "{method}: {reached}/{total} targets to < 1e-3, worst {worst:.2e}"
        ));
        results.push((method, reached, total, worst));
    }
    println!("{}", table.join("\n"));
    for (method, reached, total, worst) in results {
        match method {
            // The closed form, and the methods that converge on these limbs, reach every one.
            "analytic" | "pinv" | "dls" | "cg" => {
                assert_eq!(reached, total, "{method}: worst {worst}");
            }
            // CCD and the transpose creep along the joint limits (linear convergence): they
            // stall short of the tolerance on some, close to the target.
            _ => assert!(
                worst < 0.1 && reached * 2 > total,
                "{method}: {reached}/{total}, worst {worst}"
            ),
        }
    }

    // Unreachable: the closest pose, never NaN.
    for method in ["analytic", "ccd", "jt", "pinv", "dls", "cg"] {
        studio.post("/api/solver", &json!({"method": method}));
        let (_, p) = studio.post(
            "/api/target",
            &json!({"effector": "lradius", "position": [400.0, 300.0, -200.0]}),
        );
        let r = p["residual"].as_f64().unwrap();
        assert!(r.is_finite() && r > 100.0, "{method}: {r}");
        for (_, t) in p["tips"].as_object().unwrap() {
            assert!(t
                .as_array()
                .unwrap()
                .iter()
                .all(|x| x.as_f64().is_some_and(f64::is_finite)));
        }
    }

    // The loop took the poses: the arm's goal registers moved away from rest.
    std::thread::sleep(Duration::from_millis(500));
    let (_, p) = studio.get("/api/pose");
    let moved = p["servos"]
        .as_array()
        .unwrap()
        .iter()
        .zip(&rest_goals)
        .filter(|(s, g)| (s["goal_deg"].as_f64().unwrap() - **g).abs() > 1.0)
        .map(|(s, _)| s["name"].as_str().unwrap().to_string())
        .collect::<Vec<_>>();
    assert!(moved.iter().any(|n| n.starts_with("lhumerus")), "{moved:?}");

    // Bad requests: 400 with one line; the loop goes on.
    let ticks = studio.get("/api/stats").1["loop"]["ticks"].as_u64().unwrap();
    for (path, body, says) in [
        ("/api/target", "{\"effector\": \"lradius\", ", "bad JSON"),
        ("/api/target", "[1, 2]", "expected a JSON object"),
        (
            "/api/target",
            "{\"effector\": \"nose\", \"position\": [1, 2, 3]}",
            "no bone named 'nose'",
        ),
        (
            "/api/target",
            "{\"effector\": \"root\", \"position\": [1, 2, 3]}",
            "cannot be an effector",
        ),
        (
            "/api/target",
            "{\"effector\": \"lradius\", \"position\": [1e999, 0, 0]}",
            "bad JSON",
        ),
        (
            "/api/target",
            "{\"effector\": \"lradius\", \"position\": [NaN, 0, 0]}",
            "bad JSON",
        ),
        (
            "/api/target",
            "{\"effector\": \"lradius\", \"position\": [null, 0, 0]}",
            "three numbers",
        ),
        (
            "/api/target",
            "{\"effector\": \"lradius\", \"position\": [1, 2]}",
            "[x, y, z]",
        ),
        (
            "/api/target",
            "{\"effector\": \"lradius\"}",
            "missing field `position`",
        ),
        (
            "/api/target",
            "{\"position\": [1, 2, 3]}",
            "missing field `effector`",
        ),
        (
            "/api/solver",
            "{\"method\": \"newton\"}",
            "unknown method 'newton'",
        ),
        ("/api/solver", "{\"method\": 3}", "must be a string"),
        (
            "/api/solver",
            "{\"method\": \"dls\", \"compare\": \"magic\"}",
            "unknown method 'magic'",
        ),
    ] {
        let (status, text) = studio.request("POST", path, body);
        assert_eq!(status, 400, "{body}: {text}");
        assert_eq!(text.trim_end().lines().count(), 1, "{body}: {text}");
        assert!(text.contains(says), "{body}: {text}");
    }
    std::thread::sleep(Duration::from_millis(200));
    let (_, stats) = studio.get("/api/stats");
    assert!(
        stats["loop"]["ticks"].as_u64().unwrap() > ticks,
        "the loop goes on"
    );
    assert_eq!(studio.get("/api/pose").0, 200);

    let out = studio.stop();
    assert!(
        out.contains("ended: interrupted; torque off, acknowledged by 28 servos"),
        "{out}"
    );
}

#[test]
fn the_page_drags_the_left_hand_in_a_real_browser() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/studio");
    std::fs::create_dir_all(&dir).unwrap();
    let mut studio = Studio::start(&[]);
    let script = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/browser/studio_page.py");
    let out = std::process::Command::new("python3")
        .arg(&script)
        .arg(format!("http://{}/", studio.addr))
        .arg(&dir)
        .output()
        .expect("python3 (with selenium, chromium and chromium-driver: see .ci/run)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}{stderr}");
    assert!(
        out.status.success(),
        "the browser test failed:\n{stdout}\n{stderr}"
    );
    let measured: Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert!(measured["residual"].as_f64().unwrap() < 1e-3);
    for shot in ["loaded.png", "dragged.png", "compare.png"] {
        assert!(dir.join(shot).metadata().unwrap().len() > 10_000, "{shot}");
    }
    let summary = studio.stop();
    println!("{summary}");
    assert!(summary.contains("drag → Sync Write:"), "{summary}");
}

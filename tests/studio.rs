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
use marionette::studio::request::MAX_MESSAGE_BYTES;
use marionette::studio::server::{MAX_CONNECTIONS, MAX_PAGES};
use serde_json::{json, Value};
use tungstenite::client::IntoClientRequest;
use tungstenite::protocol::frame::coding::CloseCode;
use tungstenite::Message;

const PROFILE: &str = "firmware-profile/cmu-puppet.toml";

struct Studio {
    child: Child,
    /// `127.0.0.1:PORT`.
    addr: String,
    /// The token it printed in its URL, sent with every request of [`Studio::request`].
    token: Option<String>,
    /// What it printed up to its URL.
    banner: Vec<String>,
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
        Studio::start_with(extra, &[])
    }

    fn start_with(extra: &[&str], env: &[(&str, &str)]) -> Studio {
        Studio::start_profile(PROFILE, extra, env)
    }

    fn start_profile(profile: &str, extra: &[&str], env: &[(&str, &str)]) -> Studio {
        let mut child = common::bin()
            .env_remove("MARIONETTE_STUDIO_TOKEN")
            .envs(env.iter().copied())
            .arg("studio")
            .arg(profile)
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
        let mut url = None;
        let mut seen = Vec::new();
        while url.is_none() {
            let l = lines
                .recv_timeout(Duration::from_secs(60))
                .unwrap_or_else(|_| panic!("no URL printed: {seen:?}"));
            if let Some(rest) = l.strip_prefix("studio: http://") {
                url = Some(rest.split(' ').next().unwrap().to_string());
            }
            seen.push(l);
        }
        // http://HOST:PORT/ or, with a token, http://HOST:PORT/?token=T; reached on loopback.
        let url = url.unwrap();
        let (host, rest) = url.split_once('/').unwrap();
        let port = host.rsplit_once(':').unwrap().1;
        let s = Studio {
            child,
            addr: format!("127.0.0.1:{port}"),
            token: rest.strip_prefix("?token=").map(str::to_string),
            banner: seen,
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
        let auth = self
            .token
            .as_ref()
            .map_or_else(String::new, |t| format!("Authorization: Bearer {t}\r\n"));
        let head = format!(
            "{method} {path} HTTP/1.1\r\nHost: {}\r\n{auth}Content-Type: application/json\r\n",
            self.addr
        );
        let (status, _, body) = self.raw(&head, body.as_bytes());
        (status, body)
    }

    /// `head` (request line and headers, each ending in CRLF) with Content-Length (unless it
    /// says Transfer-Encoding) and `Connection: close` added, then `body`: the status, the
    /// headers (lower case), the body.
    fn raw(&self, head: &str, body: &[u8]) -> (u16, String, String) {
        let mut s = TcpStream::connect(&self.addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
        let length = if head.contains("Transfer-Encoding") {
            String::new()
        } else {
            format!("Content-Length: {}\r\n", body.len())
        };
        let head = format!("{head}{length}Connection: close\r\n\r\n");
        s.write_all(head.as_bytes()).unwrap();
        // The server may answer (413) and close before the whole body is in: the body goes out
        // from another thread while this one reads the answer.
        let mut w = s.try_clone().unwrap();
        let body = body.to_vec();
        let writer = std::thread::spawn(move || {
            let _ = w.write_all(&body);
        });
        let mut text = Vec::new();
        let _ = s.read_to_end(&mut text);
        let _ = s.shutdown(std::net::Shutdown::Both);
        let _ = writer.join();
        let text = String::from_utf8_lossy(&text).to_string();
        let status = text.get(9..12).and_then(|c| c.parse().ok()).unwrap_or(0);
        let (headers, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
        (status, headers.to_ascii_lowercase(), body.to_string())
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

/// A profile of robot joints (the OP3): the pose carries the robot beside the human — its
/// links at the servos' present angles once the loop has read them, both soles planted with the
/// support polygon around them, the centre of mass and the ZMP inside it, all in the page's
/// frame, the robot to the human's side; a profile of bones has none.
#[test]
fn the_studio_draws_the_robot_of_a_robot_profile_beside_the_human() {
    let mut studio = Studio::start_profile("firmware-profile/robotis-op3.toml", &[], &[]);
    let mut robot = Value::Null;
    for _ in 0..100 {
        robot = studio.get("/api/pose").1["robot"].clone();
        if robot["present"] == json!(true) {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(robot["present"], json!(true), "{robot}");
    let point = |v: &Value| {
        DVec3::new(
            v[0].as_f64().unwrap(),
            v[1].as_f64().unwrap(),
            v[2].as_f64().unwrap(),
        )
    };
    let links = robot["links"].as_array().unwrap();
    assert!(links.len() >= 20, "{} links", links.len());
    for side in 0..2 {
        assert_eq!(robot["soles"][side]["planted"], json!(true), "{robot}");
    }
    let support: Vec<DVec3> = robot["support"].as_array().unwrap().iter().map(point).collect();
    assert!(support.len() >= 4, "{support:?}");
    // On the floor plane (the page's y up): the centre of mass and the ZMP inside the support
    // polygon (a convex hull: on the inner side of every edge, either turning).
    let floor = |p: DVec3| (p.x, p.z);
    let inside = |p: DVec3| {
        let (x, z) = floor(p);
        let sides: Vec<f64> = (0..support.len())
            .map(|i| {
                let (ax, az) = floor(support[i]);
                let (bx, bz) = floor(support[(i + 1) % support.len()]);
                (bx - ax) * (z - az) - (bz - az) * (x - ax)
            })
            .collect();
        sides.iter().all(|s| *s >= 0.0) || sides.iter().all(|s| *s <= 0.0)
    };
    assert!(inside(point(&robot["com"])), "{robot}");
    assert!(inside(point(&robot["zmp"])), "{robot}");
    // Beside the human: the robot's links clear of the human's bones' middle.
    let pose = studio.get("/api/pose").1;
    let pelvis = tip(&pose, "root");
    let nearest = links
        .iter()
        .flat_map(|l| [point(&l[0]), point(&l[1])])
        .map(|p| ((p.x - pelvis.x).powi(2) + (p.z - pelvis.z).powi(2)).sqrt())
        .fold(f64::INFINITY, f64::min);
    assert!(nearest > 3.0, "the robot stands {nearest} units from the pelvis");
    studio.stop();
    let mut puppet = Studio::start(&[]);
    assert!(puppet.get("/api/pose").1["robot"].is_null());
    puppet.stop();
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

/// Runs `tests/browser/SCRIPT URL DIR` (Selenium driving headless Chromium), where DIR is
/// `target/DIR_NAME` for its screenshots; asserts that it passed and returns the JSON of its
/// last line and DIR.
fn browser(script: &str, url: &str, dir_name: &str) -> (Value, std::path::PathBuf) {
    common::needs_python("selenium", "selenium==4.35.0");
    common::needs_program("chromium", "chromium");
    common::needs_program("chromedriver", "chromium-driver");
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = root.join("target").join(dir_name);
    std::fs::create_dir_all(&dir).unwrap();
    let out = std::process::Command::new("python3")
        .arg(root.join("tests/browser").join(script))
        .arg(url)
        .arg(&dir)
        .output()
        .expect("python3 runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}{stderr}");
    assert!(
        out.status.success(),
        "the browser test failed:\n{stdout}\n{stderr}"
    );
    (serde_json::from_str(stdout.lines().last().unwrap()).unwrap(), dir)
}

#[test]
fn the_page_drags_the_left_hand_in_a_real_browser() {
    let mut studio = Studio::start(&[]);
    let (measured, dir) = browser("studio_page.py", &format!("http://{}/", studio.addr), "studio");
    assert!(measured["residual"].as_f64().unwrap() < 1e-3);
    for shot in ["loaded.png", "dragged.png", "compare.png"] {
        assert!(dir.join(shot).metadata().unwrap().len() > 10_000, "{shot}");
    }
    let summary = studio.stop();
    println!("{summary}");
    assert!(summary.contains("drag → Sync Write:"), "{summary}");
}

/// The OP3's profile in a real browser: the page draws the robot beside the human, and a drag
/// of the human's left hand moves the robot's left arm (its present angles).
#[test]
fn the_page_draws_the_robot_and_a_drag_moves_its_arm_in_a_real_browser() {
    let mut studio = Studio::start_profile("firmware-profile/robotis-op3.toml", &[], &[]);
    let (measured, dir) = browser(
        "robot_page.py",
        &format!("http://{}/", studio.addr),
        "studio-robot",
    );
    assert_eq!(measured["planted"], json!([true, true]), "{measured}");
    assert!(measured["support"].as_u64().unwrap() >= 4, "{measured}");
    for shot in ["robot.png", "robot_dragged.png"] {
        assert!(dir.join(shot).metadata().unwrap().len() > 10_000, "{shot}");
    }
    studio.stop();
}

type Ws = tungstenite::WebSocket<TcpStream>;

/// A WebSocket to the studio's `/ws` with these extra headers; the refusal's status (0: the
/// connection was closed without an answer).
fn ws_connect(addr: &str, headers: &[(&'static str, &str)]) -> Result<Ws, u16> {
    let mut req = format!("ws://{addr}/ws").into_client_request().unwrap();
    for (k, v) in headers {
        req.headers_mut().insert(*k, v.parse().unwrap());
    }
    let stream = TcpStream::connect(addr).map_err(|_| 0u16)?;
    stream.set_read_timeout(Some(Duration::from_secs(20))).unwrap();
    match tungstenite::client(req, stream) {
        Ok((ws, _)) => Ok(ws),
        Err(tungstenite::HandshakeError::Failure(tungstenite::Error::Http(r))) => Err(r.status().as_u16()),
        Err(_) => Err(0),
    }
}

/// Resident memory of a process, bytes.
fn rss(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .unwrap();
    kb * 1024
}

/// Every servo's goal and present angle, degrees.
fn positions(studio: &Studio) -> Vec<(f64, f64)> {
    studio.get("/api/pose").1["servos"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| {
            (
                s["goal_deg"].as_f64().unwrap(),
                s["present_deg"].as_f64().unwrap(),
            )
        })
        .collect()
}

#[test]
fn foreign_hosts_origins_media_types_and_oversized_input_are_refused() {
    let mut studio = Studio::start(&[]);
    let addr = studio.addr.clone();
    let own = format!("http://{addr}");
    let before = positions(&studio);
    let json_post = |host: &str, extra: &str, body: &str| {
        let head =
            format!("POST /api/target HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n{extra}");
        studio.raw(&head, body.as_bytes())
    };
    let target = r#"{"effector": "lradius", "position": [5, 15, 5]}"#;

    // DNS rebinding: a name that is not this server's, on every route.
    for path in ["/", "/api/pose", "/studio.js", "/api/stats"] {
        let (status, _, body) = studio.raw(
            &format!("GET {path} HTTP/1.1\r\nHost: evil.example:{}\r\n", &addr[10..]),
            b"",
        );
        assert_eq!(status, 403, "{path}: {body}");
        assert_eq!(body.trim_end().lines().count(), 1, "{body}");
        assert!(body.contains("is not a name of this studio"), "{body}");
    }
    assert_eq!(json_post("evil.example", "", target).0, 403);
    assert_eq!(ws_connect(&addr, &[("Host", "evil.example")]).err(), Some(403));

    // Foreign origins: a page of another site, another port, `null` (a sandboxed frame).
    for origin in [
        "http://evil.example",
        "http://127.0.0.1:1",
        "null",
        "http://localhost",
    ] {
        let (status, headers, body) = json_post(&addr, &format!("Origin: {origin}\r\n"), target);
        assert_eq!(status, 403, "{origin}: {body}");
        assert!(body.contains("may not drive this studio"), "{body}");
        assert!(!headers.contains("access-control-allow"), "{headers}");
        assert_eq!(
            ws_connect(&addr, &[("Origin", origin)]).err(),
            Some(403),
            "{origin}"
        );
    }
    // A preflight is never granted.
    let (status, headers, _) = studio.raw(
        &format!("OPTIONS /api/target HTTP/1.1\r\nHost: {addr}\r\nOrigin: http://evil.example\r\nAccess-Control-Request-Method: POST\r\n"),
        b"",
    );
    assert!(
        status >= 400 && !headers.contains("access-control-allow"),
        "{status} {headers}"
    );

    // Not JSON: a "simple" request's media types, and none.
    for media in [
        "text/plain",
        "application/x-www-form-urlencoded",
        "multipart/form-data; boundary=x",
    ] {
        let head = format!("POST /api/target HTTP/1.1\r\nHost: {addr}\r\nContent-Type: {media}\r\n");
        let (status, _, body) = studio.raw(&head, target.as_bytes());
        assert_eq!(status, 415, "{media}: {body}");
        assert!(body.contains("expected Content-Type: application/json"), "{body}");
    }
    let (status, _, _) = studio.raw(
        &format!("POST /api/solver HTTP/1.1\r\nHost: {addr}\r\n"),
        br#"{"method": "ccd"}"#,
    );
    assert_eq!(status, 415);

    // 10 MB bodies, declared and chunked: 413, and the server's memory stays where it was.
    let pid = studio.child.id();
    let rss_before = rss(pid);
    let big = vec![b' '; 10_000_000];
    for _ in 0..5 {
        let (status, _, body) = json_post(&addr, "", std::str::from_utf8(&big).unwrap());
        assert_eq!(status, 413, "{body}");
        let mut chunked = Vec::new();
        for chunk in big.chunks(65_536) {
            chunked.extend_from_slice(format!("{:x}\r\n", chunk.len()).as_bytes());
            chunked.extend_from_slice(chunk);
            chunked.extend_from_slice(b"\r\n");
        }
        chunked.extend_from_slice(b"0\r\n\r\n");
        let head = format!(
            "POST /api/target HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n"
        );
        let (status, _, body) = studio.raw(&head, &chunked);
        assert_eq!(status, 413, "{body}");
    }
    let rss_after = rss(pid);
    let grown = rss_after.saturating_sub(rss_before);
    println!("resident memory {rss_before} → {rss_after} bytes after ten 10 MB bodies");
    assert!(
        grown < 4_000_000,
        "the server kept the bodies: {grown} bytes more"
    );

    // A WebSocket message over the limit: closed with 1009 and the reason.
    let mut ws = ws_connect(&addr, &[("Origin", &own)]).expect("the own page's WebSocket");
    let hello = ws.read().unwrap();
    assert!(hello.to_text().unwrap().contains("\"hello\""));
    let _ = ws.send(Message::text("x".repeat(MAX_MESSAGE_BYTES + 1)));
    let close = loop {
        match ws.read() {
            Ok(Message::Close(frame)) => break frame,
            Ok(_) => continue,
            Err(e) => panic!("no close frame: {e}"),
        }
    };
    let close = close.expect("a close frame with a reason");
    assert_eq!(close.code, CloseCode::Size);
    assert!(close.reason.contains("at most 65536 bytes"), "{}", close.reason);

    // Nothing of it moved a servo; the loop goes on; own requests work as before.
    let after = positions(&studio);
    for (k, (b, a)) in before.iter().zip(&after).enumerate() {
        assert!(
            (a.0 - b.0).abs() < 1e-9 && (a.1 - b.1).abs() < 0.01,
            "servo {k}: {b:?} → {a:?}"
        );
    }
    let (_, stats) = studio.get("/api/stats");
    println!("refused: {}", stats["refused"]);
    assert!(stats["refused"]["host"].as_u64().unwrap() >= 6);
    assert!(stats["refused"]["origin"].as_u64().unwrap() >= 9);
    assert!(stats["refused"]["media_type"].as_u64().unwrap() >= 4);
    assert!(stats["refused"]["too_large"].as_u64().unwrap() >= 11);
    let (status, _) = studio.post(
        "/api/target",
        &json!({"effector": "lradius", "position": [5, 15, 5]}),
    );
    assert_eq!(status, 200);
    let out = studio.stop();
    assert!(out.contains("studio refused: {"), "{out}");
}

#[test]
fn two_hundred_websockets_at_once_leave_the_page_limit_and_the_loop_as_they_were() {
    let mut studio = Studio::start(&[]);
    let addr = studio.addr.clone();
    let own = format!("http://{addr}");
    // A second of the loop alone, then a second with the flood on (figures printed).
    std::thread::sleep(Duration::from_millis(2100));
    let quiet = studio.get("/api/stats").1["loop"].clone();
    let opened: Vec<Result<Ws, u16>> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..200)
            .map(|_| scope.spawn(|| ws_connect(&addr, &[("Origin", own.as_str())])))
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    let accepted = opened.iter().filter(|r| r.is_ok()).count();
    let busy = opened.iter().filter(|r| r.as_ref().err() == Some(&503)).count();
    let closed = opened.iter().filter(|r| r.as_ref().err() == Some(&0)).count();
    std::thread::sleep(Duration::from_millis(1100));
    let (_, flooded) = studio.get("/api/stats");
    println!(
        "200 WebSockets: {accepted} accepted, {busy} answered 503, {closed} closed unanswered (at most {MAX_CONNECTIONS} connections); loop before {quiet}, during {}",
        flooded["loop"]
    );
    assert_eq!(accepted, MAX_PAGES);
    assert_eq!(accepted + busy + closed, 200);
    assert_eq!(flooded["pages"].as_u64(), Some(MAX_PAGES as u64));
    assert!(flooded["loop"]["ticks"].as_u64() > quiet["ticks"].as_u64());
    drop(opened);
    // The places come back when the pages go.
    let mut pages = u64::MAX;
    for _ in 0..200 {
        pages = studio.get("/api/stats").1["pages"].as_u64().unwrap();
        if pages == 0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(pages, 0);
    assert!(ws_connect(&addr, &[("Origin", own.as_str())]).is_ok());
    println!("{}", studio.stop());
}

#[test]
fn off_loopback_every_request_needs_the_token() {
    let mut studio = Studio::start(&["--listen", "0.0.0.0"]);
    let token = studio.token.clone().expect("a token in the printed URL");
    assert_eq!(token.len(), 64);
    let addr = studio.addr.clone();
    let get =
        |extra: &str, path: &str| studio.raw(&format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\n{extra}"), b"");
    for (extra, path) in [
        ("", "/api/pose"),
        ("", "/"),
        ("Authorization: Bearer wrong\r\n", "/api/pose"),
        (
            &format!("Authorization: Bearer {}\r\n", &token[..63]) as &str,
            "/api/pose",
        ),
        (&format!("Cookie: marionette_studio_1={token}\r\n"), "/api/pose"),
    ] {
        let (status, headers, body) = get(extra, path);
        assert_eq!(status, 401, "{extra} {path}: {body}");
        assert!(headers.contains("www-authenticate: bearer"), "{headers}");
        assert!(body.contains("needs its token"), "{body}");
    }
    let (status, _, body) = studio.raw(
        &format!("POST /api/target HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\n"),
        br#"{"effector": "lradius", "position": [5, 15, 5]}"#,
    );
    assert_eq!(status, 401, "{body}");
    assert_eq!(ws_connect(&addr, &[]).err(), Some(401));
    // The right token: in the header, the URL (which sets the cookie), the cookie.
    assert_eq!(studio.get("/api/pose").0, 200);
    let (status, headers, _) = get("", &format!("/?token={token}"));
    assert_eq!(status, 303);
    let cookie = headers
        .lines()
        .find_map(|l| l.strip_prefix("set-cookie: "))
        .expect("a cookie")
        .to_string();
    assert!(
        cookie.contains("; httponly") && cookie.contains("; samesite=strict"),
        "{cookie}"
    );
    let pair = cookie.split(';').next().unwrap().to_string();
    assert!(pair.ends_with(&token), "{pair}");
    let with_cookie = format!("Cookie: {pair}\r\n");
    assert_eq!(get(&with_cookie, "/").0, 200);
    assert_eq!(get(&with_cookie, "/api/pose").0, 200);
    let own = format!("http://{addr}");
    assert!(ws_connect(&addr, &[("Origin", own.as_str()), ("Cookie", &pair)]).is_ok());
    let (status, _) = studio.post(
        "/api/target",
        &json!({"effector": "lradius", "position": [5, 15, 5]}),
    );
    assert_eq!(status, 200);
    assert!(
        studio.banner[0].contains("reachable from other machines: every request needs the token"),
        "{:?}",
        studio.banner
    );
    studio.stop();

    // A fixed token from the environment.
    let mut studio = Studio::start_with(
        &["--listen", "0.0.0.0"],
        &[("MARIONETTE_STUDIO_TOKEN", "a-fixed-token-42")],
    );
    assert_eq!(studio.token.as_deref(), Some("a-fixed-token-42"));
    assert_eq!(studio.get("/api/pose").0, 200);
    studio.stop();
}

#[test]
fn a_foreign_page_in_a_real_browser_moves_nothing_and_the_own_page_still_drags() {
    let mut studio = Studio::start(&[]);
    let (seen, _) = browser(
        "hostile_page.py",
        &format!("http://{}/", studio.addr),
        "studio-hostile",
    );
    assert!(!seen["own_page_moved"].as_array().unwrap().is_empty());
    let summary = studio.stop();
    println!("{summary}");
    assert!(summary.contains("studio refused: {"), "{summary}");
}

#[test]
fn off_loopback_the_page_keeps_its_token_in_a_cookie_and_drags_in_a_real_browser() {
    let mut studio = Studio::start(&["--listen", "0.0.0.0"]);
    let token = studio.token.clone().unwrap();
    let url = format!("http://{}/?token={token}", studio.addr);
    let (seen, _) = browser("token_page.py", &url, "studio-token");
    assert!(!seen["moved"].as_array().unwrap().is_empty());
    studio.stop();
}

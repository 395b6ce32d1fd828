//! The studio's HTTP server: the page, its WebSocket (`/ws`) and the JSON API (`/api/…`).
//!
//! Every request that cannot be done answers 400 with a one-line reason; nothing a client
//! sends stops the loop.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use glam::DVec3;
use serde_json::{json, Value};

use super::scene::{Method, Scene};
use super::Studio;

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/studio.js");
const STYLE: &str = include_str!("page/studio.css");

/// How often a connected page gets the state without asking.
const PUSH: Duration = Duration::from_millis(33);

type Reply = Result<Json<Value>, (StatusCode, String)>;

fn bad(reason: impl std::fmt::Display) -> (StatusCode, String) {
    // One line, whatever the reason's text held.
    let line = reason.to_string().replace(['\n', '\r'], " ");
    (StatusCode::BAD_REQUEST, line + "\n")
}

/// The routes.
pub fn router(studio: Arc<Studio>) -> Router {
    Router::new()
        .route(
            "/",
            get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX) }),
        )
        .route(
            "/studio.js",
            get(|| async { ([(header::CONTENT_TYPE, "text/javascript; charset=utf-8")], SCRIPT) }),
        )
        .route(
            "/studio.css",
            get(|| async { ([(header::CONTENT_TYPE, "text/css; charset=utf-8")], STYLE) }),
        )
        .route("/ws", get(ws))
        .route("/api/pose", get(pose))
        .route("/api/target", post(target))
        .route("/api/solver", post(solver))
        .route("/api/stats", get(stats))
        .with_state(studio)
}

/// Serves `listener` until the studio stops.
///
/// # Errors
/// The listener cannot be handed to the runtime.
pub fn serve(studio: Arc<Studio>, listener: std::net::TcpListener) -> std::io::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("studio-http")
        .enable_all()
        .build()?;
    listener.set_nonblocking(true)?;
    let result = rt.block_on(async {
        let listener = tokio::net::TcpListener::from_std(listener)?;
        let stopping = Arc::clone(&studio);
        axum::serve(listener, router(studio))
            .with_graceful_shutdown(async move {
                while !stopping.stop.load(Ordering::Relaxed) {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
            })
            .await
    });
    rt.shutdown_timeout(Duration::from_secs(1));
    result
}

fn parse(body: &[u8]) -> Result<Value, (StatusCode, String)> {
    let v: Value = serde_json::from_slice(body).map_err(|e| bad(format!("bad JSON: {e}")))?;
    if !v.is_object() {
        return Err(bad("expected a JSON object"));
    }
    Ok(v)
}

fn vec3(v: &Value, what: &str) -> Result<DVec3, String> {
    let a = v
        .as_array()
        .filter(|a| a.len() == 3)
        .ok_or_else(|| format!("{what} must be [x, y, z]"))?;
    let mut p = [0.0; 3];
    for (x, v) in p.iter_mut().zip(a) {
        *x = v
            .as_f64()
            .ok_or_else(|| format!("{what} must be three numbers"))?;
    }
    let p = DVec3::from_array(p);
    if !p.is_finite() {
        return Err(format!("{what} must be finite numbers"));
    }
    Ok(p)
}

fn string<'a>(v: &'a Value, key: &str) -> Result<&'a str, String> {
    match v.get(key) {
        Some(Value::String(s)) => Ok(s),
        Some(_) => Err(format!("`{key}` must be a string")),
        None => Err(format!("missing field `{key}`")),
    }
}

async fn pose(State(studio): State<Arc<Studio>>) -> Json<Value> {
    Json(studio.pose_json())
}

async fn stats(State(studio): State<Arc<Studio>>) -> Json<Value> {
    let scene = studio.scene();
    let report = scene.primary.report.clone();
    drop(scene);
    let (event, receipt) = studio.latency();
    Json(json!({
        "loop": studio.loop_json(),
        "drag_to_write_us": event,
        "receipt_to_write_us": receipt,
        "solve": report,
    }))
}

/// `{"effector": "lradius", "position": [x, y, z]}` (root frame; `null` releases it).
async fn target(State(studio): State<Arc<Studio>>, body: Bytes) -> Reply {
    let v = parse(&body)?;
    let effector = string(&v, "effector").map_err(bad)?;
    let position = match v.get("position") {
        None => return Err(bad("missing field `position`")),
        Some(Value::Null) => None,
        Some(p) => Some(vec3(p, "position").map_err(bad)?),
    };
    studio.set_target(effector, position, None).map_err(bad)?;
    Ok(Json(studio.pose_json()))
}

/// `{"method": "ccd"}`, optionally `"compare": "dls"`.
async fn solver(State(studio): State<Arc<Studio>>, body: Bytes) -> Reply {
    let v = parse(&body)?;
    let method = string(&v, "method").map_err(bad)?;
    let compare = match v.get("compare") {
        None | Some(Value::Null) => None,
        Some(Value::String(s)) => Some(s.as_str()),
        Some(_) => return Err(bad("`compare` must be a method name or null")),
    };
    studio.set_solver(method, compare).map_err(bad)?;
    Ok(Json(studio.pose_json()))
}

async fn ws(State(studio): State<Arc<Studio>>, upgrade: WebSocketUpgrade) -> Response {
    upgrade
        .on_upgrade(move |socket| session(studio, socket))
        .into_response()
}

/// What the page needs once: the skeleton's bones, the servos, the methods.
fn hello(studio: &Studio) -> Value {
    let scene = studio.scene();
    let skel = scene.skeleton();
    let bones: Vec<Value> = skel
        .bones()
        .iter()
        .map(|b| json!({"name": b.name(), "parent": b.parent()}))
        .collect();
    json!({
        "type": "hello",
        "bones": bones,
        "metres_per_unit": skel.units().meters_per_unit(),
        "servos": studio.servos,
        "methods": Method::ALL.iter().map(|m| m.name()).collect::<Vec<_>>(),
        "has_clip": scene.has_clip(),
        "rate_hz": studio.rate_hz,
        "bus": studio.bus,
    })
}

fn segments(scene: &Scene, channels: &[f64]) -> Vec<[f64; 6]> {
    scene
        .segments(channels)
        .into_iter()
        .map(|(s, t)| [s.x, s.y, s.z, t.x, t.y, t.z])
        .collect()
}

/// The state a page draws: both poses, the effectors, the selected limb's swivel circle and
/// limit region, the timeline, the servos and the loop.
fn state(studio: &Studio, selected: Option<&str>) -> Value {
    let scene = studio.scene();
    let tips = scene.tips(&scene.primary.channels);
    let effectors: Vec<Value> = scene
        .effectors
        .iter()
        .map(|e| {
            json!({
                "name": e.name,
                "bone": e.bone,
                "tip": tips[e.bone].to_array(),
                "target": e.target.map(|t| t.to_array()),
            })
        })
        .collect();
    let chosen = selected.and_then(|n| scene.effectors.iter().position(|e| e.name == n));
    let (circle, region) = chosen.map_or((Vec::new(), Vec::new()), |k| {
        (scene.swivel_circle(k), scene.limit_region(k))
    });
    let ghost = scene.ghost.as_ref().map(|g| {
        json!({
            "solver": g.method.name(),
            "bones": segments(&scene, &g.channels),
            "report": g.report,
        })
    });
    let v = json!({
        "type": "state",
        "version": studio.version.load(Ordering::Relaxed),
        "bones": segments(&scene, &scene.primary.channels),
        "report": scene.primary.report,
        "ghost": ghost,
        "effectors": effectors,
        "selected": chosen.map(|k| scene.effectors[k].name.clone()),
        "swivel": {
            "fixed_deg": scene.swivel.map(f64::to_degrees),
            "circle": circle,
            "region": region,
        },
        "timeline": scene.has_clip().then_some(scene.timeline),
    });
    drop(scene);
    let mut v = v;
    v["servos"] = studio.servos_json();
    v["loop"] = studio.loop_json();
    v["latency"] = json!(studio.latency().0);
    v
}

/// One page's WebSocket: its messages in, the state out after each and every [`PUSH`].
async fn session(studio: Arc<Studio>, mut socket: WebSocket) {
    if socket
        .send(Message::Text(hello(&studio).to_string().into()))
        .await
        .is_err()
    {
        return;
    }
    let mut selected: Option<String> = None;
    let mut push = tokio::time::interval(PUSH);
    loop {
        tokio::select! {
            msg = socket.recv() => match msg {
                Some(Ok(Message::Text(text))) => {
                    if let Err(reason) = handle(&studio, &text, &mut selected) {
                        let e = json!({"type": "error", "message": reason});
                        if socket.send(Message::Text(e.to_string().into())).await.is_err() {
                            break;
                        }
                    }
                }
                Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                Some(Ok(_)) => continue,
            },
            _ = push.tick() => {
                if studio.stop.load(Ordering::Relaxed) {
                    let _ = socket.send(Message::Close(None)).await;
                    break;
                }
            }
        }
        let s = state(&studio, selected.as_deref());
        if socket.send(Message::Text(s.to_string().into())).await.is_err() {
            break;
        }
    }
}

/// A page's message: `drag`, `release`, `pin`, `pick`, `select`, `solver`, `swivel`,
/// `timeline`, `reset`.
fn handle(studio: &Studio, text: &str, selected: &mut Option<String>) -> Result<(), String> {
    let v: Value = serde_json::from_str(text).map_err(|e| format!("bad JSON: {e}"))?;
    let kind = string(&v, "type")?;
    let event_ms = v.get("t").and_then(Value::as_f64);
    let mut scene = studio.scene();
    match kind {
        "drag" => {
            let name = string(&v, "effector")?;
            let p = vec3(v.get("position").unwrap_or(&Value::Null), "position")?;
            let k = scene.effector(name).map_err(|e| e.to_string())?;
            scene.set_target(k, Some(p)).map_err(|e| e.to_string())?;
            *selected = Some(name.to_string());
        }
        "release" => {
            let k = scene
                .effector(string(&v, "effector")?)
                .map_err(|e| e.to_string())?;
            scene.set_target(k, None).map_err(|e| e.to_string())?;
        }
        "pin" => {
            let k = scene
                .effector(string(&v, "effector")?)
                .map_err(|e| e.to_string())?;
            scene.pin(k);
        }
        "pick" | "select" => {
            *selected = match v.get("effector").or_else(|| v.get("bone")) {
                Some(Value::String(name)) => {
                    scene.effector(name).map_err(|e| e.to_string())?;
                    Some(name.clone())
                }
                _ => None,
            };
        }
        "solver" => {
            let m = string(&v, "method")?;
            let m = Method::parse(m).ok_or_else(|| format!("unknown method '{m}'"))?;
            let c = match v.get("compare") {
                Some(Value::String(c)) => {
                    Some(Method::parse(c).ok_or_else(|| format!("unknown method '{c}'"))?)
                }
                _ => None,
            };
            scene.set_methods(m, c);
        }
        "swivel" => {
            scene.swivel = match v.get("deg") {
                Some(Value::Number(n)) => {
                    let d = n.as_f64().filter(|d| d.is_finite()).ok_or("deg must be finite")?;
                    Some(d.to_radians())
                }
                _ => None,
            };
        }
        "timeline" => {
            if !scene.has_clip() {
                return Err("no clip: start the studio with an AMC to use the timeline".into());
            }
            if let Some(p) = v.get("playing").and_then(Value::as_bool) {
                scene.timeline.playing = p;
            }
            if let Some(l) = v.get("looping").and_then(Value::as_bool) {
                scene.timeline.looping = l;
            }
            if let Some(s) = v.get("speed").and_then(Value::as_f64) {
                if !(s.is_finite() && (0.0..=4.0).contains(&s)) {
                    return Err("speed must be between 0 and 4".into());
                }
                scene.timeline.speed = s;
            }
            if let Some(t) = v.get("time").and_then(Value::as_f64) {
                scene.seek(t).map_err(|e| e.to_string())?;
            }
        }
        "reset" => {
            for k in 0..scene.effectors.len() {
                let _ = scene.set_target(k, None);
            }
        }
        other => return Err(format!("unknown message type '{other}'")),
    }
    studio.commit(&mut scene, event_ms);
    Ok(())
}

//! The studio's HTTP server: the page, its WebSocket (`/ws`) and the JSON API (`/api/…`).
//!
//! Every request passes [`access::guard`] first (Host, token, Origin, media type, size). A
//! request that cannot be done answers 400 with a one-line reason; nothing a client sends stops
//! the loop. The server holds at most [`MAX_CONNECTIONS`] connections and [`MAX_PAGES`]
//! WebSockets, closes a connection whose request head is not in within [`READ_TIMEOUT`], and
//! drops a page that does not take its state within [`SEND_TIMEOUT`].

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use axum::body::{Body, Bytes};
use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use serde_json::{json, Value};

use super::access::{self, Access, Refusal};
use super::request::{PageEvent, SolverRequest, TargetRequest, MAX_MESSAGE_BYTES};
use super::scene::Scene;
use super::Studio;
use crate::ik_numeric::IkMethod;

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/studio.js");
const STYLE: &str = include_str!("page/studio.css");

/// How often a connected page gets the state without asking.
const PUSH: Duration = Duration::from_millis(33);
/// Pages connected at once over the WebSocket; one more is answered 503.
pub const MAX_PAGES: usize = 16;
/// HTTP connections open at once (WebSockets not counted); one more is closed at once.
pub const MAX_CONNECTIONS: usize = 64;
/// A request's head, and its body, must arrive within this.
pub const READ_TIMEOUT: Duration = Duration::from_secs(10);
/// A page that takes no state for this long is dropped.
pub const SEND_TIMEOUT: Duration = Duration::from_secs(5);
/// WebSocket close code: the message was too big (RFC 6455, 7.4.1).
const CLOSE_TOO_BIG: u16 = 1009;

/// The server's shared state: the studio and the checks.
#[derive(Debug)]
pub struct Server {
    /// The studio.
    pub studio: Arc<Studio>,
    /// Who may talk to it.
    pub access: Arc<Access>,
    pages: AtomicUsize,
}

impl Server {
    /// A server of `studio` under `access`.
    #[must_use]
    pub fn new(studio: Arc<Studio>, access: Arc<Access>) -> Server {
        Server {
            studio,
            access,
            pages: AtomicUsize::new(0),
        }
    }
}

type Reply = Result<Json<Value>, Response>;

fn bad(reason: impl std::fmt::Display) -> Response {
    // One line, whatever the reason's text held.
    let line = reason.to_string().replace(['\n', '\r'], " ");
    (StatusCode::BAD_REQUEST, line + "\n").into_response()
}

/// The routes, behind the checks.
pub fn router(server: Arc<Server>) -> Router {
    let access = Arc::clone(&server.access);
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
        .with_state(server)
        .layer(axum::middleware::from_fn_with_state(access, access::guard))
}

/// Serves `listener` until the studio stops.
///
/// # Errors
/// The listener cannot be handed to the runtime.
pub fn serve(server: Arc<Server>, listener: std::net::TcpListener) -> std::io::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("studio-http")
        .enable_all()
        .build()?;
    listener.set_nonblocking(true)?;
    let result = rt.block_on(accept(server, listener));
    rt.shutdown_timeout(Duration::from_secs(1));
    result
}

/// Accepts connections until the studio stops: each one served as HTTP/1.1 (with upgrades) on
/// a task of its own, while fewer than [`MAX_CONNECTIONS`] are open.
async fn accept(server: Arc<Server>, listener: std::net::TcpListener) -> std::io::Result<()> {
    use hyper_util::rt::{TokioIo, TokioTimer};
    use hyper_util::service::TowerToHyperService;

    let listener = tokio::net::TcpListener::from_std(listener)?;
    let app = router(Arc::clone(&server));
    let open = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
    let mut stopping = tokio::time::interval(Duration::from_millis(50));
    loop {
        let stream = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok((stream, _)) => stream,
                // Out of descriptors and the like: the next accept may do.
                Err(_) => {
                    tokio::time::sleep(Duration::from_millis(10)).await;
                    continue;
                }
            },
            _ = stopping.tick() => {
                if server.studio.stop.load(Ordering::Relaxed) {
                    return Ok(());
                }
                continue;
            }
        };
        let Ok(permit) = Arc::clone(&open).try_acquire_owned() else {
            server.access.refused.count(Refusal::Busy);
            drop(stream);
            continue;
        };
        let _ = stream.set_nodelay(true);
        let service = TowerToHyperService::new(app.clone());
        tokio::spawn(async move {
            let _ = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(READ_TIMEOUT)
                .max_buf_size(2 * MAX_MESSAGE_BYTES)
                .serve_connection(TokioIo::new(stream), service)
                .with_upgrades()
                .await;
            drop(permit);
        });
    }
}

/// A request's body, read within [`READ_TIMEOUT`] and up to [`MAX_MESSAGE_BYTES`].
async fn body_of(server: &Server, body: Body) -> Result<Bytes, Response> {
    match tokio::time::timeout(READ_TIMEOUT, axum::body::to_bytes(body, MAX_MESSAGE_BYTES)).await {
        Ok(Ok(bytes)) => Ok(bytes),
        Ok(Err(_)) => {
            server.access.refused.count(Refusal::TooLarge);
            Err(access::too_large().into_response())
        }
        Err(_) => {
            server.access.refused.count(Refusal::Busy);
            Err((StatusCode::REQUEST_TIMEOUT, "the body did not arrive in time\n").into_response())
        }
    }
}

async fn pose(State(server): State<Arc<Server>>) -> Json<Value> {
    Json(server.studio.pose_json())
}

async fn stats(State(server): State<Arc<Server>>) -> Json<Value> {
    let studio = &server.studio;
    let scene = studio.scene();
    let report = scene.primary.report.clone();
    drop(scene);
    let (event, receipt) = studio.latency();
    Json(json!({
        "loop": studio.loop_json(),
        "drag_to_write_us": event,
        "receipt_to_write_us": receipt,
        "solve": report,
        "refused": server.access.refused.json(),
        "pages": server.pages.load(Ordering::Relaxed),
    }))
}

/// `{"effector": "lradius", "position": [x, y, z]}` (root frame; `null` releases it).
async fn target(State(server): State<Arc<Server>>, body: Body) -> Reply {
    let body = body_of(&server, body).await?;
    let r = TargetRequest::decode(&body).map_err(bad)?;
    server
        .studio
        .set_target(&r.effector, r.position, None)
        .map_err(bad)?;
    Ok(Json(server.studio.pose_json()))
}

/// `{"method": "ccd"}`, optionally `"compare": "dls"`.
async fn solver(State(server): State<Arc<Server>>, body: Body) -> Reply {
    let body = body_of(&server, body).await?;
    server
        .studio
        .set_solver(SolverRequest::decode(&body).map_err(bad)?);
    Ok(Json(server.studio.pose_json()))
}

/// One page's place among the [`MAX_PAGES`]; given back when dropped.
struct Page(Arc<Server>);

impl Page {
    fn take(server: &Arc<Server>) -> Option<Page> {
        server
            .pages
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |n| {
                (n < MAX_PAGES).then_some(n + 1)
            })
            .ok()
            .map(|_| Page(Arc::clone(server)))
    }
}

impl Drop for Page {
    fn drop(&mut self) {
        self.0.pages.fetch_sub(1, Ordering::AcqRel);
    }
}

async fn ws(State(server): State<Arc<Server>>, upgrade: WebSocketUpgrade) -> Response {
    let Some(page) = Page::take(&server) else {
        server.access.refused.count(Refusal::Busy);
        return access::busy(format!(
            "{MAX_PAGES} pages are connected already, the most this studio serves"
        ))
        .into_response();
    };
    upgrade
        .max_message_size(MAX_MESSAGE_BYTES)
        .max_frame_size(MAX_MESSAGE_BYTES)
        .on_upgrade(move |socket| session(page, socket))
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
        "methods": IkMethod::ALL.iter().map(|m| m.name()).collect::<Vec<_>>(),
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
    v["robot"] = studio.robot_json(false);
    v["loop"] = studio.loop_json();
    v["latency"] = json!(studio.latency().0);
    v
}

/// Sends within [`SEND_TIMEOUT`]; false when the page is gone or does not read.
async fn send(socket: &mut WebSocket, message: Message) -> bool {
    matches!(
        tokio::time::timeout(SEND_TIMEOUT, socket.send(message)).await,
        Ok(Ok(()))
    )
}

/// One page's WebSocket: its messages in, the state out after each and every [`PUSH`].
async fn session(page: Page, mut socket: WebSocket) {
    let studio = Arc::clone(&page.0.studio);
    if !send(&mut socket, Message::Text(hello(&studio).to_string().into())).await {
        return;
    }
    let mut selected: Option<String> = None;
    let mut push = tokio::time::interval(PUSH);
    loop {
        tokio::select! {
            msg = socket.recv() => match msg {
                Some(Ok(Message::Text(text))) => {
                    let done = PageEvent::decode(&text).and_then(|e| studio.apply(e, &mut selected));
                    if let Err(reason) = done {
                        let e = json!({"type": "error", "message": reason});
                        if !send(&mut socket, Message::Text(e.to_string().into())).await {
                            break;
                        }
                    }
                }
                Some(Err(e)) => {
                    // Over the size limit (or broken): told why, then closed.
                    if e.to_string().contains("too long") {
                        page.0.access.refused.count(Refusal::TooLarge);
                        let reason = format!("a message may hold at most {MAX_MESSAGE_BYTES} bytes");
                        let frame = CloseFrame { code: CLOSE_TOO_BIG, reason: reason.into() };
                        let _ = send(&mut socket, Message::Close(Some(frame))).await;
                    }
                    break;
                }
                Some(Ok(Message::Close(_))) | None => break,
                Some(Ok(_)) => continue,
            },
            _ = push.tick() => {
                if studio.stop.load(Ordering::Relaxed) {
                    let _ = send(&mut socket, Message::Close(None)).await;
                    break;
                }
            }
        }
        let s = state(&studio, selected.as_deref());
        if !send(&mut socket, Message::Text(s.to_string().into())).await {
            break;
        }
    }
}

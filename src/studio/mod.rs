//! `marionette studio`: drag IK targets in a browser, compare the solvers, and puppeteer the rig.
//!
//! [`scene`] is the pose model (no I/O). [`Studio`] joins it to the running control loop: every
//! new pose goes into the loop's input channel as a frame, and the loop's [`LiveView`] comes
//! back as the servos' commanded and present angles. [`server`] serves the page, its WebSocket
//! and the JSON API.

#[cfg(feature = "studio")]
pub mod access;
pub mod request;
pub mod robot;
pub mod scene;
#[cfg(feature = "studio")]
pub mod server;

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, OnceLock, PoisonError};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use glam::DVec3;
use serde_json::{json, Value};

use crate::clock::SystemClock;
use crate::control::input::{Input, InputSender};
use crate::control::live::LiveView;
use crate::control::source::{Grid, Sink, Source};
use crate::control::sources::ProducerReport;
use crate::schedule::Clock;
use request::{PageEvent, PageMessage, SolverRequest};
use scene::{Scene, SceneError};

/// Drag latencies kept for the percentiles.
const LATENCY_WINDOW: usize = 20_000;
/// How often the studio's own thread advances a playing clip and reads the loop.
pub const FRAME: Duration = Duration::from_micros(16_667);

/// A servo as the page lists it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ServoInfo {
    /// Its name in the profile.
    pub name: String,
    /// The bone it moves (a rig of bones), for the marker on the skeleton.
    pub bone: Option<String>,
}

/// Where new poses go.
#[derive(Debug)]
pub enum Feed {
    /// Into the loop's input channel, stamped on the loop's clock (set when the loop starts).
    Direct {
        /// The channel.
        tx: InputSender,
        /// The loop's clock and `wall − loop` in ns.
        clock: OnceLock<(SystemClock, i128)>,
    },
    /// To a [`StudioSource`] that the simulator's lockstep clock drains.
    Lockstep(crossbeam_channel::Sender<(Vec<f64>, f64)>),
    /// Nowhere (tests of the scene and the API alone).
    None,
}

/// Drag-to-goal latency: browser event → the first Sync Write that carried the pose.
#[derive(Debug, Default)]
struct Latency {
    /// Poses sent from drags, `(made_ns, received_ns)` on the loop clock, awaiting their Sync
    /// Write.
    pending: VecDeque<(u64, u64)>,
    /// Event → write and receipt → write, µs.
    samples: VecDeque<(f64, f64)>,
    cursor: u64,
}

/// Quantiles of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct Quantiles {
    /// Samples.
    pub n: usize,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Quantiles {
    /// Of `values` (any order).
    #[must_use]
    pub fn of(values: impl IntoIterator<Item = f64>) -> Quantiles {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Quantiles::default();
        }
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)];
        Quantiles {
            n: v.len(),
            p50: at(0.5),
            p99: at(0.99),
            max: v[v.len() - 1],
        }
    }
}

/// The studio: the scene, the feed into the loop and what the loop reports.
#[derive(Debug)]
pub struct Studio {
    scene: Mutex<Scene>,
    /// Where poses go.
    pub feed: Feed,
    /// The loop's live view.
    pub live: Arc<LiveView>,
    /// The rig's servos.
    pub servos: Vec<ServoInfo>,
    /// The loop's rate, Hz.
    pub rate_hz: f64,
    /// The bus, as the summary names it.
    pub bus: String,
    latency: Mutex<Latency>,
    /// Bumped at every change of the scene (the WebSocket pushes then).
    pub version: AtomicU64,
    seq: AtomicU64,
    sent: AtomicU64,
    /// Set when the studio ends.
    pub stop: AtomicBool,
    /// Ticks per second the loop made over the last second.
    measured_rate: Mutex<(Instant, u64, f64)>,
    /// A profile of robot joints: the robot drawn beside the human.
    robot: Option<Mutex<robot::RobotView>>,
}

impl Studio {
    /// A studio on `scene` sending poses to `feed`.
    #[must_use]
    pub fn new(scene: Scene, feed: Feed, servos: Vec<ServoInfo>, rate_hz: f64, bus: String) -> Studio {
        let mut scene = scene;
        scene.solve();
        Studio {
            scene: Mutex::new(scene),
            feed,
            live: Arc::new(LiveView::default()),
            servos,
            rate_hz,
            bus,
            latency: Mutex::new(Latency::default()),
            version: AtomicU64::new(1),
            seq: AtomicU64::new(0),
            sent: AtomicU64::new(0),
            stop: AtomicBool::new(false),
            measured_rate: Mutex::new((Instant::now(), 0, 0.0)),
            robot: None,
        }
    }

    /// The studio drawing `view`'s robot beside the human.
    #[must_use]
    pub fn with_robot(mut self, view: robot::RobotView) -> Studio {
        self.robot = Some(Mutex::new(view));
        self
    }

    /// The studio showing `live` (the view the loop publishes into) instead of its own.
    #[must_use]
    pub fn with_live_view(mut self, live: Arc<LiveView>) -> Studio {
        self.live = live;
        self
    }

    /// The scene (locked; keep the guard short).
    pub fn scene(&self) -> MutexGuard<'_, Scene> {
        self.scene.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Gives the loop's clock to a direct feed (the producer thread calls this as it starts).
    pub fn set_loop_clock(&self, mut clock: SystemClock) {
        if let Feed::Direct { clock: slot, .. } = &self.feed {
            let wall = wall_ns();
            let offset = wall - i128::from(clock.now_ns());
            let _ = slot.set((clock, offset));
        }
    }

    /// Sends the present primary pose again (the first one, once the loop is there).
    pub fn republish(&self) {
        let scene = self.scene();
        self.send(&scene.primary.channels, scene.timeline.time, None);
    }

    /// Solves the scene, sends the primary pose to the loop and tells the viewers. `event_ms`
    /// is the browser's time of the event behind it (ms since the Unix epoch), for the
    /// latency; `None` for changes of the studio's own (the timeline).
    pub fn commit(&self, scene: &mut Scene, event_ms: Option<f64>) {
        scene.solve();
        let clip_time = scene.timeline.time;
        self.send(&scene.primary.channels, clip_time, event_ms);
        self.version.fetch_add(1, Ordering::Relaxed);
    }

    fn send(&self, channels: &[f64], clip_time: f64, event_ms: Option<f64>) {
        match &self.feed {
            Feed::Direct { tx, clock } => {
                let Some((mut clock, offset)) = clock.get().copied() else {
                    return;
                };
                let now = clock.now_ns();
                // The event's time on the loop clock: never later than now, never 0 (unknown).
                let made = event_ms
                    .filter(|t| t.is_finite())
                    .map(|t| ((t * 1e6) as i128 - offset).clamp(1, i128::from(now.max(1))) as u64)
                    .unwrap_or(now.max(1));
                let seq = self.seq.fetch_add(1, Ordering::Relaxed);
                if tx
                    .send_newest(Input::frame(seq, 0, made, channels, clip_time))
                    .is_ok()
                {
                    self.sent.fetch_add(1, Ordering::Relaxed);
                    if event_ms.is_some() {
                        let mut l = self.latency.lock().unwrap_or_else(PoisonError::into_inner);
                        l.pending.push_back((made, now));
                        if l.pending.len() > 256 {
                            l.pending.pop_front();
                        }
                    }
                }
            }
            Feed::Lockstep(tx) => {
                if tx.try_send((channels.to_vec(), clip_time)).is_ok() {
                    self.sent.fetch_add(1, Ordering::Relaxed);
                }
            }
            Feed::None => {}
        }
    }

    /// One frame of the studio's own thread: advance a playing clip, and match the loop's Sync
    /// Writes with the drags they carried.
    pub fn frame(&self, dt: f64) {
        {
            let mut scene = self.scene();
            if scene.advance(dt) {
                self.commit(&mut scene, None);
            }
        }
        let mut l = self.latency.lock().unwrap_or_else(PoisonError::into_inner);
        let live = self.live.read();
        let ticks = live.ticks;
        let cursor = l.cursor;
        let mut carried = Vec::new();
        l.cursor = live.carried_since(cursor, |c| carried.push(c));
        drop(live);
        for c in carried {
            // Drags superseded before a tick took them are never carried: dropped here.
            while l.pending.front().is_some_and(|&(m, _)| m < c.made_ns) {
                l.pending.pop_front();
            }
            if let Some(&(made, received)) = l.pending.front().filter(|p| p.0 == c.made_ns) {
                l.pending.pop_front();
                let us = |from: u64| c.write_ns.saturating_sub(from) as f64 * 1e-3;
                l.samples.push_back((us(made), us(received)));
                if l.samples.len() > LATENCY_WINDOW {
                    l.samples.pop_front();
                }
            }
        }
        drop(l);
        let mut r = self.measured_rate.lock().unwrap_or_else(PoisonError::into_inner);
        let elapsed = r.0.elapsed().as_secs_f64();
        if elapsed >= 1.0 {
            r.2 = (ticks.saturating_sub(r.1)) as f64 / elapsed;
            *r = (Instant::now(), ticks, r.2);
        }
    }

    /// Runs [`Studio::frame`] every [`FRAME`] until `done` says so.
    pub fn run_frames(&self, mut done: impl FnMut() -> bool) {
        let mut last = Instant::now();
        while !done() && !self.stop.load(Ordering::Relaxed) {
            std::thread::sleep(FRAME);
            let now = Instant::now();
            self.frame((now - last).as_secs_f64());
            last = now;
        }
    }

    /// What was sent to the loop.
    #[must_use]
    pub fn report(&self) -> ProducerReport {
        ProducerReport {
            sent: self.sent.load(Ordering::Relaxed),
            ..ProducerReport::default()
        }
    }

    /// Drag-to-goal latency so far, µs: from the browser's event, and from the server's
    /// receipt of it, to the Sync Write that carried it.
    #[must_use]
    pub fn latency(&self) -> (Quantiles, Quantiles) {
        let l = self.latency.lock().unwrap_or_else(PoisonError::into_inner);
        (
            Quantiles::of(l.samples.iter().map(|s| s.0)),
            Quantiles::of(l.samples.iter().map(|s| s.1)),
        )
    }

    /// The loop's figures: rate asked and measured, ticks, misses, compute p50/p99, µs.
    #[must_use]
    pub fn loop_json(&self) -> Value {
        let live = self.live.read();
        let measured = self
            .measured_rate
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .2;
        json!({
            "bus": self.bus,
            "rate_hz": self.rate_hz,
            "measured_hz": measured,
            "ticks": live.ticks,
            "misses": live.misses,
            "compute_p50_us": live.compute_quantile_ns(0.5) as f64 * 1e-3,
            "compute_p99_us": live.compute_quantile_ns(0.99) as f64 * 1e-3,
            // In lockstep with MuJoCo the loop's clock is the simulation's: compute is not timed.
            "simulated_time": matches!(self.feed, Feed::Lockstep(_)),
        })
    }

    /// Each servo's commanded (goal) and present angle, degrees (null before the loop ran).
    #[must_use]
    pub fn servos_json(&self) -> Value {
        let live = self.live.read();
        let deg = |r: f64| {
            if r.is_finite() {
                json!(r.to_degrees())
            } else {
                Value::Null
            }
        };
        Value::Array(
            self.servos
                .iter()
                .enumerate()
                .map(|(k, s)| {
                    let (g, p) = if k < live.len {
                        (live.goal_rad[k], live.present_rad[k])
                    } else {
                        (f64::NAN, f64::NAN)
                    };
                    json!({"name": s.name, "goal_deg": deg(g), "present_deg": deg(p)})
                })
                .collect(),
        )
    }

    /// `GET /api/pose`: every bone's tip in the root's frame, the residual, the solver, the
    /// servos.
    #[must_use]
    pub fn pose_json(&self) -> Value {
        let scene = self.scene();
        let tips = scene.tips(&scene.primary.channels);
        let mut map = serde_json::Map::new();
        for (b, bone) in scene.skeleton().bones().iter().enumerate() {
            map.insert(
                bone.name().to_string(),
                json!(scene.world_to_root(tips[b]).to_array()),
            );
        }
        let report = scene.primary.report.clone();
        drop(scene);
        json!({
            "robot": self.robot_json(true),
            "tips": map,
            "residual": report.residual,
            "solver": report.solver,
            "iterations": report.iterations,
            "micros": report.micros,
            "servos": self.servos_json(),
        })
    }

    /// A profile of robot joints: the robot beside the human ([`robot::RobotView::view`]) at
    /// the servos' present angles, in the human's world (as the page draws the bones) or, with
    /// `root_frame`, in the root's frame (as the API gives the tips); null otherwise.
    #[must_use]
    pub fn robot_json(&self, root_frame: bool) -> Value {
        let Some(view) = &self.robot else {
            return Value::Null;
        };
        let present: Vec<f64> = {
            let live = self.live.read();
            live.present_rad[..live.len].to_vec()
        };
        let scene = self.scene();
        let human = scene.pose64();
        view.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .view(&human, FRAME.as_secs_f64(), &present, |p| {
                if root_frame {
                    scene.world_to_root(p)
                } else {
                    p
                }
            })
    }

    /// `POST /api/target`: `effector` to `position` (root frame), or released with `None`.
    ///
    /// # Errors
    /// [`SceneError`].
    pub fn set_target(
        &self,
        effector: &str,
        position: Option<DVec3>,
        event_ms: Option<f64>,
    ) -> Result<(), SceneError> {
        if position.is_some_and(|p| !p.is_finite()) {
            return Err(SceneError::NotFinite("position"));
        }
        let mut scene = self.scene();
        let k = scene.effector(effector)?;
        let world = position.map(|p| scene.root_to_world(p));
        scene.set_target(k, world)?;
        self.commit(&mut scene, event_ms);
        Ok(())
    }

    /// `POST /api/solver`, the page's `solver`: the method, and optionally one to compare.
    pub fn set_solver(&self, request: SolverRequest) {
        let mut scene = self.scene();
        scene.set_methods(request.method, request.compare);
        self.commit(&mut scene, None);
    }

    /// Carries out a page's message; `selected` is that page's selected effector.
    ///
    /// # Errors
    /// Why it cannot be done, in one line (an unknown bone, the timeline without a clip …).
    pub fn apply(&self, event: PageEvent, selected: &mut Option<String>) -> Result<(), String> {
        let mut scene = self.scene();
        let effector = |scene: &mut Scene, name: &str| scene.effector(name).map_err(|e| e.to_string());
        match event.message {
            PageMessage::Drag {
                effector: name,
                position,
            } => {
                let k = effector(&mut scene, &name)?;
                scene.set_target(k, Some(position)).map_err(|e| e.to_string())?;
                *selected = Some(name);
            }
            PageMessage::Release { effector: name } => {
                let k = effector(&mut scene, &name)?;
                scene.set_target(k, None).map_err(|e| e.to_string())?;
            }
            PageMessage::Pin { effector: name } => {
                let k = effector(&mut scene, &name)?;
                scene.pin(k);
            }
            PageMessage::Select { effector: name } => {
                if let Some(name) = &name {
                    effector(&mut scene, name)?;
                }
                *selected = name;
            }
            PageMessage::Solver(request) => scene.set_methods(request.method, request.compare),
            PageMessage::Swivel { deg } => scene.swivel = deg.map(f64::to_radians),
            PageMessage::Timeline {
                playing,
                looping,
                speed,
                time,
            } => {
                if !scene.has_clip() {
                    return Err("no clip: start the studio with an AMC to use the timeline".into());
                }
                if let Some(p) = playing {
                    scene.timeline.playing = p;
                }
                if let Some(l) = looping {
                    scene.timeline.looping = l;
                }
                if let Some(s) = speed {
                    scene.timeline.speed = s;
                }
                if let Some(t) = time {
                    scene.seek(t).map_err(|e| e.to_string())?;
                }
            }
            PageMessage::Reset => {
                for k in 0..scene.effectors.len() {
                    let _ = scene.set_target(k, None);
                }
            }
        }
        self.commit(&mut scene, event.event_ms);
        Ok(())
    }
}

/// Now, ns since the Unix epoch.
fn wall_ns() -> i128 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as i128)
}

/// The studio as the loop's (live) source. In real time its drags go straight into the loop's
/// channel, stamped on the loop's clock, and this source advances the timeline every
/// [`FRAME`]. In lockstep with the simulator the drags come through `rx`: at each tick the
/// newest pose is sent, the simulation paced to the wall clock (a person drags in real time),
/// and the timeline advanced every [`FRAME`] of wall time.
#[derive(Debug)]
pub struct StudioSource {
    studio: Arc<Studio>,
    rx: Option<crossbeam_channel::Receiver<(Vec<f64>, f64)>>,
    started: Option<(Instant, u64)>,
    last_frame: Option<Instant>,
    seq: u64,
    sent: u64,
}

impl StudioSource {
    /// The source of `studio`; `rx` receives its poses when its feed is
    /// [`Feed::Lockstep`].
    #[must_use]
    pub fn new(
        studio: Arc<Studio>,
        rx: Option<crossbeam_channel::Receiver<(Vec<f64>, f64)>>,
    ) -> StudioSource {
        StudioSource {
            studio,
            rx,
            started: None,
            last_frame: None,
            seq: 0,
            sent: 0,
        }
    }
}

impl Source for StudioSource {
    fn name(&self) -> &'static str {
        "studio-frames"
    }
    fn live(&self) -> bool {
        true
    }
    fn runs_in_lockstep(&self) -> bool {
        self.rx.is_some()
    }
    fn next_due(&self, _grid: Grid) -> Option<u64> {
        None
    }
    fn begin(&mut self, clock: SystemClock) {
        self.studio.set_loop_clock(clock);
        self.studio.republish();
    }
    fn feed(&mut self, _grid: Grid, until_ns: u64, now_ns: u64, sink: &Sink<'_>) -> bool {
        let Some(rx) = &self.rx else {
            // Real time: the drags are sent as they come; the timeline runs here.
            self.studio.run_frames(|| sink.stopped());
            return false;
        };
        let _ = until_ns;
        let (t0, s0) = *self.started.get_or_insert((Instant::now(), now_ns));
        let due = t0 + Duration::from_nanos(now_ns.saturating_sub(s0));
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let last = *self.last_frame.get_or_insert_with(|| {
            self.studio.republish();
            Instant::now()
        });
        if last.elapsed() >= FRAME {
            let now = Instant::now();
            self.studio.frame((now - last).as_secs_f64());
            self.last_frame = Some(now);
        }
        let mut newest = None;
        while let Ok(p) = rx.try_recv() {
            newest = Some(p);
        }
        if let Some((channels, clip_time)) = newest {
            self.seq += 1;
            if sink
                .send_newest(Input::frame(self.seq, 0, now_ns.max(1), &channels, clip_time))
                .is_ok()
            {
                self.sent += 1;
            }
        }
        !sink.stopped() && !self.studio.stop.load(Ordering::Relaxed)
    }
    fn report(&self) -> ProducerReport {
        if self.rx.is_some() {
            ProducerReport {
                sent: self.sent,
                ..ProducerReport::default()
            }
        } else {
            self.studio.report()
        }
    }
}

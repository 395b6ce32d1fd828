//! The fixed-rate control loop: newest input → FK/IK → rig mapping → command stage → Sync
//! Write → Sync Read → telemetry, on the absolute-deadline [`Schedule`].
//!
//! Everything a tick needs is prepared before the loop starts ([`Controller::new`]); a tick
//! allocates nothing (the `alloc_free` test and the `allocations_in_tick` statistic prove it
//! with a counting allocator). Time is passed in through a [`Clock`], so tests run the loop on
//! virtual time.
//!
//! Fault policy: a failed or corrupt read is never used; after `hold_after` consecutive failed
//! reads the last command sent is held (new inputs are not acted on; no step back); after `torque_off_after`
//! without a valid read every servo's torque is turned off and the loop stops with a fault.
//! A host that stops altogether is covered by the servos' Bus Watchdog, armed at start-up.
//! The port itself failing (a USB adapter unplugged: reads and writes fail with EIO) ends the
//! run at once: nothing more is commanded, one torque-off Sync Write is tried.
//!
//! Stopping: [`StopRequests`] are counted. The first ends the loop with the ramp to rest (or the
//! hold); a second during the ramp cuts it short and turns torque off at once.

pub mod fidelity;
mod follow;
pub mod identify;
pub mod input;
pub mod live;
pub mod lockstep;
pub mod lookahead;
pub mod plot;
mod retarget_stage;
pub mod source;
pub mod sources;
pub mod stats;
mod tick;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use crossbeam_channel::{Sender, TrySendError};
use glam::DVec3;

use crate::bus::{BusError, ServoBus};
use crate::command::CommandStage;
use crate::fk::{ancestors, fk64, fk64_bones, Pose64};
use crate::rig::Rig;
use crate::schedule::{Clock, Schedule, Tick};
use crate::servo::MAX_SERVOS;
use crate::servo::{addr, TICKS_PER_TURN};
use crate::skeleton::{Skeleton, MAX_BONES, MAX_CHANNELS};
use input::{InputPort, Payload};
use live::LiveView;
use lookahead::{Lookahead, Preview, SourceSample};
use stats::{LoopStats, Stage};

pub use follow::{pointer_bone, target_range, Effector, FollowError, Follower, TARGET_RANGE_REACHES};
pub use retarget_stage::RetargetStage;

/// Most inputs turned into source samples in one tick (a look-ahead's preview fills over a few
/// ticks at the start rather than in one long tick).
const MAX_INGEST: usize = 16;

/// Half-width of the swivel window searched around the previous frame's swivel (40°).
const SWIVEL_WINDOW: f64 = 40.0 * core::f64::consts::PI / 180.0;

/// How the loop ends a run that was not stopped by a fault.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum StopMode {
    /// Move to the rest pose (all joint angles 0, clamped to the limits) over `ramp_s` seconds
    /// with an ease-in/out (eq. 13), then torque off.
    Rest {
        /// Ramp duration, seconds.
        ramp_s: f64,
    },
    /// Hold the last command for `hold_s` seconds, then torque off.
    Hold {
        /// Hold duration, seconds.
        hold_s: f64,
    },
}

/// Settings of the loop.
#[derive(Clone, Copy, Debug)]
pub struct LoopConfig {
    /// Ticks per second (50 … 1000 in practice).
    pub rate_hz: f64,
    /// Consecutive failed reads after which the last command sent is held (K).
    pub hold_after: u32,
    /// Milliseconds without a valid read after which torque goes off (T).
    pub torque_off_after_ms: f64,
    /// How a run ends (end of input, duration, Ctrl-C).
    pub stop: StopMode,
    /// Stop after this many ticks (the `--duration`).
    pub max_ticks: Option<u64>,
    /// Heap allocations made so far on this thread (a counting global allocator's counter), to
    /// count allocations inside ticks.
    pub allocations: Option<fn() -> u64>,
    /// Seconds over which the first commands blend from where the servos stood to the input
    /// (0: the first input is commanded at once, within the velocity limits).
    pub ease_in_s: f64,
    /// Metres per skeleton file unit at the rig's size, for effector distances (the puppet's
    /// scale times the skeleton's unit; a robot's are in its own metres).
    pub effector_metres_per_unit: f64,
    /// Pipelined reads: each tick requests the present positions after its Sync Write and
    /// takes the replies at the start of the next tick, so the servos answer while the loop
    /// sleeps ([`ServoBus::request_positions`]).
    pub pipelined: bool,
    /// Accumulate the fidelity on a thread of its own ([`fidelity::FidelityWorker`]; real-time
    /// runs), not in the tick (lockstep runs, whose results must not depend on timing).
    pub fidelity_worker: bool,
}

impl Default for LoopConfig {
    fn default() -> Self {
        LoopConfig {
            rate_hz: 120.0,
            hold_after: 3,
            torque_off_after_ms: 100.0,
            stop: StopMode::Rest { ramp_s: 1.0 },
            max_ticks: None,
            allocations: None,
            ease_in_s: 0.0,
            effector_metres_per_unit: 0.0,
            pipelined: false,
            fidelity_worker: false,
        }
    }
}

/// One tick's figures, sent to each telemetry consumer (never blocking the loop).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Telemetry {
    /// Tick index.
    pub index: u64,
    /// Deadline, ns on the loop clock.
    pub deadline_ns: u64,
    /// Wake-up, ns.
    pub woke_ns: u64,
    /// Work without bus I/O, ns.
    pub compute_ns: u64,
    /// Whole tick, ns.
    pub total_ns: u64,
    /// Whether the tick ended after the next deadline.
    pub missed: bool,
    /// Whether the read succeeded (pipelined: the replies taken and the request sent this
    /// tick; the first tick has only a request).
    pub read_ok: bool,
    /// Whether the tick held the last command.
    pub held: bool,
    /// RMS of commanded − present over the servos this tick, degrees (NaN without a read).
    pub tracking_rms_deg: f64,
    /// Tips of up to four watched bones (the effectors) after the solve, root frame.
    pub tips: [DVec3; 4],
    /// Clip time of the frame used (play), seconds.
    pub clip_time: f64,
    /// Present positions of the last valid read, ticks (`servos` of them, rig order).
    pub present: [i32; MAX_SERVOS],
    /// Number of servos.
    pub servos: usize,
    /// Loop-clock time (ns) of the last valid read: when `present` was measured.
    pub read_ns: u64,
    /// Whether the tick belongs to the stop ramp (after the input's end or a stop request).
    pub stopping: bool,
}

impl Default for Telemetry {
    fn default() -> Self {
        Telemetry {
            index: 0,
            deadline_ns: 0,
            woke_ns: 0,
            compute_ns: 0,
            total_ns: 0,
            missed: false,
            read_ok: false,
            held: false,
            tracking_rms_deg: f64::NAN,
            tips: [DVec3::ZERO; 4],
            clip_time: f64::NAN,
            present: [0; MAX_SERVOS],
            servos: 0,
            read_ns: 0,
            stopping: false,
        }
    }
}

impl Telemetry {
    /// The present positions (ticks), rig order.
    #[must_use]
    pub fn present(&self) -> &[i32] {
        &self.present[..self.servos.min(MAX_SERVOS)]
    }
}

/// Most telemetry consumers a controller feeds (the status line, a ROS 2 publisher).
pub const MAX_TELEMETRY_SINKS: usize = 4;

/// Why a run ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RunEnd {
    /// The input ended (clip played once, target file done).
    InputEnded,
    /// The tick count (`--duration`) was reached.
    Duration,
    /// Stopped from outside (a signal, Ctrl-C).
    Interrupted,
    /// No valid read for the torque-off time: torque was turned off.
    ReadsFailed,
    /// The port failed (I/O error: the adapter went away); one torque-off was tried.
    PortLost,
}

/// Requests to stop the loop (from signal handlers, a user interface, a test), counted from
/// the moment the value was made: the loop ends at the first; a second during the ramp to
/// rest cuts it short and turns torque off at once.
#[derive(Clone, Debug, Default)]
pub struct StopRequests {
    count: Arc<AtomicUsize>,
    base: usize,
}

impl StopRequests {
    /// Requests on their own counter, none yet.
    #[must_use]
    pub fn new() -> StopRequests {
        StopRequests::default()
    }

    /// Requests on a shared counter (e.g. one a signal handler increments), counted from its
    /// present value.
    #[must_use]
    pub fn counting_from_now(count: Arc<AtomicUsize>) -> StopRequests {
        let base = count.load(Ordering::SeqCst);
        StopRequests { count, base }
    }

    /// Asks the loop to stop (again).
    pub fn request(&self) {
        self.count.fetch_add(1, Ordering::SeqCst);
    }

    /// Requests made since this value was made.
    #[must_use]
    pub fn made(&self) -> usize {
        self.count.load(Ordering::SeqCst).saturating_sub(self.base)
    }
}

/// What the loop does with the input.
#[derive(Debug)]
pub enum Solve {
    /// Frames are joint angles already (AMC playback).
    Frames,
    /// Effector targets solved by IK.
    Follow(Box<Follower>),
}

/// What a read taken after a tick's Sync Write belongs to (kept until a pipelined read's
/// replies are taken).
#[derive(Clone, Copy)]
struct ReadContext {
    /// Due time of the tick's source sample (the fidelity's reference, in the preview).
    sample_due: u64,
    /// Whether the tick held its last command.
    holding: bool,
    /// The goals it wrote.
    goals: [i32; MAX_SERVOS],
    /// The goals written a tick before, which the servos had a period to reach.
    tracked: Option<[i32; MAX_SERVOS]>,
    /// Whether the read counts for fidelity (input flowing, not held, eased in, past the
    /// pre-roll).
    record: bool,
    /// The tick's index.
    tick: u64,
}

/// An input taken and being solved (over one tick or several).
#[derive(Clone, Copy, Debug)]
struct Solving {
    /// When its sample is due, ns.
    due: u64,
    clip_time: f64,
    made_ns: u64,
    /// The first effector not yet solved.
    next_effector: usize,
}

/// What [`Controller::take_input`] found.
enum Taken {
    /// An input to solve.
    Input(Solving),
    /// One passed over (superseded or refused).
    PassedOver,
    /// None due.
    Nothing,
}

/// What a read gave.
struct Absorbed {
    ok: bool,
    tracking: f64,
    end: Option<RunEnd>,
}

/// The loop's state: everything a tick touches, allocated before the first tick.
pub struct Controller {
    skeleton: Arc<Skeleton>,
    rig: Rig,
    ids: Vec<u8>,
    config: LoopConfig,
    period_ns: u64,
    stage: CommandStage,
    channels: [f64; MAX_CHANNELS],
    angles: Vec<f64>,
    present: Vec<i32>,
    read_buf: Vec<i32>,
    /// A pipelined read on the wire and the tick it belongs to.
    in_flight: Option<ReadContext>,
    /// Goals of the previous tick's write: what the servos had a period to reach.
    previous_goals: Vec<i32>,
    have_previous: bool,
    pose: Box<Pose64>,
    watch: [Option<usize>; 4],
    /// The watched bones and their ancestors, parents first: the bones a sample's forward
    /// kinematics needs when nothing else reads the pose.
    watched_chains: heapless::Vec<usize, MAX_BONES>,
    input: InputPort,
    solve: Solve,
    telemetry: heapless::Vec<Sender<Telemetry>, MAX_TELEMETRY_SINKS>,
    live: Option<Arc<LiveView>>,
    /// The statistics so far.
    pub stats: LoopStats,
    have_input: bool,
    clip_time: f64,
    failures: u32,
    /// Why the port failed, when a run ended with [`RunEnd::PortLost`].
    pub port_error: Option<std::io::Error>,
    last_valid_read_ns: u64,
    last_tick: Option<(u64, u64)>,
    retarget: Option<Box<RetargetStage>>,
    /// The joint angles the servos stood at (the ease-in's start), its length in ticks, and
    /// the commanded ticks so far.
    ease_from: Vec<f64>,
    ease_ticks: u64,
    eased: u64,
    /// Source against present, end to end: accumulated here, or by the worker when there is
    /// one.
    fidelity: Box<fidelity::Fidelity>,
    fidelity_worker: Option<fidelity::FidelityWorker>,
    /// This tick's source angles (the input mapped through the rig) and the present angles.
    source_angles: Vec<f64>,
    present_angles: Vec<f64>,
    /// Effectors at the present angles (skeleton rigs with a scale, without a worker).
    effector_pose: Option<fidelity::EffectorPose>,
    /// The due time and number of the last source pose the worker was given.
    pose_sent: (Option<u64>, u64),
    servo_names: Vec<String>,
    /// Each tick's source angles with its deadline (ns), up to the capacity reserved by
    /// [`Controller::log_source`]; never grown in a tick.
    source_log: Vec<(u64, [f64; MAX_SERVOS])>,
    /// Source samples taken ahead (the look-ahead's preview; without it, the current one).
    preview: Preview,
    /// How far ahead inputs are taken, ns.
    preview_ns: u64,
    lookahead: Option<Box<Lookahead>>,
    /// Due time of the last input turned into a sample (the retargeting's time step).
    last_due: Option<u64>,
    /// When the ease-in began (the first tick with a source), ns.
    ease_start_ns: Option<u64>,
    /// The input being solved, when its solve is spread over ticks.
    solving: Option<Solving>,
}

impl std::fmt::Debug for Controller {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Controller")
            .field("servos", &self.ids.len())
            .field("rate_hz", &self.config.rate_hz)
            .finish_non_exhaustive()
    }
}

impl Controller {
    /// A loop for `rig` (over `skeleton`) with servo `ids` in rig order, started from the
    /// present positions `present` (as [`crate::bus::start_up`] returns them).
    ///
    /// # Panics
    /// When `ids`, `present` and the rig differ in length or the rig has more than
    /// [`MAX_SERVOS`] servos (profiles guarantee neither happens).
    #[must_use]
    pub fn new(
        skeleton: Arc<Skeleton>,
        rig: Rig,
        ids: Vec<u8>,
        present: &[i32],
        input: InputPort,
        solve: Solve,
        config: LoopConfig,
    ) -> Controller {
        assert!(ids.len() == rig.len() && present.len() == rig.len() && rig.len() <= MAX_SERVOS);
        let mut stage = CommandStage::new(rig.len());
        stage.start_from(&rig, present);
        let mut watch = [None; 4];
        let names: Vec<&str> = match &solve {
            Solve::Follow(f) => f.names().collect(),
            Solve::Frames => vec!["lradius", "rradius", "ltibia", "rtibia"],
        };
        for (w, n) in watch.iter_mut().zip(names) {
            *w = skeleton.find(n);
        }
        let mut on_chain = [false; MAX_BONES];
        for b in watch.iter().flatten() {
            for a in ancestors(&skeleton, *b) {
                on_chain[a] = true;
            }
        }
        // Bones are stored parents first, so ascending indices are a valid FK order.
        let watched_chains = (0..skeleton.bones().len()).filter(|&b| on_chain[b]).collect();
        let n = rig.len();
        let period_ns = (1e9 / config.rate_hz).round().max(1.0) as u64;
        // The joint angles of the present positions: the reference for Euler re-decomposition.
        let angles: Vec<f64> = rig
            .servos
            .iter()
            .zip(present)
            .map(|(s, p)| s.ticks_to_angle(f64::from(*p)))
            .collect();
        let ease_ticks = (config.ease_in_s * config.rate_hz).round().max(0.0) as u64;
        let effector_pose = (config.effector_metres_per_unit > 0.0).then(|| {
            fidelity::EffectorPose::new(
                Arc::clone(&skeleton),
                rig.clone(),
                watch,
                config.effector_metres_per_unit,
            )
        });
        let mut stats = LoopStats::new(config.rate_hz);
        stats.allocations_in_tick = config.allocations.map(|_| 0);
        Controller {
            skeleton,
            stats,
            rig,
            ids,
            config,
            period_ns,
            stage,
            channels: [0.0; MAX_CHANNELS],
            ease_from: angles.clone(),
            ease_ticks,
            eased: 0,
            fidelity: Box::new(fidelity::Fidelity::new(n, period_ns as f64 * 1e-9)),
            // Without a thread (none could be started) the tick accumulates it.
            fidelity_worker: config
                .fidelity_worker
                .then(|| {
                    let f = fidelity::Fidelity::new(n, period_ns as f64 * 1e-9);
                    fidelity::FidelityWorker::spawn(f, effector_pose.clone()).ok()
                })
                .flatten(),
            effector_pose,
            pose_sent: (None, 0),
            source_angles: vec![f64::NAN; n],
            present_angles: vec![f64::NAN; n],
            servo_names: Vec::new(),
            source_log: Vec::new(),
            preview: Preview::new(8),
            preview_ns: 0,
            lookahead: None,
            last_due: None,
            ease_start_ns: None,
            solving: None,
            angles,
            present: present.to_vec(),
            read_buf: vec![0; n],
            in_flight: None,
            previous_goals: vec![0; n],
            have_previous: false,
            pose: Box::default(),
            watch,
            watched_chains,
            input,
            solve,
            telemetry: heapless::Vec::new(),
            live: None,
            have_input: false,
            clip_time: f64::NAN,
            failures: 0,
            port_error: None,
            last_valid_read_ns: 0,
            last_tick: None,
            retarget: None,
        }
    }

    /// Source against present for this tick (after a valid read): joints, and effectors by
    /// forward kinematics of both. Allocates nothing.
    /// Takes a read made after the Sync Write of the tick described by `context`: the present
    /// positions, tracking against the goals the servos had a period to reach, fidelity
    /// against that tick's source; a failure counted, and torque off after the torque-off
    /// time without a valid read. Returns what it found and why the port failed, if it did.
    fn absorb_read(
        &mut self,
        read: Result<(), BusError>,
        at_ns: u64,
        context: &ReadContext,
        bus: &mut dyn ServoBus,
    ) -> (Absorbed, Option<std::io::Error>) {
        let len = self.ids.len();
        let mut found = Absorbed {
            ok: read.is_ok(),
            tracking: f64::NAN,
            end: None,
        };
        match read {
            Ok(()) => {
                self.present.copy_from_slice(&self.read_buf);
                self.stats.reads_ok += 1;
                self.failures = 0;
                self.last_valid_read_ns = at_ns;
                if context.holding {
                    // Back from a hold: the next command starts, at rest, from the one held.
                    self.stage.start_from(&self.rig, &context.goals[..len]);
                }
                if let Some(goals) = &context.tracked {
                    let mut sq = 0.0;
                    for (s, (g, p)) in self.rig.servos.iter().zip(goals.iter().zip(&self.present)) {
                        let deg =
                            f64::from(g - p) * 360.0 / f64::from(TICKS_PER_TURN) / s.gear.abs().max(1e-9);
                        self.stats.tracking(deg);
                        sq += deg * deg;
                    }
                    found.tracking = (sq / len.max(1) as f64).sqrt();
                }
                if context.record {
                    self.record_fidelity(context.tick, context.sample_due);
                }
                (found, None)
            }
            Err(e) => {
                self.stats.bus_error(e.kind());
                self.failures = self.failures.saturating_add(1);
                let lost = e.port_failure();
                let silent_ms = (at_ns.saturating_sub(self.last_valid_read_ns)) as f64 * 1e-6;
                if lost.is_none() && silent_ms >= self.config.torque_off_after_ms {
                    self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
                    found.end = Some(RunEnd::ReadsFailed);
                }
                (found, lost)
            }
        }
    }

    fn record_fidelity(&mut self, tick: u64, sample_due: u64) {
        for ((p, s), t) in self
            .present_angles
            .iter_mut()
            .zip(&self.rig.servos)
            .zip(&self.present)
        {
            *p = s.ticks_to_angle(f64::from(*t));
        }
        // The tick's sample is still in the preview (current, or just behind it); not after a
        // restart, which nothing is compared across.
        let Some(sample) = self.preview.find(sample_due) else {
            return;
        };
        let n = self.present_angles.len();
        let mut record = fidelity::FidelityRecord::new(tick, n);
        record.source[..n].copy_from_slice(&sample.angles[..n]);
        record.present[..n].copy_from_slice(&self.present_angles);
        if let Some(r) = &mut self.retarget {
            let present = r.present_effectors(&self.rig, &self.present_angles, sample.base);
            for ((e, s), p) in record.effectors.iter_mut().zip(sample.effectors).zip(present) {
                *e = (s, p);
            }
        } else if let Some(pose) = &mut self.effector_pose {
            // The forward kinematics of the present pose: by the worker when there is one,
            // which is given each sample's pose once.
            let (sent_due, seq) = self.pose_sent;
            let source = |seq| {
                let mut s = fidelity::SourcePose {
                    seq,
                    channels: [0.0; MAX_CHANNELS],
                    tips: sample.tips,
                };
                let c = self.skeleton.channel_count();
                s.channels[..c].copy_from_slice(&sample.channels[..c]);
                s
            };
            match &mut self.fidelity_worker {
                Some(w) => {
                    if sent_due != Some(sample.due_ns) && w.send_pose(&source(seq + 1)) {
                        self.pose_sent = (Some(sample.due_ns), seq + 1);
                    }
                    // (Not sent: no effectors this tick.)
                    if self.pose_sent.0 == Some(sample.due_ns) {
                        record.pose = Some(self.pose_sent.1);
                    }
                }
                None => {
                    record.pose = Some(0);
                    pose.fill(&mut record, &source(0));
                }
            }
        }
        match &mut self.fidelity_worker {
            Some(w) => w.send(record),
            None => self.fidelity.take(&record),
        }
    }

    /// The fidelity so far (a worker's once it has taken every record: it is stopped, and
    /// the tick accumulates from here on). [`Controller::run`] puts it in the statistics.
    pub fn fidelity_report(&mut self) -> fidelity::FidelityReport {
        let mut dropped = 0;
        if let Some(mut w) = self.fidelity_worker.take() {
            if let Some(f) = w.finish() {
                *self.fidelity = f;
            }
            dropped = w.dropped;
        }
        let mut report = self.fidelity.report(&self.servo_names);
        report.records_dropped = dropped;
        report
    }

    /// Keeps the source angles of up to `ticks` ticks (reserved now; the tick stops logging
    /// when it is full rather than grow it), for pictures.
    pub fn log_source(&mut self, ticks: usize) {
        self.source_log = Vec::with_capacity(ticks);
    }

    /// The logged source angles: tick deadline (ns on the loop's clock) and radians per servo.
    #[must_use]
    pub fn source_log(&self) -> &[(u64, [f64; MAX_SERVOS])] {
        &self.source_log
    }

    /// Names of the servos (rig order), for the fidelity report.
    pub fn set_servo_names(&mut self, names: Vec<String>) {
        self.servo_names = names;
    }

    /// Plans the goals over a preview of the input with `lookahead` (inputs are taken that far
    /// ahead of their time: their producers must make them so early).
    pub fn set_lookahead(&mut self, lookahead: Lookahead) {
        self.preview_ns = lookahead.preview_ns();
        let ticks = (self.preview_ns / self.period_ns.max(1)) as usize;
        self.preview = Preview::new(ticks + MAX_INGEST + 8);
        self.lookahead = Some(Box::new(lookahead));
        if let Some(r) = &mut self.retarget {
            r.reserve(ticks + MAX_INGEST + 8);
        }
    }

    /// How far ahead of its tick the loop takes an input, ns (0 without a look-ahead).
    #[must_use]
    pub fn preview_ns(&self) -> u64 {
        self.preview_ns
    }

    /// Retargets each new pose onto a robot whose joints the rig's servos follow.
    pub fn set_retarget(&mut self, mut stage: RetargetStage) {
        let ticks = (self.preview_ns / self.period_ns.max(1)) as usize;
        stage.reserve(ticks + MAX_INGEST + 8);
        self.retarget = Some(Box::new(stage));
    }

    /// Publishes each tick's goals, present angles and timing in `view` (for the studio).
    pub fn set_live_view(&mut self, view: Arc<LiveView>) {
        self.live = Some(view);
    }

    /// Sends per-tick figures to `tx` as well (bounded; a full channel drops the record,
    /// counted). Each consumer has its own channel; up to [`MAX_TELEMETRY_SINKS`].
    ///
    /// # Errors
    /// `tx` back when there are [`MAX_TELEMETRY_SINKS`] already.
    pub fn add_telemetry(&mut self, tx: Sender<Telemetry>) -> Result<(), Sender<Telemetry>> {
        self.telemetry.push(tx)
    }

    /// Sends `record` to every consumer without waiting; a full channel drops it (counted).
    fn emit(&mut self, record: &Telemetry) {
        for tx in &self.telemetry {
            if let Err(TrySendError::Full(_)) = tx.try_send(*record) {
                self.stats.telemetry_dropped += 1;
            }
        }
    }

    /// The period, nanoseconds.
    #[must_use]
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The present positions of the last valid read (ticks).
    #[must_use]
    pub fn present(&self) -> &[i32] {
        &self.present
    }

    /// The last command written (ticks).
    #[must_use]
    pub fn last_command(&self) -> &[i32] {
        self.stage.last()
    }

    /// The pose in use (channels, radians).
    #[must_use]
    pub fn channels(&self) -> &[f64] {
        &self.channels[..self.skeleton.channel_count()]
    }

    /// Whether the input has ended (every producer gone, nothing left).
    #[must_use]
    pub fn input_finished(&self) -> bool {
        self.input.finished()
    }

    /// Takes the inputs due by `horizon` in order (the look-ahead's preview; without one, the
    /// tick's own window), at most [`MAX_INGEST`] a tick, and turns each into a source sample:
    /// the solve, forward kinematics, retargeting and the rig's angles — what a perfect rig
    /// would do at its time. An input already due by `due_now` with a newer one also due is
    /// passed over (only the newest counts). Ages are measured at `now`. Allocates nothing.
    ///
    /// Targets taken ahead of their time with no other input waiting are solved one effector a
    /// tick (the same solves in the same order, so the same sample, a few ticks later but still
    /// before it is due): a fast loop's ticks share the work of a slower input's solve. Live
    /// inputs and inputs due within that time are solved whole.
    fn ingest(&mut self, due_now: u64, horizon: u64, now: u64, tick_dt: f64) {
        let n = self.skeleton.channel_count();
        for _ in 0..MAX_INGEST {
            let mut p = match self.solving.take() {
                Some(p) => p,
                None => match self.take_input(due_now, horizon, now) {
                    Taken::Input(p) => p,
                    Taken::PassedOver => continue,
                    Taken::Nothing => break,
                },
            };
            if let Solve::Follow(f) = &mut self.solve {
                // Steps: each effector, then the sample.
                let count = f.effectors.len();
                let left = (count + 1).saturating_sub(p.next_effector) as u64;
                let spread =
                    p.due > due_now + (left + 1) * self.period_ns && !self.input.next_is_due(horizon);
                if p.next_effector < count {
                    let end = if spread { p.next_effector + 1 } else { count };
                    f.solve_some(
                        &self.skeleton,
                        &mut self.channels[..n],
                        &mut self.pose,
                        &mut self.stats,
                        p.next_effector..end,
                    );
                    if spread && p.next_effector == 0 {
                        self.stats.inputs_spread += 1;
                    }
                    p.next_effector = end;
                    if spread {
                        self.solving = Some(p);
                        break;
                    }
                }
            }
            self.add_sample(p, tick_dt);
        }
    }

    /// The next input due by `horizon`, checked and put in place (a frame's channels, the
    /// follower's targets).
    fn take_input(&mut self, due_now: u64, horizon: u64, now: u64) -> Taken {
        let n = self.skeleton.channel_count();
        {
            let Some(msg) = self.input.next_due(horizon) else {
                return Taken::Nothing;
            };
            if msg.due_ns <= due_now && self.input.next_is_due(due_now) {
                // Not solved, but its targets stand: a newer message may name other effectors
                // (live sources send one effector a line or a topic).
                if let (Payload::Targets(targets), Solve::Follow(f)) = (&msg.payload, &mut self.solve) {
                    if targets.iter().all(|t| f.accepts(t)) {
                        for t in targets {
                            f.targets[t.effector] = Some(*t);
                        }
                    } else {
                        self.stats.inputs_rejected += 1;
                    }
                }
                self.input.superseded += 1;
                return Taken::PassedOver;
            }
            let mut clip_time = f64::NAN;
            let ok = match (&msg.payload, &mut self.solve) {
                (
                    Payload::Frame {
                        channels,
                        len,
                        clip_time: t,
                    },
                    Solve::Frames,
                ) if *len >= n && channels[..n].iter().all(|v| v.is_finite()) => {
                    self.channels[..n].copy_from_slice(&channels[..n]);
                    clip_time = *t;
                    true
                }
                (Payload::Targets(targets), Solve::Follow(f)) => {
                    let valid = targets.iter().all(|t| f.accepts(t));
                    if valid {
                        for t in targets {
                            f.targets[t.effector] = Some(*t);
                        }
                    }
                    valid
                }
                _ => false,
            };
            if !ok {
                self.stats.inputs_rejected += 1;
                return Taken::PassedOver;
            }
            self.stats.inputs_used += 1;
            self.stats
                .stage_mut(Stage::InputAge)
                .record(now.saturating_sub(msg.made_ns));
            // Live inputs are due at once: they stand for the time they were made.
            let due = if msg.due_ns == 0 {
                msg.made_ns.min(due_now)
            } else {
                msg.due_ns
            };
            Taken::Input(Solving {
                due,
                clip_time,
                made_ns: msg.made_ns,
                next_effector: 0,
            })
        }
    }

    /// The solved (or played) pose of the input `p` as a source sample in the preview: its
    /// forward kinematics, retargeting and the rig's angles.
    fn add_sample(&mut self, p: Solving, tick_dt: f64) {
        let n = self.skeleton.channel_count();
        let Solving {
            due,
            clip_time,
            made_ns,
            ..
        } = p;
        {
            // The retargeting reads the whole pose; otherwise only the watched tips are used.
            if self.retarget.is_some() {
                fk64(&self.skeleton, &self.channels[..n], &mut self.pose);
            } else {
                fk64_bones(
                    &self.skeleton,
                    &self.channels[..n],
                    &mut self.pose,
                    &self.watched_chains,
                );
            }
            let mut sample = SourceSample {
                due_ns: due,
                clip_time,
                made_ns,
                ..SourceSample::default()
            };
            sample.channels[..n].copy_from_slice(&self.channels[..n]);
            for (t, w) in sample.tips.iter_mut().zip(self.watch) {
                if let Some(b) = w {
                    *t = self.pose.tip[b];
                }
            }
            if let Some(r) = &mut self.retarget {
                let dt = match self.last_due {
                    Some(d) if due > d => (due - d) as f64 * 1e-9,
                    _ => tick_dt,
                };
                r.step(&self.pose, clip_time, dt, due);
                sample.effectors = r.frame.effectors;
                sample.base = (r.frame.base_pos, r.frame.base_rot);
            }
            self.last_due = Some(due);
            let joints: &[f64] = match &self.retarget {
                Some(r) => &r.frame.q,
                None => &[],
            };
            self.rig
                .joint_angles(&self.skeleton, &self.channels[..n], joints, &mut self.angles);
            if self.angles.iter().any(|a| !a.is_finite()) {
                // Refused as a whole: the servos go on with the samples they have.
                self.stats.commands_refused += 1;
                return;
            }
            let len = self.angles.len();
            sample.angles[..len].copy_from_slice(&self.angles);
            self.preview.push(sample);
        }
    }

    /// One tick at `tick` (from [`Schedule::wait`]), in its phases (`control/tick.rs`): the
    /// pipelined replies, the input, the command, the bus, the telemetry. Allocates nothing.
    pub fn tick(&mut self, tick: &Tick, bus: &mut dyn ServoBus, clock: &mut dyn Clock) -> Option<RunEnd> {
        let allocs = self.config.allocations.map(|f| f());
        let start = self.begin(tick, clock);
        let replies = match self.collect_replies(bus, clock) {
            Ok(replies) => replies,
            Err(end) => return Some(end),
        };
        let t_solve = clock.now_ns();
        let dt = self.period_ns as f64 * 1e-9 * (1 + tick.skipped) as f64;
        let current = self.take_current(tick, start, dt);
        let t_encode = clock.now_ns();
        self.stats.stage_mut(Stage::Solve).record(t_encode - t_solve);
        let holding = self.failures >= self.config.hold_after;
        let goals = self.encode(tick, dt, holding);
        let t_write = clock.now_ns();
        self.stats.stage_mut(Stage::Encode).record(t_write - t_encode);
        let command = tick::Command {
            goals,
            holding,
            t_write,
        };
        let done_bus = self.exchange(tick, bus, clock, &command, &current, replies);
        self.report(tick, start, clock.now_ns(), &command, &current, &done_bus);
        if let (Some(f), Some(before)) = (self.config.allocations, allocs) {
            *self.stats.allocations_in_tick.get_or_insert(0) += f().saturating_sub(before);
        }
        let mut end = done_bus.end;
        if end.is_none()
            && self.input.finished()
            && !current.fresh
            && !self.preview.has_future()
            && self.solving.is_none()
        {
            end = Some(RunEnd::InputEnded);
        }
        end
    }

    /// Runs ticks on `schedule` until the input ends, `max_ticks` pass, a stop is requested,
    /// reads fail for the torque-off time or the port fails; then (except after a fault) ramps
    /// to rest or holds, and turns torque off.
    pub fn run(
        &mut self,
        schedule: &mut Schedule,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        stop: &StopRequests,
    ) -> RunEnd {
        let why = loop {
            if stop.made() > 0 {
                break RunEnd::Interrupted;
            }
            let tick = schedule.wait(clock);
            if stop.made() > 0 {
                break RunEnd::Interrupted;
            }
            if self.config.max_ticks.is_some_and(|m| self.stats.ticks >= m) {
                break RunEnd::Duration;
            }
            if let Some(end) = self.tick(&tick, bus, clock) {
                break end;
            }
        };
        self.input.stop_producers();
        if let Some(r) = &self.retarget {
            self.stats.retarget = Some(r.report());
        }
        self.stats.fidelity = Some(self.fidelity_report());
        if matches!(why, RunEnd::ReadsFailed | RunEnd::PortLost) {
            self.record_final_present();
            return why;
        }
        self.finish(schedule, bus, clock, stop);
        self.record_final_present();
        // The port may fail during the ramp: that, not the reason the ramp began, is the end.
        if self.port_error.is_some() {
            return RunEnd::PortLost;
        }
        why
    }

    /// The end of a run: ramp to the rest pose (or hold), then torque off. A stop request
    /// made during the ramp (the second, when a request ended the loop) cuts it short; so does
    /// the port failing.
    fn finish(
        &mut self,
        schedule: &mut Schedule,
        bus: &mut dyn ServoBus,
        clock: &mut dyn Clock,
        stop: &StopRequests,
    ) {
        let (ticks, to_rest) = match self.config.stop {
            // Nothing was commanded yet: the servos stand where they started.
            _ if !self.have_input => (0, false),
            StopMode::Rest { ramp_s } => ((ramp_s.max(0.0) * self.config.rate_hz).ceil() as usize, true),
            StopMode::Hold { hold_s } => ((hold_s.max(0.0) * self.config.rate_hz).ceil() as usize, false),
        };
        // From the last command (what the servos were sent, the plan's lead included).
        let from: Vec<f64> = self
            .rig
            .servos
            .iter()
            .zip(self.stage.last())
            .map(|(s, t)| s.ticks_to_angle(f64::from(*t)))
            .collect();
        let dt = self.period_ns as f64 * 1e-9;
        let requests_at_start = stop.made();
        // After the ramp, up to two more seconds for the rate limits to arrive at rest.
        let extra = if to_rest {
            (2.0 * self.config.rate_hz).ceil() as usize
        } else {
            0
        };
        for k in 1..=ticks + extra {
            let tick = schedule.wait(clock);
            if stop.made() > requests_at_start {
                break;
            }
            if k > ticks && !to_rest {
                break;
            }
            let mut arrived = false;
            let goals: Vec<i32> = if to_rest && self.have_input {
                let w = crate::interp::ease_weight(k.min(ticks), ticks + 1);
                let angles: Vec<f64> = from.iter().map(|a| a * (1.0 - w)).collect();
                match self.stage.command(&self.rig, &angles, dt) {
                    Ok((g, limited)) => {
                        arrived = k >= ticks && limited.rate_limited == 0;
                        g.to_vec()
                    }
                    Err(_) => self.stage.last().to_vec(),
                }
            } else {
                self.stage.last().to_vec()
            };
            let written = bus.write_goals(&self.ids, &goals);
            if let Some(why) = written.as_ref().err().and_then(BusError::port_failure) {
                self.port_error = Some(why);
                break;
            }
            let read_ok = bus.read_positions(&self.ids, &mut self.read_buf).is_ok();
            if read_ok {
                self.present.copy_from_slice(&self.read_buf);
                self.last_valid_read_ns = clock.now_ns();
            }
            if !self.telemetry.is_empty() {
                let len = self.present.len().min(MAX_SERVOS);
                let mut t = Telemetry {
                    index: tick.index,
                    deadline_ns: tick.deadline_ns,
                    woke_ns: tick.woke_ns,
                    read_ok,
                    servos: len,
                    read_ns: self.last_valid_read_ns,
                    stopping: true,
                    ..Telemetry::default()
                };
                t.present[..len].copy_from_slice(&self.present[..len]);
                self.emit(&t);
            }
            if arrived {
                break;
            }
        }
        self.stats.torque_off_acknowledged = Some(torque_off(bus, &self.ids).acknowledged);
    }

    /// Puts the last valid read's positions, by servo name, into the statistics.
    fn record_final_present(&mut self) {
        let angles = self.present_angles();
        self.stats.final_present = angles
            .into_iter()
            .enumerate()
            .map(|(k, rad)| stats::ServoAngle {
                name: self
                    .servo_names
                    .get(k)
                    .cloned()
                    .unwrap_or_else(|| format!("servo {}", k + 1)),
                rad,
            })
            .collect();
    }

    /// The present positions of the last valid read as angles (radians), rig order.
    #[must_use]
    pub fn present_angles(&self) -> Vec<f64> {
        self.rig
            .servos
            .iter()
            .zip(&self.present)
            .map(|(s, p)| s.ticks_to_angle(f64::from(*p)))
            .collect()
    }
}

/// What a torque-off achieved.
#[derive(Debug)]
pub struct TorqueOff {
    /// Servos that acknowledged their torque-off write.
    pub acknowledged: usize,
    /// The first error, if any.
    pub error: Option<BusError>,
}

/// Torque off on every servo: one Sync Write (no replies needed, so it gets through a bus whose
/// reads fail), then each servo on its own (acknowledged) — unless the port itself failed.
pub fn torque_off(bus: &mut dyn ServoBus, ids: &[u8]) -> TorqueOff {
    let zeros = [0u8; MAX_SERVOS];
    let n = ids.len().min(MAX_SERVOS);
    let mut error = bus
        .sync_write(addr::TORQUE_ENABLE, 1, &ids[..n], &zeros[..n])
        .err();
    let mut acknowledged = 0;
    if error.as_ref().and_then(BusError::port_failure).is_none() {
        for &id in &ids[..n] {
            match bus.set_torque(id, false) {
                Ok(()) => acknowledged += 1,
                Err(e) => {
                    error.get_or_insert(e);
                }
            }
        }
    }
    TorqueOff { acknowledged, error }
}

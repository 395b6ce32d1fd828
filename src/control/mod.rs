//! The fixed-rate control loop: newest input → FK/IK → rig mapping → command stage → Sync
//! Write → Sync Read → telemetry, on the absolute-deadline [`Schedule`](crate::schedule::Schedule).
//!
//! Everything a tick needs is prepared before the loop starts ([`Controller::new`]); a tick
//! allocates nothing (the `alloc_free` test and the `allocations_in_tick` statistic prove it
//! with a counting allocator). Time is passed in through a [`Clock`], so tests run the loop on
//! virtual time.
//!
//! Fault policy: a failed or corrupt read is never used; after `hold_after` consecutive failed
//! reads the last command sent is held (new inputs are not acted on; no step back); after `torque_off_after`
//! without a valid read every servo's torque is turned off and the loop stops with a fault.
//! A host that stops altogether is covered by the servos' Bus Watchdog, armed at start-up; a
//! host that stalled past it and comes back finds them stopped, and recovers them ([`watchdog`]).
//! The port itself failing (a USB adapter unplugged: reads and writes fail with EIO) ends the
//! run at once: nothing more is commanded, one torque-off Sync Write is tried.
//!
//! Stopping: [`StopRequests`] are counted. The first ends the loop with the ramp to rest (or the
//! hold); a second during the ramp cuts it short and turns torque off at once.

pub mod balance;
pub mod fidelity;
mod follow;
pub mod health;
pub mod identify;
mod ingest;
pub mod input;
pub mod live;
pub mod lockstep;
pub mod lookahead;
pub mod plot;
mod read;
mod retarget_stage;
pub mod source;
pub mod sources;
pub mod stats;
mod stop;
pub use stop::REHEARSAL_LEAD_NS;
mod tick;
pub use tick::{start_move_s, START_MOVE_SPEED_SHARE};
pub mod watchdog;

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;

use crossbeam_channel::{Sender, TrySendError};
use glam::DVec3;

use crate::bus::ServoBus;
use crate::command::CommandStage;
use crate::fk::{ancestors, Pose64};
use crate::rig::Rig;
use crate::schedule::{Clock, Tick};
use crate::servo::MAX_SERVOS;
use crate::skeleton::{Skeleton, MAX_BONES, MAX_CHANNELS};
use input::{InputPort, Payload};
use live::LiveView;
use lookahead::{Lookahead, Preview};
use stats::{LoopStats, Stage};

pub use follow::{pointer_bone, target_range, Effector, FollowError, Follower, TARGET_RANGE_REACHES};
use ingest::{Solving, MAX_INGEST};
use read::{Absorbed, ReadContext};
pub use retarget_stage::RetargetStage;
pub use stop::{torque_off, TorqueOff};

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
    /// Count the loop thread's page faults from its first tick to its last (real-time runs:
    /// in lockstep the thread also runs the simulated rig, whose faults are not the loop's).
    pub count_page_faults: bool,
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
    /// Make the next tick's limb solve ahead, just before its deadline ([`Controller::rehearse`]):
    /// real-time runs, whose sleep leaves the caches cold.
    pub rehearse: bool,
    /// At the first input, lengthen the ease-in to the servos' eased move to its pose at
    /// [`START_MOVE_SPEED_SHARE`] of their speed ([`start_move_s`]) when that takes longer:
    /// for inputs whose first pose is not known before the run (targets to follow).
    pub size_start_move: bool,
    /// The Bus Watchdog the servos were armed with at start-up, ms (0: none). Once the bus has
    /// been quiet for half of it, a tick checks it and recovers servos whose watchdog expired
    /// ([`watchdog`]).
    pub bus_watchdog_ms: u32,
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
            count_page_faults: false,
            ease_in_s: 0.0,
            effector_metres_per_unit: 0.0,
            pipelined: false,
            fidelity_worker: false,
            rehearse: false,
            size_start_move: false,
            bus_watchdog_ms: 0,
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
    /// The hottest servo the health watch has read: (id, °C); `None` before a read or
    /// without a watch.
    pub hottest: Option<(u8, u8)>,
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
            hottest: None,
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
    /// A servo's health (temperature, supply, hardware error) ended the run: eased to rest,
    /// torque off ([`health::HealthWatch::stopped`] says which and why).
    Health,
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

/// The loop's state: everything a tick touches, allocated before the first tick.
pub struct Controller {
    skeleton: Arc<Skeleton>,
    rig: Rig,
    ids: Vec<u8>,
    config: LoopConfig,
    period_ns: u64,
    servo_names: Vec<String>,
    /// The input side: the channel, the pose being solved, the source samples taken ahead.
    input: InputPort,
    solve: Solve,
    channels: [f64; MAX_CHANNELS],
    /// The pose a rehearsed solve works on ([`Controller::rehearse`]).
    rehearsal: [f64; MAX_CHANNELS],
    angles: Vec<f64>,
    pose: Box<Pose64>,
    watch: [Option<usize>; 4],
    /// The watched bones and their ancestors, parents first: the bones a sample's forward
    /// kinematics needs when nothing else reads the pose.
    watched_chains: heapless::Vec<usize, MAX_BONES>,
    retarget: Option<Box<RetargetStage>>,
    /// The IMU board's reading and the legs' gyro feedback.
    balance: Option<Box<balance::Balance>>,
    /// The servos' temperature, supply and hardware errors, read at a low rate.
    health: Option<Box<health::HealthWatch>>,
    /// The health read on the wire in the position read's slot (pipelined).
    health_in_flight: Option<health::HealthItem>,
    /// Where the ramp to rest ends, radians per servo (rig order); `None`: every angle 0.
    rest_pose: Option<Vec<f64>>,
    have_input: bool,
    clip_time: f64,
    /// Source samples taken ahead (the look-ahead's preview; without it, the current one).
    preview: Preview,
    /// How far ahead inputs are taken, ns.
    preview_ns: u64,
    lookahead: Option<Box<Lookahead>>,
    /// Due time of the last input turned into a sample (the retargeting's time step).
    last_due: Option<u64>,
    /// The input being solved, when its solve is spread over ticks.
    solving: Option<Solving>,
    /// The command side.
    stage: CommandStage,
    ease: tick::Ease,
    /// When the servos last heard the loop (their Bus Watchdog's clock).
    quiet: watchdog::QuietWatch,
    /// The bus side: what the servos reported.
    reads: read::Reads,
    /// Source against present, end to end.
    measure: read::Measure,
    /// Where each tick's figures go.
    sinks: Sinks,
    last_tick: Option<(u64, u64)>,
    /// The statistics so far.
    pub stats: LoopStats,
    /// Why the port failed, when a run ended with [`RunEnd::PortLost`].
    pub port_error: Option<std::io::Error>,
}

/// Where each tick's figures go: telemetry consumers (never waited on) and the studio's view.
struct Sinks {
    telemetry: heapless::Vec<Sender<Telemetry>, MAX_TELEMETRY_SINKS>,
    live: Option<Arc<LiveView>>,
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
        let channel_count = skeleton.channel_count();
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
            fidelity::EffectorPose::new(Arc::clone(&skeleton), watch, config.effector_metres_per_unit)
        });
        let sink = Box::new(fidelity::FidelitySink::new(
            rig.clone(),
            period_ns as f64 * 1e-9,
            effector_pose,
        ));
        // Without a thread (none could be started) the tick accumulates it.
        let worker = config
            .fidelity_worker
            .then(|| fidelity::FidelityWorker::spawn(sink.clone()).ok())
            .flatten();
        let mut stats = LoopStats::new(config.rate_hz);
        stats.allocations_in_tick = config.allocations.map(|_| 0);
        Controller {
            skeleton,
            stats,
            rig,
            ids,
            config,
            period_ns,
            servo_names: Vec::new(),
            input,
            solve,
            channels: [0.0; MAX_CHANNELS],
            rehearsal: [0.0; MAX_CHANNELS],
            angles: angles.clone(),
            pose: Box::default(),
            watch,
            watched_chains,
            retarget: None,
            balance: None,
            health: None,
            health_in_flight: None,
            rest_pose: None,
            have_input: false,
            clip_time: f64::NAN,
            preview: Preview::new(8, angles.len(), channel_count),
            preview_ns: 0,
            lookahead: None,
            last_due: None,
            solving: None,
            stage,
            ease: tick::Ease {
                from: angles,
                ticks: ease_ticks,
                done: 0,
                start_ns: None,
            },
            // The first tick checks: start-up armed the watchdog some time before it.
            quiet: watchdog::QuietWatch {
                owed: config.bus_watchdog_ms > 0,
                ..watchdog::QuietWatch::default()
            },
            reads: read::Reads {
                present: present.to_vec(),
                read_buf: vec![0; n],
                in_flight: None,
                previous_goals: vec![0; n],
                have_previous: false,
                failures: 0,
                last_valid_ns: 0,
            },
            measure: read::Measure {
                sink,
                worker,
                sample_sent: (None, 0),
                dropped: 0,
                source_angles: vec![f64::NAN; n],
                present_angles: vec![f64::NAN; n],
                source_log: Vec::new(),
            },
            sinks: Sinks {
                telemetry: heapless::Vec::new(),
                live: None,
            },
            last_tick: None,
            port_error: None,
        }
    }

    /// The fidelity so far (a worker's once it has taken every record: it is stopped, and
    /// the tick accumulates from here on). [`Controller::run`] puts it in the statistics.
    pub fn fidelity_report(&mut self) -> fidelity::FidelityReport {
        if let Some(f) = self.measure.worker.take().and_then(|mut w| w.finish()) {
            self.measure.sink = f;
        }
        let mut report = self.measure.sink.report(&self.servo_names);
        report.records_dropped += self.measure.dropped;
        report
    }

    /// Keeps the source angles of up to `ticks` ticks (reserved now; the tick stops logging
    /// when it is full rather than grow it), for pictures.
    pub fn log_source(&mut self, ticks: usize) {
        self.measure.source_log = crate::resident::vec(ticks, (0, [0.0; MAX_SERVOS]));
    }

    /// The logged source angles: tick deadline (ns on the loop's clock) and radians per servo.
    #[must_use]
    pub fn source_log(&self) -> &[(u64, [f64; MAX_SERVOS])] {
        &self.measure.source_log
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
        self.preview = Preview::new(
            ticks + MAX_INGEST + 8,
            self.ids.len(),
            self.skeleton.channel_count(),
        );
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

    /// Blends the first commands from where the servos stand over `seconds` (smoothstep, the
    /// help note's eq. 13), in place of the configured ease-in.
    pub fn set_ease_in(&mut self, seconds: f64) {
        if seconds.is_finite() && seconds >= 0.0 {
            self.ease.ticks = (seconds * 1e9 / self.period_ns as f64).round() as u64;
        }
    }

    /// Ends the ramp to rest in `angles` (radians per servo, rig order) instead of every angle
    /// at 0: a robot on the floor ramps to a stance it stands in.
    pub fn set_rest_pose(&mut self, angles: Vec<f64>) {
        self.rest_pose =
            (angles.len() == self.rig.servos.len() && angles.iter().all(|a| a.is_finite())).then_some(angles);
    }

    /// Watches the servos' health from the bus's idle slot ([`health`]): a servo past its
    /// thresholds ends the run ([`RunEnd::Health`]).
    pub fn set_health(&mut self, watch: health::HealthWatch) {
        self.health = Some(Box::new(watch));
    }

    /// Why the health watch ended the run, when it did.
    #[must_use]
    pub fn health_stop(&self) -> Option<String> {
        self.health.as_ref().and_then(|h| h.stopped())
    }

    /// Reads the IMU board every tick (and, as `balance` says, feeds its gyro back to the legs).
    pub fn set_balance(&mut self, balance: balance::Balance) {
        self.balance = Some(Box::new(balance));
    }

    /// The IMU board's reads so far, when it is read.
    #[must_use]
    pub fn imu_report(&self) -> Option<balance::ImuReport> {
        self.balance.as_ref().map(|b| b.report())
    }

    /// Publishes each tick's goals, present angles and timing in `view` (for the studio).
    pub fn set_live_view(&mut self, view: Arc<LiveView>) {
        self.sinks.live = Some(view);
    }

    /// Sends per-tick figures to `tx` as well (bounded; a full channel drops the record,
    /// counted). Each consumer has its own channel; up to [`MAX_TELEMETRY_SINKS`].
    ///
    /// # Errors
    /// `tx` back when there are [`MAX_TELEMETRY_SINKS`] already.
    pub fn add_telemetry(&mut self, tx: Sender<Telemetry>) -> Result<(), Sender<Telemetry>> {
        self.sinks.telemetry.push(tx)
    }

    /// Sends `record` to every consumer without waiting; a full channel drops it (counted).
    fn emit(&mut self, record: &Telemetry) {
        for tx in &self.sinks.telemetry {
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
        &self.reads.present
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

    /// Makes the next tick's work ahead, keeping nothing: called just before the tick's
    /// deadline (`deadline_ns`), it leaves the tick's code and data in the caches, which the
    /// wait (a sleep: the kernel, other processes) has evicted. The solve's step is the next
    /// limb of the input being solved (on a copy of the pose); once every limb is solved, the
    /// sample's forward kinematics and the rig's angles; with no input being solved, the first
    /// limb of the next input waiting (its target read, the input left in place). The input's
    /// next messages are received ahead ([`InputPort::prefetch`]), and the look-ahead plans
    /// one servo of the tick on a copy ([`Lookahead::rehearse`]). Allocates nothing (counted
    /// with the ticks' allocations).
    pub fn rehearse(&mut self, deadline_ns: u64) {
        let Solve::Follow(f) = &self.solve else { return };
        let allocs = self.config.allocations.map(|f| f());
        self.input.prefetch();
        let n = self.skeleton.channel_count();
        let limb = match self.solving {
            Some(p) if p.next_effector >= f.effectors.len() => None,
            Some(p) => Some((p.next_effector, None)),
            None => {
                let next = self.input.peek().and_then(|m| match &m.payload {
                    Payload::Targets(t) => t
                        .iter()
                        .find(|t| t.effector == 0 && f.accepts(t))
                        .map(|t| t.position),
                    Payload::Frame { .. } => None,
                });
                Some((0, next))
            }
        };
        if let Some((k, target)) = limb {
            self.rehearsal[..n].copy_from_slice(&self.channels[..n]);
            if f.rehearse(&self.skeleton, &mut self.rehearsal[..n], k, target) {
                self.stats.solves_rehearsed += 1;
            }
        } else {
            self.rehearse_sample();
        }
        if let (Some(la), true) = (&self.lookahead, self.have_input) {
            let dt = self.period_ns as f64 * 1e-9;
            la.rehearse(&self.rig, &self.stage, &self.preview, deadline_ns, dt);
        }
        self.count_allocations_since(allocs);
    }

    /// The sample step's forward kinematics (into the pose, which the step computes again from
    /// the same channels) and the rig's angles (on a copy of the last ones, which the rig reads
    /// to choose among equivalent angles).
    fn rehearse_sample(&mut self) {
        self.sample_kinematics();
        let (n, len) = (self.skeleton.channel_count(), self.angles.len());
        let joints = self.retarget.as_ref().map_or(&[][..], |r| &r.frame.q[..]);
        self.rehearsal[..len].copy_from_slice(&self.angles);
        self.rig.joint_angles(
            &self.skeleton,
            &self.channels[..n],
            joints,
            &mut self.rehearsal[..len],
        );
    }

    /// Adds the allocations made since `before` (the counter's reading, when counting) to
    /// the ticks'.
    fn count_allocations_since(&mut self, before: Option<u64>) {
        if let (Some(f), Some(before)) = (self.config.allocations, before) {
            *self.stats.allocations_in_tick.get_or_insert(0) += f().saturating_sub(before);
        }
    }

    /// One tick at `tick` (from [`crate::schedule::Schedule::wait`]), in its phases (`control/tick.rs`): the
    /// pipelined replies, the input, the command, the bus, the telemetry. Allocates nothing.
    pub fn tick(&mut self, tick: &Tick, bus: &mut dyn ServoBus, clock: &mut dyn Clock) -> Option<RunEnd> {
        let allocs = self.config.allocations.map(|f| f());
        let start = self.begin(tick, clock);
        let mut replies = match self.collect_replies(bus, clock) {
            Ok(replies) => replies,
            Err(end) => return Some(end),
        };
        if let Some(b) = &mut self.balance {
            // The bus is idle here: the pipelined replies are in, the write is yet to go. Its
            // time is the bus's (the read stage's), not the tick's compute.
            let t0 = clock.now_ns();
            b.read(bus);
            replies.1 += clock.now_ns() - t0;
        }
        let mut unhealthy = false;
        let alert = bus.take_alert();
        if let (None, Some(id), None) = (&self.health, alert, self.stats.unwatched_alert) {
            // No watch to stop the run: the summary says so.
            let at_s = self.stats.ticks as f64 * self.period_ns as f64 * 1e-9;
            self.stats.unwatched_alert = Some(stats::UnwatchedAlert { id, at_s });
        }
        if let Some(h) = &mut self.health {
            if let Some(id) = alert {
                // A servo that shut itself down: its error status is read at the next slot.
                h.alert(id);
            }
            if !self.config.pipelined {
                // Without a pipelined read: the same idle slot, one item every few ticks.
                let t0 = clock.now_ns();
                h.read(bus);
                replies.1 += clock.now_ns() - t0;
            }
            unhealthy = h.has_stopped();
        }
        let t_solve = clock.now_ns();
        let dt = self.period_ns as f64 * 1e-9 * (1 + tick.skipped) as f64;
        let current = self.take_current(tick, start, dt);
        let t_encode = clock.now_ns();
        self.stats.stage_mut(Stage::Solve).record(t_encode - t_solve);
        let holding = self.reads.failures >= self.config.hold_after;
        let mut goals = self.encode(tick, dt, holding);
        let mut t_write = clock.now_ns();
        self.stats.stage_mut(Stage::Encode).record(t_write - t_encode);
        if let Some(checked) = self.check_watchdog(tick, bus, clock, t_write, true) {
            // Its transactions are the bus's time, not the tick's compute.
            replies.1 += checked.bus_ns;
            if let Some(hold) = checked.hold {
                goals = hold;
            }
            t_write = clock.now_ns();
        }
        let command = tick::Command {
            goals,
            holding,
            t_write,
        };
        let done_bus = self.exchange(tick, bus, clock, &command, &current, replies);
        let done = clock.now_ns();
        self.note_sent(done);
        self.report(tick, start, done, &command, &current, &done_bus);
        self.count_allocations_since(allocs);
        let mut end = done_bus.end;
        if end.is_none() && unhealthy {
            end = Some(RunEnd::Health);
        }
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

    /// The present positions of the last valid read as angles (radians), rig order.
    #[must_use]
    pub fn present_angles(&self) -> Vec<f64> {
        self.rig
            .servos
            .iter()
            .zip(&self.reads.present)
            .map(|(s, p)| s.ticks_to_angle(f64::from(*p)))
            .collect()
    }
}

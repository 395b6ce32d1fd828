//! Loop statistics: log-linear latency histograms (fixed memory, recording allocates nothing),
//! counters, and the summary printed and written as JSON at the end of a run.

use std::fmt;

use serde::Serialize;

use crate::bus::ErrorKind;

mod histogram;

pub use histogram::{Histogram, Quantiles};

/// The measured stages of a tick, in order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Age of the input used (tick wake-up minus the time the input was made).
    InputAge,
    /// Forward and inverse kinematics.
    Solve,
    /// Rig mapping, command limits and the goal records.
    Encode,
    /// The Sync Write of goal positions.
    BusWrite,
    /// The Sync Read of present positions.
    BusRead,
}

impl Stage {
    /// All stages.
    pub const ALL: [Stage; 5] = [
        Stage::InputAge,
        Stage::Solve,
        Stage::Encode,
        Stage::BusWrite,
        Stage::BusRead,
    ];

    /// Lower-case name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Stage::InputAge => "input_age",
            Stage::Solve => "solve",
            Stage::Encode => "encode",
            Stage::BusWrite => "bus_write",
            Stage::BusRead => "bus_read",
        }
    }
}

/// Everything the loop measures. Recording allocates nothing.
#[derive(Debug, Default)]
pub struct LoopStats {
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Ticks run.
    pub ticks: u64,
    /// Ticks whose work ended after the next tick was due.
    pub deadline_misses: u64,
    /// Deadlines passed over after an overrun (their ticks never ran).
    pub skipped_ticks: u64,
    /// Tick work without bus I/O: input, solve, encode, telemetry.
    pub tick_compute: Histogram,
    /// Whole tick, bus included.
    pub tick_total: Histogram,
    /// |interval between tick starts − period|.
    pub period_error: Histogram,
    /// Wake-up lateness after the deadline.
    pub wake_late: Histogram,
    /// Per-stage histograms, indexed as [`Stage::ALL`].
    pub stages: [Histogram; 5],
    /// Bus errors by kind, indexed as [`ErrorKind::ALL`].
    pub bus_errors: [u64; 6],
    /// Commands sent (ticks with a successful Sync Write).
    pub commands_sent: u64,
    /// Successful reads.
    pub reads_ok: u64,
    /// Inputs taken (distinct messages used).
    pub inputs_used: u64,
    /// Inputs taken ahead whose solve was spread over several ticks.
    pub inputs_spread: u64,
    /// Limb solves made ahead of their tick, on a copy of the pose, to warm the caches
    /// ([`super::Controller::rehearse`]).
    pub solves_rehearsed: u64,
    /// Ticks without a new input (the last one used again).
    pub inputs_stale: u64,
    /// Inputs refused (non-finite values, wrong size, unsolvable).
    pub inputs_rejected: u64,
    /// Commands refused by the command stage (the last one stood).
    pub commands_refused: u64,
    /// Servos clamped to their position limits, summed over ticks.
    pub clamped: u64,
    /// Servos slowed by the velocity or acceleration limit, summed over ticks.
    pub rate_limited: u64,
    /// Effector targets out of reach (IK), summed over ticks.
    pub unreachable: u64,
    /// Ticks that held the last command after consecutive read failures.
    pub held_ticks: u64,
    /// Seconds of the eased move from where the servos stood to the first input's pose, when
    /// the loop lengthened the ease-in for it ([`super::LoopConfig::size_start_move`]).
    pub start_move_s: Option<f64>,
    /// Telemetry records dropped because the consumer was behind.
    pub telemetry_dropped: u64,
    /// The longest the servos heard nothing from the loop, ms (measured only with a Bus
    /// Watchdog; [`super::watchdog`]).
    pub longest_quiet_ms: f64,
    /// Times the servos heard nothing from the loop for half their Bus Watchdog or more.
    pub quiet_spells: u64,
    /// Ticks that read the servos' Bus Watchdog: the first, and after quiet spells.
    pub watchdog_checks: u64,
    /// Checks that found servos whose watchdog had expired (stopped, refusing goals): each
    /// time they were recovered and eased back to the input.
    pub watchdog_expiries: u64,
    /// Seconds of the eased moves back to the input after expiries (not in the fidelity).
    pub resumed_s: f64,
    /// With the health watch off: the first servo whose replies carried the hardware-alert
    /// flag (it reported a hardware error and turned its torque off), and when.
    pub unwatched_alert: Option<UnwatchedAlert>,
    /// The last valid read's positions when the run ended (set after the loop, never in a
    /// tick).
    pub final_present: Vec<ServoAngle>,
    /// Heap allocations inside ticks (`None` without a counting allocator).
    pub allocations_in_tick: Option<u64>,
    /// Page faults the loop thread took while it ran ticks (their waits and rehearsals
    /// included; `None` where the system does not count them per thread).
    pub page_faults_in_loop: Option<u64>,
    /// Servos that acknowledged the torque-off at the end (`None` before the end).
    pub torque_off_acknowledged: Option<usize>,
    /// What retargeting onto a robot measured (profiles whose servos follow robot joints).
    pub retarget: Option<crate::retarget::RetargetReport>,
    /// What the IMU board read (profiles with one).
    pub imu: Option<super::balance::ImuReport>,
    /// What the health watch read: each servo's temperature, supply and errors, the warnings,
    /// and why it ended the run when it did.
    pub health: Option<super::health::HealthReport>,
    /// Source against present, end to end (set when a run ends).
    pub fidelity: Option<super::fidelity::FidelityReport>,
    /// With the simulator: its report (tracking, the torso, a walk's footsteps), set when the
    /// run ends.
    pub sim: Option<serde_json::Value>,
    tracking_sq: f64,
    tracking_n: u64,
    tracking_max_deg: f64,
    /// Largest IK residual, file units.
    pub ik_error_max: f64,
    ik_error_sq: f64,
    ik_error_n: u64,
}

impl LoopStats {
    /// Empty statistics for a loop at `rate_hz`.
    #[must_use]
    pub fn new(rate_hz: f64) -> LoopStats {
        LoopStats {
            rate_hz,
            ..LoopStats::default()
        }
    }

    /// The histogram of a stage.
    pub fn stage_mut(&mut self, s: Stage) -> &mut Histogram {
        &mut self.stages[s as usize]
    }

    /// The histogram of a stage.
    #[must_use]
    pub fn stage(&self, s: Stage) -> &Histogram {
        &self.stages[s as usize]
    }

    /// Counts a bus error.
    pub fn bus_error(&mut self, kind: ErrorKind) {
        if let Some(k) = ErrorKind::ALL.iter().position(|e| *e == kind) {
            self.bus_errors[k] += 1;
        }
    }

    /// Total bus errors.
    #[must_use]
    pub fn bus_error_total(&self) -> u64 {
        self.bus_errors.iter().sum()
    }

    /// Adds one servo's tracking error (commanded minus present, degrees).
    pub fn tracking(&mut self, deg: f64) {
        self.tracking_sq += deg * deg;
        self.tracking_n += 1;
        self.tracking_max_deg = self.tracking_max_deg.max(deg.abs());
    }

    /// RMS tracking error, degrees (0 before any read).
    #[must_use]
    pub fn tracking_rms_deg(&self) -> f64 {
        if self.tracking_n == 0 {
            0.0
        } else {
            (self.tracking_sq / self.tracking_n as f64).sqrt()
        }
    }

    /// Adds one effector's IK residual.
    pub fn ik_error(&mut self, e: f64) {
        self.ik_error_sq += e * e;
        self.ik_error_n += 1;
        self.ik_error_max = self.ik_error_max.max(e);
    }

    /// The JSON summary.
    #[must_use]
    pub fn report(&self) -> Report {
        let [timeout, crc, wrong_id, servo, malformed, io] = self.bus_errors;
        let stages = StageReport {
            input_age_us: self.stage(Stage::InputAge).summary_us(),
            solve_us: self.stage(Stage::Solve).summary_us(),
            encode_us: self.stage(Stage::Encode).summary_us(),
            bus_write_us: self.stage(Stage::BusWrite).summary_us(),
            bus_read_us: self.stage(Stage::BusRead).summary_us(),
        };
        Report {
            rate_hz: self.rate_hz,
            ticks: self.ticks,
            deadline_misses: self.deadline_misses,
            skipped_ticks: self.skipped_ticks,
            tick_compute_us: self.tick_compute.summary_us(),
            tick_total_us: self.tick_total.summary_us(),
            period_error_us: self.period_error.summary_us(),
            wake_late_us: self.wake_late.summary_us(),
            stages,
            bus_errors: self.bus_error_total(),
            bus_errors_by_kind: BusErrorCounts {
                timeout,
                crc,
                wrong_id,
                servo,
                malformed,
                io,
            },
            allocations_in_tick: self.allocations_in_tick,
            page_faults_in_loop: self.page_faults_in_loop,
            torque_off_acknowledged: self.torque_off_acknowledged,
            retarget: self.retarget.clone(),
            imu: self.imu.clone(),
            health: self.health.clone(),
            fidelity: self.fidelity.clone(),
            sim: self.sim.clone(),
            tracking_rms_deg: self.tracking_rms_deg(),
            tracking_max_deg: self.tracking_max_deg,
            commands_sent: self.commands_sent,
            reads_ok: self.reads_ok,
            inputs_used: self.inputs_used,
            inputs_spread: self.inputs_spread,
            solves_rehearsed: self.solves_rehearsed,
            inputs_stale: self.inputs_stale,
            inputs_rejected: self.inputs_rejected,
            commands_refused: self.commands_refused,
            clamped: self.clamped,
            rate_limited: self.rate_limited,
            unreachable: self.unreachable,
            held_ticks: self.held_ticks,
            start_move_s: self.start_move_s,
            telemetry_dropped: self.telemetry_dropped,
            longest_quiet_ms: self.longest_quiet_ms,
            quiet_spells: self.quiet_spells,
            unwatched_alert: self.unwatched_alert,
            watchdog_checks: self.watchdog_checks,
            watchdog_expiries: self.watchdog_expiries,
            resumed_s: self.resumed_s,
            final_present: self.final_present.clone(),
            ik_error_rms: if self.ik_error_n == 0 {
                0.0
            } else {
                (self.ik_error_sq / self.ik_error_n as f64).sqrt()
            },
            ik_error_max: self.ik_error_max,
        }
    }
}

/// The statistics of a run as written by `--stats-json`.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Ticks run.
    pub ticks: u64,
    /// Ticks that ended after the next was due.
    pub deadline_misses: u64,
    /// Deadlines skipped after overruns.
    pub skipped_ticks: u64,
    /// Tick work without bus I/O, µs.
    pub tick_compute_us: Quantiles,
    /// Whole tick including bus I/O, µs.
    pub tick_total_us: Quantiles,
    /// |tick start interval − period|, µs.
    pub period_error_us: Quantiles,
    /// Wake-up lateness, µs.
    pub wake_late_us: Quantiles,
    /// Per-stage quantiles, µs.
    pub stages: StageReport,
    /// All bus errors.
    pub bus_errors: u64,
    /// Bus errors by kind.
    pub bus_errors_by_kind: BusErrorCounts,
    /// Heap allocations inside ticks (null without a counting allocator).
    pub allocations_in_tick: Option<u64>,
    /// Page faults the loop thread took while it ran ticks, waits and rehearsals included
    /// (null where the system does not count them per thread).
    pub page_faults_in_loop: Option<u64>,
    /// Servos that acknowledged the torque-off at the end.
    pub torque_off_acknowledged: Option<usize>,
    /// What retargeting onto a robot measured (profiles whose servos follow robot joints).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub retarget: Option<crate::retarget::RetargetReport>,
    /// What the IMU board read: reads, failures, the torso's largest tilt, the feedback given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub imu: Option<super::balance::ImuReport>,
    /// What the health watch read (temperature, supply, hardware errors per servo), its
    /// warnings, and why it ended the run when it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub health: Option<super::health::HealthReport>,
    /// With the simulator (`--bus sim`): its report, as `--sim-report` writes it (`fell`,
    /// `torso_max_tilt_deg`, `torso_travel_m`, a walk's `footsteps`, `footstep_error_mm`,
    /// `zmp_margin_mm` …).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim: Option<serde_json::Value>,
    /// Source against present, end to end: the input mapped through the rig (what a perfect
    /// rig would do) against the present positions read back.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fidelity: Option<super::fidelity::FidelityReport>,
    /// RMS of commanded − present over servos and reads, degrees.
    pub tracking_rms_deg: f64,
    /// Largest |commanded − present|, degrees.
    pub tracking_max_deg: f64,
    /// Commands sent.
    pub commands_sent: u64,
    /// Successful reads.
    pub reads_ok: u64,
    /// Inputs used.
    pub inputs_used: u64,
    /// Inputs whose solve was spread over several ticks.
    pub inputs_spread: u64,
    /// Limb solves made ahead of their tick to warm the caches.
    pub solves_rehearsed: u64,
    /// Ticks without a new input.
    pub inputs_stale: u64,
    /// Inputs refused.
    pub inputs_rejected: u64,
    /// Commands refused by the command stage.
    pub commands_refused: u64,
    /// Servo-ticks clamped to position limits.
    pub clamped: u64,
    /// Servo-ticks slowed by rate limits.
    pub rate_limited: u64,
    /// Effector-ticks out of reach.
    pub unreachable: u64,
    /// Ticks holding after read failures.
    pub held_ticks: u64,
    /// Seconds of the eased move to the first input's pose, when the loop sized it.
    pub start_move_s: Option<f64>,
    /// Telemetry records dropped.
    pub telemetry_dropped: u64,
    /// The longest the servos heard nothing from the loop, ms (0 without a Bus Watchdog).
    pub longest_quiet_ms: f64,
    /// Times the servos heard nothing from the loop for half their Bus Watchdog or more.
    pub quiet_spells: u64,
    /// Ticks that read the servos' Bus Watchdog: the first, and after quiet spells.
    pub watchdog_checks: u64,
    /// Checks that found expired watchdogs (the servos stopped; recovered, eased back).
    pub watchdog_expiries: u64,
    /// Seconds of the eased moves back to the input after expiries (not in the fidelity).
    pub resumed_s: f64,
    /// With the health watch off (`--no-health`): the first servo whose replies carried the
    /// hardware-alert flag, its id, and when, seconds into the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub unwatched_alert: Option<UnwatchedAlert>,
    /// Each servo's present position at the end of the run (the last valid read), radians.
    pub final_present: Vec<ServoAngle>,
    /// RMS IK residual, file units.
    pub ik_error_rms: f64,
    /// Largest IK residual, file units.
    pub ik_error_max: f64,
}

/// One servo's angle.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ServoAngle {
    /// The servo's name in the profile.
    pub name: String,
    /// Radians (the rig's joint angle).
    pub rad: f64,
}

/// Per-stage latency quantiles of a run, µs (the stages of [`Stage`], by [`Stage::name`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct StageReport {
    /// [`Stage::InputAge`].
    pub input_age_us: Quantiles,
    /// [`Stage::Solve`].
    pub solve_us: Quantiles,
    /// [`Stage::Encode`].
    pub encode_us: Quantiles,
    /// [`Stage::BusWrite`].
    pub bus_write_us: Quantiles,
    /// [`Stage::BusRead`].
    pub bus_read_us: Quantiles,
}

/// Bus errors of a run by [`ErrorKind`] (named by [`ErrorKind::name`]).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct BusErrorCounts {
    /// [`ErrorKind::Timeout`].
    pub timeout: u64,
    /// [`ErrorKind::Crc`].
    pub crc: u64,
    /// [`ErrorKind::WrongId`].
    pub wrong_id: u64,
    /// [`ErrorKind::Servo`].
    pub servo: u64,
    /// [`ErrorKind::Malformed`].
    pub malformed: u64,
    /// [`ErrorKind::Io`].
    pub io: u64,
}

/// What `--stats-json` writes: the loop's [`Report`], how the run ended, what the input
/// producer did, and what the command adds (`play`: the clip's figures).
#[derive(Clone, Debug, Serialize)]
pub struct RunReport<X: Serialize> {
    /// The loop's statistics.
    #[serde(flatten)]
    pub stats: Report,
    /// How the run ended.
    pub end: &'static str,
    /// Inputs the producer made.
    pub inputs_produced: u64,
    /// Inputs the producer dropped (the loop's channel was full).
    pub inputs_dropped_by_producer: u64,
    /// Input lines that were refused.
    pub bad_input_lines: u64,
    /// Input datagrams refused whole for their size.
    pub oversized_datagrams: u64,
    /// The command's own fields.
    #[serde(flatten)]
    pub extra: X,
}

/// A servo that reported a hardware error while the health watch was off.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct UnwatchedAlert {
    /// Its id.
    pub id: u8,
    /// Seconds into the run.
    pub at_s: f64,
}

/// `play`'s fields of a [`RunReport`].
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ClipFigures {
    /// Frames in the clip.
    pub clip_frames: usize,
    /// Loop samples in one pass of the clip.
    pub samples_per_pass: u64,
    /// Whether every sample of every pass reached the loop.
    pub all_samples_sent: bool,
}

impl fmt::Display for LoopStats {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let period_us = 1e6 / self.rate_hz;
        writeln!(
            f,
            "{} ticks at {} Hz (period {:.1} µs): {} deadline misses, {} skipped",
            self.ticks, self.rate_hz, period_us, self.deadline_misses, self.skipped_ticks
        )?;
        writeln!(f, "tick compute    {}", self.tick_compute.summary_us())?;
        writeln!(f, "tick total      {}", self.tick_total.summary_us())?;
        writeln!(f, "period error    {}", self.period_error.summary_us())?;
        for s in Stage::ALL {
            if self.stage(s).count() > 0 {
                writeln!(f, "{:<15} {}", s.name(), self.stage(s).summary_us())?;
            }
        }
        let p99 = self.tick_compute.summary_us().p99;
        writeln!(
            f,
            "tick compute p99 is {:.2} % of the period",
            100.0 * p99 / period_us
        )?;
        write!(f, "bus errors      {}", self.bus_error_total())?;
        for (k, n) in ErrorKind::ALL.iter().zip(self.bus_errors) {
            if n > 0 {
                write!(f, "  {} {n}", k.name())?;
            }
        }
        writeln!(f)?;
        writeln!(
            f,
            "commands sent   {}  refused {}  held {}  clamped {}  rate-limited {}",
            self.commands_sent, self.commands_refused, self.held_ticks, self.clamped, self.rate_limited
        )?;
        writeln!(
            f,
            "inputs used     {}  stale ticks {}  rejected {}  solved over several ticks {}",
            self.inputs_used, self.inputs_stale, self.inputs_rejected, self.inputs_spread
        )?;
        if self.solves_rehearsed > 0 {
            writeln!(
                f,
                "solves rehearsed {} (ahead of their ticks, to warm the caches)",
                self.solves_rehearsed
            )?;
        }
        if self.ik_error_n > 0 {
            writeln!(
                f,
                "IK residual     rms {:.4}  max {:.4} (file units)  unreachable {}",
                self.report().ik_error_rms,
                self.ik_error_max,
                self.unreachable
            )?;
        }
        writeln!(
            f,
            "tracking        rms {:.3}°  max {:.3}° (commanded − present, {} reads)",
            self.tracking_rms_deg(),
            self.tracking_max_deg,
            self.reads_ok
        )?;
        if let Some(UnwatchedAlert { id, at_s }) = self.unwatched_alert {
            writeln!(
                f,
                "hardware alert  servo {id} reported a hardware error {at_s:.2} s into the run and turned its torque off; the health watch was off (--no-health), so the run went on around it"
            )?;
        }
        if self.quiet_spells > 0 || self.watchdog_expiries > 0 {
            // Spells of half the watchdog or more without a word to the servos; expired: they
            // had stopped, and were recovered where they stood.
            writeln!(
                f,
                "bus watchdog    quiet spells {} (longest {:.0} ms)  checks {}  expired {}  eased back {:.2} s (not in the fidelity)",
                self.quiet_spells, self.longest_quiet_ms, self.watchdog_checks, self.watchdog_expiries, self.resumed_s
            )?;
        }
        if let Some(s) = self.start_move_s {
            writeln!(
                f,
                "start move      {s:.2} s, eased from where the servos stood to the first input's pose (not in the fidelity)"
            )?;
        }
        if let Some(r) = &self.fidelity {
            write!(
                f,
                "fidelity        rms {:.3}°  max {:.3}° (source − present, {} ticks), lag {:.0} ms (rms {:.3}° aligned)",
                r.joint_rms_deg, r.joint_max_deg, r.samples, r.lag_ms, r.rms_after_lag_deg
            )?;
            match r.effector_rms_mm {
                Some(e) => writeln!(f, ", effectors rms {e:.1} mm")?,
                None => writeln!(f)?,
            }
        }
        if let Some(r) = &self.retarget {
            let e = &r.limb_direction_error_deg;
            let rms = |x: &Option<crate::retarget::RmsMax>| x.map_or(f64::NAN, |v| v.rms);
            write!(
                f,
                "retarget        direction rms {:.2}° (arms {:.2}° / {:.2}°, legs {:.2}° / {:.2}°), foot slide max {:.2} mm",
                e.overall.rms,
                rms(&e.left_arm),
                rms(&e.right_arm),
                rms(&e.left_leg),
                rms(&e.right_leg),
                r.foot_slide_mm.max
            )?;
            match r.com_margin_mm.min {
                Some(m) => writeln!(f, ", CoM margin min {m:.1} mm, {} limit clamps", r.limit_clamps)?,
                None => writeln!(f, ", {} limit clamps", r.limit_clamps)?,
            }
        }
        writeln!(f, "telemetry drops {}", self.telemetry_dropped)?;
        match self.allocations_in_tick {
            Some(n) => write!(f, "allocations in ticks: {n}")?,
            None => write!(f, "allocations in ticks: not counted")?,
        }
        match self.page_faults_in_loop {
            Some(n) => write!(f, ", page faults in the loop: {n}"),
            None => Ok(()),
        }
    }
}

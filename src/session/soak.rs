//! A fault soak in virtual time: the whole control loop (clip → FK → rig mapping → command
//! stage → Sync Write → Sync Read) on the in-process virtual chain, with bursts of seeded
//! faults of every kind the injector knows, until a given number of faults was applied.
//!
//! After every tick the chain's own record is checked against what the loop did: a read the
//! loop used must hold exactly the positions the servos reported this tick — a value a servo
//! reported a tick before is counted as stale (a lost reply whose slot a late copy of the
//! previous reply filled: valid CRC, right id, right time; Protocol 2.0 cannot tell it from a
//! fresh one), any other value as corrupt; every command and every goal register must be
//! inside the rig's limits. A burst
//! long enough to silence the reads for the torque-off time must end with torque off on every
//! servo, after which the rig is started up again. After each burst the ticks until the loop
//! commands from fresh reads again are counted.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{controller, RigDrive, SessionSpec};
use crate::bus::faults::{Fault, FaultInjector, Rng};
use crate::bus::virtual_chain::{chain_for, VirtualRig};
use crate::bus::{start_up, ErrorKind, StartupError};
use crate::control::input::{input_channel, Input};
use crate::control::sources::ClipPlayer;
use crate::control::{RunEnd, Solve, StopMode};
use crate::motion::Motion;
use crate::profile::Profile;
use crate::rig::{Rig, ServoMap};
use crate::schedule::{Clock, Schedule};
use crate::skeleton::{Skeleton, MAX_CHANNELS};

/// Fault chances a burst draws from, per reply.
pub const BURST_RATES: [f64; 5] = [0.005, 0.02, 0.1, 0.5, 1.0];

/// How a soak runs.
#[derive(Clone, Copy, Debug)]
pub struct SoakConfig {
    /// Stop once this many faults were applied.
    pub faults: u64,
    /// Seed of the fault sequence (and of the bursts' lengths and chances).
    pub seed: u64,
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// Longest burst, ticks (each burst lasts 1 … this many ticks).
    pub max_burst_ticks: u64,
    /// Fault-free ticks after each burst.
    pub quiet_ticks: u64,
    /// How much later than its wire time a reply may come (the host's margin).
    pub margin: Duration,
    /// How long a delay fault holds a reply back (longer than the margin: a time-out).
    pub delay: Duration,
}

impl Default for SoakConfig {
    fn default() -> Self {
        SoakConfig {
            faults: 1_000_000,
            seed: 1,
            rate_hz: 100.0,
            max_burst_ticks: 30,
            quiet_ticks: 10,
            margin: Duration::from_millis(2),
            delay: Duration::from_millis(3),
        }
    }
}

/// What a soak counted.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct SoakReport {
    /// Faults applied.
    pub faults: u64,
    /// Faults applied by kind, in [`Fault::ALL`] order.
    pub faults_by_kind: Vec<(&'static str, u64)>,
    /// Loop ticks run.
    pub ticks: u64,
    /// Virtual time the soak covered, seconds.
    pub virtual_seconds: f64,
    /// Bursts of faults.
    pub bursts: u64,
    /// Ticks that panicked.
    pub panics: u64,
    /// Servo positions the loop used that no servo reported.
    pub corrupt_values_used: u64,
    /// Servo positions the loop used that the servo reported a tick before (a late copy of an
    /// earlier reply in the slot of a lost one). The loop uses present positions for its
    /// tracking figures only; no command depends on them.
    pub stale_values_used: u64,
    /// Commands (goal ticks the loop sent) outside the rig's limits.
    pub commands_outside_limits: u64,
    /// Goal registers of the servos outside the rig's limits.
    pub goals_outside_limits: u64,
    /// Bursts that silenced the reads for the torque-off time: the run stopped with torque off.
    pub torque_off_stops: u64,
    /// Of those, stops that left some servo's torque on (must be 0).
    pub torque_left_on: u64,
    /// Ticks whose read was used.
    pub reads_used: u64,
    /// Ticks whose read failed.
    pub reads_failed: u64,
    /// Ticks that held the last command.
    pub held_ticks: u64,
    /// Bus errors by kind, in [`ErrorKind::ALL`] order.
    pub bus_errors: Vec<(&'static str, u64)>,
    /// Bursts after which the loop recovered in 0, 1, 2, … ticks (the last entry counts that
    /// many or more).
    pub recovery_ticks: Vec<u64>,
    /// The most ticks any recovery took.
    pub recovery_max_ticks: u64,
    /// Bursts whose recovery the next burst or stop cut off before it ended.
    pub recovery_unfinished: u64,
    /// Wall time, seconds.
    pub wall_seconds: f64,
}

/// Why a soak could not run.
#[derive(Debug, thiserror::Error)]
pub enum SoakError {
    /// The rig did not start on the fault-free chain.
    #[error("start-up on the virtual chain failed: {0}")]
    StartUp(#[from] StartupError),
    /// The clip has no frames.
    #[error("the clip has no frames")]
    EmptyClip,
}

/// The longest recovery kept apart in [`SoakReport::recovery_ticks`].
const RECOVERY_BINS: usize = 8;

/// Runs the soak: `motion` played on a loop through `profile`'s rig.
///
/// # Errors
/// [`SoakError`].
pub fn soak(
    skeleton: &Arc<Skeleton>,
    motion: &Arc<Motion>,
    profile: &Profile,
    rig: &Rig,
    config: &SoakConfig,
    mut progress: impl FnMut(&SoakReport),
) -> Result<SoakReport, SoakError> {
    if motion.is_empty() {
        return Err(SoakError::EmptyClip);
    }
    let began = Instant::now();
    let rest: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let limits: Vec<(i32, i32)> = rig.servos.iter().map(|s| (s.min_tick, s.max_tick)).collect();
    let delay_us = u32::try_from(config.delay.as_micros()).unwrap_or(u32::MAX);
    // The adapter's latency comes on top of every reply, and so of the host's margin.
    let latency = Duration::from_micros(u64::from(profile.bus.usb_latency_us));
    let mut vr = VirtualRig::new(
        chain_for(profile.bus_section(), |k| rest[k]),
        profile.bus.baud,
        config.margin + latency,
    )
    .with_usb_latency(latency);
    vr.with(|t| t.injector = Some(FaultInjector::new(config.seed, 0.0, &Fault::ALL, delay_us)));
    let applied = |vr: &VirtualRig| vr.with(|t| t.injector.as_ref().map_or(0, FaultInjector::total));
    let mut rng = Rng::new(config.seed ^ 0x5eed_5eed);
    let mut report = SoakReport {
        recovery_ticks: vec![0; RECOVERY_BINS + 1],
        ..SoakReport::default()
    };
    // As `play` runs (the goal paths planned over a preview, each servo led by its lag), held
    // at a stop.
    let spec = SessionSpec {
        rate_hz: config.rate_hz,
        stop: StopMode::Hold { hold_s: 0.0 },
        // No effector errors in metres: the soak checks the servos.
        scale: 0.0,
        // The soak counts the ticks a position read takes to recover after a burst; the health
        // watch's slot (a tick without positions every few) would count as one.
        health: false,
        ..SessionSpec::default()
    };
    let pipelined = profile.bus.pipeline;
    let n = skeleton.channel_count();
    let mut player = ClipPlayer::new(Arc::clone(skeleton), Arc::clone(motion), config.rate_hz, true);
    let mut frame = [0.0; MAX_CHANNELS];
    let mut next_progress = config.faults / 20;
    let mut virtual_ns = 0u64;
    let mut errors = [0u64; 6];

    // One session: start-up, then ticks until a stop (or the soak's end); then start over.
    'sessions: while applied(&vr) < config.faults {
        // Start-up on a quiet line (it refuses to run on a faulty one, by design).
        let injector = vr.with(|t| t.injector.take());
        let present = start_up(&mut vr, profile.bus_section());
        vr.with(|t| t.injector = injector);
        let present = present?;
        let (tx, port) = input_channel(4);
        let drive = RigDrive {
            skeleton: Arc::clone(skeleton),
            rig: rig.clone(),
            retarget: None,
            balance: None,
            rest_pose: None,
            start_pose: None,
        };
        let mut c = controller(&spec, profile, drive, &present, port, Solve::Frames, false);
        let ahead = c.preview_ns();
        let period = c.period_ns();
        let mut clock = vr.clone();
        // What the chain last reported, and pipelined, what it reported a tick before (the
        // replies a pipelined tick uses were made in the tick before it).
        let mut reported: Vec<Option<i32>> =
            vr.with(|t| t.chain().servos().iter().map(|s| s.reported_position()).collect());
        let mut reported_before = reported.clone();
        let session_start = clock.now_ns();
        let mut schedule = Schedule::new(session_start + period, period);
        // Burst state: ticks left in the burst or in the quiet after it.
        let mut burst_left = 0u64;
        let mut quiet_left = config.quiet_ticks;
        let mut recovering: Option<u64> = None;
        let mut k = 0u64;
        loop {
            if burst_left == 0 && quiet_left == 0 {
                burst_left = 1 + rng.below(config.max_burst_ticks.max(1));
                let rate = BURST_RATES[rng.below(BURST_RATES.len() as u64) as usize];
                vr.with(|t| t.injector.as_mut().map(|i| i.set_rate(rate)));
                report.bursts += 1;
                if recovering.take().is_some() {
                    report.recovery_unfinished += 1;
                }
            }
            let t = player.next_sample(&mut frame[..n]).unwrap_or(0.0);
            let _ = tx.send_newest(Input::frame(
                k,
                schedule.deadline(k) + ahead,
                clock.now_ns(),
                &frame[..n],
                t,
            ));
            let tick = schedule.wait(&mut clock);
            let (reads_before, held_before) = (c.stats.reads_ok, c.stats.held_ticks);
            let result = catch_unwind(AssertUnwindSafe(|| c.tick(&tick, &mut vr, &mut clock)));
            k += 1;
            report.ticks += 1;
            let end = match result {
                Ok(end) => end,
                Err(_) => {
                    report.panics += 1;
                    None
                }
            };
            let read_used = c.stats.reads_ok > reads_before;
            let held = c.stats.held_ticks > held_before;
            // The chain's record against what the loop did.
            vr.with(|t| {
                for (((((servo, used), command), (lo, hi)), last), older) in t
                    .chain()
                    .servos()
                    .iter()
                    .zip(c.present())
                    .zip(c.last_command())
                    .zip(&limits)
                    .zip(reported.iter_mut())
                    .zip(reported_before.iter_mut())
                {
                    let now = servo.reported_position();
                    let (truth, stale) = if pipelined { (*last, *older) } else { (now, *last) };
                    if read_used && truth != Some(*used) {
                        if stale == Some(*used) {
                            report.stale_values_used += 1;
                        } else {
                            report.corrupt_values_used += 1;
                        }
                    }
                    *older = *last;
                    *last = now;
                    if !(lo..=hi).contains(&command) {
                        report.commands_outside_limits += 1;
                    }
                    if !(lo..=hi).contains(&&servo.goal_tick()) {
                        report.goals_outside_limits += 1;
                    }
                }
            });
            if let Some(since) = recovering {
                if read_used && !held {
                    let bin = (since as usize).min(RECOVERY_BINS);
                    report.recovery_ticks[bin] += 1;
                    report.recovery_max_ticks = report.recovery_max_ticks.max(since);
                    recovering = None;
                } else {
                    recovering = Some(since + 1);
                }
            }
            if burst_left > 0 {
                burst_left -= 1;
                if burst_left == 0 {
                    vr.with(|t| t.injector.as_mut().map(|i| i.set_rate(0.0)));
                    quiet_left = config.quiet_ticks;
                    recovering = Some(0);
                }
            } else {
                quiet_left = quiet_left.saturating_sub(1);
            }
            let total = applied(&vr);
            if total >= next_progress {
                report.faults = total;
                progress(&report);
                next_progress = total + config.faults / 20;
            }
            let stopped = matches!(end, Some(RunEnd::ReadsFailed | RunEnd::PortLost)) || report.panics > 0;
            if stopped || total >= config.faults {
                if matches!(end, Some(RunEnd::ReadsFailed)) {
                    report.torque_off_stops += 1;
                    if vr.with(|t| t.chain().servos().iter().any(|s| s.torque_on())) {
                        report.torque_left_on += 1;
                    }
                }
                if recovering.is_some() {
                    report.recovery_unfinished += 1;
                }
                report.reads_used += c.stats.reads_ok;
                report.reads_failed += c.stats.ticks - c.stats.reads_ok;
                report.held_ticks += c.stats.held_ticks;
                for (e, n) in errors.iter_mut().zip(c.stats.bus_errors) {
                    *e += n;
                }
                virtual_ns += clock.now_ns() - session_start;
                vr.with(|t| t.injector.as_mut().map(|i| i.set_rate(0.0)));
                if report.panics > 0 {
                    // A panicked loop's state is not trusted: the soak ends there.
                    break 'sessions;
                }
                continue 'sessions;
            }
        }
    }
    let counts = vr.with(|t| t.injector.as_ref().map_or([0; 8], |i| i.counts));
    report.faults = counts.iter().sum();
    report.faults_by_kind = Fault::ALL.iter().map(|f| f.name()).zip(counts).collect();
    report.bus_errors = ErrorKind::ALL.iter().map(|e| e.name()).zip(errors).collect();
    report.virtual_seconds = virtual_ns as f64 * 1e-9;
    report.wall_seconds = began.elapsed().as_secs_f64();
    Ok(report)
}

impl std::fmt::Display for SoakReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "faults applied         {} in {} bursts ({} ticks, {:.0} s of virtual time, {:.1} s wall)",
            self.faults, self.bursts, self.ticks, self.virtual_seconds, self.wall_seconds
        )?;
        let kinds: Vec<String> = self
            .faults_by_kind
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        writeln!(f, "  by kind              {}", kinds.join(", "))?;
        let errors: Vec<String> = self.bus_errors.iter().map(|(k, n)| format!("{k} {n}")).collect();
        writeln!(f, "bus errors reported    {}", errors.join(", "))?;
        writeln!(
            f,
            "reads used {}, failed {}; ticks held {}",
            self.reads_used, self.reads_failed, self.held_ticks
        )?;
        writeln!(f, "panics                 {}", self.panics)?;
        writeln!(f, "corrupt values used    {}", self.corrupt_values_used)?;
        writeln!(
            f,
            "stale values used      {} (a lost reply's slot filled by a late copy of the servo's previous reply; used for tracking figures only)",
            self.stale_values_used
        )?;
        writeln!(f, "commands outside limits {}", self.commands_outside_limits)?;
        writeln!(f, "goals outside limits   {}", self.goals_outside_limits)?;
        writeln!(
            f,
            "torque-off stops       {} (reads silent for the torque-off time; torque left on after {})",
            self.torque_off_stops, self.torque_left_on
        )?;
        let bins: Vec<String> = self
            .recovery_ticks
            .iter()
            .enumerate()
            .map(|(k, n)| {
                if k == RECOVERY_BINS {
                    format!("≥{k}: {n}")
                } else {
                    format!("{k}: {n}")
                }
            })
            .collect();
        writeln!(f, "recovery after a burst (ticks: bursts) {}", bins.join("  "))?;
        write!(
            f,
            "recovery max           {} ticks ({} recoveries cut off by the next burst or a stop)",
            self.recovery_max_ticks, self.recovery_unfinished
        )
    }
}

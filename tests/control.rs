//! The control loop on virtual time (the virtual chain in-process is both bus and clock):
//! playback of a real clip, following targets made from its wrist and ankle paths, and the
//! fault policy — reads failing, the host going quiet, NaN inputs.

mod common;

use std::sync::Arc;
use std::time::Duration;

use glam::DVec3;
use marionette::bus::faults::{Fault, FaultInjector};
use marionette::bus::virtual_chain::{chain_for, VirtualRig};
use marionette::bus::{start_up, ServoBus};
use marionette::control::input::{input_channel, Input, InputSender, Payload, Target, MAX_EFFECTORS};
use marionette::control::sources::{clip_track, ClipPlayer, TrackFrame};
use marionette::control::{Controller, Follower, LoopConfig, RunEnd, Solve, StopMode, StopRequests};
use marionette::formats::{amc, asf};
use marionette::motion::Motion;
use marionette::profile::Profile;
use marionette::rig::{Rig, ServoMap};
use marionette::schedule::{Clock, Schedule};
use marionette::skeleton::{Skeleton, MAX_CHANNELS};

struct Setup {
    skel: Arc<Skeleton>,
    motion: Arc<Motion>,
    profile: Profile,
    rig: Rig,
    vr: VirtualRig,
    present: Vec<i32>,
}

fn setup() -> Setup {
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let profile = Profile::load(&path).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    // Servos resting at their zero angle, clamped into their limits.
    let zero: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let mut vr = VirtualRig::new(
        chain_for(profile.bus_section(), |k| zero[k]),
        profile.bus.baud,
        Duration::from_millis(2),
    );
    let present = start_up(&mut vr, profile.bus_section()).unwrap();
    Setup {
        skel: Arc::new(skel),
        motion: Arc::new(motion),
        profile,
        rig,
        vr,
        present,
    }
}

fn config(rate_hz: f64) -> LoopConfig {
    LoopConfig {
        rate_hz,
        stop: StopMode::Hold { hold_s: 0.0 },
        ..LoopConfig::default()
    }
}

/// Runs the loop by hand on virtual time, asking `feed` before each tick for the input due at
/// that tick (`None` ends the input). Returns why it ended and the goal ticks written per tick.
fn run(
    c: &mut Controller,
    vr: &mut VirtualRig,
    tx: InputSender,
    mut feed: impl FnMut(u64, u64, &mut VirtualRig) -> Option<Input>,
    max_ticks: u64,
    mut each: impl FnMut(u64, &mut Controller, &mut VirtualRig),
) -> RunEnd {
    let period = c.period_ns();
    let mut clock = vr.clone();
    let mut schedule = Schedule::new(clock.now_ns() + period, period);
    let mut tx = Some(tx);
    for k in 0..max_ticks {
        if let Some(sender) = &tx {
            match feed(k, schedule.deadline(k), vr) {
                Some(msg) => {
                    sender.send_newest(msg).unwrap();
                }
                None => tx = None,
            }
        }
        let tick = schedule.wait(&mut clock);
        assert_eq!(tick.index, k);
        let end = c.tick(&tick, vr, &mut clock);
        each(k, c, vr);
        if let Some(e) = end {
            return e;
        }
    }
    RunEnd::Duration
}

/// A loop over the setup's rig with an input channel of `capacity`.
fn controller(s: &Setup, solve: Solve, config: LoopConfig, capacity: usize) -> (Controller, InputSender) {
    let (tx, port) = input_channel(capacity);
    let c = Controller::new(
        Arc::clone(&s.skel),
        s.rig.clone(),
        s.profile.ids(),
        &s.present,
        port,
        solve,
        config,
    );
    (c, tx)
}

fn frames_controller(s: &Setup, rate: f64) -> (Controller, InputSender) {
    controller(s, Solve::Frames, config(rate), 4)
}

/// A 120 Hz follower of the named effectors.
fn follow_controller(s: &Setup, names: &[String]) -> (Controller, InputSender) {
    let follower = Follower::new(&s.skel, names).unwrap();
    controller(s, Solve::Follow(Box::new(follower)), config(120.0), 4)
}

#[test]
fn play_sends_every_frame_of_a_real_clip() {
    for rate in [120.0, 500.0] {
        let s = setup();
        let (mut c, tx) = frames_controller(&s, rate);
        let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), rate, false);
        let expected = player.samples_per_pass();
        let mut buf = [0.0; MAX_CHANNELS];
        let n = s.skel.channel_count();
        let end = run(
            &mut c,
            &mut s.vr.clone(),
            tx,
            |k, due, vr| {
                let t = player.next_sample(&mut buf[..n])?;
                Some(Input::frame(k, due, vr.now_ns(), &buf[..n], t))
            },
            100_000,
            |_, _, _| {},
        );
        let st = &c.stats;
        println!("{rate} Hz:\n{st}");
        assert_eq!(end, RunEnd::InputEnded);
        assert_eq!(st.inputs_used, expected, "every sample used once");
        assert_eq!(st.inputs_stale, 1, "only the tick that found the input ended");
        assert_eq!(st.commands_sent, st.ticks);
        assert_eq!(st.bus_error_total(), 0);
        assert_eq!(
            st.deadline_misses, 0,
            "the bus cycle fits the period on virtual time"
        );
        assert_eq!(st.commands_refused, 0);
        // The servos followed the clip: on virtual time the only lag is the servo's own motion.
        assert!(
            st.tracking_rms_deg() < 1.0,
            "tracking rms {}",
            st.tracking_rms_deg()
        );
        // The last frame is where the servos went (within the rate limits' reach).
        let chain_goals: Vec<i32> =
            s.vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
        assert_eq!(chain_goals, c.last_command());
    }
}

#[test]
fn play_resamples_by_slerp_and_seeks() {
    let s = setup();
    let mut p = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 240.0, false);
    let n = s.skel.channel_count();
    let mut a = vec![0.0; n];
    // At 240 Hz every second sample is a clip frame.
    let mut frames = 0;
    while let Some(t) = p.next_sample(&mut a) {
        let f = t * 120.0;
        if (f - f.round()).abs() < 1e-9 {
            let want = marionette::motion::frame_to_radians(&s.skel, s.motion.frame(f.round() as usize));
            for (x, y) in a.iter().zip(&want) {
                assert!((x - y).abs() < 1e-9);
            }
            frames += 1;
        }
    }
    assert_eq!(frames, s.motion.len());
    // Seek, pause and loop.
    let mut p = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    p.control(marionette::control::sources::PlayerCommand::Seek(1.0));
    assert!((p.next_sample(&mut a).unwrap() - 1.0).abs() < 1e-12);
    p.control(marionette::control::sources::PlayerCommand::Pause);
    assert!((p.next_sample(&mut a).unwrap() - 1.0).abs() < 1e-12);
    p.control(marionette::control::sources::PlayerCommand::Resume);
    let mut last = 0.0;
    for _ in 0..2 * s.motion.len() {
        last = p.next_sample(&mut a).unwrap();
    }
    assert!(last < s.motion.duration(), "looping wraps around");
}

/// [`run`] of target sample `k` at tick `k` ([`each_tick`]) until the input ends, on a copy of
/// the setup's chain.
fn run_track(
    (c, tx): (&mut Controller, InputSender),
    s: &Setup,
    samples: &[(f64, heapless::Vec<Target, MAX_EFFECTORS>)],
    each: impl FnMut(u64, &mut Controller, &mut VirtualRig),
) -> RunEnd {
    run(c, &mut s.vr.clone(), tx, each_tick(samples), 100_000, each)
}

/// A feed for [`run`]: target sample `k` at tick `k`, due at its deadline; ends after the last.
fn each_tick(
    samples: &[(f64, heapless::Vec<Target, MAX_EFFECTORS>)],
) -> impl FnMut(u64, u64, &mut VirtualRig) -> Option<Input> + '_ {
    |k, due, vr| {
        let (_, targets) = samples.get(k as usize)?;
        Some(Input {
            seq: k,
            due_ns: due,
            made_ns: vr.now_ns(),
            payload: Payload::Targets(targets.clone()),
        })
    }
}

fn effectors() -> Vec<String> {
    ["lradius", "rradius", "ltibia", "rtibia"]
        .iter()
        .map(|s| (*s).to_string())
        .collect()
}

#[test]
fn follow_tracks_real_wrist_and_ankle_paths() {
    let names = effectors();
    for frame in [TrackFrame::Limb, TrackFrame::Root] {
        let s = setup();
        let track = clip_track(&s.skel, &s.motion, &names, frame).unwrap();
        let (mut c, tx) = follow_controller(&s, &names);
        let samples = track.samples.clone();
        let mut ankle_gap = 0.0f64;
        let mut pose = marionette::fk::Pose64::default();
        let end = run_track((&mut c, tx), &s, &samples, |k, c, _| {
            // The legs hang from the root as in the capture: their targets are met.
            let Some((_, targets)) = samples.get(k as usize) else {
                return;
            };
            marionette::fk::fk64(&s.skel, c.channels(), &mut pose);
            for (e, name) in names.iter().enumerate().skip(2) {
                let b = s.skel.find(name).unwrap();
                ankle_gap = ankle_gap.max((pose.tip[b] - targets[e].position).length());
            }
        });
        let st = &c.stats;
        let r = st.report();
        println!("follow, {frame:?} frame:\n{st}");
        assert_eq!(end, RunEnd::InputEnded);
        assert_eq!(st.inputs_used, samples.len() as u64);
        assert_eq!(st.bus_error_total(), 0);
        assert!(ankle_gap < 1e-6, "ankle gap {ankle_gap}");
        match frame {
            TrackFrame::Limb => {
                // Every limb motion is one the rig can make: all reached.
                assert_eq!(st.unreachable, 0);
                assert!(r.ik_error_max < 1e-6, "IK max {}", r.ik_error_max);
            }
            TrackFrame::Root => {
                // With the spine at rest the captured wrists are sometimes past the arms'
                // reach: stretched towards them and counted, never more than a few cm off.
                assert!(
                    st.unreachable < samples.len() as u64,
                    "unreachable {}",
                    st.unreachable
                );
                assert!(r.ik_error_max < 1.0, "IK max {}", r.ik_error_max);
            }
        }
        assert!(st.tracking_rms_deg() < 1.0, "tracking {}", st.tracking_rms_deg());
    }
}

#[test]
fn failing_reads_hold_then_torque_off() {
    let s = setup();
    let (mut c, tx) = frames_controller(&s, 120.0);
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let mut held_goals: Option<Vec<i32>> = None;
    let mut fail_from = None;
    let k_fail = 60u64;
    let end = run(
        &mut c,
        &mut s.vr.clone(),
        tx,
        |k, due, vr| {
            if k == k_fail {
                // From now on every reply is lost.
                vr.with(|t| t.injector = Some(FaultInjector::new(7, 1.0, &[Fault::Drop], 0)));
            }
            let t = player.next_sample(&mut buf[..n])?;
            Some(Input::frame(k, due, vr.now_ns(), &buf[..n], t))
        },
        10_000,
        |k, c, vr| {
            if k < k_fail {
                return;
            }
            fail_from.get_or_insert(k);
            let goals: Vec<i32> = vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
            // K = 3: after the third failed read, the command written with the last good read
            // stands.
            if k >= k_fail + 3 {
                match &held_goals {
                    None => held_goals = Some(goals),
                    Some(h) if c.stats.held_ticks > 0 => {
                        let on: bool = vr.with(|t| t.chain().servos().iter().all(|v| v.torque_on()));
                        if on {
                            assert_eq!(&goals, h, "tick {k}: goals moved while holding");
                        }
                    }
                    Some(_) => {}
                }
            }
        },
    );
    let st = &c.stats;
    println!("{st}");
    assert_eq!(end, RunEnd::ReadsFailed);
    // 100 ms without a valid read at 120 Hz: the 12th or 13th failed tick turns torque off.
    let failed = st.ticks - k_fail;
    assert!(
        (12..=14).contains(&failed),
        "torque off after {failed} failed ticks"
    );
    assert_eq!(st.held_ticks, failed - 3);
    assert!(
        st.bus_errors[0] + st.bus_errors[2] >= failed,
        "{:?}",
        st.bus_errors
    );
    let torque: Vec<bool> =
        s.vr.with(|t| t.chain().servos().iter().map(|v| v.torque_on()).collect());
    assert!(torque.iter().all(|on| !on), "torque still on: {torque:?}");
}

#[test]
fn watchdog_stops_servos_when_the_host_goes_quiet() {
    let s = setup();
    let (mut c, tx) = frames_controller(&s, 120.0);
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let mut vr = s.vr.clone();
    run(
        &mut c,
        &mut vr,
        tx,
        |k, due, vr| {
            let t = player.next_sample(&mut buf[..n])?;
            Some(Input::frame(k, due, vr.now_ns(), &buf[..n], t))
        },
        60,
        |_, _, _| {},
    );
    // The host dies mid-motion: no more instructions. The profile arms a 100 ms watchdog.
    let moving = s.vr.with(|t| {
        t.chain()
            .servos()
            .iter()
            .filter(|v| v.present_tick() != v.goal_tick())
            .count()
    });
    assert!(moving > 0, "the rig was moving when the host stopped");
    for _ in 0..12 {
        let now = vr.now_ns();
        vr.wait_until(now + 10_000_000);
    }
    let before: Vec<i32> =
        s.vr.with(|t| t.chain().servos().iter().map(|v| v.present_tick()).collect());
    let expired =
        s.vr.with(|t| t.chain().servos().iter().all(|v| v.watchdog_expired()));
    assert!(
        expired,
        "every servo's watchdog expired 120 ms after the last instruction"
    );
    let now = vr.now_ns();
    vr.wait_until(now + 500_000_000);
    let after: Vec<i32> =
        s.vr.with(|t| t.chain().servos().iter().map(|v| v.present_tick()).collect());
    assert_eq!(before, after, "stopped servos do not move");
    // And a goal write is refused until the host re-arms the watchdog.
    let id = s.profile.ids()[0];
    let e = vr
        .write(
            id,
            marionette::servo::addr::GOAL_POSITION,
            &before[0].to_le_bytes(),
        )
        .unwrap_err();
    assert!(matches!(e, marionette::bus::BusError::Servo { .. }), "{e}");
}

#[test]
fn nan_and_out_of_range_inputs_never_reach_the_bus() {
    let s = setup();
    let names = effectors();
    let track = clip_track(&s.skel, &s.motion, &names, TrackFrame::Limb).unwrap();
    let (mut c, tx) = follow_controller(&s, &names);
    let limits: Vec<(i32, i32)> = s.rig.servos.iter().map(|m| (m.min_tick, m.max_tick)).collect();
    let samples = track.samples.clone();
    let poisoned = |k: u64| k % 7 == 3;
    let mut rejected = 0;
    let mut last_pose: Vec<f64> = Vec::new();
    let end = run(
        &mut c,
        &mut s.vr.clone(),
        tx,
        |k, due, vr| {
            let (_, targets) = samples.get(k as usize)?;
            let mut targets = targets.clone();
            if poisoned(k) {
                // Not finite, or finite and beyond the target range (a wrong unit, a corrupt
                // message): ten times the skeleton's reach.
                let range = marionette::control::target_range(&s.skel);
                // Ten times the spine, the right clavicle and arm down to the fingers.
                assert!((range - 220.296).abs() < 0.01, "{range}");
                let bad = [
                    f64::NAN,
                    f64::INFINITY,
                    -f64::INFINITY,
                    1e308 * 10.0,
                    1e300,
                    -1.01 * range,
                ][(k as usize / 7) % 6];
                targets[(k as usize) % 4].position.y = bad;
                if k % 2 == 0 {
                    targets[0].direction = Some(DVec3::new(0.0, bad, 0.0));
                }
                rejected += 1;
            }
            Some(Input {
                seq: k,
                due_ns: due,
                made_ns: vr.now_ns(),
                payload: Payload::Targets(targets),
            })
        },
        100_000,
        |k, c, vr| {
            let goals: Vec<i32> = vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
            for (g, (lo, hi)) in goals.iter().zip(&limits) {
                assert!(lo <= g && g <= hi, "tick {k}: goal {g} outside {lo}…{hi}");
            }
            if poisoned(k) {
                // A refused input changes nothing: the pose is the previous one (what the stage
                // sends is that pose, approached within the rate limits).
                assert_eq!(c.stats.inputs_rejected as usize, (k as usize + 4) / 7);
                assert_eq!(
                    c.channels(),
                    &last_pose[..],
                    "tick {k}: a refused input moved the pose"
                );
            }
            last_pose = c.channels().to_vec();
        },
    );
    assert_eq!(end, RunEnd::InputEnded);
    assert_eq!(c.stats.inputs_rejected, rejected);
    assert_eq!(
        c.stats.commands_refused, 0,
        "nothing non-finite got as far as the command stage"
    );
    assert!(c.stats.report().ik_error_rms.is_finite());
    // A frame with a NaN in play mode is refused too.
    let (mut c, tx) = frames_controller(&s, 120.0);
    let mut frame = vec![0.0; s.skel.channel_count()];
    frame[10] = f64::NAN;
    let mut sent = false;
    run(
        &mut c,
        &mut s.vr.clone(),
        tx,
        |k, due, _| {
            if sent {
                return None;
            }
            sent = true;
            Some(Input::frame(k, due, 0, &frame, 0.0))
        },
        5,
        |_, _, _| {},
    );
    assert_eq!(c.stats.inputs_rejected, 1);
    assert_eq!(c.stats.inputs_used, 0);
}

/// A 120 Hz loop of `cfg` over the setup's rig with the walk's first 250 frames queued, each due
/// at its tick (a channel that holds them all); its input's sender and its schedule.
fn queued_walk(s: &Setup, cfg: LoopConfig) -> (Controller, InputSender, Schedule) {
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let period = 1_000_000_000 / 120;
    let schedule = Schedule::new(s.vr.clone().now_ns() + period, period);
    let (c, tx) = controller(s, Solve::Frames, cfg, 300);
    for k in 0..250 {
        let t = player.next_sample(&mut buf[..n]).unwrap();
        tx.send_newest(Input::frame(k, schedule.deadline(k), 0, &buf[..n], t))
            .unwrap();
    }
    (c, tx, schedule)
}

#[test]
fn run_ramps_to_rest_then_turns_torque_off() {
    let s = setup();
    let mut cfg = config(120.0);
    cfg.stop = StopMode::Rest { ramp_s: 0.5 };
    cfg.max_ticks = Some(200);
    let mut clock = s.vr.clone();
    let (mut c, _tx, mut schedule) = queued_walk(&s, cfg);
    let stop = StopRequests::new();
    let end = c.run(&mut schedule, &mut s.vr.clone(), &mut clock, &stop);
    assert_eq!(end, RunEnd::Duration);
    assert_eq!(c.stats.ticks, 200);
    let rest: Vec<i32> = s.rig.servos.iter().map(ServoMap::rest_tick).collect();
    let goals: Vec<i32> =
        s.vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
    let off = s.vr.with(|t| t.chain().servos().iter().all(|v| !v.torque_on()));
    assert!(off, "torque off at the end");
    for (g, r) in goals.iter().zip(&rest) {
        assert!((g - r).abs() <= 1, "goal {g}, rest {r}");
    }
}

/// Effectors that do not end a 2-bone limb are solved numerically, and a pointing direction
/// turns the hand: both in the loop, from the capture's own hand positions and directions.
#[test]
fn follow_solves_numeric_effectors_and_pointing() {
    let s = setup();
    // The left wrist by the analytic limb with the left hand pointed; the right hand's tip
    // numerically (rhand ends no 2-bone limb: its parent, rwrist, has one DOF).
    let names = vec!["lradius".to_string(), "rhand".to_string()];
    let (mut c, tx) = follow_controller(&s, &names);
    let bone = |n: &str| s.skel.find(n).unwrap();
    let (lr, lh, rh) = (bone("lradius"), bone("lhand"), bone("rhand"));
    // Goals from the capture's arm channels on a rest body (root and spine at rest).
    let arms: Vec<usize> = [
        "lhumerus", "lradius", "lwrist", "lhand", "rhumerus", "rradius", "rwrist", "rhand",
    ]
    .iter()
    .flat_map(|b| s.skel.bones()[bone(b)].channels())
    .collect();
    let mut pose = marionette::fk::Pose64::default();
    let mut goals = Vec::new();
    for f in (0..s.motion.len()).step_by(40) {
        let full = marionette::motion::frame_to_radians(&s.skel, s.motion.frame(f));
        let mut ch = vec![0.0; s.skel.channel_count()];
        for &c in &arms {
            ch[c] = full[c];
        }
        marionette::fk::fk64(&s.skel, &ch, &mut pose);
        let dir = (pose.tip[lh] - pose.start[lh]).normalize();
        goals.push((pose.tip[lr], dir, pose.tip[rh]));
    }
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    let g = goals.clone();
    run(
        &mut c,
        &mut s.vr.clone(),
        tx,
        |k, due, _| {
            let (wrist, dir, hand) = *g.get(k as usize / 4)?;
            let mut t = heapless::Vec::new();
            let _ = t.push(marionette::control::input::Target {
                effector: 0,
                position: wrist,
                direction: Some(dir),
            });
            let _ = t.push(marionette::control::input::Target {
                effector: 1,
                position: hand,
                direction: None,
            });
            Some(Input {
                seq: k,
                due_ns: due,
                made_ns: 0,
                payload: Payload::Targets(t),
            })
        },
        10_000,
        |k, c, _| {
            if k % 4 != 3 {
                return;
            }
            let Some(&(wrist, dir, hand)) = goals.get(k as usize / 4) else {
                return;
            };
            let mut pose = marionette::fk::Pose64::default();
            marionette::fk::fk64(&s.skel, c.channels(), &mut pose);
            let got = (pose.tip[lh] - pose.start[lh]).normalize();
            worst.0 = worst.0.max((pose.tip[lr] - wrist).length());
            worst.1 = worst.1.max(got.angle_between(dir).to_degrees());
            worst.2 = worst.2.max((pose.tip[rh] - hand).length());
        },
    );
    println!(
        "{} goals: wrist {:.2e}, hand pointing {:.3}°, right hand (numeric) {:.2e}",
        goals.len(),
        worst.0,
        worst.1,
        worst.2
    );
    assert_eq!(c.stats.inputs_rejected, 0);
    assert!(worst.0 < 1e-6, "wrist off by {}", worst.0);
    assert!(worst.1 < 0.5, "pointing off by {}°", worst.1);
    assert!(worst.2 < 0.01, "right hand off by {}", worst.2);
}

/// A short burst of failed reads: held after K = 3, then back to following, with no jump
/// beyond the rate limits when the hold ends.
#[test]
fn a_burst_of_failed_reads_holds_then_resumes() {
    let s = setup();
    let (mut c, tx) = frames_controller(&s, 120.0);
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, false);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let limits: Vec<f64> = s
        .rig
        .servos
        .iter()
        .map(|m| m.max_velocity / 120.0 + 1.0)
        .collect();
    let mut last: Option<Vec<i32>> = None;
    let mut worst_excess = 0.0f64;
    let end = run(
        &mut c,
        &mut s.vr.clone(),
        tx,
        |k, due, vr| {
            match k {
                60 => vr.with(|t| t.injector = Some(FaultInjector::new(3, 1.0, &[Fault::Drop], 0))),
                66 => vr.with(|t| t.injector = None),
                _ => {}
            }
            let t = player.next_sample(&mut buf[..n])?;
            Some(Input::frame(k, due, vr.now_ns(), &buf[..n], t))
        },
        10_000,
        |_, _, vr| {
            // What the servos were told, hold or not.
            let now: Vec<i32> = vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
            if let Some(prev) = &last {
                for ((a, b), lim) in now.iter().zip(prev).zip(&limits) {
                    worst_excess = worst_excess.max(f64::from((a - b).abs()) - lim);
                }
            }
            last = Some(now);
        },
    );
    let st = &c.stats;
    assert_eq!(end, RunEnd::InputEnded);
    assert_eq!(st.held_ticks, 4, "ticks 63–66 held");
    assert!(
        worst_excess <= 0.0,
        "a step exceeded the velocity limit by {worst_excess} ticks"
    );
    assert!(s.vr.with(|t| t.chain().servos().iter().all(|v| v.torque_on())));
}

/// A clock that asks the loop to stop at given waits (tick deadlines, ramp ticks included).
struct StoppingClock {
    inner: VirtualRig,
    stop: StopRequests,
    waits: u64,
    at: Vec<u64>,
}

impl Clock for StoppingClock {
    fn now_ns(&mut self) -> u64 {
        self.inner.now_ns()
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        self.waits += 1;
        if self.at.contains(&self.waits) {
            self.stop.request();
        }
        self.inner.wait_until(deadline_ns);
    }
}

/// Runs a looping clip at 120 Hz with a 2 s ramp to rest, stop requests made at the waits in
/// `at`; returns why it ended, the ticks run and the goal writes of one servo.
fn run_with_stops(s: &Setup, at: Vec<u64>) -> (RunEnd, u64, u32) {
    let mut cfg = config(120.0);
    cfg.stop = StopMode::Rest { ramp_s: 2.0 };
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let period = 1_000_000_000 / 120;
    let mut vr = s.vr.clone();
    let stop = StopRequests::new();
    let mut clock = StoppingClock {
        inner: vr.clone(),
        stop: stop.clone(),
        waits: 0,
        at,
    };
    let mut schedule = Schedule::new(clock.now_ns() + period, period);
    let (mut c, tx) = controller(s, Solve::Frames, cfg, 400);
    for k in 0..400 {
        let t = player.next_sample(&mut buf[..n]).unwrap();
        tx.send_newest(Input::frame(k, schedule.deadline(k), 0, &buf[..n], t))
            .unwrap();
    }
    let writes_before = vr.with(|t| t.chain().servos()[0].goal_writes());
    let end = c.run(&mut schedule, &mut vr, &mut clock, &stop);
    let writes = vr.with(|t| t.chain().servos()[0].goal_writes()) - writes_before;
    let off = vr.with(|t| t.chain().servos().iter().all(|v| !v.torque_on()));
    assert!(off, "torque off at the end");
    assert_eq!(c.stats.torque_off_acknowledged, Some(28));
    (end, c.stats.ticks, writes)
}

#[test]
fn a_stop_request_ramps_to_rest_and_a_second_cuts_the_ramp() {
    let s = setup();
    // One request at tick 100: 99 ticks, then the whole 2 s ramp (240 ticks) and more.
    let (end, ticks, writes) = run_with_stops(&s, vec![100]);
    assert_eq!(end, RunEnd::Interrupted);
    assert_eq!(ticks, 99);
    assert!(writes >= 99 + 240, "{writes} goal writes");
    // A second request 10 ticks into the ramp: torque off at once.
    let (end, ticks, writes) = run_with_stops(&s, vec![100, 110]);
    assert_eq!(end, RunEnd::Interrupted);
    assert_eq!(ticks, 99);
    assert_eq!(writes, 99 + 9, "the ramp stopped at the second request");
}

/// A bus whose port fails for good after a number of transactions, as an unplugged adapter
/// does (every call then fails with EIO), counting what is tried afterwards.
struct Unplugged {
    inner: VirtualRig,
    left: u32,
    goal_writes_after: u32,
    torque_writes_after: u32,
    other_after: u32,
}

impl Unplugged {
    fn gone(&mut self) -> bool {
        if self.left == 0 {
            return true;
        }
        self.left -= 1;
        false
    }
}

fn eio() -> marionette::bus::BusError {
    std::io::Error::from_raw_os_error(5).into()
}

impl ServoBus for Unplugged {
    fn ping(&mut self, id: u8) -> Result<marionette::bus::PingInfo, marionette::bus::BusError> {
        self.inner.ping(id)
    }
    fn scan(&mut self) -> Result<Vec<marionette::bus::PingInfo>, marionette::bus::BusError> {
        self.inner.scan()
    }
    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), marionette::bus::BusError> {
        if self.gone() {
            self.other_after += 1;
            return Err(eio());
        }
        self.inner.read(id, address, out)
    }
    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), marionette::bus::BusError> {
        if self.gone() {
            self.other_after += 1;
            return Err(eio());
        }
        self.inner.write(id, address, data)
    }
    fn sync_write(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        data: &[u8],
    ) -> Result<(), marionette::bus::BusError> {
        if self.gone() {
            match address {
                marionette::servo::addr::GOAL_POSITION => self.goal_writes_after += 1,
                marionette::servo::addr::TORQUE_ENABLE => self.torque_writes_after += 1,
                _ => self.other_after += 1,
            }
            return Err(eio());
        }
        self.inner.sync_write(address, len, ids, data)
    }
    fn sync_read(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
    ) -> Result<(), marionette::bus::BusError> {
        if self.gone() {
            self.other_after += 1;
            return Err(eio());
        }
        self.inner.sync_read(address, len, ids, out)
    }
    fn reboot(&mut self, id: u8) -> Result<(), marionette::bus::BusError> {
        self.inner.reboot(id)
    }
}

#[test]
fn an_unplugged_port_ends_the_run_with_one_torque_off_try() {
    let s = setup();
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let period = 1_000_000_000 / 120;
    let mut clock = s.vr.clone();
    // Two transactions a tick (Sync Write, Sync Read): the port goes at tick 50, mid-tick
    // (after its write), then at tick 80 before its write.
    for (left, tick) in [(99, 50), (158, 80)] {
        let mut bus = Unplugged {
            inner: s.vr.clone(),
            left,
            goal_writes_after: 0,
            torque_writes_after: 0,
            other_after: 0,
        };
        let (mut c2, tx2) = controller(&s, Solve::Frames, config(120.0), 400);
        let start = clock.now_ns() + period;
        for k in 0..400 {
            let t = player.next_sample(&mut buf[..n]).unwrap();
            tx2.send_newest(Input::frame(k, start + k * period, 0, &buf[..n], t))
                .unwrap();
        }
        let mut schedule = Schedule::new(start, period);
        let end = c2.run(&mut schedule, &mut bus, &mut clock, &StopRequests::new());
        assert_eq!(end, RunEnd::PortLost, "port gone at tick {tick}");
        assert_eq!(c2.stats.ticks, tick, "the run ended in the tick the port failed");
        assert!(c2.port_error.is_some());
        assert_eq!(bus.torque_writes_after, 1, "one torque-off Sync Write");
        assert!(
            bus.goal_writes_after <= 1,
            "no command after the failure: {}",
            bus.goal_writes_after
        );
        assert!(
            bus.other_after <= 1,
            "only the tick's own read failed: {}",
            bus.other_after
        );
    }
    // The port goes during the ramp to rest after 60 ticks: the ramp stops there, one torque-off
    // is tried, and the run ends as a lost port (not as its duration).
    let mut bus = Unplugged {
        inner: s.vr.clone(),
        left: 2 * 60 + 10,
        goal_writes_after: 0,
        torque_writes_after: 0,
        other_after: 0,
    };
    let mut cfg = config(120.0);
    cfg.stop = StopMode::Rest { ramp_s: 1.0 };
    cfg.max_ticks = Some(60);
    let (mut c, tx) = controller(&s, Solve::Frames, cfg, 400);
    let start = clock.now_ns() + period;
    for k in 0..400 {
        let t = player.next_sample(&mut buf[..n]).unwrap();
        tx.send_newest(Input::frame(k, start + k * period, 0, &buf[..n], t))
            .unwrap();
    }
    let end = c.run(
        &mut Schedule::new(start, period),
        &mut bus,
        &mut clock,
        &StopRequests::new(),
    );
    assert_eq!(end, RunEnd::PortLost);
    assert_eq!(c.stats.ticks, 60);
    assert!(c.port_error.is_some());
    assert_eq!(bus.goal_writes_after, 1, "the ramp stopped at its failed write");
    assert_eq!(bus.torque_writes_after, 1, "one torque-off Sync Write");
    assert_eq!(bus.other_after, 0, "no servo asked on its own");
}

/// Plays the walk (its capture dropouts filled) through the whole loop on the virtual chain in
/// lockstep (virtual time), after a half-second pre-roll to its first frame, with or without
/// the look-ahead; returns the loop's fidelity figures.
fn walk_fidelity(rate: f64, lookahead: Option<f64>) -> marionette::control::fidelity::FidelityReport {
    walk_in_lockstep(rate, lookahead).0
}

/// [`walk_fidelity`], with the ticks skipped because the bus work overran the period.
fn walk_in_lockstep(
    rate: f64,
    lookahead: Option<f64>,
) -> (marionette::control::fidelity::FidelityReport, u64) {
    use marionette::control::lockstep::FeedingClock;
    use marionette::control::lookahead::{Lookahead, LookaheadSettings};
    use marionette::control::source::{ClipSource, Grid};
    let s = setup();
    let mut motion = (*s.motion).clone();
    let dropouts = marionette::motion::dropouts::repair(&s.skel, &mut motion);
    assert_eq!(dropouts.len(), 5, "{dropouts:?}");
    let config = LoopConfig {
        ease_in_s: 0.5,
        // The puppet's scale (0.3 of the subject), as `play` measures effectors.
        effector_metres_per_unit: 0.3 * f64::from(s.skel.units().meters_per_unit()),
        // Twice the clip and pre-roll: a run that stops taking its input ends too.
        max_ticks: Some(((s.motion.duration() + 0.5) * rate * 2.0) as u64),
        ..config(rate)
    };
    let (mut c, tx) = controller(&s, Solve::Frames, config, 4096);
    if let Some(lead_s) = lookahead {
        let leads = vec![lead_s; s.rig.len()];
        c.set_lookahead(Lookahead::new(&s.rig, rate, &leads, LookaheadSettings::default()));
    }
    let mut vr = s.vr.clone();
    let period = c.period_ns();
    let start = vr.now_ns() + period;
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::new(motion), rate, false);
    player.set_pre_roll(0.5);
    let pre_roll = player.pre_roll_samples();
    let feed = Box::new(ClipSource::new(player, None));
    let grid = Grid {
        start_ns: start,
        period_ns: period,
    };
    let mut clock = FeedingClock::new(vr.clone(), feed, tx, grid).with_preview(c.preview_ns());
    let mut schedule = Schedule::new(start, period);
    let end = c.run(&mut schedule, &mut vr, &mut clock, &StopRequests::new());
    assert_eq!(end, RunEnd::InputEnded);
    let samples = (s.motion.duration() * rate).floor() as u64 + 1;
    assert_eq!(c.stats.inputs_used, pre_roll + samples, "every sample played");
    assert_eq!(c.stats.commands_refused, 0);
    (
        c.stats.fidelity.clone().expect("fidelity measured"),
        c.stats.skipped_ticks,
    )
}

/// A rate beyond what the bus allows (28 servos' Sync Write and Sync Read at 1 Mbps take
/// longer than 0.5 ms): every tick is late and deadlines are skipped, yet each tick's inputs are
/// fed (the lockstep clock sees every deadline, a late one too) and the run ends with its input.
#[test]
fn a_lockstep_run_beyond_the_wire_still_plays_every_sample_and_ends() {
    let (fidelity, skipped) = walk_in_lockstep(2000.0, Some(0.0));
    println!("2 kHz on the wire: {skipped} ticks skipped, fidelity {fidelity:?}");
    assert!(skipped > 1000, "{skipped}");
    assert!(fidelity.samples > 0);
}

/// Planning the goal path over a preview of the clip follows the source closer than
/// the greedy limiter on the same servos — smaller error end to end and a shorter lag — two
/// runs on virtual time are identical, and led by the virtual servos' lag the walk at 500 Hz
/// stays within 0.5° RMS.
#[test]
fn the_lookahead_follows_the_clip_closer_than_the_greedy_limiter() {
    let greedy = walk_fidelity(500.0, None);
    let planned = walk_fidelity(500.0, Some(0.0));
    println!(
        "greedy: rms {:.3}°, lag {} ms, effectors {:?} mm; look-ahead: rms {:.3}°, lag {} ms, effectors {:?} mm",
        greedy.joint_rms_deg,
        greedy.lag_ms,
        greedy.effector_rms_mm,
        planned.joint_rms_deg,
        planned.lag_ms,
        planned.effector_rms_mm
    );
    assert!(planned.joint_rms_deg < 0.75 * greedy.joint_rms_deg);
    assert!(planned.lag_ms < greedy.lag_ms);
    assert!(planned.effector_rms_mm.unwrap() < greedy.effector_rms_mm.unwrap());
    let again = walk_fidelity(500.0, Some(0.0));
    assert_eq!(planned, again, "the same run twice gives the same figures");
    // Led by the virtual servo's lag (it brakes to each goal: ~5 ms at the walk's speeds) and
    // the period: within half a degree.
    let led = walk_fidelity(500.0, Some(0.007));
    println!(
        "led 7 ms: rms {:.3}°, lag {} ms, effectors {:?} mm",
        led.joint_rms_deg, led.lag_ms, led.effector_rms_mm
    );
    assert!(led.joint_rms_deg <= 0.5, "{led:?}");
}

/// Targets taken ahead of their time are solved one effector a tick (a fast loop's
/// ticks share a slower input's solve), and every tick's source is the same, bit for bit, as
/// when each input is solved whole in the tick it comes due.
#[test]
fn targets_taken_ahead_are_solved_over_ticks_with_the_same_result() {
    use marionette::control::lookahead::{Lookahead, LookaheadSettings};
    let names = effectors();
    let s = setup();
    let track = clip_track(&s.skel, &s.motion, &names, TrackFrame::Limb).unwrap();
    // 30 Hz targets at 250 Hz: about eight ticks an input.
    let inputs: Vec<_> = track.samples.iter().step_by(4).cloned().collect();
    let rate = 250.0;
    let follow = |ahead: bool, rehearse: bool| {
        let follower = Follower::new(&s.skel, &names).unwrap();
        let (mut c, tx) = controller(&s, Solve::Follow(Box::new(follower)), config(rate), 4096);
        let leads = vec![0.02; s.rig.len()];
        c.set_lookahead(Lookahead::new(&s.rig, rate, &leads, LookaheadSettings::default()));
        c.log_source(10_000);
        let period = c.period_ns();
        // Ahead by the preview, or in the tick whose window it falls in.
        let early = if ahead { c.preview_ns() } else { period / 2 };
        let mut vr = s.vr.clone();
        let mut clock = vr.clone();
        let start = clock.now_ns() + period;
        let mut schedule = Schedule::new(start, period);
        let t0 = inputs[0].0;
        let mut tx = Some(tx);
        let mut next = 0;
        let mut end = None;
        for k in 0..10_000 {
            // Every input sent `early` before its time.
            while let (Some(sender), Some((t, targets))) = (&tx, inputs.get(next)) {
                let due = start + ((t - t0) * 1e9) as u64;
                if due > schedule.deadline(k) + early {
                    break;
                }
                let msg = Input {
                    seq: next as u64,
                    due_ns: due,
                    made_ns: clock.now_ns(),
                    payload: Payload::Targets(targets.clone()),
                };
                sender.send_newest(msg).unwrap();
                next += 1;
            }
            if next == inputs.len() {
                tx = None;
            }
            if rehearse {
                c.rehearse(schedule.next_deadline());
            }
            let tick = schedule.wait(&mut clock);
            end = c.tick(&tick, &mut vr, &mut clock);
            if end.is_some() {
                break;
            }
        }
        assert_eq!(end, Some(RunEnd::InputEnded));
        assert_eq!(c.stats.inputs_used, inputs.len() as u64);
        assert_eq!(c.stats.unreachable, 0);
        // Times from the first deadline (the two runs share the virtual clock).
        let log: Vec<_> = c.source_log().iter().map(|(d, a)| (d - start, *a)).collect();
        let goals: Vec<i32> = vr.with(|t| t.chain().servos().iter().map(|v| v.goal_tick()).collect());
        if rehearse {
            assert!(
                c.stats.solves_rehearsed > c.stats.inputs_used,
                "{}",
                c.stats.solves_rehearsed
            );
        }
        (c.stats.inputs_spread, log, goals)
    };
    let (spread, sliced, goals) = follow(true, false);
    let (whole, at_once, _) = follow(false, false);
    // Each solve made ahead on a copy, as a real-time run does before each deadline, changes
    // nothing: the same sources, bit for bit, and the servos end where they did.
    let (rehearsed_spread, rehearsed, rehearsed_goals) = follow(true, true);
    assert_eq!(rehearsed_spread, spread);
    assert_eq!(rehearsed.len(), sliced.len());
    assert!(rehearsed
        .iter()
        .zip(&sliced)
        .all(|((d, a), (e, b))| d == e && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())));
    assert_eq!(rehearsed_goals, goals);
    println!(
        "{} inputs: {spread} solved over several ticks when taken ahead, {whole} when taken as they come due",
        inputs.len()
    );
    assert_eq!(whole, 0);
    assert!(spread as usize > inputs.len() * 9 / 10, "{spread}");
    assert!(sliced.len() > 900, "{} ticks logged", sliced.len());
    // Each tick's source from the deadline on which both runs have one (the one fed ahead has
    // its first sample in place before the first deadline).
    let mut compared = 0;
    for (d, a) in &at_once {
        let Some((_, b)) = sliced.iter().find(|(e, _)| e == d) else {
            continue;
        };
        let n = s.rig.len();
        assert!(
            a[..n]
                .iter()
                .zip(&b[..n])
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "tick at {d} ns: {:?} against {:?}",
            &a[..n],
            &b[..n]
        );
        compared += 1;
    }
    assert!(
        compared > at_once.len() * 9 / 10,
        "{compared} of {} ticks compared",
        at_once.len()
    );
    // Both end on the same last sample, at the same tick.
    assert_eq!(sliced.last().map(|(d, _)| *d), at_once.last().map(|(d, _)| *d));
}

/// Live sources (a UDP line, a ROS 2 topic) name one effector a message. Messages due together
/// are taken in one tick and only the newest is solved, but the targets of those it supersedes
/// still stand: four one-effector messages give the pose that one four-effector message gives.
#[test]
fn superseded_live_targets_still_set_their_effectors() {
    let names = effectors();
    let s = setup();
    let track = clip_track(&s.skel, &s.motion, &names, TrackFrame::Limb).unwrap();
    let targets = &track.samples[100].1;
    assert_eq!(targets.len(), 4);
    let pose_after = |messages: Vec<heapless::Vec<marionette::control::input::Target, 8>>| {
        let (mut c, tx) = controller(
            &s,
            Solve::Follow(Box::new(Follower::new(&s.skel, &names).unwrap())),
            config(120.0),
            8,
        );
        let mut vr = s.vr.clone();
        let mut clock = vr.clone();
        let period = c.period_ns();
        let mut schedule = Schedule::new(clock.now_ns() + period, period);
        for (seq, m) in messages.into_iter().enumerate() {
            let msg = Input {
                seq: seq as u64,
                due_ns: 0,
                made_ns: clock.now_ns(),
                payload: Payload::Targets(m),
            };
            tx.send_newest(msg).unwrap();
        }
        for _ in 0..3 {
            let tick = schedule.wait(&mut clock);
            c.tick(&tick, &mut vr, &mut clock);
        }
        (
            c.channels().to_vec(),
            c.stats.inputs_used,
            c.stats.inputs_rejected,
        )
    };
    let (together, used, rejected) = pose_after(vec![targets.clone()]);
    assert_eq!((used, rejected), (1, 0));
    let one_each = targets
        .iter()
        .map(|t| {
            let mut v = heapless::Vec::new();
            v.push(*t).unwrap();
            v
        })
        .collect();
    let (apart, used, rejected) = pose_after(one_each);
    // One solved (the newest), three passed over with their targets set.
    assert_eq!((used, rejected), (1, 0));
    assert_eq!(apart, together);
    // And the pose is not the rest pose: the targets were acted on.
    assert!(together.iter().any(|a| a.abs() > 0.1));
}

/// `targets --directions`: each target carries the unit direction of the bone its effector
/// points (the hand, the foot) — as captured in the root frame, turned with the limb in the
/// limb frame — and following them turns the feet where points alone leave them at rest.
#[test]
fn pointing_tracks_carry_the_captured_directions_and_turn_the_feet() {
    use marionette::control::pointer_bone;
    use marionette::control::sources::clip_track_pointing;
    use marionette::fk::{fk64, Pose64};
    let names = effectors();
    let s = setup();
    let pointers: Vec<usize> = names
        .iter()
        .map(|n| pointer_bone(&s.skel, s.skel.find(n).unwrap()).unwrap())
        .collect();
    assert_eq!(s.skel.bones()[pointers[2]].name(), "lfoot");
    let root = clip_track_pointing(&s.skel, &s.motion, &names, TrackFrame::Root).unwrap();
    let limb = clip_track_pointing(&s.skel, &s.motion, &names, TrackFrame::Limb).unwrap();
    let plain = clip_track(&s.skel, &s.motion, &names, TrackFrame::Root).unwrap();
    let mut pose = Pose64::default();
    for f in [0, 150, 300] {
        let mut ch = marionette::motion::frame_to_radians(&s.skel, s.motion.frame(f));
        for c in s.skel.bones()[0].channels() {
            ch[c] = 0.0;
        }
        fk64(&s.skel, &ch, &mut pose);
        for (k, &h) in pointers.iter().enumerate() {
            let want = (pose.tip[h] - pose.start[h]).normalize();
            let got = root.samples[f].1[k].direction.unwrap();
            assert!((got - want).length() < 1e-12, "frame {f}, {}", names[k]);
            assert_eq!(root.samples[f].1[k].position, plain.samples[f].1[k].position);
            assert!((limb.samples[f].1[k].direction.unwrap().length() - 1.0).abs() < 1e-12);
        }
    }
    // Following them: the feet turn (points alone leave them at rest).
    let feet = |track: &marionette::control::sources::TargetTrack| {
        let (mut c, tx) = follow_controller(&s, &names);
        let mut vr = s.vr.clone();
        let mut clock = vr.clone();
        let period = c.period_ns();
        let mut schedule = Schedule::new(clock.now_ns() + period, period);
        let lfoot = s.skel.find("lfoot").unwrap();
        let mut most: f64 = 0.0;
        for (seq, (_, targets)) in track.samples.iter().enumerate().step_by(10) {
            let msg = Input {
                seq: seq as u64,
                due_ns: 0,
                made_ns: clock.now_ns(),
                payload: Payload::Targets(targets.clone()),
            };
            tx.send_newest(msg).unwrap();
            let tick = schedule.wait(&mut clock);
            c.tick(&tick, &mut vr, &mut clock);
            for ch in s.skel.bones()[lfoot].channels() {
                most = most.max(c.channels()[ch].abs());
            }
        }
        most
    };
    assert_eq!(
        feet(&clip_track(&s.skel, &s.motion, &names, TrackFrame::Limb).unwrap()),
        0.0
    );
    let turned = feet(&limb);
    assert!(turned > 0.1, "the left foot turned {turned} rad at most");
}

#[test]
fn the_move_to_a_clips_first_pose_is_sized_by_the_farthest_servo() {
    use marionette::control::{start_move_s, START_MOVE_SPEED_SHARE};
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let profile = Profile::load(&path).unwrap();
    let skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let rig = profile.rig(Some(&skeleton)).unwrap();
    let n = rig.servos.len();
    let present: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    // The move's length for servo k to `angle`: its target taken inside its range, as the
    // command stage takes it, at the smoothstep's peak (1.5 times the mean speed) a quarter
    // of its velocity limit.
    let expected = |k: usize, angle: f64| {
        let s = &rig.servos[k];
        let to = s
            .angle_to_ticks_exact(angle)
            .clamp(f64::from(s.min_tick), f64::from(s.max_tick));
        1.5 * (to - f64::from(present[k])).abs() / (START_MOVE_SPEED_SHARE * s.max_velocity)
    };
    let mut pose: Vec<f64> = rig
        .servos
        .iter()
        .map(|s| s.ticks_to_angle(f64::from(s.rest_tick())))
        .collect();
    let (still, _, degrees) = start_move_s(&rig, &present, &pose).unwrap();
    assert!(
        still.abs() < 1e-9 && degrees.abs() < 1e-6,
        "{still} s, {degrees}°"
    );

    // Two servos away from where they stand: the one that takes longer sets the time.
    pose[3] += 0.2;
    pose[7] += 0.6;
    let (seconds, servo, degrees) = start_move_s(&rig, &present, &pose).unwrap();
    let longer = if expected(7, pose[7]) >= expected(3, pose[3]) {
        7
    } else {
        3
    };
    assert_eq!(servo, longer);
    assert!(
        (seconds - expected(longer, pose[longer])).abs() < 1e-9,
        "{seconds}"
    );
    assert!(seconds > 0.0 && degrees > 0.0);

    // A target far past the range is taken at its end; a NaN is left out; nothing finite: no
    // move.
    pose[7] = 100.0;
    let (far, _, _) = start_move_s(&rig, &present, &pose).unwrap();
    assert!((far - expected(7, 100.0).max(expected(3, pose[3]))).abs() < 1e-9);
    pose[3] = f64::NAN;
    assert!((start_move_s(&rig, &present, &pose).unwrap().0 - expected(7, 100.0)).abs() < 1e-9);
    assert!(start_move_s(&rig, &present, &vec![f64::NAN; n]).is_none());
}

/// Following the walk's targets from rest, where the humerus twists are 80–90° from their first
/// pose: with the move sized at the first input the loop eases there at a quarter of the
/// servos' speed (as long as `start_move_s` says for the pose the follower's first solve gives)
/// and leaves the move out of the fidelity; without it, the trip from rest at full speed counts.
#[test]
fn the_move_to_the_first_targets_is_eased_and_left_out_of_the_fidelity() {
    use marionette::control::start_move_s;
    let names = effectors();
    let follow = |size_start_move: bool| {
        let s = setup();
        let mut motion = (*s.motion).clone();
        marionette::motion::dropouts::repair(&s.skel, &mut motion);
        let track = clip_track(&s.skel, &motion, &names, TrackFrame::Limb).unwrap();
        let follower = Follower::new(&s.skel, &names).unwrap();
        let first = follower.first_pose(&s.skel, &track.samples[0].1).unwrap();
        let mut angles = vec![0.0; s.rig.len()];
        s.rig.joint_angles(&s.skel, &first, &[], &mut angles);
        let expected = start_move_s(&s.rig, &s.present, &angles).unwrap().0;
        let config = LoopConfig {
            size_start_move,
            ..config(120.0)
        };
        let (mut c, tx) = controller(&s, Solve::Follow(Box::new(follower)), config, 4);
        let samples = track.samples;
        let mut first_solved = None;
        let end = run_track((&mut c, tx), &s, &samples, |_, c, _| {
            first_solved.get_or_insert_with(|| c.channels().to_vec());
        });
        assert_eq!(end, RunEnd::InputEnded);
        // The pose solved before the run is the loop's first.
        let first_solved = first_solved.unwrap();
        let gap = first
            .iter()
            .zip(&first_solved)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(gap < 1e-12, "first pose {gap} rad from the loop's first solve");
        (c.stats.start_move_s, expected, c.fidelity_report())
    };
    let (sized, expected, eased) = follow(true);
    let (none, _, abrupt) = follow(false);
    println!(
        "start move {sized:?} s (expected {expected:.3}); fidelity eased: rms {:.2}° max {:.2}° over {} ticks; from rest at full speed: rms {:.2}° max {:.2}° over {}",
        eased.joint_rms_deg, eased.joint_max_deg, eased.samples, abrupt.joint_rms_deg, abrupt.joint_max_deg, abrupt.samples
    );
    let sized = sized.expect("the ease lengthened");
    assert!(
        expected > 1.0,
        "the humerus twists are far from rest: {expected} s"
    );
    assert!((sized - expected).abs() < 1e-6, "{sized} s against {expected} s");
    assert!(none.is_none());
    assert!(eased.joint_max_deg < 15.0, "{eased:?}");
    assert!(abrupt.joint_max_deg > 45.0, "{abrupt:?}");
    assert!(
        eased.samples + (sized * 120.0) as u64 >= abrupt.samples,
        "the move is left out"
    );
}

/// A host that stalls past the servos' Bus Watchdog finds them stopped, refusing goals (a Sync
/// Write gets no status to say so). The loop notices before its next write, holds them where
/// they stand, clears and re-arms the watchdog, and eases back to the clip — no jump, and the
/// walk followed again. A stall under half the watchdog costs no check; one past half checks
/// and finds none expired.
#[test]
fn the_loop_recovers_servos_its_stall_let_the_watchdog_stop() {
    let mut fidelity_rms = Vec::new();
    // The stall's length, the tick after which it comes (`None`: between start-up, which armed
    // the watchdog, and the first tick), the checks (the first tick's included) and expiries.
    let cases = [
        (0, Some(160), 1, 0),
        (40, Some(160), 1, 0),
        (70, Some(160), 2, 0),
        (250, Some(160), 2, 1),
        (250, None, 1, 1),
    ];
    for (stall_ms, stall_after, checks, expiries) in cases {
        let s = setup();
        let watchdog_ms = s.profile.bus.watchdog_ms;
        assert_eq!(watchdog_ms, 100);
        let config = LoopConfig {
            bus_watchdog_ms: watchdog_ms,
            ..config(120.0)
        };
        let (mut c, tx) = controller(&s, Solve::Frames, config, 4);
        let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, false);
        let mut buf = [0.0; MAX_CHANNELS];
        let n = s.skel.channel_count();
        let mut vr = s.vr.clone();
        let mut clock = vr.clone();
        let period = c.period_ns();
        let mut schedule = Schedule::new(clock.now_ns() + period, period);
        if stall_after.is_none() {
            let now = clock.now_ns();
            clock.wait_until(now + stall_ms * 1_000_000);
        }
        let servos = || s.vr.with(|t| t.chain().servos().to_vec());
        let mut seq = 0;
        let mut resumed = None;
        'run: loop {
            let tick = schedule.wait(&mut clock);
            // The clip goes on in the stall, as a real-time source does: the tick after it takes
            // the frame due then.
            for _ in 0..tick.skipped {
                if player.next_sample(&mut buf[..n]).is_none() {
                    break 'run;
                }
            }
            let Some(t) = player.next_sample(&mut buf[..n]) else {
                break;
            };
            seq += 1;
            tx.send_newest(Input::frame(seq, tick.deadline_ns, clock.now_ns(), &buf[..n], t))
                .unwrap();
            if tick.skipped > 0 {
                assert!(stall_ms > 0);
                let stopped = servos().iter().filter(|v| v.watchdog_expired()).count();
                assert_eq!(
                    stopped,
                    if expiries > 0 { s.rig.len() } else { 0 },
                    "{stall_ms} ms"
                );
            }
            assert_eq!(c.tick(&tick, &mut vr, &mut clock), None);
            if tick.skipped > 0 && expiries > 0 {
                // Held where they stopped, taking goals again, their watchdog armed.
                for v in servos() {
                    assert!(!v.watchdog_expired() && v.torque_on(), "servo {}", v.id());
                    assert!(
                        (v.goal_tick() - v.present_tick()).abs() <= 1,
                        "servo {} jumped",
                        v.id()
                    );
                    assert_eq!(
                        v.register(marionette::servo::addr::BUS_WATCHDOG, 1),
                        watchdog_ms / 20
                    );
                }
                resumed = Some(tick.index);
            }
            if stall_after == Some(tick.index) && stall_ms > 0 {
                // Mid-stride: the host goes quiet.
                let now = clock.now_ns();
                clock.wait_until(now + stall_ms * 1_000_000);
            }
        }
        let st = &c.stats;
        assert_eq!(
            (st.watchdog_checks, st.watchdog_expiries),
            (checks, expiries),
            "{stall_ms} ms stall"
        );
        assert_eq!(st.allocations_in_tick, None);
        if let Some(at) = resumed {
            // Eased back at a quarter of the servos' speed: longer than the stall itself.
            assert!(st.resumed_s > 0.25, "{} s", st.resumed_s);
            assert!(at < 200, "{at}");
        }
        // Following again: every servo's goal register is the last command sent.
        for (v, g) in servos().iter().zip(c.last_command()) {
            assert_eq!(v.goal_tick(), *g, "servo {} after a {stall_ms} ms stall", v.id());
        }
        let (checks, expiries, resumed_s) = (st.watchdog_checks, st.watchdog_expiries, st.resumed_s);
        let f = c.fidelity_report();
        println!(
            "{stall_ms} ms stall after tick {stall_after:?}: {} checks, {} expiries, resumed over {:.2} s, fidelity rms {:.3}° max {:.3}° over {} ticks",
            checks, expiries, resumed_s, f.joint_rms_deg, f.joint_max_deg, f.samples
        );
        fidelity_rms.push(f.joint_rms_deg);
    }
    // The stalled runs follow the walk about as well as the run without a stall (a stall short
    // of the watchdog ends in a catch-up at the servos' speed, which the fidelity counts).
    for (k, rms) in fidelity_rms.iter().enumerate() {
        assert!(*rms < fidelity_rms[0] * 2.5, "run {k}: {fidelity_rms:?}");
    }
}

/// The virtual rig as a bus whose host stalls inside one goal write, before it goes out; and
/// on which one servo's Bus Watchdog may read 0 whatever it holds.
struct StallingBus {
    inner: VirtualRig,
    writes: u64,
    stall_at_write: u64,
    stall_ns: u64,
    unarmed: Option<usize>,
}

impl StallingBus {
    /// Stalling `stall_ms` inside the `stall_at_write`th goal write.
    fn new(inner: VirtualRig, stall_at_write: u64, stall_ms: u64) -> StallingBus {
        StallingBus {
            inner,
            writes: 0,
            stall_at_write,
            stall_ns: stall_ms * 1_000_000,
            unarmed: None,
        }
    }
}

impl ServoBus for StallingBus {
    fn ping(&mut self, id: u8) -> Result<marionette::bus::PingInfo, marionette::bus::BusError> {
        self.inner.ping(id)
    }
    fn scan(&mut self) -> Result<Vec<marionette::bus::PingInfo>, marionette::bus::BusError> {
        self.inner.scan()
    }
    fn read(&mut self, id: u8, address: u16, out: &mut [u8]) -> Result<(), marionette::bus::BusError> {
        self.inner.read(id, address, out)
    }
    fn write(&mut self, id: u8, address: u16, data: &[u8]) -> Result<(), marionette::bus::BusError> {
        self.inner.write(id, address, data)
    }
    fn sync_write(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        data: &[u8],
    ) -> Result<(), marionette::bus::BusError> {
        self.inner.sync_write(address, len, ids, data)
    }
    fn sync_read(
        &mut self,
        address: u16,
        len: u16,
        ids: &[u8],
        out: &mut [u8],
    ) -> Result<(), marionette::bus::BusError> {
        self.inner.sync_read(address, len, ids, out)?;
        if let (marionette::servo::addr::BUS_WATCHDOG, Some(k)) = (address, self.unarmed) {
            out[k] = 0;
        }
        Ok(())
    }
    fn reboot(&mut self, id: u8) -> Result<(), marionette::bus::BusError> {
        self.inner.reboot(id)
    }
    fn write_goals(&mut self, ids: &[u8], ticks: &[i32]) -> Result<(), marionette::bus::BusError> {
        self.writes += 1;
        if self.writes == self.stall_at_write {
            let now = self.inner.now_ns();
            self.inner.wait_until(now + self.stall_ns);
        }
        self.inner.write_goals(ids, ticks)
    }
}

/// A stall inside a tick — after its watchdog check, before its write — in the ramp to rest:
/// the servos refuse that write and the next; the span between the ticks' transactions owes a
/// check, which recovers them, and the ramp ends at rest rather than limp where they stopped.
#[test]
fn the_ramp_to_rest_goes_on_after_a_stall_inside_a_tick() {
    let s = setup();
    let cfg = LoopConfig {
        stop: StopMode::Rest { ramp_s: 0.5 },
        max_ticks: Some(200),
        bus_watchdog_ms: s.profile.bus.watchdog_ms,
        ..config(120.0)
    };
    let mut clock = s.vr.clone();
    let (mut c, _tx, mut schedule) = queued_walk(&s, cfg);
    // The 200 ticks write once each; the ramp's third tick stalls.
    let mut bus = StallingBus::new(s.vr.clone(), 203, 250);
    let end = c.run(&mut schedule, &mut bus, &mut clock, &StopRequests::new());
    assert_eq!(end, RunEnd::Duration);
    assert!(bus.writes > 203, "{} writes", bus.writes);
    let rest: Vec<i32> = s.rig.servos.iter().map(ServoMap::rest_tick).collect();
    let servos = s.vr.with(|t| t.chain().servos().to_vec());
    for (v, r) in servos.iter().zip(&rest) {
        assert!(!v.torque_on(), "servo {}: torque off at the end", v.id());
        assert!(
            (v.goal_tick() - r).abs() <= 1,
            "servo {}: goal {}, rest {r}",
            v.id(),
            v.goal_tick()
        );
    }
    // The first tick's check, and the stall's.
    assert_eq!((c.stats.watchdog_checks, c.stats.watchdog_expiries), (2, 1));
    assert!(c.stats.longest_quiet_ms >= 250.0, "{}", c.stats.longest_quiet_ms);
    assert_eq!(
        c.stats.resumed_s, 0.0,
        "the ramp goes on; nothing eases back to the input"
    );
}

/// A servo whose Bus Watchdog reads back otherwise after it is armed again costs the loop a few
/// checks at the start and after each quiet spell, not one every tick; the run goes on.
#[test]
fn a_watchdog_that_will_not_arm_costs_a_few_checks() {
    let s = setup();
    let cfg = LoopConfig {
        max_ticks: Some(200),
        bus_watchdog_ms: s.profile.bus.watchdog_ms,
        ..config(120.0)
    };
    let mut clock = s.vr.clone();
    let (mut c, _tx, mut schedule) = queued_walk(&s, cfg);
    // 70 ms inside the 100th tick: short of the watchdog, past half of it.
    let mut bus = StallingBus {
        unarmed: Some(3),
        ..StallingBus::new(s.vr.clone(), 100, 70)
    };
    let end = c.run(&mut schedule, &mut bus, &mut clock, &StopRequests::new());
    assert_eq!(end, RunEnd::Duration);
    assert_eq!(c.stats.ticks, 200);
    // Three at the first tick, three after the stall.
    assert_eq!((c.stats.watchdog_checks, c.stats.watchdog_expiries), (6, 0));
    assert!(s
        .vr
        .with(|t| t.chain().servos().iter().all(|v| !v.watchdog_expired())));
}

/// A clock on the virtual rig whose `jump_at`th wait returns `jump_ns` late (the host stalled).
struct StallingClock {
    inner: VirtualRig,
    waits: u64,
    jump_at: u64,
    jump_ns: u64,
}

impl Clock for StallingClock {
    fn now_ns(&mut self) -> u64 {
        self.inner.now_ns()
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        self.waits += 1;
        let late = if self.waits == self.jump_at {
            self.jump_ns
        } else {
            0
        };
        self.inner.wait_until(deadline_ns + late);
    }
}

/// `identify` of the puppet's first servo on the virtual rig, ticks on `clock`, 120 Hz.
fn identify_first(
    s: &Setup,
    clock: &mut dyn Clock,
) -> Result<Vec<marionette::control::identify::ServoResponse>, marionette::control::identify::IdentifyError> {
    use marionette::control::identify::{identify, Excitation};
    let names: Vec<String> = s.profile.servos.iter().map(|v| v.name.clone()).collect();
    identify(
        &mut s.vr.clone(),
        clock,
        &s.rig,
        &s.profile.ids(),
        &names,
        &s.present,
        &[0],
        &Excitation::default(),
        120.0,
    )
}

/// `identify` pairs each goal with the read a tick later: a stall while a servo moves would
/// pair them a stall apart (and past the watchdog, stop the servos). It ends with an error
/// naming the servo and torque off, rather than a wrong lag.
#[test]
fn identify_stops_when_the_host_falls_behind() {
    use marionette::control::identify::IdentifyError;
    let s = setup();
    let mut clock = StallingClock {
        inner: s.vr.clone(),
        waits: 0,
        jump_at: 300,
        jump_ns: 150_000_000,
    };
    let e = identify_first(&s, &mut clock).unwrap_err();
    let IdentifyError::FellBehind { servo, skipped, .. } = &e else {
        panic!("{e}");
    };
    // Its 300th tick falls in its excitation (after a 60-tick move to the centre).
    assert_eq!(servo, &s.profile.servos[0].name, "{e}");
    assert!(*skipped >= 17, "{e}");
    println!("{e}");
    assert!(e.to_string().contains("ms) behind the 120 Hz schedule"), "{e}");
    assert!(s.vr.with(|t| t.chain().servos().iter().all(|v| !v.torque_on())));
}

/// A servo that shuts itself down while `identify` runs stops it at the next read, torque off,
/// naming the servo and its error: its record would show it limp.
#[test]
fn identify_stops_when_a_servo_shuts_itself_down() {
    use marionette::control::identify::IdentifyError;
    let s = setup();
    let ids = s.profile.ids();
    // Servo 3 (holding) overloads in servo 1's excitation.
    let mut clock = ShutdownClock {
        inner: s.vr.clone(),
        waits: 0,
        at: 200,
        id: ids[2],
        bits: 0x20,
    };
    let e = identify_first(&s, &mut clock).unwrap_err();
    let IdentifyError::HardwareError {
        servo,
        id,
        bits,
        during,
    } = &e
    else {
        panic!("{e}");
    };
    let names = &s.profile.servos;
    assert_eq!(
        (servo, *id, *bits, during),
        (&names[2].name, ids[2], 0x20, &names[0].name),
        "{e}"
    );
    assert!(e.to_string().contains("hardware error 0x20 (overload)"), "{e}");
    assert!(s.vr.with(|t| t.chain().servos().iter().all(|v| !v.torque_on())));
}

/// A clock on the virtual rig that raises `bits` in servo `id`'s Hardware Error Status (which
/// turns its torque off, as an overload shutdown does) before the tick after `at` waits.
struct ShutdownClock {
    inner: VirtualRig,
    waits: u64,
    at: u64,
    id: u8,
    bits: u8,
}

impl Clock for ShutdownClock {
    fn now_ns(&mut self) -> u64 {
        self.inner.now_ns()
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        self.waits += 1;
        if self.waits == self.at + 1 {
            let (id, bits) = (self.id, self.bits);
            self.inner
                .with(|t| t.chain_mut().servo_mut(id).unwrap().raise_hardware_error(bits));
        }
        self.inner.wait_until(deadline_ns);
    }
}

/// The walk at 120 Hz for up to `max_ticks` on the puppet, with the health watch when `watched`,
/// servo 4 shutting itself down (an overload) after tick 100: the run's end and its controller.
fn run_with_a_shutdown(pipelined: bool, watched: bool, max_ticks: u64) -> (Setup, Controller, RunEnd) {
    use marionette::control::health::HealthWatch;
    let s = setup();
    let cfg = LoopConfig {
        pipelined,
        max_ticks: Some(max_ticks),
        ..config(120.0)
    };
    let (mut c, tx) = controller(&s, Solve::Frames, cfg, 300);
    if watched {
        c.set_health(HealthWatch::of_profile(&s.profile, 120.0));
    }
    let mut player = ClipPlayer::new(Arc::clone(&s.skel), Arc::clone(&s.motion), 120.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = s.skel.channel_count();
    let period = c.period_ns();
    let mut schedule = Schedule::new(s.vr.clone().now_ns() + period, period);
    for k in 0..250 {
        let t = player.next_sample(&mut buf[..n]).unwrap();
        tx.send_newest(Input::frame(k, schedule.deadline(k), 0, &buf[..n], t))
            .unwrap();
    }
    let mut clock = ShutdownClock {
        inner: s.vr.clone(),
        waits: 0,
        at: 100,
        id: s.profile.servos[3].id,
        bits: 0x20,
    };
    let end = c.run(&mut schedule, &mut s.vr.clone(), &mut clock, &StopRequests::new());
    (s, c, end)
}

/// A servo that shuts itself down mid-run (an overload) ends the run within a few ticks, with
/// either kind of read: its replies' alert flag brings its Hardware Error Status read forward.
/// At its turn alone it would be found up to a round of reads later (28 servos: 5.6 s).
#[test]
fn a_servo_that_shuts_itself_down_ends_the_run_within_ticks() {
    for pipelined in [false, true] {
        let (s, c, end) = run_with_a_shutdown(pipelined, true, 1200);
        assert_eq!(end, RunEnd::Health, "pipelined {pipelined}");
        let ticks_after = c.stats.ticks - 100;
        assert!(
            (1..=3).contains(&ticks_after),
            "pipelined {pipelined}: ended {ticks_after} ticks after the shutdown"
        );
        let (id, name) = (s.profile.servos[3].id, &s.profile.servos[3].name);
        let health = c.stats.health.as_ref().unwrap();
        assert_eq!(
            health.stopped.as_deref(),
            Some(format!("id {id} {name}: hardware error 0x20 (overload)").as_str())
        );
        assert_eq!(health.alert_reads, 1, "pipelined {pipelined}");
        let off = s.vr.with(|t| t.chain().servos().iter().all(|v| !v.torque_on()));
        assert!(off, "pipelined {pipelined}: torque off at the end");
        assert!(c.stats.unwatched_alert.is_none());
    }
}

/// With the health watch off the run goes on, and its summary says which servo shut itself
/// down and when.
#[test]
fn a_shutdown_the_watch_does_not_see_is_in_the_summary() {
    let (s, c, end) = run_with_a_shutdown(true, false, 300);
    assert_eq!(end, RunEnd::Duration);
    let id = s.profile.servos[3].id;
    let alert = c.stats.unwatched_alert.unwrap();
    let (got, at_s) = (alert.id, alert.at_s);
    assert_eq!(got, id);
    // Seen at the first read after tick 100 (the pipelined read's replies come a tick later).
    assert!((0.84..0.86).contains(&at_s), "{at_s}");
    let summary = c.stats.to_string();
    assert!(
        summary.contains(&format!(
            "hardware alert  servo {id} reported a hardware error 0.8"
        )),
        "{summary}"
    );
}

//! Proof, with a counting global allocator, that the hot paths allocate nothing: forward
//! kinematics over a whole clip (frame conversion included) and the core ASF reader.

mod common;

use marionette::alloc_count::{allocations, Counting};
use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf};
use marionette::skeleton::MAX_CHANNELS;

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn counter_sees_allocations() {
    let before = allocations();
    let v = std::hint::black_box(vec![1u8; 64]);
    assert!(allocations() > before);
    drop(v);
}

#[test]
fn fk_of_whole_clips_allocates_nothing() {
    for (a, m) in [("16.asf", "16_15.amc"), ("01.asf", "01_01.amc")] {
        let file = asf::load(&common::data(a)).unwrap();
        let s = &file.skeleton;
        let motion = amc::load(s, &common::data(m)).unwrap();
        let mut channels = [0.0f32; MAX_CHANNELS];
        let mut pose = Pose::new();
        let mut checksum = 0.0f32;
        let before = allocations();
        for i in 0..motion.len() {
            motion.channels_into(s, i, &mut channels);
            forward_kinematics(s, &channels, &mut pose).unwrap();
            checksum += pose.tip[s.len() - 1].y;
        }
        let during = allocations() - before;
        assert_eq!(
            during,
            0,
            "{m}: {during} allocations over {} frames",
            motion.len()
        );
        assert!(std::hint::black_box(checksum).is_finite());
    }
}

#[test]
fn core_asf_reader_allocates_nothing() {
    let text = common::read("16.asf");
    let before = allocations();
    let parsed = marionette::asf::parse_asf(&text).map(|a| a.skeleton.len());
    let during = allocations() - before;
    assert_eq!(parsed, Ok(31));
    assert_eq!(during, 0);
}

/// One control cycle over the in-process virtual chain — rig mapping (with Euler
/// re-decomposition), command stage, Sync Write of goals, Sync Read of present positions,
/// servo dynamics — allocates nothing, for every frame of the 16_15 walk on the CMU puppet.
#[test]
fn rig_and_bus_cycle_allocates_nothing() {
    use marionette::bus::packet::PacketBus;
    use marionette::bus::virtual_chain::{chain_for, InProcess};
    use marionette::bus::{start_up, ServoBus};
    use marionette::command::CommandStage;
    use marionette::profile::Profile;
    use std::time::Duration;

    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let profile = Profile::load(&path).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let mut bus = PacketBus::new(
        InProcess::new(chain_for(profile.bus_section(), |_| 2048), profile.bus.baud),
        Duration::from_millis(2),
    );
    let present = start_up(&mut bus, profile.bus_section()).unwrap();
    let ids = profile.ids();
    let mut stage = CommandStage::new(rig.len());
    stage.start_from(&rig, &present);
    // Frames as radians, prepared outside the measured loop.
    let frames: Vec<Vec<f64>> = (0..motion.len())
        .map(|f| marionette::motion::frame_to_radians(&skel, motion.frame(f)))
        .collect();
    let mut angles = vec![0.0; rig.len()];
    let mut read = vec![0i32; rig.len()];
    let dt = 1.0 / 120.0;
    let before = allocations();
    for channels in &frames {
        rig.joint_angles(&skel, channels, &[], &mut angles);
        let (goals, _) = stage.command(&rig, &angles, dt).unwrap();
        bus.write_goals(&ids, goals).unwrap();
        bus.read_positions(&ids, &mut read).unwrap();
        bus.link_mut().advance(Duration::from_secs_f64(dt));
    }
    let allocated = allocations() - before;
    println!(
        "{} cycles of {} servos: {allocated} allocations",
        frames.len(),
        rig.len()
    );
    assert_eq!(allocated, 0);
    // And the servos did follow.
    assert!(bus
        .link()
        .chain()
        .servos()
        .iter()
        .all(|s| s.goal_writes() >= frames.len() as u32));
}

/// Every IK solve allocates nothing: the analytic limb (searched and fixed swivel, a stream with
/// warm start) and each numerical method with both Jacobians, on several constraints.
#[test]
fn ik_solves_allocate_nothing() {
    use glam::DVec3;
    use marionette::fk::{fk64, Pose64};
    use marionette::ik::{Limb, Swivel};
    use marionette::ik_numeric::{chain_mask, Constraint, JacobianKind, Method, Settings, Solver};
    let skel = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &common::data("16_15.amc")).unwrap();
    let frames: Vec<Vec<f64>> = (0..motion.len())
        .map(|f| marionette::motion::frame_to_radians(&skel, motion.frame(f)))
        .collect();
    let (u, l) = (skel.find("lhumerus").unwrap(), skel.find("lradius").unwrap());
    let (fu, fl) = (skel.find("rfemur").unwrap(), skel.find("rtibia").unwrap());
    let arm = Limb::new(&skel, u, l, None).unwrap();
    let mut arm_solver = Solver::new(&skel, &chain_mask(&skel, u, l), false);
    let mut both = [false; marionette::skeleton::MAX_BONES];
    for (i, b) in chain_mask(&skel, u, l)
        .iter()
        .zip(chain_mask(&skel, fu, fl))
        .enumerate()
    {
        both[i] = *b.0 || b.1;
    }
    let mut two_solver = Solver::new(&skel, &both, false);
    let mut pose = Pose64::default();
    let mut ch = frames[0].clone();
    let mut solved = 0usize;
    let before = allocations();
    let mut previous = None;
    for f in frames.iter().step_by(5) {
        fk64(&skel, f, &mut pose);
        let (hand, foot) = (pose.tip[l], pose.tip[fl]);
        let s = arm.solve(&skel, &mut ch, hand, Swivel::Auto { previous });
        previous = Some(s.swivel);
        let _ = arm.solve(&skel, &mut ch, hand + DVec3::X, Swivel::Fixed(0.5));
        solved += 2;
        for method in Method::ALL {
            for jacobian in [JacobianKind::Analytic, JacobianKind::FiniteDifference] {
                let settings = Settings {
                    method,
                    jacobian,
                    max_iterations: 30,
                    ..Settings::default()
                };
                let axes = Some((pose.frame[l].x_axis, pose.frame[l].y_axis));
                ch.copy_from_slice(&frames[0]);
                let _ = arm_solver.solve(
                    &skel,
                    &[Constraint {
                        bone: l,
                        position: hand,
                        axes,
                    }],
                    &mut ch,
                    &settings,
                );
                ch.copy_from_slice(&frames[0]);
                let goals = [
                    Constraint {
                        bone: l,
                        position: hand,
                        axes: None,
                    },
                    Constraint {
                        bone: fl,
                        position: foot,
                        axes: None,
                    },
                ];
                let _ = two_solver.solve(&skel, &goals, &mut ch, &settings);
                solved += 2;
            }
        }
    }
    let during = allocations() - before;
    assert_eq!(during, 0, "{during} allocations over {solved} solves");
    assert!(std::hint::black_box(ch).iter().all(|x| x.is_finite()));
}

/// Whole control-loop ticks allocate nothing, and neither do their rehearsed solves: AMC
/// playback and IK following (four limbs), with telemetry, with and without the look-ahead (inputs taken ahead into its preview and
/// planned), over the virtual chain — counted inside the tick by the controller itself.
#[test]
fn control_loop_ticks_allocate_nothing() {
    use marionette::bus::start_up;
    use marionette::bus::virtual_chain::{chain_for, VirtualRig};
    use marionette::control::input::{input_channel, Input, Payload};
    use marionette::control::sources::{clip_track, ClipPlayer, TrackFrame};
    use marionette::control::{Controller, Follower, LoopConfig, Solve, StopMode};
    use marionette::profile::Profile;
    use marionette::schedule::{Clock, Schedule};
    use std::sync::Arc;
    use std::time::Duration;

    let skel = Arc::new(asf::load(&common::data("16.asf")).unwrap().skeleton);
    let motion = Arc::new(amc::load(&skel, &common::data("16_15.amc")).unwrap());
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml");
    let profile = Profile::load(&path).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let names: Vec<String> = ["lradius", "rradius", "ltibia", "rtibia"]
        .iter()
        .map(|s| (*s).to_string())
        .collect();
    let track = clip_track(&skel, &motion, &names, TrackFrame::Limb).unwrap();
    for (follow, lookahead) in [(false, false), (true, false), (false, true), (true, true)] {
        let mut vr = VirtualRig::new(
            chain_for(profile.bus_section(), |_| 2048),
            profile.bus.baud,
            Duration::from_millis(2),
        );
        let present = start_up(&mut vr, profile.bus_section()).unwrap();
        let (tx, port) = input_channel(4);
        let solve = if follow {
            Solve::Follow(Box::new(Follower::new(&skel, &names).unwrap()))
        } else {
            Solve::Frames
        };
        let config = LoopConfig {
            rate_hz: 240.0,
            stop: StopMode::Hold { hold_s: 0.0 },
            allocations: Some(allocations),
            // The real-time runs' worker (a record handed over each tick) and the lockstep
            // runs' accumulation in the tick.
            fidelity_worker: follow,
            // The host stalls once past it (below): the recovery runs in a tick too.
            bus_watchdog_ms: profile.bus.watchdog_ms,
            ..LoopConfig::default()
        };
        let mut c = Controller::new(
            Arc::clone(&skel),
            rig.clone(),
            profile.ids(),
            &present,
            port,
            solve,
            config,
        );
        let (ttx, trx) = crossbeam_channel::bounded(8);
        c.add_telemetry(ttx).unwrap();
        // A second consumer (the ROS 2 publisher's place), never drained: a full channel costs
        // the tick a dropped record, not an allocation.
        let (rtx, _rrx) = crossbeam_channel::bounded(16);
        c.add_telemetry(rtx).unwrap();
        // The studio's live view: updated every tick, skipped while a reader holds it.
        let live = Arc::new(marionette::control::live::LiveView::default());
        c.set_live_view(Arc::clone(&live));
        let mut carried = 0;
        let mut cursor = 0;
        if lookahead {
            use marionette::control::lookahead::{Lookahead, LookaheadSettings};
            let leads = vec![0.02; rig.len()];
            c.set_lookahead(Lookahead::new(&rig, 240.0, &leads, LookaheadSettings::default()));
        }
        // Inputs are made as far ahead as the loop takes them.
        let ahead = c.preview_ns();
        let mut player = ClipPlayer::new(Arc::clone(&skel), Arc::clone(&motion), 240.0, false);
        let mut buf = [0.0; MAX_CHANNELS];
        let n = skel.channel_count();
        let mut clock = vr.clone();
        let period = c.period_ns();
        let mut schedule = Schedule::new(clock.now_ns() + period, period);
        let mut ticks = 0;
        for k in 0..(2 * motion.len() as u64) {
            let msg = if follow {
                track.samples.get(k as usize / 2).map(|(_, t)| Input {
                    seq: k,
                    due_ns: schedule.deadline(k) + ahead,
                    made_ns: k + 1,
                    payload: Payload::Targets(t.clone()),
                })
            } else {
                player
                    .next_sample(&mut buf[..n])
                    .map(|t| Input::frame(k, schedule.deadline(k) + ahead, k + 1, &buf[..n], t))
            };
            let Some(msg) = msg else { break };
            tx.send_newest(msg).unwrap();
            // As a real-time run does before each deadline.
            c.rehearse(schedule.next_deadline());
            let tick = schedule.wait(&mut clock);
            if k % 13 == 0 {
                let held = live.read();
                c.tick(&tick, &mut vr, &mut clock);
                drop(held);
            } else {
                c.tick(&tick, &mut vr, &mut clock);
            }
            ticks += 1;
            if k == 500 {
                // The host stalls for 250 ms: every servo's 100 ms watchdog expires.
                let now = clock.now_ns();
                clock.wait_until(now + 250_000_000);
            }
            cursor = live.read().carried_since(cursor, |_| carried += 1);
            // The consumer keeps up with some of the records only: drops are counted, not waited for.
            if k % 20 == 0 {
                while trx.try_recv().is_ok() {}
            }
        }
        let st = &c.stats;
        println!(
            "{} ticks ({}): {:?} allocations in ticks, {} telemetry records dropped",
            ticks,
            match (follow, lookahead) {
                (true, false) => "follow, 4 limbs",
                (false, false) => "play",
                (true, true) => "follow, 4 limbs, look-ahead",
                (false, true) => "play, look-ahead",
            },
            st.allocations_in_tick,
            st.telemetry_dropped
        );
        assert!(ticks > 900);
        assert_eq!(st.commands_sent, ticks);
        assert!(st.inputs_used > ticks / 3, "{} inputs used", st.inputs_used);
        assert_eq!(st.allocations_in_tick, Some(0));
        assert_eq!(st.watchdog_expiries, 1, "the stall's expiry found and recovered");
        assert!(st.telemetry_dropped > 0, "the full-channel path was taken");
        let view = live.read();
        assert!(
            view.ticks > 0 && view.ticks < ticks,
            "updated, and skipped while held"
        );
        assert!(view.goal_rad[..view.len].iter().all(|g| g.is_finite()));
        assert!(carried > ticks / 4, "{carried} inputs carried to the bus");
        if follow {
            assert_eq!(st.unreachable, 0);
        }
        let fidelity = c.fidelity_report();
        assert!(
            fidelity.samples + fidelity.records_dropped > ticks / 2,
            "{} ticks compared, {} dropped",
            fidelity.samples,
            fidelity.records_dropped
        );
    }
}

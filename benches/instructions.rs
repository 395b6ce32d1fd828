//! Instruction counts of the hot paths (Callgrind, through gungraun) on fixed inputs: the same
//! count on every machine, so CI can notice a change that makes them slower. `k` 0.32 runs on
//! the same inputs in the same run, so the ratios against it are instruction ratios.
//!
//! ```text
//! cargo bench --bench instructions        # needs valgrind and gungraun-runner (scripts/bench-gate)
//! ```
//!
//! `scripts/bench-gate` runs this and compares every benchmark's instructions with
//! `benches/instructions-baseline.json`.
//!
//! The groups: `fk` (the 31-bone skeleton in f32 and f64, and `k`'s), `ik` (limb IK with the
//! swivel search on arm and leg targets, `k`'s on the same, the windowed stream solve),
//! `command` (the look-ahead planner, a Sync Write encoded), `retargeting` (the OP3, whole and
//! upper body) and `tick` (whole control-loop ticks of `play` and `follow`, with and without the
//! look-ahead, and of the OP3 walking with its IMU fed back).
//!
//! Each benchmark does a fixed batch of work (16 frames, 100 targets, …) prepared outside the
//! measured function, its input boxed so that passing it in and out copies nothing; nothing inside it reads a file or a clock (the control ticks read a
//! stepped clock, and accumulate the fidelity in the tick as a lockstep run does: no second
//! thread).

use std::hint::black_box;
use std::path::{Path, PathBuf};

use glam::DVec3;
use gungraun::{library_benchmark, library_benchmark_group, main};
use k::nalgebra::Isometry3;
use marionette::bus::faults::Rng;
use marionette::command::CommandStage;
use marionette::control::input::Input;
use marionette::control::lookahead::{Lookahead, Preview};
use marionette::fk::{fk64, forward_kinematics, Pose, Pose64};
use marionette::formats::{amc, asf};
use marionette::ik::{Limb, Swivel};
use marionette::motion::frame_to_radians;
use marionette::profile::Profile;
use marionette::protocol::{encode, instruction, BROADCAST_ID};
use marionette::retarget::{floor_of_clip, Options, RetargetFrame, Retargeter, Setup};
use marionette::rig::Rig;
use marionette::skeleton::{Skeleton, MAX_CHANNELS};
use std::sync::Arc;
use tick_support::{Kind, TickBench};

#[path = "support/k_model.rs"]
mod k_model;
#[path = "support/planner.rs"]
mod planner;
#[path = "support/tick.rs"]
mod tick_support;

fn path(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn walk_skeleton() -> Skeleton {
    asf::load(&path("data/cmu/16.asf")).unwrap().skeleton
}

/// Frames 100, 120, … of the bundled walk, as f64 radians.
fn walk_frames(skel: &Skeleton, n: usize) -> Vec<Vec<f64>> {
    let motion = amc::load(skel, &path("data/cmu/16_15.amc")).unwrap();
    (0..n)
        .map(|k| frame_to_radians(skel, motion.frame(100 + 20 * k)))
        .collect()
}

// --- Forward kinematics of the 31-bone skeleton, 16 frames ---------------------------------

struct FkInput {
    skel: Skeleton,
    frames32: Vec<[f32; MAX_CHANNELS]>,
    frames64: Vec<Vec<f64>>,
    pose: Box<Pose>,
    pose64: Box<Pose64>,
}

fn fk_input_value() -> FkInput {
    let skel = walk_skeleton();
    let frames64 = walk_frames(&skel, 16);
    let frames32 = frames64
        .iter()
        .map(|f| {
            let mut c = [0.0f32; MAX_CHANNELS];
            for (a, b) in c.iter_mut().zip(f) {
                *a = *b as f32;
            }
            c
        })
        .collect();
    FkInput {
        skel,
        frames32,
        frames64,
        pose: Box::new(Pose::new()),
        pose64: Box::default(),
    }
}

#[library_benchmark]
#[bench::walk_16_frames(setup = fk_input)]
fn fk_f32(mut input: Box<FkInput>) -> Box<FkInput> {
    for f in &input.frames32 {
        forward_kinematics(&input.skel, black_box(f), &mut input.pose).unwrap();
    }
    input
}

#[library_benchmark]
#[bench::walk_16_frames(setup = fk_input)]
fn fk_f64(mut input: Box<FkInput>) -> Box<FkInput> {
    for f in &input.frames64 {
        fk64(&input.skel, black_box(f), &mut input.pose64);
    }
    input
}

struct KFkInput {
    chain: k::Chain<f64>,
    positions: Vec<Vec<f64>>,
}

/// The walk's 16 frames as `k`'s joint positions, the chain checked against `fk64`.
fn k_fk_input_value() -> KFkInput {
    let skel = walk_skeleton();
    let frames = walk_frames(&skel, 16);
    let (chain, channels, tips) = k_model::skeleton_chain(&skel);
    let positions: Vec<Vec<f64>> = frames
        .iter()
        .map(|f| channels.iter().map(|&c| f[c]).collect())
        .collect();
    let mut pose = Pose64::default();
    fk64(&skel, &frames[0], &mut pose);
    chain.set_joint_positions_unchecked(&positions[0]);
    chain.update_transforms();
    for (b, name) in tips.iter().enumerate() {
        let t = chain
            .find(name)
            .unwrap()
            .world_transform()
            .unwrap()
            .translation
            .vector;
        let d = (DVec3::new(t.x, t.y, t.z) - pose.tip[b]).length();
        assert!(d < 1e-9, "k's tip of bone {b} is {d} from fk64's");
    }
    KFkInput { chain, positions }
}

#[library_benchmark]
#[bench::walk_16_frames(setup = k_fk_input)]
fn fk_k(input: Box<KFkInput>) -> Box<KFkInput> {
    for q in &input.positions {
        input.chain.set_joint_positions_unchecked(black_box(q));
        black_box(input.chain.update_transforms());
    }
    input
}

library_benchmark_group!(name = fk; benchmarks = fk_f32, fk_f64, fk_k);

// --- Limb IK on 100 reachable targets, against k -------------------------------------------

struct LimbInput {
    skel: Skeleton,
    limb: Limb,
    bones: [usize; 2],
    targets: Vec<DVec3>,
    channels: Vec<f64>,
}

/// 100 targets as `ik_compare` makes them (FK of random angles inside the ASF limits).
fn limb_input(upper: &str, lower: &str, seed: u64) -> LimbInput {
    let skel = walk_skeleton();
    let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
    let limb = Limb::new(&skel, u, l, None).unwrap();
    let mut rng = Rng::new(seed);
    let mut pose = Pose64::default();
    let targets = (0..100)
        .map(|_| {
            let mut ch = vec![0.0; skel.channel_count()];
            for b in [u, l] {
                let bone = &skel.bones()[b];
                for (kk, d) in bone.dofs().iter().enumerate() {
                    if d.is_rotation() {
                        let lim = bone.limits()[kk];
                        let t = (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
                        ch[bone.first_channel() + kk] = f64::from(lim.min) + t * f64::from(lim.max - lim.min);
                    }
                }
            }
            fk64(&skel, &ch, &mut pose);
            pose.tip[l]
        })
        .collect();
    let channels = vec![0.0; skel.channel_count()];
    LimbInput {
        skel,
        limb,
        bones: [u, l],
        targets,
        channels,
    }
}

fn arm_input_value() -> LimbInput {
    limb_input("lhumerus", "lradius", 2026)
}

fn leg_input_value() -> LimbInput {
    limb_input("lfemur", "ltibia", 2027)
}

#[library_benchmark]
#[bench::arm_100_targets(setup = arm_input)]
#[bench::leg_100_targets(setup = leg_input)]
fn limb_ik(mut input: Box<LimbInput>) -> Box<LimbInput> {
    for t in &input.targets {
        input.channels.iter_mut().for_each(|x| *x = 0.0);
        black_box(input.limb.solve(
            &input.skel,
            &mut input.channels,
            black_box(*t),
            Swivel::Auto { previous: None },
        ));
    }
    input
}

struct KLimbInput {
    chain: k::SerialChain<f64>,
    solver: k::JacobianIkSolver<f64>,
    goals: Vec<Isometry3<f64>>,
    rest: Vec<f64>,
}

fn k_limb_input(input: &LimbInput) -> KLimbInput {
    let (chain, _) = k_model::limb_chain(&input.skel, input.bones[0], input.bones[1]);
    let rest = vec![0.0; chain.dof()];
    KLimbInput {
        solver: k::JacobianIkSolver::new(1e-3, 0.005, 0.5, 100),
        goals: input
            .targets
            .iter()
            .map(|t| Isometry3::translation(t.x, t.y, t.z))
            .collect(),
        chain,
        rest,
    }
}

fn k_arm_input_value() -> KLimbInput {
    k_limb_input(&arm_input())
}

fn k_leg_input_value() -> KLimbInput {
    k_limb_input(&leg_input())
}

#[library_benchmark]
#[bench::arm_100_targets(setup = k_arm_input)]
#[bench::leg_100_targets(setup = k_leg_input)]
fn limb_ik_k(input: Box<KLimbInput>) -> Box<KLimbInput> {
    let position_only = k::Constraints {
        rotation_x: false,
        rotation_y: false,
        rotation_z: false,
        ..k::Constraints::default()
    };
    for g in &input.goals {
        input.chain.set_joint_positions_clamped(&input.rest);
        let _ = k::InverseKinematicsSolver::solve_with_constraints(
            &input.solver,
            &input.chain,
            black_box(g),
            &position_only,
        );
    }
    input
}

struct StreamInput {
    skel: Skeleton,
    limb: Limb,
    path: Vec<(Vec<f64>, DVec3)>,
    frame: Vec<f64>,
    previous: f64,
}

/// 100 frames of the walk's left wrist path, the swivel searched within 40° of the last one as
/// the loop does; the first solve (the whole circle) is made in the setup.
fn stream_input_value() -> StreamInput {
    let skel = walk_skeleton();
    let (u, l) = (skel.find("lhumerus").unwrap(), skel.find("lradius").unwrap());
    let limb = Limb::new(&skel, u, l, None).unwrap();
    let motion = amc::load(&skel, &path("data/cmu/16_15.amc")).unwrap();
    let mut pose = Pose64::default();
    let path: Vec<(Vec<f64>, DVec3)> = (100..201)
        .map(|f| {
            let frame = frame_to_radians(&skel, motion.frame(f));
            fk64(&skel, &frame, &mut pose);
            (frame, pose.tip[l])
        })
        .collect();
    let mut frame = path[0].0.clone();
    let previous = limb
        .solve(&skel, &mut frame, path[0].1, Swivel::Auto { previous: None })
        .swivel;
    StreamInput {
        skel,
        limb,
        path,
        frame,
        previous,
    }
}

#[library_benchmark]
#[bench::walk_wrist_100_frames(setup = stream_input)]
fn windowed_stream(mut input: Box<StreamInput>) -> Box<StreamInput> {
    for (frame, target) in &input.path[1..] {
        input.frame.copy_from_slice(frame);
        let s = input.limb.solve(
            &input.skel,
            &mut input.frame,
            black_box(*target),
            Swivel::Track {
                previous: input.previous,
                window: 40f64.to_radians(),
            },
        );
        input.previous = s.swivel;
    }
    input
}

library_benchmark_group!(name = ik; benchmarks = limb_ik, limb_ik_k, windowed_stream);

// --- The command side: the planner and the Sync Write --------------------------------------

struct PlanInput {
    rig: Rig,
    look: Lookahead,
    stage: CommandStage,
    preview: Preview,
}

/// The CMU puppet's 28 servos following the walk at 500 Hz, a full preview ahead.
fn plan_input_value() -> PlanInput {
    let skel = Arc::new(walk_skeleton());
    let motion = Arc::new(amc::load(&skel, &path("data/cmu/16_15.amc")).unwrap());
    let profile = Profile::load(&path("firmware-profile/cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let (look, stage, preview) = planner::walk_planner(&skel, &motion, &profile, &rig);
    PlanInput {
        rig,
        look,
        stage,
        preview,
    }
}

#[library_benchmark]
#[bench::puppet_28_servos_10_ticks(setup = plan_input)]
fn plan(mut input: Box<PlanInput>) -> Box<PlanInput> {
    for tick in 1..=10u64 {
        let targets = input.look.targets(
            &input.rig,
            &input.stage,
            &input.preview,
            2_000_000 * tick,
            0.002,
            None,
        );
        let _ = input.stage.command_planned(&input.rig, black_box(targets), 0.002);
    }
    input
}

struct SyncWriteInput {
    params: Vec<u8>,
    packet: Vec<u8>,
}

/// The parameters of a Sync Write of 28 servos' Goal Position (116, 4 bytes each).
fn sync_write_input_value() -> SyncWriteInput {
    let mut params = vec![116, 0, 4, 0];
    for id in 1..=28u8 {
        params.push(id);
        params.extend_from_slice(&(2048 + 37 * i32::from(id)).to_le_bytes());
    }
    SyncWriteInput {
        params,
        packet: vec![0; 1024],
    }
}

#[library_benchmark]
#[bench::goal_positions_28_servos(setup = sync_write_input)]
fn sync_write(mut input: Box<SyncWriteInput>) -> Box<SyncWriteInput> {
    black_box(
        encode(
            BROADCAST_ID,
            instruction::SYNC_WRITE,
            black_box(&input.params),
            &mut input.packet,
        )
        .unwrap(),
    );
    input
}

library_benchmark_group!(name = command; benchmarks = plan, sync_write);

// --- Retargeting onto the OP3 ----------------------------------------------------------------

struct RetargetInput {
    setup: Setup,
    retargeter: Retargeter,
    poses: Vec<Pose64>,
    out: RetargetFrame,
}

/// 16 frames of the walk (from frame 200) after the retargeter has followed frames 0…199.
fn retarget_input(upper_body: bool) -> RetargetInput {
    let profile = Profile::load(&path("firmware-profile/robotis-op3.toml")).unwrap();
    let skel = walk_skeleton();
    let motion = amc::load(&skel, &path("data/cmu/16_15.amc")).unwrap();
    let setup = Setup::new(&profile, &skel).unwrap();
    let options = Options {
        upper_body,
        ..Options::default()
    };
    let mut retargeter = setup.retargeter(&skel, floor_of_clip(&skel, &motion, &setup.map.human), options);
    let mut pose = Pose64::default();
    let mut out = RetargetFrame::default();
    for f in 0..200 {
        fk64(&skel, &frame_to_radians(&skel, motion.frame(f)), &mut pose);
        retargeter.step(&setup.robot, &pose, 1.0 / 120.0, &mut out);
    }
    let poses = (200..216)
        .map(|f| {
            let mut p = Pose64::default();
            fk64(&skel, &frame_to_radians(&skel, motion.frame(f)), &mut p);
            p
        })
        .collect();
    RetargetInput {
        setup,
        retargeter,
        poses,
        out,
    }
}

fn whole_body_value() -> RetargetInput {
    retarget_input(false)
}

fn upper_body_value() -> RetargetInput {
    retarget_input(true)
}

#[library_benchmark]
#[bench::whole_body_16_frames(setup = whole_body)]
#[bench::upper_body_16_frames(setup = upper_body)]
fn retarget(mut input: Box<RetargetInput>) -> Box<RetargetInput> {
    for p in &input.poses {
        input
            .retargeter
            .step(&input.setup.robot, black_box(p), 1.0 / 120.0, &mut input.out);
    }
    input
}

library_benchmark_group!(name = retargeting; benchmarks = retarget);

// --- The control loop's tick -----------------------------------------------------------------

struct TickInput {
    bench: TickBench,
    inputs: Vec<Input>,
}

/// A tick after 300 ticks of the walk (the look-ahead's preview full, the swivel windows and
/// the command stage under way), and the next 10 ticks' inputs: the puppet at 500 Hz, the OP3
/// walking on its plan at 125 Hz.
fn tick_input(kind: Kind, lookahead: bool) -> TickInput {
    let mut bench = TickBench::new(kind, lookahead, false);
    let warm = bench.take_inputs(300);
    bench.run_stepped(warm);
    assert!(bench.bus.bytes > 0, "the ticks wrote goals");
    if let Kind::Op3Walk = kind {
        let imu = bench.controller.imu_report().expect("the OP3 walk reads its IMU");
        assert!(imu.reads_ok >= 299 && imu.reads_failed == 0, "{imu:?}");
        assert!(imu.max_rate_dps > 0.0, "{imu:?}");
    }
    let inputs = bench.take_inputs(10);
    TickInput { bench, inputs }
}

fn play_input_value() -> TickInput {
    tick_input(Kind::Play, false)
}
fn play_lookahead_input_value() -> TickInput {
    tick_input(Kind::Play, true)
}
fn follow_input_value() -> TickInput {
    tick_input(Kind::Follow, false)
}
fn follow_lookahead_input_value() -> TickInput {
    tick_input(Kind::Follow, true)
}
fn op3_walk_input_value() -> TickInput {
    tick_input(Kind::Op3Walk, false)
}

#[library_benchmark]
#[bench::play_10_ticks(setup = play_input)]
#[bench::play_lookahead_10_ticks(setup = play_lookahead_input)]
#[bench::follow_4_limbs_10_ticks(setup = follow_input)]
#[bench::follow_4_limbs_lookahead_10_ticks(setup = follow_lookahead_input)]
#[bench::op3_walk_imu_feedback_10_ticks(setup = op3_walk_input)]
fn control_tick(mut input: Box<TickInput>) -> Box<TickInput> {
    let inputs = std::mem::take(&mut input.inputs);
    input.bench.run_stepped(black_box(inputs));
    input
}

library_benchmark_group!(name = tick; benchmarks = control_tick);

// Each benchmark's input is boxed: moving it in and out of the measured function then costs
// a pointer, not a copy of the skeleton or the controller.
fn arm_input() -> Box<LimbInput> {
    Box::new(arm_input_value())
}
fn fk_input() -> Box<FkInput> {
    Box::new(fk_input_value())
}
fn follow_input() -> Box<TickInput> {
    Box::new(follow_input_value())
}
fn follow_lookahead_input() -> Box<TickInput> {
    Box::new(follow_lookahead_input_value())
}
fn k_arm_input() -> Box<KLimbInput> {
    Box::new(k_arm_input_value())
}
fn k_fk_input() -> Box<KFkInput> {
    Box::new(k_fk_input_value())
}
fn k_leg_input() -> Box<KLimbInput> {
    Box::new(k_leg_input_value())
}
fn leg_input() -> Box<LimbInput> {
    Box::new(leg_input_value())
}
fn op3_walk_input() -> Box<TickInput> {
    Box::new(op3_walk_input_value())
}
fn plan_input() -> Box<PlanInput> {
    Box::new(plan_input_value())
}
fn play_input() -> Box<TickInput> {
    Box::new(play_input_value())
}
fn play_lookahead_input() -> Box<TickInput> {
    Box::new(play_lookahead_input_value())
}
fn stream_input() -> Box<StreamInput> {
    Box::new(stream_input_value())
}
fn sync_write_input() -> Box<SyncWriteInput> {
    Box::new(sync_write_input_value())
}
fn upper_body() -> Box<RetargetInput> {
    Box::new(upper_body_value())
}
fn whole_body() -> Box<RetargetInput> {
    Box::new(whole_body_value())
}

main!(library_benchmark_groups = fk, ik, command, retargeting, tick);

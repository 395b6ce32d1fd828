//! marionette: drive servo rigs from motion capture.
//!
//! This crate is the std edge over the `no_std` core, `marionette-core` (folder `core/`), whose
//! modules it re-exports under the same names ([`math`], [`skeleton`], [`asf`], [`fk`],
//! [`interp`], [`robot`], [`ik`], [`ik_numeric`], [`servo`], [`rig`], [`command`], [`protocol`],
//! [`device`], [`schedule`]). The edge adds files, buses, threads, pictures and the command
//! line; its modules depend on the core and on those above them in this list:
//!
//! * [`alloc_count`] — the counting global allocator (`allocations_in_tick`, allocation tests).
//! * [`clock`] — the machine's clock for the core's schedule.
//! * [`rt`] — real-time settings of a thread (`SCHED_FIFO`, CPU affinity, `mlockall`), for the
//!   loop and for the virtual chain's thread; its stack made resident, its page faults counted.
//! * [`resident`] — storage that a loop writes, every page written before the loop starts.
//! * [`motion`] — a clip of frames (values as files hold them), its frame vectors, editing
//!   (matching, connecting, blending, seams).
//! * [`formats`] — file loading with `file:line:column` errors, AMC read/write, ASF write,
//!   BVH import/export.
//! * [`profile`] — rig profiles (TOML) into a core [`rig::Rig`]; [`budget`] — bus time per cycle.
//! * [`retarget`] — the core's retargeting with a profile's map resolved against the robot's
//!   model and a skeleton, the floor from a clip, whole clips and their report.
//! * [`bus`] — servo buses (serial through `dynamixel2`, the virtual chain on a pseudo-terminal,
//!   fault injection).
//! * [`control`] — the fixed-rate loop, its inputs, statistics and fault policy.
//! * [`signals`] — termination signals as the loop's stop requests.
//! * `ros2` — ROS 2 over DDS: `/joint_states` out, effector targets in (the `ros2` feature).
//! * [`sim`] — MuJoCo models of rigs and simulated servos (the simulator itself needs the
//!   `sim` feature).
//! * [`plot`] — pictures (SVG or PNG by the file's extension).
//! * [`cli`] — the `marionette` command.
#![deny(unsafe_code)]
#![warn(missing_docs)]

// The std edge works in f64; the core's `f32` feature is for firmware images built on their own.
const _: () = assert!(
    !marionette_core::math::SINGLE_PRECISION,
    "marionette needs marionette-core in f64: its `f32` feature is for firmware images"
);

pub use marionette_core::{
    asf, command, control_table, device, fk, footstep, ik, ik_numeric, interp, math, plan, preview, protocol,
    rig, robot, schedule, sensor_board, servo, skeleton, swivel,
};

pub mod alloc_count;

pub mod clock;

pub mod rt;

pub mod resident;

pub mod motion;

pub mod formats;

pub mod profile;

pub mod servo_dynamics;

pub mod budget;

pub mod doctor;

pub mod calibrate;

pub mod retarget;

pub mod bus;

pub mod control;

pub mod signals;

#[cfg(feature = "ros2")]
pub mod ros2;

pub mod sim;

pub mod plot;

pub mod studio;

pub mod session;

pub mod cli;

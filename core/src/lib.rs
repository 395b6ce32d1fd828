//! marionette's core: everything a control tick needs, `no_std`, without a heap.
//!
//! Equation numbers ("eq. 16") are those of *the help note*: Steve Lin, "Help note for
//! assignment 2" (ASF/AMC, motion editing and inverse kinematics), April 2010; the numerical
//! solvers follow the IK assignment that goes with it (`docs/references.md` lists both).
//!
//! Modules are layers, listed here from the bottom up; each imports only modules above it in
//! this list (checked by `tests/layers.rs`):
//!
//! * [`math`] — axes, the 12 Euler orders, Euler angles near a reference, angle wrapping,
//!   quaternion distance (help note eq. 27–28).
//! * [`skeleton`] — fixed-capacity bones, channel layout, limits, a bone's channel rotation
//!   `M` (eq. 2).
//! * [`asf`] — the ASF text reader: text to skeleton, without allocation (file loading with
//!   paths lives in the std edge, `marionette::formats`).
//! * [`fk`] — forward kinematics, eq. (1)–(5): f32 into a [`fk::Pose`], f64 into a
//!   [`fk::Pose64`].
//! * [`interp`] — per-frame editing maths in f64: facing (eq. 6–7), SLERP (eq. 12), ease
//!   weights (eq. 13), frame interpolation.
//! * [`preview`] — the centre of mass from Kajita's ZMP preview control on the cart-table
//!   model: the gains designed once, a step without allocation.
//! * [`footstep`] — the robot's footsteps from a retargeted clip (the clip's steps relative to
//!   the stance foot, flights and steps beyond reach or speed substituted) and the ZMP
//!   reference they give.
//! * [`robot`] — a robot's own kinematic tree (bodies, hinges, masses, as its MJCF model
//!   says), its forward kinematics and centre of mass.
//! * [`swivel`] — the swivel circle in closed form: legal arcs from the Euler limits, eq. 30's
//!   global minimum over them.
//! * [`ik`] — the analytic limb solver with swivel search (help note §IV) and closed-form
//!   pointing; [`ik_numeric`] — CCD, Jacobian transpose, pseudoinverse, DLS, conjugate gradient.
//! * [`retarget`] — a human pose onto a robot of other proportions: arm directions, legs to
//!   the feet in closed form, head, planted feet, balance over the support polygon.
//! * [`servo`] — X-series servo models, control-table addresses, the velocity- and
//!   acceleration-limited step, [`servo::MAX_SERVOS`]; [`control_table`] — each model's
//!   control table item by item (factory values, ranges, access).
//! * [`plan`] — look-ahead: one servo's least-deviation goal path over a preview window
//!   within its velocity and acceleration limits (ADMM on a banded system).
//! * [`rig`] — joint sources and angle ↔ tick mapping, Euler re-decomposition.
//! * [`command`] — the command stage: finite check, position, velocity and acceleration limits.
//! * [`protocol`] — Dynamixel Protocol 2.0 packets: CRC-16, byte stuffing, encode/decode.
//! * [`sensor_board`] — a humanoid's sensor board on the servos' bus (the OP3's OpenCR: IMU,
//!   buttons, voltage), its control table and the IMU's scales.
//! * [`device`] — the device side of Protocol 2.0: a chain of virtual servos (and a sensor
//!   board).
//! * [`schedule`] — the absolute-deadline fixed-rate schedule over a [`schedule::Clock`] that
//!   the caller supplies (time is an argument; the std edge has the system clock).
//!
//! Maths uses `glam` with `libm` (bit-identical across platforms); capacities are named
//! constants ([`skeleton::MAX_BONES`], [`servo::MAX_SERVOS`]) and `heapless` containers; a full
//! container is an error, never a panic.
#![no_std]
#![deny(unsafe_code)]
#![warn(missing_docs)]

#[cfg(test)]
extern crate std;

pub mod math;

pub mod skeleton;

pub mod asf;

pub mod fk;

pub mod interp;

pub mod preview;

pub mod footstep;

pub mod robot;

pub mod swivel;

pub mod ik;

pub mod ik_numeric;

pub mod retarget;

pub mod servo;

pub mod control_table;

pub mod plan;

pub mod rig;

pub mod command;

pub mod protocol;

pub mod sensor_board;

pub mod device;

pub mod schedule;

//! marionette: drive servo rigs from motion capture.
//!
//! Layers, each depending only on those above it in this list:
//!
//! * [`math`] — axes, the 12 Euler orders, quaternion distance (help note eq. 27–28).
//! * [`skeleton`] — fixed-capacity bones, channel layout, limits.
//! * [`asf`] — the ASF reader, text to skeleton, without allocation.
//! * [`fk`] — forward kinematics, eq. (1)–(5), into caller buffers.
//! * [`interp`] — per-frame editing maths in f64: facing (eq. 6–7), SLERP (eq. 12), ease
//!   weights (eq. 13), frame interpolation.
//!
//! * [`ik`] — f64 FK and the analytic limb solver with swivel search (help note §IV);
//!   [`ik_numeric`] — CCD, Jacobian transpose, pseudoinverse, DLS, conjugate gradient.
//! * [`servo`] — X-series servo models and control-table addresses.
//! * [`rig`] — joint sources and angle ↔ tick mapping, Euler re-decomposition.
//! * [`command`] — the command stage: finite check, position, velocity and acceleration limits.
//! * [`protocol`] — Dynamixel Protocol 2.0 packets: CRC-16, byte stuffing, encode/decode.
//! * [`device`] — the device side of Protocol 2.0: a chain of virtual servos.
//!
//! These are the `no_std` core (build with `--no-default-features`); they use `glam` with
//! `libm` and `heapless`, never the standard library or the heap.
//!
//! With the default `std` feature, the edge:
//!
//! * `motion` — a clip of frames (values as files hold them) and its frame vectors.
//! * `formats` — file loading with `file:line:column` errors, AMC read/write, ASF write,
//!   BVH import/export.
//! * `bus` — servo buses (serial through `dynamixel2`, the virtual chain).
//! * `control` — the fixed-rate loop, its inputs, statistics and fault policy.
//! * `cli` — the `marionette` command.
#![cfg_attr(not(feature = "std"), no_std)]
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod asf;
pub mod command;
pub mod device;
pub mod fk;
pub mod ik;
pub mod ik_numeric;
pub mod interp;
pub mod math;
pub mod protocol;
pub mod rig;
pub mod schedule;
pub mod servo;
pub mod skeleton;

#[cfg(feature = "std")]
pub mod budget;
#[cfg(feature = "std")]
pub mod bus;
#[cfg(feature = "std")]
/// The command line.
pub mod cli;
#[cfg(feature = "std")]
pub mod control;
#[cfg(feature = "std")]
pub mod formats;
#[cfg(feature = "std")]
pub mod ik_cli;
#[cfg(feature = "std")]
pub mod motion;
#[cfg(feature = "std")]
pub mod play_cli;
#[cfg(feature = "std")]
pub mod profile;
#[cfg(feature = "std")]
pub mod rig_cli;
#[cfg(feature = "std")]
pub mod sim;
#[cfg(feature = "std")]
pub mod sim_cli;

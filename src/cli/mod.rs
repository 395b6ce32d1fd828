//! The `marionette` command line: [`Cli`] parses it, [`run`] runs it. One file per command or
//! close group; this file only names the commands and hands each to its file.

mod args;
mod calibrate;
mod convert;
mod edit;
mod error;
mod identify;
mod ik;
mod inspect;
mod play;
mod retarget;
mod rig;
mod sim;
mod soak;
#[cfg(feature = "studio")]
mod studio;

pub use error::CliError;

use crate::motion::matching::Metric;
use clap::{Parser, Subcommand, ValueEnum};
use std::io;

/// Drive servo rigs from motion capture: ASF/AMC and BVH, forward and inverse kinematics.
#[derive(Debug, Parser)]
#[command(name = "marionette", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: CliCommand,
}

#[derive(Debug, Subcommand)]
enum CliCommand {
    /// Stream a clip to the servos at a fixed rate (the control loop), SLERP-resampled.
    Play(play::PlayArgs),
    /// Identify each servo's response (a step and a chirp, small and inside its limits): lag,
    /// rise, bandwidth; `--write` puts the lags into the profile as `lag_ms`, which the
    /// look-ahead leads each servo by.
    Identify(identify::IdentifyCmd),
    /// Serve the studio on 127.0.0.1: drag IK targets in a browser, compare the solvers, and
    /// drive the rig live (the virtual chain by default, --bus sim or a port). Only its own page
    /// drives it: other host names, other origins, non-JSON posts and oversized input are
    /// refused.
    #[cfg(feature = "studio")]
    Studio(studio::StudioCmd),
    /// Follow effector targets (file, stdin or UDP) with inverse kinematics at a fixed rate.
    Follow(play::FollowArgs),
    /// Write the effector paths of a clip as a target file for `follow`.
    Targets(play::TargetsArgs),
    /// Check a rig profile (TOML) and list its servos; with --asf, its bones too.
    Profile(rig::ProfileArgs),
    /// The MuJoCo simulator: export a puppet model, serve simulated servos on a pseudo-terminal.
    Sim(sim::SimArgs),
    /// Bus time per control cycle for a profile, and the highest loop rate it allows.
    Budget(rig::BudgetArgs),
    /// Serve the profile's servos as a virtual chain on a pseudo-terminal (no MuJoCo; `sim
    /// serve` adds physics), keeping line time: bytes at the profile's baud, return delays, the
    /// USB adapter's latency. Prints the device path to give any Protocol 2.0 client.
    Serve(rig::ServeArgs),
    /// A fault soak in virtual time: the whole loop on the in-process virtual chain, playing a
    /// clip through seeded bursts of every bus fault; prints what it counted (panics, corrupt
    /// values used, goals outside limits, ticks to recover after each burst).
    Soak(soak::SoakCmd),
    /// Retarget a clip onto a robot (the profile's [retarget] map): joint trajectory as CSV,
    /// a report, a picture.
    Retarget(retarget::RetargetCmd),
    /// Inverse kinematics: move a bone's tip to a target and print the result.
    Ik(ik::IkCmd),
    /// Keep a bone's tip where it was at one frame over a range of frames (foot planting),
    /// blended in and out; writes the edited motion.
    IkEdit(ik::IkEditCmd),
    /// List serial adapters (USB VID/PID, U2D2/FTDI, latency timer).
    Ports,
    /// Ping every id on a bus: ids, models, firmware, hardware error status.
    Scan(rig::ScanArgs),
    /// Check a rig against its profile before its first motion: the adapter, every servo
    /// (missing, other model, hardware error, Return Delay Time, operating mode, EEPROM
    /// limits, supply, temperature) and the loop's cycle; one line per finding with what to
    /// do; exit 1 when the rig cannot run the profile. `--fix` writes what it safely can.
    Doctor(rig::DoctorArgs),
    /// Measure each servo's zero and direction on the rig: torque off, the rig posed in its
    /// reference pose, each joint moved a little (or by hand) and watched; written into the
    /// profile, wrap-safe (a Homing Offset for a servo near the 0/4095 seam).
    Calibrate(calibrate::CalibrateArgs),
    /// Describe a skeleton (ASF or BVH) and, given one, a motion: bones, DOFs, limits, frames.
    Info(inspect::InfoArgs),
    /// Global position of every bone's tip (the root: its position) per frame.
    Fk(inspect::FkArgs),
    /// Convert between BVH and ASF/AMC: IN.bvh → OUT.amc (+ OUT.asf) or IN.amc → OUT.bvh.
    Convert(convert::ConvertArgs),
    /// Connect clip A to clip B through their best-matching windows (help note §III).
    Connect(edit::ConnectArgs),
    /// Make a seamless cycle of a clip by connecting it to itself, repeated --cycles times.
    Loop(edit::LoopCmd),
    /// Turn a clip about its first frame's root to a facing angle and move it (eq. 6–10).
    Transform(edit::TransformArgs),
    /// Blend two clips frame by frame with a constant weight (0: A, 1: B).
    Blend(edit::BlendArgs),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum MethodArg {
    /// Insert interpolated frames between the end poses.
    Interp,
    /// Blend the overlapping matched windows.
    Blend,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum DirectionArg {
    /// Match A's end in B; A is kept whole.
    Forward,
    /// Match B's start in A; B is kept whole.
    Backward,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum MetricArg {
    /// Euler angles.
    Euler,
    /// Quaternion log distance.
    Quat,
    /// Normalised joint positions.
    Position,
}

impl MetricArg {
    fn metric(self) -> Metric {
        match self {
            MetricArg::Euler => Metric::Euler,
            MetricArg::Quat => Metric::Quat,
            MetricArg::Position => Metric::Position,
        }
    }
}

/// Where `targets` puts the paths.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum FrameArg {
    /// Relative to each limb's parent bone, on the rest pose.
    Limb,
    /// As captured, in the root's frame.
    Root,
}

/// Runs the command line; the process exit code is 0 on `Ok`.
///
/// # Errors
/// [`CliError`], to be printed on one line.
pub fn run(cli: Cli) -> Result<(), CliError> {
    run_with(cli, None)
}

/// [`run`], with the counter of a counting global allocator (allocations so far on the calling
/// thread) so the control loop can report `allocations_in_tick`.
///
/// # Errors
/// [`CliError`], to be printed on one line.
pub fn run_with(cli: Cli, allocations: Option<fn() -> u64>) -> Result<(), CliError> {
    let result = match cli.command {
        CliCommand::Play(a) => a.run(allocations),
        CliCommand::Identify(a) => a.run(),
        #[cfg(feature = "studio")]
        CliCommand::Studio(a) => a.run(allocations),
        CliCommand::Follow(a) => a.run(allocations),
        CliCommand::Targets(a) => a.run(),
        CliCommand::Profile(a) => a.run(),
        CliCommand::Sim(a) => a.run(),
        CliCommand::Budget(a) => a.run(),
        CliCommand::Serve(a) => a.run(),
        CliCommand::Soak(a) => a.run(),
        CliCommand::Retarget(a) => a.run(),
        CliCommand::Ik(a) => a.run(),
        CliCommand::IkEdit(a) => a.run(),
        CliCommand::Ports => rig::ports_cmd(&mut io::stdout().lock()),
        CliCommand::Scan(a) => a.run(),
        CliCommand::Doctor(a) => a.run(),
        CliCommand::Calibrate(a) => a.run(),
        CliCommand::Info(a) => a.run(),
        CliCommand::Fk(a) => a.run(),
        CliCommand::Convert(a) => a.run(),
        CliCommand::Connect(a) => a.run(),
        CliCommand::Loop(a) => a.run(),
        CliCommand::Transform(a) => a.run(),
        CliCommand::Blend(a) => a.run(),
    };
    match result {
        // A closed pipe (`marionette fk … | head`) is not a failure.
        Err(CliError::Output(e)) if e.kind() == io::ErrorKind::BrokenPipe => Ok(()),
        other => other,
    }
}

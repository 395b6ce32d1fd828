//! Why a command failed: [`CliError`], printed as one line, with the process exit code.

use std::io;

use crate::bus::{BusError, StartupError};
use crate::fk::ShortFrame;
use crate::formats::FileError;
use crate::ik::PointError;
use crate::motion::connect::ConnectError;
use crate::plot::PlotError;
use crate::sim::mjcf::MjcfError;

/// Why a command failed; printed as one line. [`CliError::exit_code`]: 2 for a usage error
/// (the arguments are wrong or do not fit the inputs they name), 1 for the rest.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CliError {
    /// The arguments are wrong or do not fit together or with the files they name.
    #[error("{0}")]
    Usage(String),
    /// A file could not be read, parsed or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// Writing the output failed.
    #[error("writing output: {0}")]
    Output(#[from] io::Error),
    /// A serial port could not be opened.
    #[error("{port}: {source}")]
    Port {
        /// The port.
        port: String,
        /// What the system said.
        source: io::Error,
    },
    /// The serial ports could not be listed.
    #[error("listing serial ports: {0}")]
    Ports(#[from] serialport::Error),
    /// A bus transaction failed outside the loop (scanning).
    #[error("{port}: {source}")]
    Bus {
        /// The port.
        port: String,
        /// What failed.
        source: BusError,
    },
    /// A servo's health ended the run (eased to rest, torque off).
    #[error("{why}: the run was eased to rest and torque turned off; {}", if *.hardware_error {
        "remove the cause, then `marionette doctor PROFILE --fix` reboots the servo (its torque stays off until then)"
    } else {
        "let it cool (or fix the supply) before the next"
    })]
    ServoHealth {
        /// Which servo and why.
        why: String,
        /// Whether a servo reported a hardware error (it stays limp until rebooted).
        hardware_error: bool,
    },
    /// The servos could not be started as the profile says.
    #[error("start-up: {0}")]
    StartUp(#[from] StartupError),
    /// No valid read for the given time: the run was stopped with torque off.
    #[error("no valid read for {ms} ms: torque turned off on every servo")]
    ServosSilent {
        /// The `--torque-off-after` time, milliseconds.
        ms: f64,
    },
    /// The port failed mid-run (adapter unplugged): nothing more was commanded, one torque-off
    /// was tried.
    #[error("{port} went away mid-run ({reason}): servos held, one torque-off tried; check the adapter and the cable")]
    PortLost {
        /// The port.
        port: String,
        /// The operating system's error.
        reason: String,
    },
    /// The soak could not run.
    #[error("soak: {0}")]
    Soak(#[from] crate::session::soak::SoakError),
    /// The soak counted safety violations (panics, corrupt values used, goals outside limits,
    /// torque left on).
    #[error("the soak counted {0} safety violations (see the figures above)")]
    SoakFailed(u64),
    /// `doctor` found faults: the rig cannot run the profile.
    #[error("doctor: {0} fault(s): the rig cannot run the profile (see the lines above)")]
    RigNotReady(usize),
    /// The control loop's thread ended by a panic.
    #[error("the control loop thread panicked")]
    LoopPanicked,
    /// Two clips cannot be connected (or a clip looped).
    #[error(transparent)]
    Connect(#[from] ConnectError),
    /// A bone cannot be pointed.
    #[error("cannot point '{bone}': {source}")]
    Point {
        /// The bone.
        bone: String,
        /// Why.
        source: PointError,
    },
    /// A frame shorter than its skeleton.
    #[error(transparent)]
    Frame(#[from] ShortFrame),
    /// A picture was not drawn.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// A puppet model could not be generated.
    #[error(transparent)]
    Mjcf(#[from] MjcfError),
    /// The simulator failed (model, actuators).
    #[cfg(feature = "sim")]
    #[error(transparent)]
    Sim(#[from] crate::sim::plant::SimError),
    /// The simulator was asked for in a build without it.
    #[error("{0} {not_built}", not_built = crate::sim::NOT_BUILT)]
    NoSimulator(&'static str),
    /// A report could not be written as JSON.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
}

impl From<crate::session::SessionError> for CliError {
    /// The session's errors as the command line has always printed them.
    fn from(e: crate::session::SessionError) -> CliError {
        use crate::session::SessionError as S;
        match e {
            S::Invalid(s) => CliError::Usage(s),
            S::File(f) => CliError::File(f),
            S::Port { port, source } => CliError::Port { port, source },
            S::StartUp(s) => CliError::StartUp(s),
            S::Output(e) => CliError::Output(e),
            S::LoopPanicked => CliError::LoopPanicked,
            #[cfg(feature = "sim")]
            S::Sim(e) => CliError::Sim(e),
            S::NoSimulator(s) => CliError::NoSimulator(s),
            S::Plot(e) => CliError::Plot(e),
            S::Json(e) => CliError::Json(e),
        }
    }
}

impl CliError {
    /// Makes a [`CliError::Port`] for `port` out of what the system said.
    pub(super) fn at_port(port: &str) -> impl FnOnce(io::Error) -> CliError + '_ {
        move |source| CliError::Port {
            port: port.to_string(),
            source,
        }
    }

    /// The process exit code: 2 for [`CliError::Usage`], 1 otherwise.
    #[must_use]
    pub fn exit_code(&self) -> u8 {
        match self {
            CliError::Usage(_) => 2,
            _ => 1,
        }
    }
}

//! `marionette sim`: export a generated rig model, and serve simulated servos on a
//! pseudo-terminal (hardware in the loop without hardware).

use std::io::Write;
use std::path::{Path, PathBuf};

use clap::Subcommand;

use super::error::CliError;
use crate::formats::asf;
use crate::profile::Profile;
use crate::sim::mjcf::{puppet, PuppetOptions};
use clap::Args;

/// What `marionette sim` does.
#[derive(Debug, Subcommand)]
pub enum SimCommand {
    /// Write the MuJoCo model (MJCF) of a puppet: the skeleton's bones, one hinge and position
    /// actuator per servo of the profile, on a stand. Needs no MuJoCo.
    ExportMjcf {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Where to write the model.
        #[arg(short = 'o', long)]
        output: PathBuf,
        /// Model metres per subject metre.
        #[arg(long, default_value_t = 0.3)]
        scale: f64,
        /// Physics time step, seconds.
        #[arg(long, default_value_t = 0.001)]
        timestep: f64,
    },
    /// Serve simulated servos on a pseudo-terminal in real time: Protocol 2.0 in, MuJoCo
    /// physics behind each servo. Prints the device path to give `--bus` of `play`/`follow`.
    Serve {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf) to generate the puppet from (or give --model).
        asf: Option<PathBuf>,
        /// An MJCF model whose actuators are named as the profile's servos or joints.
        #[arg(long)]
        model: Option<PathBuf>,
        /// Model metres per subject metre (generated puppet).
        #[arg(long, default_value_t = 0.3)]
        scale: f64,
        /// Stop after this many seconds (default: at Ctrl-C).
        #[arg(long)]
        duration: Option<f64>,
        /// Answer at once instead of keeping line time (baud, return delays, USB latency).
        #[arg(long)]
        no_line_time: bool,
    },
    /// What a clip asks of each servo: inverse dynamics (MuJoCo's mj_inverse) of the clip on the
    /// rig's model → peak and RMS torque, peak speed and acceleration per servo against its
    /// model's stall torque and no-load speed; which servos saturate, and which model would not.
    Size {
        /// The rig profile.
        profile: PathBuf,
        /// Skeleton (.asf).
        asf: PathBuf,
        /// Clip (.amc); capture dropouts are filled as `play` fills them.
        amc: PathBuf,
        /// An MJCF model whose actuators are named as the profile's servos (default: the
        /// puppet generated from the skeleton).
        #[arg(long)]
        model: Option<PathBuf>,
        /// Model metres per subject metre (generated puppet).
        #[arg(long, default_value_t = 0.3)]
        scale: f64,
        /// Low-pass the clip's angles at this frequency before differentiating, Hz (0: as
        /// captured, marker noise and all).
        #[arg(long, default_value_t = 6.0)]
        cutoff_hz: f64,
        /// Write the figures as JSON here.
        #[arg(long)]
        json: Option<PathBuf>,
    },
}

/// Runs a `sim` subcommand.
///
/// # Errors
/// [`CliError`].
pub fn sim_cmd(cmd: &SimCommand, out: &mut dyn Write) -> Result<(), CliError> {
    match cmd {
        SimCommand::ExportMjcf {
            profile,
            asf: asf_path,
            output,
            scale,
            timestep,
        } => export(profile, asf_path, output, *scale, *timestep, out),
        SimCommand::Serve {
            profile,
            asf: asf_path,
            model,
            scale,
            duration,
            no_line_time,
        } => serve(
            profile,
            asf_path.as_deref(),
            model.as_deref(),
            *scale,
            (*duration, !*no_line_time),
            out,
        ),
        SimCommand::Size {
            profile,
            asf: asf_path,
            amc,
            model,
            scale,
            cutoff_hz,
            json,
        } => size(
            profile,
            asf_path,
            amc,
            model.as_deref(),
            *scale,
            *cutoff_hz,
            json.as_deref(),
            out,
        ),
    }
}

#[cfg(not(feature = "sim"))]
#[allow(clippy::too_many_arguments)]
fn size(
    _profile: &Path,
    _asf: &Path,
    _amc: &Path,
    _model: Option<&Path>,
    _scale: f64,
    _cutoff_hz: f64,
    _json: Option<&Path>,
    _out: &mut dyn Write,
) -> Result<(), CliError> {
    Err(CliError::NoSimulator("sim size"))
}

#[cfg(feature = "sim")]
#[allow(clippy::too_many_arguments)]
fn size(
    profile_path: &Path,
    asf_path: &Path,
    amc_path: &Path,
    model: Option<&Path>,
    scale: f64,
    cutoff_hz: f64,
    json: Option<&Path>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    use crate::sim::plant::load_world;
    if !(cutoff_hz.is_finite() && cutoff_hz >= 0.0) {
        return Err(CliError::Usage("--cutoff-hz must be 0 or more".into()));
    }
    let profile = Profile::load(profile_path)?;
    let skeleton = asf::load(asf_path)?.skeleton;
    let mut motion = crate::formats::amc::load(&skeleton, amc_path)?;
    if let Some(pose) = crate::motion::calibration::leave_out(&skeleton, &mut motion) {
        writeln!(out, "{}: {pose}; left out", amc_path.display())?;
    }
    for d in crate::motion::dropouts::repair(&skeleton, &mut motion) {
        writeln!(out, "{}: capture dropout filled: {d}", amc_path.display())?;
    }
    let rig = profile.rig(Some(&skeleton))?;
    let options = PuppetOptions {
        scale,
        ..PuppetOptions::default()
    };
    let mut world = load_world(model, Some(&skeleton), &profile, &rig, &options)?;
    let report = crate::sim::size::size(&mut world, &profile, &rig, &skeleton, &motion, cutoff_hz)?;
    writeln!(
        out,
        "{}: {} frames of {} on {} ({:.2} kg), inverse dynamics per frame, {}",
        profile.name,
        report.frames,
        amc_path.display(),
        model.map_or_else(
            || format!("the puppet at scale {scale}"),
            |m| m.display().to_string()
        ),
        world.total_mass(),
        if cutoff_hz > 0.0 {
            format!("angles low-passed at {cutoff_hz} Hz")
        } else {
            "angles as captured".to_string()
        }
    )?;
    write!(out, "{report}")?;
    if let Some(path) = json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n").map_err(|e| crate::formats::FileError::io(path, e))?;
        writeln!(out, "figures written to {}", path.display())?;
    }
    Ok(())
}

fn export(
    profile_path: &Path,
    asf_path: &Path,
    output: &Path,
    scale: f64,
    timestep: f64,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let profile = Profile::load(profile_path)?;
    let skeleton = asf::load(asf_path)?.skeleton;
    let rig = profile.rig(Some(&skeleton))?;
    let options = PuppetOptions {
        scale,
        timestep,
        ..PuppetOptions::default()
    };
    let xml = puppet(&skeleton, &profile, &rig, &options)?;
    std::fs::write(output, &xml).map_err(|e| crate::formats::FileError::io(output, e))?;
    writeln!(
        out,
        "{}: {} bones, {} hinges and position actuators, scale {scale}, time step {} ms → {}",
        profile.name,
        skeleton.len(),
        rig.len(),
        timestep * 1e3,
        output.display()
    )?;
    Ok(())
}

#[cfg(not(feature = "sim"))]
fn serve(
    _profile: &Path,
    _asf: Option<&Path>,
    _model: Option<&Path>,
    _scale: f64,
    _run: (Option<f64>, bool),
    _out: &mut dyn Write,
) -> Result<(), CliError> {
    Err(CliError::NoSimulator("sim serve"))
}

#[cfg(feature = "sim")]
fn serve(
    profile_path: &Path,
    asf_path: Option<&Path>,
    model: Option<&Path>,
    scale: f64,
    (duration, line_time): (Option<f64>, bool),
    out: &mut dyn Write,
) -> Result<(), CliError> {
    use crate::bus::virtual_chain::{chain_for, LineTiming, PtyChain};
    use crate::sim::plant::{load_world, rest_angles, SimPlant};

    if duration.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
        return Err(CliError::Usage(
            "--duration must be a positive number of seconds".into(),
        ));
    }
    let profile = Profile::load(profile_path)?;
    let skeleton = match asf_path {
        Some(p) => Some(asf::load(p)?.skeleton),
        None => None,
    };
    let rig = profile.rig(skeleton.as_ref())?;
    let options = PuppetOptions {
        scale,
        ..PuppetOptions::default()
    };
    let world = load_world(model, skeleton.as_ref(), &profile, &rig, &options)?;
    let mut plant = SimPlant::new(world, &profile, &rig)?;
    plant.set_angles(&rest_angles(&rig));
    let present = plant.present_ticks();
    let timestep = plant.world().timestep();
    let chain = chain_for(profile.bus_section(), |k| present[k]);
    let chain = if line_time {
        PtyChain::serve_timed_with(chain, plant, LineTiming::of(&profile.bus))
    } else {
        PtyChain::serve_with(chain, plant, None)
    }
    .map_err(CliError::Output)?;
    writeln!(
        out,
        "{}: {} simulated servos (MuJoCo, time step {} ms) on {}{}",
        profile.name,
        profile.servos.len(),
        timestep * 1e3,
        chain.path(),
        if line_time {
            format!(
                ", line time of {} bit/s and a {} µs USB latency",
                profile.bus.baud, profile.bus.usb_latency_us
            )
        } else {
            String::new()
        }
    )?;
    super::rig::serve_until_stopped(&chain, duration, out)
}

/// The arguments of `marionette sim`.
#[derive(Debug, Args)]
pub(super) struct SimArgs {
    #[command(subcommand)]
    pub(super) command: SimCommand,
}

impl SimArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let SimArgs { command } = self;
        sim_cmd(&command, &mut std::io::stdout().lock())
    }
}

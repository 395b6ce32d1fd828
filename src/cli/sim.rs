//! `marionette sim`: export a generated rig model, and serve simulated servos on a
//! pseudo-terminal (hardware in the loop without hardware).

use std::io::Write;
use std::path::{Path, PathBuf};

use clap::Subcommand;

use super::error::CliError;
use crate::formats::asf;
use crate::profile::Profile;
use crate::sim::mjcf::{puppet, PuppetOptions};

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
        } => serve(
            profile,
            asf_path.as_deref(),
            model.as_deref(),
            *scale,
            *duration,
            out,
        ),
    }
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
    _duration: Option<f64>,
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
    duration: Option<f64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    use std::time::{Duration, Instant};

    use crate::bus::virtual_chain::{chain_for, PtyChain};
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
    let chain =
        PtyChain::serve_with(chain_for(&profile, |k| present[k]), plant, None).map_err(CliError::Output)?;
    writeln!(
        out,
        "{}: {} simulated servos (MuJoCo, time step {} ms) on {}",
        profile.name,
        profile.servos.len(),
        timestep * 1e3,
        chain.path()
    )?;
    writeln!(out, "{}", chain.path())?;
    out.flush()?;
    let stop = crate::signals::stop_requests().map_err(CliError::Output)?;
    let began = Instant::now();
    while stop.made() == 0 && duration.is_none_or(|d| began.elapsed().as_secs_f64() < d) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let handled = chain.chain().instructions();
    writeln!(
        out,
        "served {handled} instructions in {:.1} s",
        began.elapsed().as_secs_f64()
    )?;
    Ok(())
}

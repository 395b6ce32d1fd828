//! `marionette identify`: step and chirp responses per servo — on the in-process virtual chain
//! (virtual time), the MuJoCo model in lockstep, or a real port with small motions — giving
//! lag and bandwidth per servo, optionally written into the profile as `lag_ms`.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use clap::Args;

use super::error::CliError;
use super::play::BusArg;
use crate::bus::start_up;
use crate::bus::virtual_chain::{chain_for, VirtualRig};
use crate::clock::{SystemClock, LOOP_SPIN_NS};
use crate::control::identify::{identify, Excitation, ServoResponse};
use crate::control::torque_off;
use crate::formats::{asf, FileError};
use crate::profile::{set_servo_lags, Profile};
use crate::rig::Rig;
use crate::session::{self, BusChoice, SessionSpec};
use crate::skeleton::Skeleton;

/// Options of `identify`.
#[derive(Clone, Debug, Args)]
pub struct IdentifyArgs {
    /// Where the servos are: `virtual` (the in-process chain, virtual time), `sim` (MuJoCo in
    /// lockstep) or a serial port (real servos: small motions, inside their limits).
    #[arg(long, default_value = "virtual")]
    pub bus: BusArg,
    /// Loop rate, Hz (identify at the rate you play at).
    #[arg(long, default_value_t = 120.0)]
    pub rate: f64,
    /// Only these servos (names; default: all).
    #[arg(long, value_delimiter = ',')]
    pub servos: Vec<String>,
    /// Step and chirp amplitude, joint degrees (reduced where the limits are closer).
    #[arg(long, default_value_t = 5.0)]
    pub amplitude_deg: f64,
    /// The chirp's highest frequency, Hz.
    #[arg(long, default_value_t = 8.0)]
    pub to_hz: f64,
    /// With --bus sim: the MJCF model (default: the puppet generated from the skeleton).
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// With --bus sim and a generated puppet: model metres per subject metre.
    #[arg(long, default_value_t = 0.3)]
    pub scale: f64,
    /// Write every figure as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write the lags into the profile (`lag_ms` of each identified servo; comments and layout
    /// kept).
    #[arg(long)]
    pub write: bool,
}

/// `marionette identify PROFILE [ASF]`.
///
/// # Errors
/// [`CliError`].
pub fn identify_cmd(
    profile_path: &Path,
    asf_path: Option<&Path>,
    args: &IdentifyArgs,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    if !(args.rate.is_finite() && (10.0..=2000.0).contains(&args.rate)) {
        return Err(CliError::Usage("--rate must be between 10 and 2000 Hz".into()));
    }
    if !(args.amplitude_deg.is_finite() && args.amplitude_deg > 0.0 && args.amplitude_deg <= 30.0) {
        return Err(CliError::Usage(
            "--amplitude-deg must be above 0 and at most 30".into(),
        ));
    }
    if !(args.to_hz.is_finite() && args.to_hz > 0.5 && args.to_hz <= args.rate / 4.0) {
        return Err(CliError::Usage(format!(
            "--to-hz must be above 0.5 Hz and at most a quarter of the rate ({} Hz)",
            args.rate / 4.0
        )));
    }
    let profile = Profile::load(profile_path)?;
    let skeleton = asf_path.map(asf::load).transpose()?.map(|a| Arc::new(a.skeleton));
    let rig = profile.rig(skeleton.as_deref())?;
    let names: Vec<String> = profile.servos.iter().map(|s| s.name.clone()).collect();
    let which: Vec<usize> = if args.servos.is_empty() {
        (0..names.len()).collect()
    } else {
        args.servos
            .iter()
            .map(|n| {
                names
                    .iter()
                    .position(|m| m == n)
                    .ok_or_else(|| CliError::Usage(format!("--servos: no servo named `{n}` in the profile")))
            })
            .collect::<Result<_, _>>()?
    };
    let e = Excitation {
        amplitude_deg: args.amplitude_deg,
        to_hz: args.to_hz,
        ..Excitation::default()
    };
    writeln!(
        out,
        "identifying {} servo(s) at {} Hz: a {}° step and a {:.1}–{} Hz chirp each ({:.1} s), the others holding; lags fitted up to {} Hz",
        which.len(),
        args.rate,
        args.amplitude_deg,
        e.from_hz,
        e.to_hz,
        e.duration_s() + 1.0,
        e.lag_band_hz
    )?;
    let responses = match &args.bus {
        BusArg::Virtual => {
            let rest: Vec<i32> = rig.servos.iter().map(crate::rig::ServoMap::rest_tick).collect();
            let mut bus = VirtualRig::keeping_time_of(
                chain_for(profile.bus_section(), |k| rest[k]),
                crate::bus::virtual_chain::ServoMotion,
                &profile.bus,
            );
            let present = start_up(&mut bus, profile.bus_section())?;
            let mut clock = bus.clone();
            let r = identify(
                &mut bus,
                &mut clock,
                &rig,
                &profile.ids(),
                &names,
                &present,
                &which,
                &e,
                args.rate,
            );
            let _ = torque_off(&mut bus, &profile.ids());
            r
        }
        BusArg::Sim => run_sim(args, &profile, skeleton.as_deref(), &rig, &names, &which, &e)?,
        BusArg::Port(port) => {
            // The bus as a session opens it (the project's host, the profile's read mode).
            let spec = SessionSpec {
                rate_hz: args.rate,
                bus: BusChoice::Port(port.clone()),
                ..SessionSpec::default()
            };
            let mut bus = session::open_bus(&spec, &profile, &rig, out)?.bus;
            let present = start_up(bus.as_mut(), profile.bus_section())?;
            writeln!(out, "{port}: {} servos up, torque on", present.len())?;
            let mut clock = SystemClock::new(LOOP_SPIN_NS);
            let r = identify(
                bus.as_mut(),
                &mut clock,
                &rig,
                &profile.ids(),
                &names,
                &present,
                &which,
                &e,
                args.rate,
            );
            let off = torque_off(bus.as_mut(), &profile.ids());
            writeln!(out, "torque off, acknowledged by {} servos", off.acknowledged)?;
            r
        }
    }
    .map_err(|e| CliError::Usage(format!("identification stopped: {e}")))?;
    print_table(&responses, out)?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&responses)?;
        std::fs::write(path, text + "\n").map_err(|e| FileError::io(path, e))?;
        writeln!(out, "figures written to {}", path.display())?;
    }
    if args.write {
        let text = std::fs::read_to_string(profile_path).map_err(|e| FileError::io(profile_path, e))?;
        let lags: Vec<(String, f64)> = responses
            .iter()
            .map(|r| (r.name.clone(), (r.lag_ms * 10.0).round() / 10.0))
            .collect();
        let updated = set_servo_lags(&text, &lags);
        std::fs::write(profile_path, updated).map_err(|e| FileError::io(profile_path, e))?;
        // The result must still load.
        Profile::load(profile_path)?;
        writeln!(
            out,
            "lag_ms of {} servo(s) written into {}",
            lags.len(),
            profile_path.display()
        )?;
    }
    Ok(())
}

fn print_table(responses: &[ServoResponse], out: &mut dyn Write) -> Result<(), CliError> {
    writeln!(
        out,
        "{:<16} {:>8} {:>9} {:>10} {:>8} {:>10} {:>12} {:>7}",
        "servo", "lag ms", "measured", "step 50%", "rise", "overshoot", "bandwidth", "ampl."
    )?;
    let ms = |v: Option<f64>| v.map_or_else(|| "—".to_string(), |x| format!("{x:.1} ms"));
    for r in responses {
        writeln!(
            out,
            "{:<16} {:>8.1} {:>9.1} {:>10} {:>8} {:>9.1}% {:>12} {:>6.1}°",
            r.name,
            r.lag_ms,
            r.measured_lag_ms,
            ms(r.step_delay_ms),
            ms(r.rise_ms),
            r.overshoot_pct,
            r.bandwidth_hz
                .map_or_else(|| "> chirp".to_string(), |b| format!("{b:.1} Hz")),
            r.amplitude_deg
        )?;
    }
    Ok(())
}

#[cfg(not(feature = "sim"))]
fn run_sim(
    _args: &IdentifyArgs,
    _profile: &Profile,
    _skeleton: Option<&Skeleton>,
    _rig: &Rig,
    _names: &[String],
    _which: &[usize],
    _e: &Excitation,
) -> Result<Result<Vec<ServoResponse>, crate::control::identify::IdentifyError>, CliError> {
    Err(CliError::NoSimulator("identify --bus sim"))
}

/// In MuJoCo, in lockstep (simulated time).
#[cfg(feature = "sim")]
fn run_sim(
    args: &IdentifyArgs,
    profile: &Profile,
    skeleton: Option<&Skeleton>,
    rig: &Rig,
    names: &[String],
    which: &[usize],
    e: &Excitation,
) -> Result<Result<Vec<ServoResponse>, crate::control::identify::IdentifyError>, CliError> {
    use crate::sim::{mjcf::PuppetOptions, plant};
    let options = PuppetOptions {
        scale: args.scale,
        ..PuppetOptions::default()
    };
    let world = plant::load_world(args.model.as_deref(), skeleton, profile, rig, &options)?;
    let mut bus = plant::sim_bus(world, profile, rig)?;
    let present = start_up(&mut bus, profile.bus_section())?;
    let mut clock = bus.clone();
    let r = identify(
        &mut bus,
        &mut clock,
        rig,
        &profile.ids(),
        names,
        &present,
        which,
        e,
        args.rate,
    );
    let _ = torque_off(&mut bus, &profile.ids());
    Ok(r)
}

/// The arguments of `marionette identify`.
#[derive(Debug, Args)]
pub(super) struct IdentifyCmd {
    /// The rig profile.
    pub(super) profile: PathBuf,
    /// Skeleton (.asf): for profiles of bones, and the generated puppet of --bus sim.
    pub(super) asf: Option<PathBuf>,
    #[command(flatten)]
    pub(super) args: IdentifyArgs,
}

impl IdentifyCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let IdentifyCmd { profile, asf, args } = self;
        identify_cmd(&profile, asf.as_deref(), &args, &mut std::io::stdout().lock())
    }
}

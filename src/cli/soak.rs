//! `marionette soak`: the fault soak in virtual time ([`crate::session::soak`]).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::error::CliError;
use crate::formats::{amc, asf};
use crate::profile::Profile;
use crate::session::soak::{soak, SoakConfig};
use clap::Args;

/// The soak's settings from the command line.
pub struct SoakArgs {
    pub faults: u64,
    pub seed: u64,
    pub rate: f64,
    pub max_burst: u64,
    pub json: Option<PathBuf>,
}

/// `marionette soak`.
///
/// # Errors
/// [`CliError`].
pub fn soak_cmd(
    profile_path: &Path,
    asf_path: &Path,
    amc_path: &Path,
    args: SoakArgs,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    if !(args.rate.is_finite() && (1.0..=2000.0).contains(&args.rate)) {
        return Err(CliError::Usage("--rate must be between 1 and 2000 Hz".into()));
    }
    if args.max_burst == 0 {
        return Err(CliError::Usage("--max-burst must be at least 1 tick".into()));
    }
    let profile = Profile::load(profile_path)?;
    let skeleton = Arc::new(asf::load(asf_path)?.skeleton);
    let motion = Arc::new(amc::load(&skeleton, amc_path)?);
    let rig = profile.rig(Some(&skeleton))?;
    let config = SoakConfig {
        faults: args.faults,
        seed: args.seed,
        rate_hz: args.rate,
        max_burst_ticks: args.max_burst,
        ..SoakConfig::default()
    };
    writeln!(
        out,
        "soak: {} faults (seed {}) on a virtual chain of {} servos at {} bit/s, loop at {} Hz, bursts of 1–{} ticks",
        config.faults,
        config.seed,
        profile.servos.len(),
        profile.bus.baud,
        config.rate_hz,
        config.max_burst_ticks
    )?;
    let report = soak(&skeleton, &motion, &profile, &rig, &config, |r| {
        eprintln!("  {} faults, {} ticks", r.faults, r.ticks);
    })?;
    writeln!(out, "{report}")?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)?;
        std::fs::write(path, text + "\n").map_err(|e| crate::formats::FileError::io(path, e))?;
        writeln!(out, "figures written to {}", path.display())?;
    }
    let bad = report.panics
        + report.corrupt_values_used
        + report.commands_outside_limits
        + report.goals_outside_limits
        + report.torque_left_on;
    if bad > 0 {
        return Err(CliError::SoakFailed(bad));
    }
    Ok(())
}

/// The arguments of `marionette soak`.
#[derive(Debug, Args)]
pub(super) struct SoakCmd {
    /// The profile.
    pub(super) profile: PathBuf,
    /// Skeleton (.asf).
    pub(super) asf: PathBuf,
    /// Clip (.amc), played on a loop.
    pub(super) amc: PathBuf,
    /// Faults to apply before stopping.
    #[arg(long, default_value_t = 1_000_000)]
    pub(super) faults: u64,
    /// Seed of the faults and the bursts (the same seed replays the same soak).
    #[arg(long, default_value_t = 1)]
    pub(super) seed: u64,
    /// Loop rate, Hz.
    #[arg(long, default_value_t = 100.0)]
    pub(super) rate: f64,
    /// Longest burst of faults, ticks.
    #[arg(long, default_value_t = 30)]
    pub(super) max_burst: u64,
    /// Also write the figures as JSON to this file.
    #[arg(long)]
    pub(super) json: Option<PathBuf>,
}

impl SoakCmd {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let SoakCmd {
            profile,
            asf,
            amc,
            faults,
            seed,
            rate,
            max_burst,
            json,
        } = self;
        soak_cmd(
            &profile,
            &asf,
            &amc,
            SoakArgs {
                faults,
                seed,
                rate,
                max_burst,
                json,
            },
            &mut std::io::stdout().lock(),
        )
    }
}

//! `marionette calibrate`: zero offsets and directions measured on the rig, written into the
//! profile.

use std::io::{BufRead, Write};
use std::path::PathBuf;

use super::CliError;
use crate::calibrate::{self, CalibrationError, Directions, Found, Operator};
use crate::formats::FileError;
use crate::profile::{Profile, ServoSpec};

/// The arguments of `marionette calibrate`.
#[derive(clap::Args, Debug)]
pub(super) struct CalibrateArgs {
    /// The rig profile: its `zero`, `direction` and `homing_offset` are measured and written.
    profile: PathBuf,
    /// Serial port of the rig, e.g. /dev/ttyUSB0 (at the profile's baud).
    #[arg(long)]
    port: String,
    /// Find each joint's direction by turning it by hand (torque stays off throughout).
    #[arg(long, conflicts_with = "zeros_only")]
    by_hand: bool,
    /// Measure the zeros only; keep the profile's directions.
    #[arg(long)]
    zeros_only: bool,
    /// Print what was measured without writing the profile.
    #[arg(long)]
    dry_run: bool,
    /// Also write what was measured as JSON to this file.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,
}

impl CalibrateArgs {
    /// Runs it, asking on the terminal (stdin) and printing to stdout.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        use std::io::IsTerminal;
        let stdin = std::io::stdin();
        let mut operator = Terminal {
            tty: stdin.is_terminal(),
            input: stdin.lock(),
            output: std::io::stdout(),
        };
        let mut out = std::io::stdout();
        calibrate_cmd(&self, &mut operator, &mut out)
    }
}

/// The operator at the terminal: questions on stdout, answers from stdin, a line each.
struct Terminal<R: BufRead, W: Write> {
    input: R,
    output: W,
    /// Whether the input is a terminal (which shows the answers as they are typed).
    tty: bool,
}

impl<R: BufRead, W: Write> Terminal<R, W> {
    fn ask(&mut self, question: &str) -> Result<String, CalibrationError> {
        let stopped = |e: std::io::Error| CalibrationError::Operator(format!("the terminal failed: {e}"));
        write!(self.output, "{question} ").map_err(stopped)?;
        self.output.flush().map_err(stopped)?;
        let mut line = String::new();
        if self.input.read_line(&mut line).map_err(stopped)? == 0 {
            return Err(CalibrationError::Operator(
                "no answer (stdin closed): calibrate needs someone at the rig to pose and watch it".into(),
            ));
        }
        let answer = line.trim().to_ascii_lowercase();
        if !self.tty {
            // Answers typed at a terminal are on the screen already; piped ones are not.
            writeln!(self.output, "{answer}").map_err(stopped)?;
        }
        if answer == "q" || answer == "quit" {
            return Err(CalibrationError::Operator("stopped by the operator".into()));
        }
        Ok(answer)
    }
}

impl<R: BufRead, W: Write> Operator for Terminal<R, W> {
    fn hold_reference_pose(&mut self, pose: &str) -> Result<(), CalibrationError> {
        self.ask(&format!(
            "Torque is off. Pose the rig in its reference pose — {pose} — and hold it; press Enter (q stops):"
        ))
        .map(drop)
    }

    fn turned_positive(&mut self, servo: &ServoSpec, positive: &str) -> Result<bool, CalibrationError> {
        loop {
            match self
                .ask(&format!(
                    "id {} {} moved a little and back. Was the way out {positive}? [y/n]",
                    servo.id, servo.name
                ))?
                .as_str()
            {
                "y" | "yes" => return Ok(true),
                "n" | "no" => return Ok(false),
                _ => {}
            }
        }
    }

    fn turn_by_hand(&mut self, servo: &ServoSpec, positive: &str) -> Result<(), CalibrationError> {
        self.ask(&format!(
            "Turn id {} {} by hand a few degrees, {positive}, hold it there and press Enter:",
            servo.id, servo.name
        ))
        .map(drop)
    }
}

fn calibrate_cmd(
    a: &CalibrateArgs,
    operator: &mut dyn Operator,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let profile = Profile::load(&a.profile)?;
    let text = std::fs::read_to_string(&a.profile).map_err(|e| FileError::io(&a.profile, e))?;
    let path = a.port.clone();
    let mut bus = crate::bus::open(
        crate::bus::Wire::Port(path.clone()),
        &profile.bus,
        profile.servos.len(),
    )
    .map_err(CliError::at_port(&path))?;
    let how = if a.zeros_only {
        Directions::Keep
    } else if a.by_hand {
        Directions::ByHand
    } else {
        Directions::Step
    };
    writeln!(
        out,
        "calibrate: {} on {path} at {} bit/s, {} servos; torque off",
        a.profile.display(),
        profile.bus.baud,
        profile.servos.len()
    )?;
    let done = calibrate::calibrate(bus.as_mut(), &profile, how, operator, &mut calibrate::WallClock)
        .map_err(|e| match e {
            CalibrationError::Bus(source) => CliError::Bus {
                port: path.clone(),
                source,
            },
            e => CliError::Usage(format!(
                "calibration stopped, the profile is unchanged, torque is off: {e}"
            )),
        })?;
    writeln!(out)?;
    writeln!(
        out,
        "  id  servo                 horn  direction        zero  homing offset"
    )?;
    for c in &done {
        let how = match c.found {
            Found::Step => "watched",
            Found::Hand => "by hand",
            Found::Kept => "kept",
        };
        let changed = if (f64::from(c.zero), c.direction) == c.was {
            String::new()
        } else {
            format!("   (was {} {:+})", c.was.0, c.was.1)
        };
        writeln!(
            out,
            "{:>4}  {:<20} {:>5}  {:+} {how:<8} {:>6}  {:>13}{changed}",
            c.id, c.name, c.horn, c.direction, c.zero, c.homing_offset
        )?;
    }
    let offsets = done.iter().filter(|c| c.homing_offset != 0).count();
    if offsets > 0 {
        writeln!(
            out,
            "{offsets} servo(s) sit near the 0/4095 seam in the reference pose: a Homing Offset centres their range (written to them and into the profile)"
        )?;
    }
    if let Some(json) = &a.json {
        let s = serde_json::to_string_pretty(&done).map_err(|e| CliError::Output(e.into()))?;
        std::fs::write(json, s + "\n").map_err(|e| FileError::io(json, e))?;
    }
    if a.dry_run {
        writeln!(out, "--dry-run: the profile is unchanged")?;
        return Ok(());
    }
    let updated = calibrate::write_into(&text, &profile, &done);
    std::fs::write(&a.profile, &updated).map_err(|e| FileError::io(&a.profile, e))?;
    // The result must still load.
    Profile::load(&a.profile)?;
    writeln!(
        out,
        "zero and direction of {} servo(s) written into {}; torque is off",
        done.len(),
        a.profile.display()
    )?;
    Ok(())
}

//! The rig and bus commands: `profile`, `budget`, `ports`, `scan`.

use std::io::Write;
use std::path::Path;

use super::error::CliError;
use crate::budget::{plan, plan_with_board};
use crate::bus::virtual_chain::{chain_for, LineTiming, PtyChain};
use crate::bus::ServoBus;
use crate::formats::asf;
use crate::profile::{BusConfig, Drive, Profile};
use crate::rig::JointSource;
use clap::Args;
use std::path::PathBuf;

/// `marionette profile`: validate a profile (against a skeleton when given) and list it.
pub fn profile_cmd(path: &Path, asf_path: Option<&Path>, out: &mut dyn Write) -> Result<(), CliError> {
    let profile = Profile::load(path)?;
    let skeleton = asf_path.map(asf::load).transpose()?;
    let rig = profile.rig(skeleton.as_ref().map(|a| &a.skeleton))?;
    let b = &profile.bus;
    writeln!(out, "{} — {} servos", profile.name, profile.servos.len())?;
    writeln!(
        out,
        "bus: {} bit/s, return delay {} µs, {} read, USB latency {} µs, watchdog {} ms",
        b.baud,
        b.return_delay_us,
        b.read.name(),
        b.usb_latency_us,
        b.watchdog_ms
    )?;
    writeln!(
        out,
        "{:>3}  {:<16} {:<11} {:<16} {:>4} {:>7} {:>7} {:>6} {:>8}",
        "id", "name", "model", "drive", "dir", "min", "max", "°/s", "source"
    )?;
    for (s, m) in profile.servos.iter().zip(&rig.servos) {
        let drive = match &s.drive {
            Drive::Bone { bone, dof } => format!("{bone}.{}", dof.name()),
            Drive::Joint(j) => j.clone(),
        };
        let source = match m.source {
            JointSource::Channel(c) => format!("ch {c}"),
            JointSource::Joint(j) => format!("joint {j}"),
            JointSource::Redecomposed { order, slot, .. } => format!("{}[{slot}]", order.name()),
        };
        writeln!(
            out,
            "{:>3}  {:<16} {:<11} {:<16} {:>4} {:>7} {:>7} {:>6} {:>8}",
            s.id,
            s.name,
            s.model.name,
            drive,
            s.direction,
            m.min_tick,
            m.max_tick,
            s.max_velocity_dps,
            source
        )?;
    }
    if skeleton.is_none()
        && profile
            .servos
            .iter()
            .any(|s| matches!(s.drive, Drive::Bone { .. }))
    {
        writeln!(
            out,
            "(bones not checked: give --asf to check them against a skeleton)"
        )?;
    }
    Ok(())
}

/// `marionette budget`.
pub fn budget_cmd(
    path: &Path,
    rate: Option<f64>,
    (json, imu): (bool, bool),
    measure: Option<usize>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let profile = Profile::load(path)?;
    if imu && profile.bus.imu_board.is_none() {
        return Err(CliError::Usage(format!(
            "--imu: {} has no sensor board (imu_board_id in [bus])",
            path.display()
        )));
    }
    if let Some(cycles) = measure {
        return measure_cycles(&profile, cycles, json, out);
    }
    if let Some(r) = rate {
        if !(r.is_finite() && r > 0.0) {
            return Err(CliError::Usage(format!(
                "--rate must be a positive number of Hz, got {r}"
            )));
        }
    }
    let board = imu.then_some(crate::sensor_board::IMU_BYTES as u32);
    let budget = plan_with_board(&profile.bus, profile.servos.len(), rate, board);
    if json {
        let text = serde_json::to_string_pretty(&budget)?;
        writeln!(out, "{text}")?;
    } else {
        write!(out, "{}: {budget}", profile.name)?;
    }
    Ok(())
}

/// `budget --measure N`: N cycles of the loop's bus work — a Sync Write of goals and the
/// profile's read of positions (Sync, Bulk, Fast Sync or Fast Bulk Read), through the project's
/// host as the loop would use it — timed against the planner's cycle on the profile's line-timed
/// chain twice: in process and in real time (the loop's `--bus virtual`: exact line time), and
/// served on a pseudo-terminal (what an outside client sees: the pty adds the serving thread's
/// and the host's wake-ups). The chain starts up as the loop does (the profile's Return Delay
/// Time written; the factory's is 500 µs per servo).
fn measure_cycles(profile: &Profile, cycles: usize, json: bool, out: &mut dyn Write) -> Result<(), CliError> {
    if cycles == 0 {
        return Err(CliError::Usage("--measure needs at least one cycle".into()));
    }
    let planned = plan(&profile.bus, profile.servos.len(), None);
    let mut in_process =
        crate::bus::line_timed_chain(chain_for(profile.bus_section(), |_| 2048), &profile.bus);
    let in_process = time_cycles(&mut in_process, profile, cycles, "in process")?;
    let pty = PtyChain::serve_timed(
        chain_for(profile.bus_section(), |_| 2048),
        LineTiming::of(&profile.bus),
    )
    .map_err(CliError::Output)?;
    let path = pty.path().to_string();
    let mut bus = crate::bus::open(
        crate::bus::Wire::Port(path.clone()),
        &profile.bus,
        profile.servos.len(),
    )
    .map_err(CliError::at_port(&path))?;
    let served = time_cycles(bus.as_mut(), profile, cycles, &path)?;
    if json {
        let v = serde_json::json!({
            "profile": profile.name,
            "servos": profile.servos.len(),
            "baud": profile.bus.baud,
            "planned_cycle_us": planned.cycle_time_us,
            "planned_max_rate_hz": planned.max_rate_hz,
            "cycles": served.took.len(),
            "failed": served.failed,
            "measured_mean_us": served.mean(),
            "measured_p50_us": served.at(0.5),
            "measured_p99_us": served.at(0.99),
            "measured_over_planned": served.mean() / planned.cycle_time_us,
            "in_process": {
                "cycles": in_process.took.len(),
                "failed": in_process.failed,
                "measured_mean_us": in_process.mean(),
                "measured_p50_us": in_process.at(0.5),
                "measured_p99_us": in_process.at(0.99),
                "measured_over_planned": in_process.mean() / planned.cycle_time_us,
            },
        });
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
    } else {
        writeln!(
            out,
            "{}: {} servos at {} bit/s, Sync Write + {} read on a line-timed virtual chain",
            profile.name,
            profile.servos.len(),
            profile.bus.baud,
            profile.bus.read.name()
        )?;
        writeln!(
            out,
            "planned      {:>8.1} µs per cycle ({:.0} Hz at most)",
            planned.cycle_time_us, planned.max_rate_hz
        )?;
        for (name, m) in [("in process", &in_process), ("on a pty  ", &served)] {
            writeln!(
                out,
                "{name}   {:>8.1} µs mean, p50 {:.1}, p99 {:.1} over {} cycles ({} failed): {:.1} % of the plan",
                m.mean(),
                m.at(0.5),
                m.at(0.99),
                m.took.len(),
                m.failed,
                m.mean() / planned.cycle_time_us * 100.0
            )?;
        }
    }
    Ok(())
}

/// Cycle times (µs, sorted) of the cycles whose bus work succeeded, and how many failed.
struct Cycles {
    took: Vec<f64>,
    failed: usize,
}

impl Cycles {
    fn mean(&self) -> f64 {
        self.took.iter().sum::<f64>() / self.took.len().max(1) as f64
    }

    fn at(&self, q: f64) -> f64 {
        self.took
            .get(((self.took.len().max(1) - 1) as f64 * q).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    }
}

/// Starts `bus` up as the loop does, then times `cycles` cycles of Sync Write + read.
fn time_cycles(
    bus: &mut dyn ServoBus,
    profile: &Profile,
    cycles: usize,
    name: &str,
) -> Result<Cycles, CliError> {
    use std::time::Instant;

    let ids = profile.ids();
    let mut present = crate::bus::start_up(bus, profile.bus_section())
        .map_err(|e| CliError::Usage(format!("{name}: {e}")))?;
    let mut took = Vec::with_capacity(cycles);
    let mut failed = 0usize;
    for _ in 0..cycles {
        let t = Instant::now();
        let ok = bus.write_goals(&ids, &present).is_ok() && bus.read_positions(&ids, &mut present).is_ok();
        if ok {
            took.push(t.elapsed().as_secs_f64() * 1e6);
        } else {
            failed += 1;
        }
    }
    took.sort_by(f64::total_cmp);
    Ok(Cycles { took, failed })
}

/// `marionette serve PROFILE`: the profile's servos as a virtual chain on a pseudo-terminal,
/// keeping line time when `line_time` is given (served at its `SCHED_FIFO` priority, if any),
/// until a stop signal or `duration` seconds.
///
/// # Errors
/// [`CliError`].
pub fn serve_cmd(
    path: &Path,
    line_time: Option<Option<i32>>,
    duration: Option<f64>,
    misconfigure: Option<&str>,
    miscalibrate: Option<u64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    if duration.is_some_and(|d| !(d.is_finite() && d > 0.0)) {
        return Err(CliError::Usage(
            "--duration must be a positive number of seconds".into(),
        ));
    }
    let profile = Profile::load(path)?;
    // Each horn at its joint's zero.
    let mut chain = chain_for(profile.bus_section(), |k| {
        profile.servos[k].zero.round().clamp(0.0, 4095.0) as i32
    });
    if let Some(spec) = misconfigure {
        crate::bus::virtual_chain::misconfigure(&mut chain, spec)
            .map_err(|e| CliError::Usage(format!("--misconfigure: {e}")))?;
    }
    if let Some(seed) = miscalibrate {
        let truth = crate::bus::virtual_chain::miscalibration(seed, profile.servos.len());
        crate::bus::virtual_chain::miscalibrate(&mut chain, &profile.ids(), &truth);
    }
    let pty = if let Some(priority) = line_time {
        PtyChain::serve_timed(chain, LineTiming::of(&profile.bus).at_priority(priority))
    } else {
        PtyChain::serve(chain, None)
    }
    .map_err(CliError::Output)?;
    // A servo set to another baud is silent, as on the rig.
    pty.keep_to_the_line_baud();
    writeln!(
        out,
        "{}: {} virtual servos on {}, {}",
        profile.name,
        profile.servos.len(),
        pty.path(),
        if line_time.is_some() {
            format!(
                "line time of {} bit/s and a {} µs USB latency",
                profile.bus.baud, profile.bus.usb_latency_us
            )
        } else {
            "no line time".to_string()
        }
    )?;
    serve_until_stopped(&pty, duration, out)
}

/// Prints a served chain's path (a line of its own, for scripts), serves until a stop signal
/// or `duration` seconds, then says how many instructions it answered (`serve`, `sim serve`).
///
/// # Errors
/// Output, or the signal handlers cannot be installed.
pub(super) fn serve_until_stopped(
    pty: &PtyChain,
    duration: Option<f64>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    use std::time::{Duration, Instant};

    writeln!(out, "{}", pty.path())?;
    out.flush()?;
    let stop = crate::signals::stop_requests().map_err(CliError::Output)?;
    let began = Instant::now();
    while stop.made() == 0 && duration.is_none_or(|d| began.elapsed().as_secs_f64() < d) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let handled = pty.chain().instructions();
    writeln!(
        out,
        "served {handled} instructions in {:.1} s",
        began.elapsed().as_secs_f64()
    )?;
    Ok(())
}

/// USB vendor id of FTDI (the U2D2 and most Dynamixel adapters).
const FTDI_VID: u16 = 0x0403;
/// FT232H, the chip of the ROBOTIS U2D2.
const U2D2_PID: u16 = 0x6014;

/// `marionette ports`.
pub fn ports_cmd(out: &mut dyn Write) -> Result<(), CliError> {
    let ports = serialport::available_ports()?;
    if ports.is_empty() {
        writeln!(
            out,
            "no serial ports found (try `marionette scan --virtual <PROFILE>` to run without hardware)"
        )?;
    }
    for p in ports {
        match p.port_type {
            serialport::SerialPortType::UsbPort(u) => {
                let mark = match (u.vid, u.pid) {
                    (FTDI_VID, U2D2_PID) => "  [U2D2 / FTDI FT232H]",
                    (FTDI_VID, _) => "  [FTDI]",
                    _ => "",
                };
                let product = u.product.unwrap_or_default();
                let maker = u.manufacturer.unwrap_or_default();
                write!(
                    out,
                    "{}  USB {:04x}:{:04x} {maker} {product}{mark}",
                    p.port_name, u.vid, u.pid
                )?;
                match crate::bus::latency_timer_ms(&p.port_name) {
                    Some(ms) if ms > 1 => writeln!(
                        out,
                        "\n  warning: latency timer {ms} ms caps the loop near {} Hz; \
                         `echo 1 | sudo tee /sys/bus/usb-serial/devices/{}/latency_timer`",
                        1000 / ms.max(1),
                        Path::new(&p.port_name)
                            .file_name()
                            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
                    )?,
                    Some(ms) => writeln!(out, "  latency timer {ms} ms")?,
                    None => writeln!(out)?,
                }
            }
            serialport::SerialPortType::PciPort => writeln!(out, "{}  PCI", p.port_name)?,
            serialport::SerialPortType::BluetoothPort => writeln!(out, "{}  Bluetooth", p.port_name)?,
            serialport::SerialPortType::Unknown => writeln!(out, "{}", p.port_name)?,
        }
    }
    Ok(())
}

/// `marionette scan`: over a port, or over a virtual chain for a profile served on a
/// pseudo-terminal (so the same serial path is used), through the project's host.
pub fn scan_cmd(
    port: Option<&str>,
    baud: u32,
    virtual_profile: Option<&Path>,
    out: &mut dyn Write,
) -> Result<(), CliError> {
    let (_served, path, baud) = match (port, virtual_profile) {
        (Some(p), None) => (None, p.to_string(), baud),
        (None, Some(prof)) => {
            let profile = Profile::load(prof)?;
            let pty = PtyChain::serve(chain_for(profile.bus_section(), |_| 2048), None)
                .map_err(CliError::Output)?;
            let path = pty.path().to_string();
            (Some(pty), path, profile.bus.baud)
        }
        _ => {
            return Err(CliError::Usage(
                "give either --port <PATH> or --virtual <PROFILE>".into(),
            ))
        }
    };
    let mut bus = crate::bus::open(crate::bus::Wire::Port(path.clone()), &BusConfig::unknown(baud), 1)
        .map_err(CliError::at_port(&path))?;
    let found = bus.scan().map_err(|source| CliError::Bus {
        port: path.clone(),
        source,
    })?;
    writeln!(out, "{path} at {baud} bit/s: {} device(s)", found.len())?;
    for p in &found {
        write!(out, "{p}")?;
        if p.model_number == crate::sensor_board::OPENCR_OP3_MODEL_NUMBER {
            // A sensor board: no Hardware Error Status (its table ends at 51).
            writeln!(out)?;
            continue;
        }
        match bus.hardware_error(p.id) {
            Ok(0) => writeln!(out, "  ok")?,
            Ok(e) => writeln!(out, "  hardware error status {e:#04x}")?,
            Err(e) => writeln!(out, "  ({e})")?,
        }
    }
    Ok(())
}

/// The arguments of `marionette profile`.
#[derive(Debug, Args)]
pub(super) struct ProfileArgs {
    /// The profile, e.g. firmware-profile/cmu-puppet.toml.
    pub(super) profile: PathBuf,
    /// The skeleton the profile's bones refer to.
    #[arg(long)]
    pub(super) asf: Option<PathBuf>,
}

impl ProfileArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let ProfileArgs { profile, asf } = self;
        profile_cmd(&profile, asf.as_deref(), &mut std::io::stdout().lock())
    }
}

/// The arguments of `marionette budget`.
#[derive(Debug, Args)]
pub(super) struct BudgetArgs {
    /// The profile.
    pub(super) profile: PathBuf,
    /// A loop rate to check, Hz.
    #[arg(long)]
    pub(super) rate: Option<f64>,
    /// Print JSON.
    #[arg(long)]
    pub(super) json: bool,
    /// Count the profile's sensor board (the OP3's IMU) read every cycle, as `play --walk
    /// --imu read|feedback` reads it.
    #[arg(long)]
    pub(super) imu: bool,
    /// Measure this many cycles on the profile's virtual chain served with line time (baud,
    /// return delay, USB latency) through the real client, against the plan.
    #[arg(long)]
    pub(super) measure: Option<usize>,
}

impl BudgetArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let BudgetArgs {
            profile,
            rate,
            json,
            imu,
            measure,
        } = self;
        budget_cmd(
            &profile,
            rate,
            (json, imu),
            measure,
            &mut std::io::stdout().lock(),
        )
    }
}

/// The arguments of `marionette serve`.
#[derive(Debug, Args)]
pub(super) struct ServeArgs {
    /// The profile.
    pub(super) profile: PathBuf,
    /// Answer at once instead of at line speed.
    #[arg(long)]
    pub(super) no_line_time: bool,
    /// Stop after this many seconds (default: at Ctrl-C).
    #[arg(long)]
    pub(super) duration: Option<f64>,
    /// Serve at this `SCHED_FIFO` priority (1–99; needs CAP_SYS_NICE), as hardware keeps
    /// its own time whatever else the machine does.
    #[arg(long)]
    pub(super) rt_priority: Option<i32>,
    /// Make the chain wrong on purpose, to try `doctor`: a comma-separated list of
    /// `missing=ID`, `extra=ID`, `model=ID:NAME`, `rdt=ID:MICROSECONDS`, `srl=ID:LEVEL`,
    /// `mode=ID:N`, `max_limit=ID:TICK`, `velocity_limit=ID:UNITS`, `pwm_limit=ID:N`,
    /// `baud=ID:BITS_PER_S`, `temp=ID:CELSIUS`, `supply=ID:VOLTS`, `hwerror=ID:BITS`.
    #[arg(long, value_name = "LIST")]
    pub(super) misconfigure: Option<String>,
    /// Mount every servo unlike the profile says, to try `calibrate`: each horn somewhere in
    /// its turn in the reference pose, its direction either way, a third with a Homing Offset
    /// left in them — chosen by this seed, not told.
    #[arg(long, value_name = "SEED")]
    pub(super) miscalibrate: Option<u64>,
}

impl ServeArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let ServeArgs {
            profile,
            no_line_time,
            duration,
            rt_priority,
            misconfigure,
            miscalibrate,
        } = self;
        serve_cmd(
            &profile,
            (!no_line_time).then_some(rt_priority),
            duration,
            misconfigure.as_deref(),
            miscalibrate,
            &mut std::io::stdout().lock(),
        )
    }
}

/// The arguments of `marionette scan`.
#[derive(Debug, Args)]
pub(super) struct ScanArgs {
    /// Serial port, e.g. /dev/ttyUSB0.
    #[arg(long, conflicts_with = "virtual")]
    pub(super) port: Option<String>,
    /// Baud rate of --port.
    #[arg(long, default_value_t = 57_600)]
    pub(super) baud: u32,
    /// Scan a virtual chain built from this profile (served on a pseudo-terminal).
    #[arg(long = "virtual", value_name = "PROFILE")]
    r#virtual: Option<PathBuf>,
}

impl ScanArgs {
    /// Runs it.
    ///
    /// # Errors
    /// [`CliError`].
    pub(super) fn run(self) -> Result<(), CliError> {
        let ScanArgs {
            port,
            baud,
            r#virtual,
        } = self;
        scan_cmd(
            port.as_deref(),
            baud,
            r#virtual.as_deref(),
            &mut std::io::stdout().lock(),
        )
    }
}

/// `marionette doctor`.
#[derive(clap::Args, Debug)]
pub(super) struct DoctorArgs {
    /// The rig profile to check the rig against.
    profile: PathBuf,
    /// Serial port of the rig, e.g. /dev/ttyUSB0 (at the profile's baud).
    #[arg(long, conflicts_with = "bus")]
    port: Option<String>,
    /// `virtual`: a virtual chain built from the profile, served on a pseudo-terminal.
    #[arg(long, value_parser = ["virtual"])]
    bus: Option<String>,
    /// Print the report as JSON (one object) instead of lines.
    #[arg(long)]
    json: bool,
    /// Write what can be written safely (torque off first), say what was written, check again.
    #[arg(long)]
    fix: bool,
}

impl DoctorArgs {
    /// Runs it: exit 0 when the rig can run the profile, 1 when not.
    ///
    /// # Errors
    /// [`CliError`]; [`CliError::RigNotReady`] when a fault remains.
    pub(super) fn run(self) -> Result<(), CliError> {
        doctor_cmd(&self, &mut std::io::stdout().lock())
    }
}

fn doctor_cmd(a: &DoctorArgs, out: &mut dyn Write) -> Result<(), CliError> {
    use crate::doctor::{self, Level};
    let profile = Profile::load(&a.profile)?;
    let (_served, path) = match (&a.port, a.bus.as_deref()) {
        (Some(p), None) => (None, p.clone()),
        (None, Some("virtual")) => {
            // Line time kept (the profile's baud and latency timer): the measured cycle means
            // what it would on the wire.
            let chain = chain_for(profile.bus_section(), |_| 2048);
            let pty = PtyChain::serve_timed(chain, LineTiming::of(&profile.bus)).map_err(CliError::Output)?;
            pty.keep_to_the_line_baud();
            let path = pty.path().to_string();
            (Some(pty), path)
        }
        _ => return Err(CliError::Usage("give --port <PATH> or --bus virtual".into())),
    };
    let as_found = doctor::bus_as_found(&profile.bus);
    // The port is held by one bus at a time: the baud search opens it at other bauds.
    let open = || {
        crate::bus::open(
            crate::bus::Wire::Port(path.clone()),
            &as_found,
            profile.servos.len(),
        )
        .map_err(CliError::at_port(&path))
    };
    let at_port = |source| CliError::Bus {
        port: path.clone(),
        source,
    };
    let mut report = doctor::examine(open()?.as_mut(), &profile).map_err(at_port)?;
    // Servos that did not answer may be at another baud: the port is opened at each in turn.
    let search = |report: &mut doctor::Report| -> Result<(), CliError> {
        if report.has_silent() {
            doctor::search_bauds(&path, &profile, report).map_err(at_port)?;
        }
        if a.port.is_some() {
            doctor::check_adapter(&path, report);
        }
        Ok(())
    };
    search(&mut report)?;
    if a.fix {
        let mut fixed = doctor::apply_baud_fixes(&path, &profile, &report).map_err(at_port)?;
        let mut bus = open()?;
        fixed.extend(doctor::apply_fixes(bus.as_mut(), &report).map_err(at_port)?);
        if !fixed.is_empty() {
            report = doctor::examine(bus.as_mut(), &profile).map_err(at_port)?;
            // A servo moved to the profile's baud may bring fixes of its own.
            let more = doctor::apply_fixes(bus.as_mut(), &report).map_err(at_port)?;
            if !more.is_empty() {
                report = doctor::examine(bus.as_mut(), &profile).map_err(at_port)?;
                fixed.extend(more);
            }
            drop(bus);
            search(&mut report)?;
        }
        report.fixed = fixed;
    }
    let faults = report.at(Level::Fault).count();
    if a.json {
        writeln!(
            out,
            "{}",
            serde_json::to_string(&report).map_err(|e| CliError::Output(e.into()))?
        )?;
    } else {
        writeln!(
            out,
            "doctor: {} on {path} at {} bit/s ({} servos{})",
            a.profile.display(),
            profile.bus.baud,
            profile.servos.len(),
            profile
                .bus
                .imu_board
                .map_or(String::new(), |b| format!(", IMU board at id {b}"))
        )?;
        for f in &report.fixed {
            writeln!(out, "fixed  {f}")?;
        }
        // The same finding on several servos is one line naming them.
        let mut lines: Vec<(&doctor::Finding, Vec<String>)> = Vec::new();
        for f in &report.findings {
            let who = match (f.id, &f.servo) {
                (Some(id), Some(name)) => Some(format!("{id} {name}")),
                (Some(id), None) => Some(id.to_string()),
                _ => None,
            };
            match lines
                .iter_mut()
                .find(|(g, _)| g.level == f.level && g.what == f.what && g.todo == f.todo && who.is_some())
            {
                Some((_, names)) => names.extend(who),
                None => lines.push((f, who.into_iter().collect())),
            }
        }
        for (f, names) in &lines {
            let level = match f.level {
                Level::Ok => "ok    ",
                Level::Warn => "warn  ",
                Level::Fault => "FAULT ",
            };
            let who = match names.len() {
                0 => String::new(),
                1 => format!("id {}: ", names[0]),
                n if n == profile.servos.len() => format!("all {n} servos: "),
                n => format!("{n} servos (ids {}): ", names.join(", ")),
            };
            let todo = if f.todo.is_empty() {
                String::new()
            } else {
                format!(" — {}", f.todo)
            };
            writeln!(out, "{level} {who}{}{todo}", f.what)?;
        }
        let warnings = report.at(Level::Warn).count();
        let answering = profile.servos.len() - report.unreachable();
        writeln!(
            out,
            "{answering} of {} servos answer at {} bit/s; {faults} fault(s), {warnings} warning(s): {}",
            profile.servos.len(),
            profile.bus.baud,
            if faults == 0 {
                "the rig can run the profile"
            } else {
                "the rig cannot run the profile until the faults are fixed"
            }
        )?;
    }
    if faults > 0 {
        return Err(CliError::RigNotReady(faults));
    }
    Ok(())
}

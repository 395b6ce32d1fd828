//! Calibration: each servo's zero tick and direction measured on the rig itself.
//!
//! With torque off the operator poses the rig in its reference pose (every joint at 0°);
//! the present positions there are the zeros. Each joint's direction is then confirmed by a
//! small move inside its limits that the operator watches (or, by hand, a move the operator
//! makes and the servo measures): a joint's direction is how its servo is mounted against the
//! model's axis, which only someone looking at the rig can tell.
//!
//! Zeros are kept wrap-safe. A joint whose range around its zero stays inside the servo's
//! 0…4095 keeps the profile's `zero` with no Homing Offset (the profile alone says where
//! 0° is, and a servo swapped in needs nothing written). A joint whose range would cross
//! the 0/4095 seam — the servo mounted with its horn near the seam at the reference pose —
//! gets a Homing Offset that puts the middle of its range at tick 2048 (Present Position =
//! the horn's + the offset, e-manual), recorded in the profile as `homing_offset` and
//! written at start-up, so goals and limits never wrap.

use std::time::Duration;

use crate::bus::{retried, retried_quickly, BusError, Registers, ServoBus};
use crate::profile::{Drive, Profile, ServoSpec};
use crate::servo::{addr, MAX_TICK, TICKS_PER_TURN};

/// The direction check's move, joint degrees (less where the reference pose is closer to a
/// limit).
pub const STEP_DEG: f64 = 5.0;

/// The smallest move that tells a direction, joint degrees: a joint whose reference pose is
/// closer than this to a limit is moved by hand.
pub const MIN_STEP_DEG: f64 = 1.0;

/// The direction check's speed (Profile Velocity, 0.229 rpm units: about 60°/s, a 5° move in
/// a tenth of a second).
const STEP_PROFILE_VELOCITY: u32 = 44;

/// How long the direction check's move is given, each way.
const STEP_SETTLE: Duration = Duration::from_millis(1000);

/// How often a move is looked at while it settles.
const SETTLE_POLL: Duration = Duration::from_millis(20);

/// How calibration lets time pass while a servo moves: the wall clock on a rig
/// ([`WallClock`]); a virtual chain's own time in a test.
pub trait Wait {
    /// Lets `d` pass.
    fn wait(&mut self, d: Duration);
}

/// Real time: the thread sleeps.
#[derive(Clone, Copy, Debug, Default)]
pub struct WallClock;

impl Wait for WallClock {
    fn wait(&mut self, d: Duration) {
        std::thread::sleep(d);
    }
}

/// Who stands at the rig: poses it, watches it, moves a joint by hand.
pub trait Operator {
    /// Asks for the reference pose (`pose` describes it) and returns once it is held.
    ///
    /// # Errors
    /// The operator stopped (or cannot be asked).
    fn hold_reference_pose(&mut self, pose: &str) -> Result<(), CalibrationError>;

    /// Asks whether `servo` just turned the positive way (`positive` describes it).
    ///
    /// # Errors
    /// The operator stopped.
    fn turned_positive(&mut self, servo: &ServoSpec, positive: &str) -> Result<bool, CalibrationError>;

    /// Asks for `servo` to be turned by hand a little the positive way, and returns once it is.
    ///
    /// # Errors
    /// The operator stopped.
    fn turn_by_hand(&mut self, servo: &ServoSpec, positive: &str) -> Result<(), CalibrationError>;
}

/// How each joint's direction is found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Directions {
    /// A small move with torque on, watched by the operator (by hand where the reference pose
    /// is too close to a limit to move both ways).
    Step,
    /// The operator turns each joint; torque stays off.
    ByHand,
    /// The profile's directions are kept; only the zeros are measured.
    Keep,
}

/// How a direction was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Found {
    /// A move with torque on, watched.
    Step,
    /// A move by hand, measured.
    Hand,
    /// The profile's, kept.
    Kept,
}

/// One servo's calibration.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct Calibrated {
    /// Bus id.
    pub id: u8,
    /// The profile's name for it.
    pub name: String,
    /// The horn's tick in the reference pose (without any Homing Offset).
    pub horn: i32,
    /// +1 or −1.
    pub direction: i8,
    /// How the direction was found.
    pub found: Found,
    /// The Homing Offset it runs with (0: none).
    pub homing_offset: i32,
    /// The tick of joint angle 0, in the offset's frame: `horn + homing_offset`.
    pub zero: i32,
    /// The profile's zero and direction before.
    pub was: (f64, i8),
}

/// What stops a calibration.
#[derive(Debug, thiserror::Error)]
pub enum CalibrationError {
    /// The bus failed.
    #[error(transparent)]
    Bus(#[from] BusError),
    /// The operator stopped, or cannot be asked.
    #[error("{0}")]
    Operator(String),
    /// A servo did not move when it was told to, or was not moved by hand.
    #[error("id {id} {name}: {what}")]
    NoMove {
        /// Bus id.
        id: u8,
        /// Its name.
        name: String,
        /// What happened.
        what: String,
    },
    /// The joint's range does not fit in one turn of its servo.
    #[error("id {id} {name}: its range is more than one turn of the servo")]
    Range {
        /// Bus id.
        id: u8,
        /// Its name.
        name: String,
    },
    /// A servo reported a hardware error (overload, overheating: the alert bit of its status
    /// packets) and shut its torque off; nothing it measures then tells its direction.
    #[error(
        "id {id} {name}: reported hardware error {} {when}, and shut its torque off; torque is off on every servo — remove the cause (a blocked joint, a hot servo), then `marionette doctor PROFILE --fix` reboots it",
        crate::bus::hardware_error_names(*.bits)
    )]
    HardwareError {
        /// Bus id.
        id: u8,
        /// Its name.
        name: String,
        /// Its Hardware Error Status (0 when it could not be read).
        bits: u8,
        /// When it was seen: "before calibration", "while the reference pose was held",
        /// "before it moved", "while it moved".
        when: &'static str,
    },
}

/// The servo whose status packet carried the hardware-error alert since the bus was last
/// asked, as an error naming it from `profile` (when it is there) with its Hardware Error
/// Status.
fn alerted(
    bus: &mut dyn ServoBus,
    profile: &[ServoSpec],
    when: &'static str,
) -> Result<(), CalibrationError> {
    match bus.take_alert() {
        None => Ok(()),
        Some(id) => Err(CalibrationError::HardwareError {
            id,
            name: profile
                .iter()
                .find(|s| s.id == id)
                .map_or_else(String::new, |s| s.name.clone()),
            bits: bus.hardware_error(id).unwrap_or(0),
            when,
        }),
    }
}

/// The reference pose in words: the profile's `[rig] reference_pose`, else the skeleton's rest
/// pose (servos driven by bones) or the robot's zero pose (joints).
#[must_use]
pub fn reference_pose(profile: &Profile) -> String {
    if let Some(p) = &profile.reference_pose {
        return p.clone();
    }
    if profile
        .servos
        .iter()
        .all(|s| matches!(s.drive, Drive::Bone { .. }))
    {
        "the skeleton's rest pose: every bone's DOF at 0°, as the ASF's base pose stands".into()
    } else {
        "the robot's zero pose: every joint at 0°, as its model stands with no angle set".into()
    }
}

/// The positive way of a servo's joint, in words.
#[must_use]
pub fn positive_way(servo: &ServoSpec) -> String {
    match &servo.drive {
        Drive::Bone { bone, dof } => format!(
            "{bone} turning positive about its {} axis (right-hand rule, the ASF's axes)",
            format!("{dof:?}").to_lowercase().trim_start_matches('r')
        ),
        Drive::Joint(j) => format!("joint {j} turning positive as in the robot's model"),
    }
}

/// Where a joint angle lands in ticks from `zero` with `direction` (exact).
fn tick_at(servo: &ServoSpec, zero: f64, direction: f64, deg: f64) -> f64 {
    zero + direction * servo.gear * deg.to_radians() * f64::from(TICKS_PER_TURN) / std::f64::consts::TAU
}

/// The Homing Offset and zero for a joint whose horn is at `horn` in the reference pose:
/// no offset when its range stays within 0…4095 from there; otherwise the offset that puts
/// the middle of its range at tick 2048.
///
/// # Errors
/// [`CalibrationError::Range`]: the range is more than a turn.
pub fn wrap_safe_zero(servo: &ServoSpec, horn: i32, direction: f64) -> Result<(i32, i32), CalibrationError> {
    let fits = |zero: f64| {
        let (a, b) = (
            tick_at(servo, zero, direction, servo.min_deg),
            tick_at(servo, zero, direction, servo.max_deg),
        );
        a.min(b) >= 0.0 && a.max(b) <= f64::from(MAX_TICK)
    };
    if fits(f64::from(horn)) {
        return Ok((0, horn));
    }
    let middle = 0.5 * (servo.min_deg + servo.max_deg);
    let zero = (2048.0 - tick_at(servo, 0.0, direction, middle)).round();
    if !fits(zero) {
        return Err(CalibrationError::Range {
            id: servo.id,
            name: servo.name.clone(),
        });
    }
    let zero = zero as i32;
    Ok((zero - horn, zero))
}

fn read_i32(bus: &mut dyn ServoBus, id: u8, address: u16) -> Result<i32, BusError> {
    retried(|| bus.read_value(id, address, 4)).map(|v| v as i32)
}

fn write(bus: &mut dyn ServoBus, id: u8, address: u16, data: &[u8]) -> Result<(), BusError> {
    retried(|| bus.write(id, address, data))
}

/// Torque off on every profiled servo (each tried three times on a busy line, as a stop does,
/// so that a rig gone silent is not waited for [`crate::bus::PATIENCE`] a servo; the first
/// error returned).
fn all_torque_off(bus: &mut dyn ServoBus, profile: &Profile) -> Result<(), BusError> {
    let mut first = None;
    for s in &profile.servos {
        if let Err(e) = retried_quickly(|| bus.set_torque(s.id, false)) {
            first.get_or_insert(e);
        }
    }
    first.map_or(Ok(()), Err)
}

/// What a servo held before calibration touched it: id, Homing Offset, Max and Min Position
/// Limit.
type Saved = (u8, i32, i32, i32);

/// Calibrates every servo of `profile` on `bus` with `operator`: zeros from the reference
/// pose, directions as `how` says, then the Homing Offset and the position limits of the
/// result written to each servo (torque off, EEPROM). Torque is off on every servo when it
/// returns, whatever happened; a calibration that stops puts back the offsets and limits the
/// servos held.
///
/// # Errors
/// [`CalibrationError`]; nothing is written into the profile then.
pub fn calibrate(
    bus: &mut dyn ServoBus,
    profile: &Profile,
    how: Directions,
    operator: &mut dyn Operator,
    clock: &mut dyn Wait,
) -> Result<Vec<Calibrated>, CalibrationError> {
    let mut saved = Vec::with_capacity(profile.servos.len());
    let result = run(bus, profile, (how, clock), operator, &mut saved);
    let off = all_torque_off(bus, profile);
    if result.is_err() {
        // Best effort: the error that stopped it is the one to report.
        for &(id, homing, max, min) in &saved {
            let _ = write(bus, id, addr::HOMING_OFFSET, &homing.to_le_bytes());
            let _ = write(bus, id, addr::MAX_POSITION_LIMIT, &max.to_le_bytes());
            let _ = write(bus, id, addr::MIN_POSITION_LIMIT, &min.to_le_bytes());
        }
    }
    let done = result?;
    off?;
    Ok(done)
}

fn run(
    bus: &mut dyn ServoBus,
    profile: &Profile,
    (how, clock): (Directions, &mut dyn Wait),
    operator: &mut dyn Operator,
    saved: &mut Vec<Saved>,
) -> Result<Vec<Calibrated>, CalibrationError> {
    for s in &profile.servos {
        retried(|| bus.ping(s.id))?;
    }
    // A servo already shut down by a hardware error would not move for its direction check.
    alerted(bus, &profile.servos, "before calibration")?;
    all_torque_off(bus, profile)?;
    for s in &profile.servos {
        // In one read: a late reply to one 4-byte read would pass for the next one's.
        let r = Registers::read(bus, s.id)?;
        saved.push((
            s.id,
            r.signed(addr::HOMING_OFFSET),
            r.signed(addr::MAX_POSITION_LIMIT),
            r.signed(addr::MIN_POSITION_LIMIT),
        ));
    }
    operator.hold_reference_pose(&reference_pose(profile))?;
    // The horn's tick at the reference pose: Present Position less the offset now in place.
    let mut horns = Vec::with_capacity(profile.servos.len());
    for (s, &(_, homing, _, _)) in profile.servos.iter().zip(saved.iter()) {
        let present = read_i32(bus, s.id, addr::PRESENT_POSITION)?;
        horns.push(present - homing);
    }
    // A servo that shut down while the pose was held (one overheating as it was posed) says
    // so in the reply just read, before anything moves.
    alerted(bus, &profile.servos, "while the reference pose was held")?;
    let mut done = Vec::with_capacity(profile.servos.len());
    for (s, &horn) in profile.servos.iter().zip(&horns) {
        let was = s.direction as i8;
        let room = s.max_deg.min(-s.min_deg);
        let (direction, found) = match how {
            Directions::Keep => (was, Found::Kept),
            Directions::Step if room >= MIN_STEP_DEG => {
                (step_direction(bus, s, horn, operator, clock)?, Found::Step)
            }
            Directions::Step | Directions::ByHand => (hand_direction(bus, s, operator)?, Found::Hand),
        };
        let (homing_offset, zero) = wrap_safe_zero(s, horn, f64::from(direction))?;
        done.push(Calibrated {
            id: s.id,
            name: s.name.clone(),
            horn,
            direction,
            found,
            homing_offset,
            zero,
            was: (s.zero, was),
        });
    }
    // The servos as the new profile runs them: the offset, then the limits in its frame.
    for (s, c) in profile.servos.iter().zip(&done) {
        let mut spec = s.clone();
        spec.zero = f64::from(c.zero);
        spec.direction = f64::from(c.direction);
        let (lo, hi) = spec.tick_limits();
        write(bus, s.id, addr::HOMING_OFFSET, &c.homing_offset.to_le_bytes())?;
        write(bus, s.id, addr::MAX_POSITION_LIMIT, &hi.to_le_bytes())?;
        write(bus, s.id, addr::MIN_POSITION_LIMIT, &lo.to_le_bytes())?;
    }
    Ok(done)
}

/// Moves `s` a small step with torque on and asks which way it turned. For the move the
/// reference pose reads 2048 (a Homing Offset for the duration) and the position limits
/// allow the step and no more, so a servo near the seam cannot wrap and none can swing far.
fn step_direction(
    bus: &mut dyn ServoBus,
    s: &ServoSpec,
    horn: i32,
    operator: &mut dyn Operator,
    clock: &mut dyn Wait,
) -> Result<i8, CalibrationError> {
    let deg = STEP_DEG.min(0.8 * s.max_deg.min(-s.min_deg));
    let step = tick_at(s, 0.0, 1.0, deg).abs().round().max(2.0) as i32;
    let velocity_before = read_i32(bus, s.id, addr::PROFILE_VELOCITY)?;
    // Raised since the last look (while another servo was checked): before it moves. From here
    // on every reply is `s`'s, so an alert in `settle` is its own.
    alerted(bus, core::slice::from_ref(s), "before it moved")?;
    write(bus, s.id, addr::HOMING_OFFSET, &(2048 - horn).to_le_bytes())?;
    write(
        bus,
        s.id,
        addr::MAX_POSITION_LIMIT,
        &(2048 + step + 8).to_le_bytes(),
    )?;
    write(
        bus,
        s.id,
        addr::MIN_POSITION_LIMIT,
        &(2048 - step - 8).to_le_bytes(),
    )?;
    let start = read_i32(bus, s.id, addr::PRESENT_POSITION)?;
    let moved = (|| -> Result<i32, CalibrationError> {
        write(bus, s.id, addr::GOAL_POSITION, &start.to_le_bytes())?;
        write(
            bus,
            s.id,
            addr::PROFILE_VELOCITY,
            &STEP_PROFILE_VELOCITY.to_le_bytes(),
        )?;
        retried(|| bus.set_torque(s.id, true))?;
        write(bus, s.id, addr::GOAL_POSITION, &(start + step).to_le_bytes())?;
        let there = settle(bus, clock, s, start + step)?;
        Ok(there - start)
    })();
    // Back, whatever happened (but after a hardware error: the servo has let go), then torque
    // off and the speed as it was.
    let back = match moved {
        Err(CalibrationError::HardwareError { .. }) => Ok(()),
        _ => write(bus, s.id, addr::GOAL_POSITION, &start.to_le_bytes())
            .map_err(CalibrationError::from)
            .and_then(|()| settle(bus, clock, s, start).map(drop)),
    };
    retried(|| bus.set_torque(s.id, false))?;
    write(bus, s.id, addr::PROFILE_VELOCITY, &velocity_before.to_le_bytes())?;
    let moved = moved?;
    back?;
    if moved.abs() < step / 2 {
        return Err(CalibrationError::NoMove {
            id: s.id,
            name: s.name.clone(),
            what: format!("told to move {step} ticks, it moved {moved}: is it blocked, or unpowered?"),
        });
    }
    let positive = operator.turned_positive(s, &positive_way(s))?;
    Ok(if positive { 1 } else { -1 })
}

/// Waits until servo `s` is within a few ticks of `goal` (or [`STEP_SETTLE`] has passed);
/// returns where it is. A hardware-error alert in its reply (an overload as it pushes against
/// something) ends the wait with [`CalibrationError::HardwareError`].
fn settle(
    bus: &mut dyn ServoBus,
    clock: &mut dyn Wait,
    s: &ServoSpec,
    goal: i32,
) -> Result<i32, CalibrationError> {
    let mut waited = Duration::ZERO;
    loop {
        clock.wait(SETTLE_POLL);
        waited += SETTLE_POLL;
        let at = read_i32(bus, s.id, addr::PRESENT_POSITION)?;
        alerted(bus, core::slice::from_ref(s), "while it moved")?;
        if (at - goal).abs() <= 3 || waited >= STEP_SETTLE {
            return Ok(at);
        }
    }
}

/// Asks the operator to turn `s` the positive way by hand and reads which way its ticks went.
fn hand_direction(
    bus: &mut dyn ServoBus,
    s: &ServoSpec,
    operator: &mut dyn Operator,
) -> Result<i8, CalibrationError> {
    let least = tick_at(s, 0.0, 1.0, 2.0 * MIN_STEP_DEG).abs().round() as i32;
    let before = read_i32(bus, s.id, addr::PRESENT_POSITION)?;
    operator.turn_by_hand(s, &positive_way(s))?;
    let after = read_i32(bus, s.id, addr::PRESENT_POSITION)?;
    let moved = after - before;
    if moved.abs() < least {
        return Err(CalibrationError::NoMove {
            id: s.id,
            name: s.name.clone(),
            what: format!(
                "it turned {moved} ticks by hand, at least {least} ({}°) tell the way",
                2.0 * MIN_STEP_DEG
            ),
        });
    }
    Ok(if moved > 0 { 1 } else { -1 })
}

/// The profile text with the calibration written into it (`zero`, `direction`, and
/// `homing_offset` where one is used or the profile had one), comments and layout kept.
#[must_use]
pub fn write_into(text: &str, profile: &Profile, done: &[Calibrated]) -> String {
    let values: Vec<(String, Vec<(&str, String)>)> = done
        .iter()
        .map(|c| {
            let mut keys = vec![
                ("direction", c.direction.to_string()),
                ("zero", c.zero.to_string()),
            ];
            let had = profile
                .servos
                .iter()
                .find(|s| s.id == c.id)
                .is_some_and(|s| s.homing_offset.is_some());
            if c.homing_offset != 0 || had {
                keys.push(("homing_offset", c.homing_offset.to_string()));
            }
            (c.name.clone(), keys)
        })
        .collect();
    crate::profile::set_servo_keys(text, &values)
}

//! Dynamixel X-series servo models and their control table (ROBOTIS e-manual figures).
//!
//! All four supported models share the X-series control-table layout; they differ in model
//! number, top baud rate and speed. Positions are 4096 ticks per turn, 0…4095 in position mode.

use crate::math::{real, Real};

/// Control-table addresses of the X series (`EEPROM` below 64, `RAM` from 64).
pub mod addr {
    /// Model number, 2 bytes (EEPROM, read-only).
    pub const MODEL_NUMBER: u16 = 0;
    /// Firmware version, 1 byte.
    pub const FIRMWARE_VERSION: u16 = 6;
    /// Id, 1 byte.
    pub const ID: u16 = 7;
    /// Baud rate index, 1 byte.
    pub const BAUD_RATE: u16 = 8;
    /// Return delay time, 1 byte, 2 µs units (default 250 = 500 µs).
    pub const RETURN_DELAY_TIME: u16 = 9;
    /// Operating mode, 1 byte (3 = position control).
    pub const OPERATING_MODE: u16 = 11;
    /// Homing Offset (4 B, signed, EEPROM): Present Position = the horn's position + it.
    pub const HOMING_OFFSET: u16 = 20;
    /// Velocity limit, 4 bytes, 0.229 rpm units.
    pub const VELOCITY_LIMIT: u16 = 44;
    /// Maximum position limit, 4 bytes.
    pub const MAX_POSITION_LIMIT: u16 = 48;
    /// Minimum position limit, 4 bytes.
    pub const MIN_POSITION_LIMIT: u16 = 52;
    /// Shutdown conditions, 1 byte (bits of the hardware error status).
    pub const SHUTDOWN: u16 = 63;
    /// Torque enable, 1 byte (RAM). EEPROM is locked while it is 1.
    pub const TORQUE_ENABLE: u16 = 64;
    /// Status return level, 1 byte (0 ping only, 1 ping + read, 2 all).
    pub const STATUS_RETURN_LEVEL: u16 = 68;
    /// Hardware error status, 1 byte.
    pub const HARDWARE_ERROR_STATUS: u16 = 70;
    /// Position P Gain, 2 bytes (RAM): the position loop's gain, `K_P = value / 128`.
    pub const POSITION_P_GAIN: u16 = 84;
    /// Bus watchdog, 1 byte, 20 ms units (1…127; 0 off; reads −1 after expiry).
    pub const BUS_WATCHDOG: u16 = 98;
    /// Profile acceleration, 4 bytes, 214.577 rev/min² units.
    pub const PROFILE_ACCELERATION: u16 = 108;
    /// Profile velocity, 4 bytes, 0.229 rpm units (0 = unlimited).
    pub const PROFILE_VELOCITY: u16 = 112;
    /// Goal position, 4 bytes.
    pub const GOAL_POSITION: u16 = 116;
    /// Moving, 1 byte.
    pub const MOVING: u16 = 122;
    /// Moving Threshold, 4 bytes, 0.229 rpm units: Moving is 1 above it.
    pub const MOVING_THRESHOLD: u16 = 24;
    /// PWM Limit, 2 bytes, 0.113 % units.
    pub const PWM_LIMIT: u16 = 36;
    /// Current Limit, 2 bytes, the model's current units.
    pub const CURRENT_LIMIT: u16 = 38;
    /// Moving Status, 1 byte: bit 0 in position, bit 1 a profile under way.
    pub const MOVING_STATUS: u16 = 123;
    /// Present PWM, 2 bytes (signed), 0.113 % units.
    pub const PRESENT_PWM: u16 = 124;
    /// Present current, 2 bytes (signed), the model's units (Present Load, 0.1 %, on models
    /// without current sensing).
    pub const PRESENT_CURRENT: u16 = 126;
    /// Present velocity, 4 bytes (signed), 0.229 rpm units.
    pub const PRESENT_VELOCITY: u16 = 128;
    /// Present position, 4 bytes (signed).
    pub const PRESENT_POSITION: u16 = 132;
    /// Present input voltage, 2 bytes, 0.1 V units.
    pub const PRESENT_INPUT_VOLTAGE: u16 = 144;
    /// Present temperature, 1 byte, °C.
    pub const PRESENT_TEMPERATURE: u16 = 146;
}

/// Bits of the hardware error status (address 70).
pub mod hardware_error {
    /// Input voltage out of range.
    pub const INPUT_VOLTAGE: u8 = 1 << 0;
    /// Overheating.
    pub const OVERHEATING: u8 = 1 << 2;
    /// Motor encoder fault.
    pub const ENCODER: u8 = 1 << 3;
    /// Electrical shock / insufficient power.
    pub const ELECTRICAL_SHOCK: u8 = 1 << 4;
    /// Persistent overload.
    pub const OVERLOAD: u8 = 1 << 5;
}

/// Error numbers of a status packet's error byte (bit 7 is the hardware-alert flag).
pub mod status_error {
    /// The instruction failed.
    pub const RESULT_FAIL: u8 = 1;
    /// Undefined instruction.
    pub const INSTRUCTION: u8 = 2;
    /// CRC mismatch in the instruction.
    pub const CRC: u8 = 3;
    /// Value out of range.
    pub const DATA_RANGE: u8 = 4;
    /// Wrong data length.
    pub const DATA_LENGTH: u8 = 5;
    /// Value beyond a limit.
    pub const DATA_LIMIT: u8 = 6;
    /// Write to a read-only or locked address (EEPROM with torque on, watchdog expired).
    pub const ACCESS: u8 = 7;
    /// The hardware-alert flag: read the hardware error status.
    pub const ALERT: u8 = 0x80;
}

/// Most servos on one bus or in one rig.
pub const MAX_SERVOS: usize = 64;
/// Ticks per output-shaft turn.
pub const TICKS_PER_TURN: u32 = 4096;
/// Highest position in position-control mode.
pub const MAX_TICK: i32 = 4095;
/// rpm per unit of velocity registers (Profile Velocity, Present Velocity, Velocity Limit).
pub const RPM_PER_VELOCITY_UNIT: Real = 0.229;
/// rev/min² per unit of Profile Acceleration.
pub const RPM2_PER_ACCELERATION_UNIT: Real = 214.577;

/// A supported servo model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ServoModel {
    /// Catalogue name, e.g. `XM430-W350`.
    pub name: &'static str,
    /// Model number in the control table (address 0).
    pub model_number: u16,
    /// Highest baud rate, bit/s.
    pub max_baud: u32,
    /// No-load speed at the recommended voltage, rev/min.
    pub no_load_rpm: Real,
    /// Stall torque at the recommended voltage, N·m.
    pub stall_torque_nm: Real,
    /// Factory Position P Gain (control-table units).
    pub position_p_gain: u16,
    /// Gear ratio (motor turns per horn turn), e-manual.
    pub gear_ratio: Real,
    /// The voltage the no-load speed and stall torque are given at (the recommended one).
    pub rated_v: Real,
    /// The supply range the e-manual allows, volts.
    pub min_v: Real,
    /// Highest supply, volts.
    pub max_v: Real,
    /// Stall current at the rated voltage, A (e-manual).
    pub stall_current_a: Real,
    /// mA per unit of Present Current (126); 0 for models that report Present Load there
    /// (0.1 % of the maximum torque) instead.
    pub current_unit_ma: Real,
    /// Current Limit's factory value (38), its units; 0 where the model has none.
    pub current_limit: u16,
    /// Temperature Limit's factory value (31), °C.
    pub temperature_limit: u8,
    /// Max and Min Voltage Limit's factory values (32, 34), 0.1 V.
    pub voltage_limits: (u16, u16),
    /// The range both voltage limits accept, 0.1 V.
    pub voltage_range: (u16, u16),
    /// Velocity Limit's factory value (44) and the largest it accepts, 0.229 rev/min.
    pub velocity_limit: (u16, u16),
    /// Factory Velocity I and P Gains (76, 78) and Position D Gain (80).
    pub velocity_i_gain: u16,
    /// Factory Velocity P Gain (78).
    pub velocity_p_gain: u16,
    /// Factory Position D Gain (80).
    pub position_d_gain: u16,
    /// The control-table family: which items the model has.
    pub family: Family,
}

/// Control-table families of the X series: where the items of one model differ from another's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Family {
    /// XL330/XC330: Baud Rate up to 4 Mbps, PWM Slope (62), Indirect Address/Data 1–20 at
    /// 168/208, Protocol Type 2–22.
    X330,
    /// XL430: no Current Limit or Goal Current (Present Load at 126), operating modes 1, 3, 4, 16.
    Xl430,
    /// XM430/XH430: the common layout, Indirect Address/Data 1–56.
    X430,
    /// XM540/XH540: the common layout plus External Ports (56–58, 152–157).
    X540,
}

impl ServoModel {
    /// No-load speed in radians per second at the rated voltage.
    #[must_use]
    pub fn max_speed_rad_s(&self) -> Real {
        self.no_load_rpm * crate::math::consts::TAU / 60.0
    }

    /// How a DC motor scales with its supply: no-load speed and stall torque in proportion to
    /// the voltage (the e-manual's figures at three voltages follow it within 2 %), the slope of
    /// the torque–speed line unchanged. The factor at `volts`, clamped to the allowed range.
    #[must_use]
    pub fn voltage_factor(&self, volts: Real) -> Real {
        if volts.is_finite() && self.rated_v > 0.0 {
            volts.clamp(self.min_v, self.max_v) / self.rated_v
        } else {
            1.0
        }
    }

    /// Stall torque at `volts`, N·m.
    #[must_use]
    pub fn stall_torque_at(&self, volts: Real) -> Real {
        self.stall_torque_nm * self.voltage_factor(volts)
    }

    /// No-load speed at `volts`, radians per second.
    #[must_use]
    pub fn max_speed_rad_s_at(&self, volts: Real) -> Real {
        self.max_speed_rad_s() * self.voltage_factor(volts)
    }
}

/// The models this release knows.
pub const MODELS: [ServoModel; 5] = [
    ServoModel {
        name: "XL330-M288",
        model_number: 1200,
        max_baud: 4_000_000,
        no_load_rpm: 103.0,
        stall_torque_nm: 0.52,
        position_p_gain: 400,
        gear_ratio: 288.35,
        rated_v: 5.0,
        min_v: 3.7,
        max_v: 6.0,
        stall_current_a: 1.47,
        current_unit_ma: 1.0,
        current_limit: 1750,
        temperature_limit: 70,
        voltage_limits: (70, 35),
        voltage_range: (31, 70),
        velocity_limit: (445, 2047),
        velocity_i_gain: 1600,
        velocity_p_gain: 180,
        position_d_gain: 0,
        family: Family::X330,
    },
    ServoModel {
        name: "XL430-W250",
        model_number: 1060,
        max_baud: 4_500_000,
        no_load_rpm: 57.0,
        stall_torque_nm: 1.4,
        position_p_gain: 640,
        gear_ratio: 258.5,
        rated_v: 11.1,
        min_v: 6.5,
        max_v: 12.0,
        stall_current_a: 1.3,
        current_unit_ma: 0.0,
        current_limit: 0,
        temperature_limit: 72,
        voltage_limits: (140, 60),
        voltage_range: (60, 140),
        velocity_limit: (265, 1023),
        velocity_i_gain: 1000,
        velocity_p_gain: 100,
        position_d_gain: 4000,
        family: Family::Xl430,
    },
    ServoModel {
        name: "XM430-W350",
        model_number: 1020,
        max_baud: 4_500_000,
        no_load_rpm: 46.0,
        stall_torque_nm: 4.1,
        position_p_gain: 800,
        gear_ratio: 353.5,
        rated_v: 12.0,
        min_v: 10.0,
        max_v: 14.8,
        stall_current_a: 2.3,
        current_unit_ma: 2.69,
        current_limit: 1193,
        temperature_limit: 80,
        voltage_limits: (160, 95),
        voltage_range: (95, 160),
        velocity_limit: (200, 1023),
        velocity_i_gain: 1920,
        velocity_p_gain: 100,
        position_d_gain: 0,
        family: Family::X430,
    },
    ServoModel {
        name: "XH540-W270",
        model_number: 1100,
        max_baud: 4_500_000,
        no_load_rpm: 30.0,
        stall_torque_nm: 10.6,
        position_p_gain: 800,
        gear_ratio: 272.5,
        rated_v: 12.0,
        min_v: 10.0,
        max_v: 14.8,
        stall_current_a: 4.4,
        current_unit_ma: 2.69,
        current_limit: 2047,
        temperature_limit: 80,
        voltage_limits: (160, 95),
        voltage_range: (95, 160),
        velocity_limit: (167, 1023),
        velocity_i_gain: 1920,
        velocity_p_gain: 100,
        position_d_gain: 0,
        family: Family::X540,
    },
    ServoModel {
        name: "XM430-W210",
        model_number: 1030,
        max_baud: 4_500_000,
        no_load_rpm: 77.0,
        stall_torque_nm: 3.0,
        position_p_gain: 800,
        gear_ratio: 212.6,
        rated_v: 12.0,
        min_v: 10.0,
        max_v: 14.8,
        stall_current_a: 2.3,
        current_unit_ma: 2.69,
        current_limit: 1193,
        temperature_limit: 80,
        voltage_limits: (160, 95),
        voltage_range: (95, 160),
        velocity_limit: (330, 1023),
        velocity_i_gain: 1920,
        velocity_p_gain: 100,
        position_d_gain: 0,
        family: Family::X430,
    },
];

/// The model with this catalogue name (case-insensitive; a `-T`/`-R` suffix is ignored).
#[must_use]
pub fn model_by_name(name: &str) -> Option<&'static ServoModel> {
    let base = name
        .strip_suffix("-T")
        .or_else(|| name.strip_suffix("-R"))
        .unwrap_or(name);
    MODELS.iter().find(|m| m.name.eq_ignore_ascii_case(base))
}

/// The model with this model number.
#[must_use]
pub fn model_by_number(number: u16) -> Option<&'static ServoModel> {
    MODELS.iter().find(|m| m.model_number == number)
}

/// One step of a velocity- and acceleration-limited follower: the velocity that would reach
/// `target` this step, bounded by `vmax`, by the speed from which `amax` can still stop at the
/// target (`√(2·amax·d)`), and by `amax·dt` of change from the last velocity.
#[must_use]
pub fn step_towards(
    position: Real,
    velocity: Real,
    target: Real,
    vmax: Real,
    amax: Real,
    dt: Real,
) -> (Real, Real) {
    let d = target - position;
    if d == 0.0 {
        // At the target: whatever the bounds, the step below ends there, at rest.
        return (target, 0.0);
    }
    let mut v = d / dt;
    let vmax = if vmax > 0.0 { vmax } else { Real::INFINITY };
    v = real::clamp(v, -vmax, vmax);
    if amax > 0.0 && amax.is_finite() {
        // Braking: from speed v we need v²/(2a) to stop; never go faster than that allows.
        let brake = real::sqrt(2.0 * amax * d.abs());
        let allowed = real::max(brake, amax * dt);
        v = real::clamp(v, -allowed, allowed);
        let dv = amax * dt;
        v = real::clamp(v, velocity - dv, velocity + dv);
    }
    // Never step past the target.
    let step = v * dt;
    if (d >= 0.0 && step > d) || (d <= 0.0 && step < d) {
        return (target, d / dt);
    }
    (position + step, v)
}

/// Bounds of one servo's motion in its own units (ticks, ticks/s, ticks/s²); a rate that is
/// not a positive finite number means "none".
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionLimits {
    /// Largest speed.
    pub velocity: Real,
    /// Largest acceleration.
    pub acceleration: Real,
    /// Lowest position.
    pub min: Real,
    /// Highest position.
    pub max: Real,
}

impl MotionLimits {
    /// (velocity, acceleration, lowest, highest) with missing rates as infinity and the range
    /// in order.
    #[must_use]
    pub fn sane(&self) -> (Real, Real, Real, Real) {
        let rate = |v: Real| {
            if v.is_finite() && v > 0.0 {
                v
            } else {
                Real::INFINITY
            }
        };
        let (lo, hi) = if self.min <= self.max {
            (self.min, self.max)
        } else {
            (self.max, self.min)
        };
        (rate(self.velocity), rate(self.acceleration), lo, hi)
    }
}

/// One step along a planned path: the velocity that reaches `next` this step, bounded by the
/// velocity limit, by the acceleration limit's change from the last velocity, and by the speed
/// from which that acceleration can still stop at the position limit ahead. Unlike
/// [`step_towards`] it does not brake towards `next`: that is a point on a path that goes on,
/// not a place to stop. Returns the new position (inside the limits) and velocity.
#[must_use]
pub fn step_along(
    position: Real,
    velocity: Real,
    next: Real,
    dt: Real,
    limits: &MotionLimits,
) -> (Real, Real) {
    let (vmax, amax, lo, hi) = limits.sane();
    let v = ((next - position) / dt).clamp(-vmax, vmax);
    let v = if amax.is_finite() {
        let dv = amax * dt;
        v.clamp(velocity - dv, velocity + dv)
    } else {
        v
    };
    brake_and_move(position, v, dt, amax, lo, hi)
}

/// Bounds `v` by the speed from which `amax` can still stop at `lo`/`hi`, then moves `dt`:
/// the new position (inside the limits) and velocity.
#[must_use]
pub fn brake_and_move(position: Real, v: Real, dt: Real, amax: Real, lo: Real, hi: Real) -> (Real, Real) {
    let mut v = v;
    if amax.is_finite() {
        let up = real::sqrt(2.0 * amax * (hi - position).max(0.0)).max(amax * dt);
        let down = real::sqrt(2.0 * amax * (position - lo).max(0.0)).max(amax * dt);
        v = v.clamp(-down, up);
    }
    ((position + v * dt).clamp(lo, hi), v)
}

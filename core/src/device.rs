//! The device side of Protocol 2.0: a chain of virtual X-series servos.
//!
//! Each servo has a control table (the X-series layout of [`crate::servo::addr`]), position
//! dynamics limited by its Profile Velocity and Profile Acceleration, a return delay time,
//! hardware error bits, the Bus Watchdog, and reboot clearing RAM. [`Chain::handle`] answers one
//! instruction packet with the status packets real servos would send, in order, each with the
//! delay before it; [`Receiver`] cuts a byte stream into packets. Everything is fixed-size, so
//! the chain also runs in the embedded build.

use crate::control_table::{self, indirect_blocks, Access, Item};
use crate::math::{real, Real};
use crate::protocol::{self, instruction, CodecError, BROADCAST_ID};
use crate::sensor_board::SensorBoard;
use crate::servo::addr::HOMING_OFFSET;
use crate::servo::{addr, status_error, step_towards, ServoModel, MAX_SERVOS, RPM2_PER_ACCELERATION_UNIT};
use crate::servo::{RPM_PER_VELOCITY_UNIT, TICKS_PER_TURN};

/// What a servo answers to an instruction on addresses no control-table item defines: a
/// write inside the table's gaps (X-series: 252–577) or past its end, a read past its end.
///
/// The e-manual lists Access Error (7) for an address "not defined". Real X-series firmware
/// answers Data Range Error (4): ROBOTIS's own `read_write` example run with Pro-series
/// addresses (Torque Enable at 562, a gap on the X series) got "The data value is out of
/// range!" from an XM430-W350-R (DynamixelSDK issue 148), an XM540-W270-R (175) and an MX-28
/// on Protocol 2.0 (456); the same reports show a read inside the table (611) answered with
/// data and no error, which is what a read here does (reserved bytes read 0). The chain
/// answers as those servos did.
pub const UNDEFINED_ADDRESS_ERROR: u8 = status_error::DATA_RANGE;

/// Bytes of control table each virtual servo keeps (addresses 0…661: Indirect Data 56 last).
pub const TABLE_LEN: usize = 662;
/// Largest packet (stuffed) the chain accepts or sends.
pub const MAX_PACKET: usize = 1024;
pub use crate::control_table::FIRMWARE_VERSION;

/// Ticks/s per unit of Profile Velocity.
const TICKS_PER_S_PER_VELOCITY_UNIT: Real = RPM_PER_VELOCITY_UNIT / 60.0 * TICKS_PER_TURN as Real;
/// Ticks/s² per unit of Profile Acceleration.
const TICKS_PER_S2_PER_ACCELERATION_UNIT: Real = RPM2_PER_ACCELERATION_UNIT / 3600.0 * TICKS_PER_TURN as Real;
/// Acceleration when Profile Acceleration is 0 ("unlimited"): the motor's own, ~0.05 s to full speed.
const DEFAULT_RAMP_S: Real = 0.05;

/// One virtual servo.
#[derive(Clone, Debug)]
pub struct VirtualServo {
    table: [u8; TABLE_LEN],
    model: &'static ServoModel,
    position: Real,
    velocity: Real,
    since_packet: Real,
    watchdog_expired: bool,
    torque_jumps: u32,
    /// On a line at another baud than its Baud Rate register's (the chain's line baud): it
    /// hears nothing.
    off_baud: bool,
    write_count: u32,
    velocity_report: Option<i32>,
    reported_position: Option<i32>,
    /// Milliseconds since power-on (Realtime Tick).
    clock_ms: Real,
    /// A write held by Reg Write until Action: address and data.
    registered: Option<(u16, heapless::Vec<u8, 128>)>,
    /// Torque at the horn, N·m, as the plant last measured it (0 without a load model).
    load_nm: Real,
    /// Where the firmware's motion profile stands (ticks, ticks/s) while one is under way.
    profile: Option<(Real, Real)>,
    /// An Indirect Address was written since power-on: Indirect Data must follow writes.
    indirect_in_use: bool,
    /// The supply it is powered from, volts (Present Input Voltage).
    supply_v: Real,
    /// The motor's temperature, °C (Present Temperature): [`VirtualServo::heat`].
    temperature_c: Real,
}

/// The air around the servos, °C: where a servo starts and what it cools towards.
pub const AMBIENT_C: Real = 25.0;

/// The thermal model's time constant, s. The e-manual gives none; a small DC motor in a
/// plastic case is assumed to take a couple of minutes to settle.
pub const THERMAL_TIME_CONSTANT_S: Real = 120.0;

/// The share of the stall current a servo carries forever at its Temperature Limit: the
/// thermal resistance follows from it (catalogue continuous ratings are about a third to a
/// half of stall).
pub const CONTINUOUS_CURRENT_SHARE: Real = 0.4;

/// PWM Limit's factory value and full scale (0.113 % units).
const PWM_FULL: Real = 885.0;

/// Baud Rate register codes (e-manual): 9,600 … 4.5 Mbps.
pub const BAUD_CODES: [u32; 8] = [
    9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000,
];
/// Realtime Tick (2 bytes, ms, wraps at 32,767).
const REALTIME_TICK: u16 = 120;
/// Secondary (Shadow) ID: 253 and above switch it off.
const SECONDARY_ID: usize = 12;
/// Temperature Limit (1 byte, °C, EEPROM).
const TEMPERATURE_LIMIT: usize = 31;
/// Protocol Type: the servo answers Protocol 2.0 only while it holds 2.
const PROTOCOL_TYPE: usize = 13;
/// Velocity Trajectory and Position Trajectory (4 bytes each): the profile's set point.
const VELOCITY_TRAJECTORY: u16 = 136;
const POSITION_TRAJECTORY: u16 = 140;
/// Registered Instruction: 1 while a Reg Write waits for Action (read-only).
const REGISTERED_INSTRUCTION: u16 = 69;

impl VirtualServo {
    /// A servo at rest at `position` ticks with factory defaults.
    #[must_use]
    pub fn new(id: u8, model: &'static ServoModel, position: i32) -> VirtualServo {
        let mut s = VirtualServo {
            table: [0; TABLE_LEN],
            model,
            position: (position as Real),
            velocity: 0.0,
            since_packet: 0.0,
            watchdog_expired: false,
            torque_jumps: 0,
            off_baud: false,
            write_count: 0,
            velocity_report: None,
            reported_position: None,
            clock_ms: 0.0,
            registered: None,
            load_nm: 0.0,
            profile: None,
            indirect_in_use: false,
            supply_v: model.rated_v,
            temperature_c: AMBIENT_C,
        };
        s.factory_defaults(id);
        s
    }

    /// Powers it from `volts` (Present Input Voltage reads it); a value that is not a positive
    /// number leaves the model's rated supply.
    pub fn set_supply(&mut self, volts: Real) {
        if volts.is_finite() && volts > 0.0 {
            self.supply_v = volts;
        }
    }

    /// Sets the motor's temperature, °C (a servo warm from an earlier run); it heats and cools
    /// from there (a first-order thermal model: [`THERMAL_TIME_CONSTANT_S`]). A value that is not finite is ignored.
    pub fn set_temperature(&mut self, celsius: Real) {
        if celsius.is_finite() {
            self.temperature_c = celsius;
            self.refresh_present();
        }
    }

    /// The motor's temperature, °C.
    #[must_use]
    pub fn temperature(&self) -> Real {
        self.temperature_c
    }

    /// The thermal model, first order: `C·dT/dt = I²R − (T − T_amb)/R_th`, with the current
    /// from the load (`I = I_stall · |τ|/τ_stall`) and the winding's resistance from the stall
    /// figures (`R = V_rated / I_stall`); `R_th` makes [`CONTINUOUS_CURRENT_SHARE`] of the stall
    /// current settle at the model's Temperature Limit and `R_th·C` is
    /// [`THERMAL_TIME_CONSTANT_S`]. At the Temperature Limit register's value the servo raises
    /// its overheating error (and, as Shutdown says, drops torque), as the firmware does.
    fn heat(&mut self, dt: Real) {
        let m = self.model;
        let share = if self.torque_on() {
            (self.load_nm / m.stall_torque_nm).abs().min(1.0)
        } else {
            0.0
        };
        let stall_w = m.rated_v * m.stall_current_a;
        let loss_w = share * share * stall_w;
        let r_th = (Real::from(m.temperature_limit) - AMBIENT_C)
            / (CONTINUOUS_CURRENT_SHARE * CONTINUOUS_CURRENT_SHARE * stall_w);
        let capacity = THERMAL_TIME_CONSTANT_S / r_th;
        self.temperature_c += dt * (loss_w - (self.temperature_c - AMBIENT_C) / r_th) / capacity;
        let limit = self.table[TEMPERATURE_LIMIT];
        if self.temperature_c >= Real::from(limit) {
            self.raise_hardware_error(crate::servo::hardware_error::OVERHEATING);
        }
    }

    /// Sets the Baud Rate register to the code of `baud` (the line the servo is on); a baud
    /// with no code leaves it.
    pub fn set_baud(&mut self, baud: u32) {
        if let Some(code) = BAUD_CODES.iter().position(|&b| b == baud) {
            self.table[usize::from(addr::BAUD_RATE)] = code as u8;
        }
    }

    /// The baud of its Baud Rate register, bit/s.
    #[must_use]
    pub fn baud(&self) -> u32 {
        BAUD_CODES
            .get(usize::from(self.table[usize::from(addr::BAUD_RATE)]))
            .copied()
            .unwrap_or(BAUD_CODES[1])
    }

    /// Every item at its factory value ([`control_table`]), the id given.
    fn factory_defaults(&mut self, id: u8) {
        self.table = [0; TABLE_LEN];
        let model = self.model;
        control_table::for_each_item(model, |i| {
            if let (Some(v), true) = (i.factory, i.eeprom()) {
                self.put(i.address, usize::from(i.size), v);
            }
        });
        self.put(addr::ID, 1, u32::from(id));
        self.clear_ram();
    }

    /// RAM at power-on: every RAM item at its initial value (torque off, no errors, watchdog
    /// off, indirect addresses at their own data), goal = present.
    fn clear_ram(&mut self) {
        for b in &mut self.table[usize::from(addr::TORQUE_ENABLE)..] {
            *b = 0;
        }
        let model = self.model;
        control_table::for_each_item(model, |i| {
            if let (Some(v), false) = (i.factory, i.eeprom()) {
                self.put(i.address, usize::from(i.size), v);
            }
        });
        self.registered = None;
        self.velocity = 0.0;
        self.load_nm = 0.0;
        self.profile = None;
        self.indirect_in_use = false;
        self.watchdog_expired = false;
        self.since_packet = 0.0;
        let p = self.present_tick() + self.homing_offset();
        self.put(addr::GOAL_POSITION, 4, p as u32);
        self.refresh_present();
    }

    /// Homing Offset, ticks.
    fn homing_offset(&self) -> i32 {
        self.get(HOMING_OFFSET, 4) as i32
    }

    /// Whether the servo answers Protocol 2.0 (Protocol Type 2) and hears `id` as its own —
    /// the primary id, or the Secondary ID (which executes but never answers).
    fn hears(&self, id: u8) -> bool {
        let secondary = self.table[SECONDARY_ID];
        self.speaks_protocol_2()
            && (id == BROADCAST_ID || id == self.id() || (secondary < 253 && id == secondary))
    }

    /// Protocol Type 2 (after any other is written the servo is silent to Protocol 2.0), on a
    /// line at its baud.
    fn speaks_protocol_2(&self) -> bool {
        self.table[PROTOCOL_TYPE] == 2 && !self.off_baud
    }

    /// Whether a packet to `id` is answered by this servo: its own primary id, on Protocol 2.0.
    fn answers(&self, id: u8) -> bool {
        self.speaks_protocol_2() && id == self.id()
    }

    fn get(&self, a: u16, n: usize) -> u32 {
        let a = usize::from(a);
        self.table[a..a + n]
            .iter()
            .rev()
            .fold(0, |acc, &b| (acc << 8) | u32::from(b))
    }

    fn put(&mut self, a: u16, n: usize, v: u32) {
        let a = usize::from(a);
        self.table[a..a + n].copy_from_slice(&v.to_le_bytes()[..n]);
    }

    /// A little-endian register of 1, 2 or 4 bytes from the control table (0 past its end).
    #[must_use]
    pub fn register(&self, address: u16, size: usize) -> u32 {
        let (a, n) = (usize::from(address), size.min(4));
        if a + n > TABLE_LEN {
            return 0;
        }
        self.get(address, n)
    }

    /// The present position (ticks) this servo's last reply that carried it reported: what a
    /// host that read it correctly must have (the chain's record, for fault soaks).
    #[must_use]
    pub fn reported_position(&self) -> Option<i32> {
        self.reported_position
    }

    /// Notes the present position a reply with `n` bytes from `a` carries.
    fn note_reply(&mut self, a: u16, n: usize) {
        let (start, p) = (usize::from(a), usize::from(addr::PRESENT_POSITION));
        if start <= p && p + 4 <= start + n && start + n <= TABLE_LEN {
            self.reported_position = Some(self.get(addr::PRESENT_POSITION, 4) as i32);
        }
    }

    /// Bus id.
    #[must_use]
    pub fn id(&self) -> u8 {
        self.table[usize::from(addr::ID)]
    }

    /// The model.
    #[must_use]
    pub fn model(&self) -> &'static ServoModel {
        self.model
    }

    /// Position in ticks (unrounded).
    #[must_use]
    pub fn position(&self) -> Real {
        self.position
    }

    /// Present Position as the servo reports it.
    #[must_use]
    pub fn present_tick(&self) -> i32 {
        real::round(self.position) as i32
    }

    /// Where the horn is sent (ticks): the Goal Position register less the Homing Offset.
    #[must_use]
    pub fn goal_tick(&self) -> i32 {
        (self.get(addr::GOAL_POSITION, 4) as i32).wrapping_sub(self.homing_offset())
    }

    /// Torque Enable register.
    #[must_use]
    pub fn torque_on(&self) -> bool {
        self.table[usize::from(addr::TORQUE_ENABLE)] != 0
    }

    /// True after the Bus Watchdog expired (until 0 is written to it).
    #[must_use]
    pub fn watchdog_expired(&self) -> bool {
        self.watchdog_expired
    }

    /// Times torque was enabled while the goal was more than one tick from the present
    /// position — a jump on a real rig.
    #[must_use]
    pub fn torque_jumps(&self) -> u32 {
        self.torque_jumps
    }

    /// Accepted writes to Goal Position.
    #[must_use]
    pub fn goal_writes(&self) -> u32 {
        self.write_count
    }

    /// Return Delay Time in microseconds.
    #[must_use]
    pub fn return_delay_us(&self) -> u32 {
        2 * u32::from(self.table[usize::from(addr::RETURN_DELAY_TIME)])
    }

    /// Hardware Error Status register.
    #[must_use]
    pub fn hardware_error(&self) -> u8 {
        self.table[usize::from(addr::HARDWARE_ERROR_STATUS)]
    }

    /// Raises hardware error bits (as overheating or overload would); the shutdown bits turn
    /// torque off. Cleared only by a reboot.
    pub fn raise_hardware_error(&mut self, bits: u8) {
        let e = self.hardware_error() | bits;
        self.table[usize::from(addr::HARDWARE_ERROR_STATUS)] = e;
        if e & self.table[usize::from(addr::SHUTDOWN)] != 0 {
            self.table[usize::from(addr::TORQUE_ENABLE)] = 0;
        }
    }

    /// Sets control-table bytes directly, bypassing the write checks — a fixture for a
    /// servo that goes silent (Status Return Level 0) or misbehaves mid-run.
    pub fn poke(&mut self, address: u16, data: &[u8]) {
        let a = usize::from(address);
        if let Some(t) = self.table.get_mut(a..a + data.len()) {
            t.copy_from_slice(data);
        }
    }

    /// Sets the position directly (a hand moving the horn with torque off).
    pub fn set_position(&mut self, ticks: Real) {
        self.position = ticks;
        self.refresh_present();
    }

    /// Makes Present Velocity read `units` whatever the motion (`None`: the real value) — a
    /// fixture for reply contents such as `FF FF FF FF` (−1).
    pub fn force_present_velocity(&mut self, units: Option<i32>) {
        self.velocity_report = units;
        self.refresh_present();
    }

    /// The status packet's error byte: the alert flag when a hardware error is present.
    fn alert(&self) -> u8 {
        if self.hardware_error() != 0 {
            status_error::ALERT
        } else {
            0
        }
    }

    fn refresh_present(&mut self) {
        let p = self.present_tick();
        let offset = self.homing_offset();
        self.put(addr::PRESENT_POSITION, 4, p.wrapping_add(offset) as u32);
        let v = self
            .velocity_report
            .unwrap_or(real::round(self.velocity / TICKS_PER_S_PER_VELOCITY_UNIT) as i32);
        self.put(addr::PRESENT_VELOCITY, 4, v as u32);
        // Moving above the Moving Threshold (e-manual); Moving Status: in position within
        // it as well, a profile under way.
        let threshold = self.get(addr::MOVING_THRESHOLD, 4) as i32;
        self.put(addr::MOVING, 1, u32::from(v.abs() > threshold));
        let in_position = (self.goal_tick() - p).abs() <= threshold.max(1);
        let status = u32::from(in_position) | (u32::from(self.profile.is_some()) << 1);
        self.put(addr::MOVING_STATUS, 1, status);
        let (current, pwm) = self.motor_readings();
        self.put(addr::PRESENT_CURRENT, 2, u32::from(current as u16));
        self.put(addr::PRESENT_PWM, 2, u32::from(pwm as u16));
        let supply = real::round(self.supply_v * 10.0) as u32;
        self.put(addr::PRESENT_INPUT_VOLTAGE, 2, supply);
        let celsius = real::round(self.temperature_c).clamp(0.0, 255.0);
        self.put(addr::PRESENT_TEMPERATURE, 1, celsius as u32);
        // The profile's set point while one runs; otherwise the goal (torque on) or where it is.
        let (tp, tv) = match (self.profile, self.torque_on()) {
            (Some((tp, tv)), _) => (
                real::round(tp) as i32,
                real::round(tv / TICKS_PER_S_PER_VELOCITY_UNIT) as i32,
            ),
            (None, true) => (self.goal_tick(), 0),
            (None, false) => (p, 0),
        };
        self.put(POSITION_TRAJECTORY, 4, tp.wrapping_add(offset) as u32);
        self.put(VELOCITY_TRAJECTORY, 4, tv as u32);
        self.mirror_indirect();
    }

    /// Where the Indirect Data byte at `data` points (its Indirect Address), when that is
    /// inside the table and not itself indirect data; `None` for any other address.
    fn indirect_target(&self, data: usize) -> Option<usize> {
        let b = control_table::indirect_data_block(self.model, data)?;
        let k = data - usize::from(b.data);
        let a = self.get(b.address + 2 * k as u16, 2) as usize;
        let inside = a < usize::from(control_table::table_end(self.model));
        (inside && control_table::indirect_data_block(self.model, a).is_none()).then_some(a)
    }

    /// Present Current (or Load) and PWM from a DC motor model at the rated voltage: the
    /// current in proportion to the horn's torque (stall torque ↔ stall current), the PWM duty
    /// the speed and torque need (no-load speed ↔ full duty, stall torque ↔ full duty), both
    /// signed as the horn turns. Zero while limp.
    fn motor_readings(&self) -> (i16, i16) {
        if !self.torque_on() {
            return (0, 0);
        }
        let torque = self.load_nm / self.model.stall_torque_nm;
        let no_load = self.model.no_load_rpm / 60.0 * (TICKS_PER_TURN as Real);
        let duty = (self.velocity / no_load + torque).clamp(-1.0, 1.0);
        let current = if self.model.current_unit_ma > 0.0 {
            torque * self.model.stall_current_a * 1e3 / self.model.current_unit_ma
        } else {
            // Present Load: 0.1 % of the maximum torque.
            torque * 1000.0
        };
        let limit = Real::from(i16::MAX);
        (
            real::round(current.clamp(-limit, limit)) as i16,
            real::round(duty * PWM_FULL) as i16,
        )
    }

    /// Sets the torque at the horn, N·m (the plant's measurement; signed as positions grow),
    /// for Present Current, Load and PWM.
    pub fn set_load(&mut self, torque_nm: Real) {
        self.load_nm = if torque_nm.is_finite() { torque_nm } else { 0.0 };
    }

    /// The position (ticks) the firmware's motion profile commands after `dt` more seconds,
    /// for a plant that moves the horn itself: with Profile Velocity 0 the goal at once,
    /// otherwise the profile towards the goal at Profile Velocity and Acceleration (0:
    /// unlimited), started from where the horn stands. `None` while limp.
    pub fn profile_target(&mut self, dt: Real) -> Option<Real> {
        let Some(goal) = self.drive_goal().map(|g| g as Real) else {
            self.profile = None;
            return None;
        };
        let pv = self.get(addr::PROFILE_VELOCITY, 4);
        if pv == 0 {
            self.profile = None;
            return Some(goal);
        }
        let v = (pv as Real) * TICKS_PER_S_PER_VELOCITY_UNIT;
        let pa = self.get(addr::PROFILE_ACCELERATION, 4);
        let a = if pa == 0 {
            Real::INFINITY
        } else {
            (pa as Real) * TICKS_PER_S2_PER_ACCELERATION_UNIT
        };
        let (p, vel) = self.profile.unwrap_or((self.position, 0.0));
        let (p, vel) = step_towards(p, vel, goal, v, a, dt);
        self.profile = (p != goal).then_some((p, vel));
        Some(p)
    }

    /// Indirect Data reads the bytes its addresses point at.
    fn mirror_indirect(&mut self) {
        if !self.indirect_in_use {
            return;
        }
        for b in indirect_blocks(self.model) {
            for d in usize::from(b.data)..usize::from(b.data + b.count) {
                self.table[d] = self.indirect_target(d).map_or(0, |a| self.table[a]);
            }
        }
    }

    /// A write to Indirect Data: each run of bytes whose addresses follow one another becomes
    /// one write there (so a 4-byte goal through four indirect bytes is one whole item).
    fn write_indirect(&mut self, first: usize, data: &[u8]) -> u8 {
        let mut k = 0;
        while k < data.len() {
            let Some(target) = self.indirect_target(first + k) else {
                return status_error::ACCESS;
            };
            let mut n = 1;
            while k + n < data.len() && self.indirect_target(first + k + n) == Some(target + n) {
                n += 1;
            }
            let e = self.write(target as u16, &data[k..k + n]);
            if e != 0 {
                return e;
            }
            k += n;
        }
        0
    }

    /// Advances the servo `dt` seconds: watchdog, then motion towards the goal.
    pub fn step(&mut self, dt: Real) {
        self.run_watchdog(dt);
        if self.torque_on() && !self.watchdog_expired {
            let goal = self.goal_tick() as Real;
            let max_v = self.model.no_load_rpm / 60.0 * (TICKS_PER_TURN as Real);
            let pv = self.get(addr::PROFILE_VELOCITY, 4);
            let v = if pv == 0 {
                max_v
            } else {
                ((pv as Real) * TICKS_PER_S_PER_VELOCITY_UNIT).min(max_v)
            };
            let pa = self.get(addr::PROFILE_ACCELERATION, 4);
            let a = if pa == 0 {
                max_v / DEFAULT_RAMP_S
            } else {
                (pa as Real) * TICKS_PER_S2_PER_ACCELERATION_UNIT
            };
            let (p, vel) = step_towards(self.position, self.velocity, goal, v, a, dt);
            self.position = p;
            self.velocity = if p == goal { 0.0 } else { vel };
        } else {
            self.velocity = 0.0;
        }
        self.heat(dt);
        self.refresh_present();
    }

    /// Advances the servo `dt` seconds with its horn moved by something else (a simulated
    /// motor and load): the watchdog runs; position (ticks) and velocity (ticks/s) are what
    /// that model measured.
    pub fn step_driven(&mut self, dt: Real, position: Real, velocity: Real) {
        self.run_watchdog(dt);
        self.position = position;
        self.velocity = velocity;
        self.heat(dt);
        self.refresh_present();
    }

    /// Position P Gain as last written (the model's factory value after power-on).
    #[must_use]
    pub fn position_p_gain(&self) -> u16 {
        self.get(addr::POSITION_P_GAIN, 2) as u16
    }

    /// What the motor holds: the goal tick while torque is on (after a watchdog expiry, the
    /// position where it stopped), `None` when limp.
    #[must_use]
    pub fn drive_goal(&self) -> Option<i32> {
        self.torque_on().then(|| self.goal_tick())
    }

    fn run_watchdog(&mut self, dt: Real) {
        self.clock_ms = real::fmod(self.clock_ms + dt * 1e3, 32_768.0);
        self.put(REALTIME_TICK, 2, self.clock_ms as u32);
        let wd = self.table[usize::from(addr::BUS_WATCHDOG)];
        self.since_packet += dt;
        if self.torque_on()
            && !self.watchdog_expired
            && (1..=127).contains(&wd)
            && self.since_packet > (wd as Real) * 0.020
        {
            // Expiry: stop where it is; the register reads −1 and goal writes fail.
            self.watchdog_expired = true;
            self.table[usize::from(addr::BUS_WATCHDOG)] = 0xFF;
            let p = self.present_tick();
            self.put(addr::GOAL_POSITION, 4, p as u32);
            self.velocity = 0.0;
        }
    }

    /// Applies a write; returns the status error number (0 = done). Checked item by item
    /// against the model's control table ([`control_table`]) before anything is stored:
    /// Access Error for a read-only item or EEPROM while torque is on, Data Length Error for
    /// an item covered in part, Data Range Error beyond an item's range (Data Limit Error for
    /// a goal beyond the position limits) and for addresses no item defines
    /// ([`UNDEFINED_ADDRESS_ERROR`]). Reserved bytes inside a write are skipped; Indirect Data
    /// is forwarded to the addresses it points at.
    fn write(&mut self, a: u16, data: &[u8]) -> u8 {
        let start = usize::from(a);
        let end = start + data.len();
        if data.is_empty() {
            return status_error::DATA_LENGTH;
        }
        if end > usize::from(control_table::table_end(self.model)) {
            return UNDEFINED_ADDRESS_ERROR;
        }
        let mut items: heapless::Vec<Item, 64> = heapless::Vec::new();
        let mut indirect = false;
        let mut cut = false;
        let mut at = start;
        while at < end {
            let Some(i) = control_table::item_at(self.model, at as u16) else {
                at += 1;
                continue;
            };
            let (first, last) = (usize::from(i.address), usize::from(i.address + i.size));
            at = last;
            if i.access == Access::Read || (i.eeprom() && self.torque_on()) {
                return status_error::ACCESS;
            }
            cut |= first < start || last > end;
            if i.name == "Indirect Data" {
                indirect = true;
            } else if items.push(i).is_err() {
                return status_error::DATA_LENGTH;
            }
        }
        if items.is_empty() && !indirect {
            return UNDEFINED_ADDRESS_ERROR;
        }
        if cut {
            return status_error::DATA_LENGTH;
        }
        let covered = |r: u16, n: u16| start <= usize::from(r) && usize::from(r + n) <= end;
        let value = |r: u16, n: u16| {
            let o = usize::from(r) - start;
            data[o..o + usize::from(n)]
                .iter()
                .rev()
                .fold(0u32, |acc, &b| (acc << 8) | u32::from(b))
        };
        // Limits held by other items: the value this write sets, else the table's.
        let register = |r: u16, n: u16| {
            if covered(r, n) {
                value(r, n)
            } else {
                self.get(r, usize::from(n))
            }
        };
        for i in &items {
            let v = value(i.address, i.size);
            if i.address == addr::GOAL_POSITION {
                if self.watchdog_expired {
                    // The e-manual's answer to a goal after Bus Watchdog expiry.
                    return status_error::DATA_RANGE;
                }
                // Position limits bound the goal in Position Control Mode only.
                let position_mode = register(addr::OPERATING_MODE, 1) == 3;
                if position_mode && !i.accepts(v, register) {
                    return status_error::DATA_LIMIT;
                }
            } else if !i.accepts(v, register) {
                return status_error::DATA_RANGE;
            }
        }
        if covered(addr::TORQUE_ENABLE, 1) {
            let on = value(addr::TORQUE_ENABLE, 1) != 0;
            if on && self.hardware_error() & self.table[usize::from(addr::SHUTDOWN)] != 0 {
                return status_error::RESULT_FAIL;
            }
        }
        let was_on = self.torque_on();
        for i in &items {
            let (first, last) = (usize::from(i.address), usize::from(i.address + i.size));
            self.table[first..last].copy_from_slice(&data[first - start..last - start]);
        }
        if indirect {
            // Each run of Indirect Data bytes forwarded on its own.
            let is_data = |d: usize| control_table::indirect_data_block(self.model, d).is_some();
            let mut d = start;
            while d < end {
                let n = (d..end).take_while(|&x| is_data(x)).count();
                if n == 0 {
                    d += 1;
                    continue;
                }
                let e = self.write_indirect(d, &data[d - start..d - start + n]);
                self.mirror_indirect();
                if e != 0 {
                    return e;
                }
                d += n;
            }
        }
        if covered(addr::BUS_WATCHDOG, 1) && value(addr::BUS_WATCHDOG, 1) == 0 {
            self.watchdog_expired = false;
        }
        if covered(addr::GOAL_POSITION, 4) {
            self.write_count += 1;
        }
        if !was_on && self.torque_on() {
            if (self.goal_tick() - self.present_tick()).abs() > 1 {
                self.torque_jumps += 1;
            }
            self.velocity = 0.0;
        }
        self.indirect_in_use |= items.iter().any(|i| i.name == "Indirect Address");
        if covered(HOMING_OFFSET, 4) {
            self.refresh_present();
        } else {
            self.mirror_indirect();
        }
        0
    }

    fn read(&self, a: u16, n: usize) -> Option<&[u8]> {
        let start = usize::from(a);
        let end = start.checked_add(n)?;
        (end <= usize::from(control_table::table_end(self.model))).then(|| &self.table[start..end])
    }
}

/// A status packet the chain sends: `len` bytes at `start` in the output buffer, sent
/// `delay_us` after the previous one (or after the instruction).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reply {
    /// The replying servo's id.
    pub id: u8,
    /// Offset in the output buffer.
    pub start: usize,
    /// Bytes.
    pub len: usize,
    /// Return delay before it, µs.
    pub delay_us: u32,
}

/// The replies to one instruction.
pub type Replies = heapless::Vec<Reply, MAX_SERVOS>;

/// A chain of virtual servos on one bus.
#[derive(Clone, Debug, Default)]
pub struct Chain {
    servos: heapless::Vec<VirtualServo, MAX_SERVOS>,
    /// The line's baud when the chain keeps to it: servos set to another hear nothing.
    line_baud: Option<u32>,
    /// A sensor board on the same bus (the OP3's OpenCR), answered after the servos.
    board: Option<SensorBoard>,
    instructions: u64,
}

/// The chain is full ([`MAX_SERVOS`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChainFull;

impl core::fmt::Display for ChainFull {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "the chain is full ({MAX_SERVOS} servos)")
    }
}

impl core::error::Error for ChainFull {}

impl Chain {
    /// An empty chain.
    #[must_use]
    pub fn new() -> Chain {
        Chain::default()
    }

    /// The line's baud (`None`: every servo hears whatever its Baud Rate register says, the
    /// default): a servo set to another baud hears nothing, as on a real bus where its UART
    /// samples the bytes at the wrong rate.
    pub fn set_line_baud(&mut self, baud: Option<u32>) {
        self.line_baud = baud;
    }

    /// Adds a servo.
    ///
    /// # Errors
    /// [`ChainFull`] past [`MAX_SERVOS`] servos.
    pub fn add(&mut self, servo: VirtualServo) -> Result<(), ChainFull> {
        self.servos.push(servo).map_err(|_| ChainFull)
    }

    /// The servos.
    #[must_use]
    pub fn servos(&self) -> &[VirtualServo] {
        &self.servos
    }

    /// Takes the servo with `id` off the bus.
    pub fn remove(&mut self, id: u8) -> Option<VirtualServo> {
        let k = self.servos.iter().position(|s| s.id() == id)?;
        Some(self.servos.remove(k))
    }

    /// Puts a sensor board on the bus (one at most: a second replaces the first).
    pub fn set_board(&mut self, board: SensorBoard) {
        self.board = Some(board);
    }

    /// The sensor board, if the bus has one.
    #[must_use]
    pub fn board(&self) -> Option<&SensorBoard> {
        self.board.as_ref()
    }

    /// The sensor board, mutable (for a simulator that feeds its IMU).
    pub fn board_mut(&mut self) -> Option<&mut SensorBoard> {
        self.board.as_mut()
    }

    /// The servos, mutable (for a simulator that moves their horns).
    pub fn servos_mut(&mut self) -> &mut [VirtualServo] {
        &mut self.servos
    }

    /// The servo with this id (the first, should ids be duplicated).
    #[must_use]
    pub fn servo(&self, id: u8) -> Option<&VirtualServo> {
        self.servos.iter().find(|s| s.id() == id)
    }

    /// The servo with this id, mutable.
    pub fn servo_mut(&mut self, id: u8) -> Option<&mut VirtualServo> {
        self.servos.iter_mut().find(|s| s.id() == id)
    }

    /// Valid instruction packets handled so far.
    #[must_use]
    pub fn instructions(&self) -> u64 {
        self.instructions
    }

    /// Advances every servo `dt` seconds.
    pub fn step(&mut self, dt: Real) {
        for s in &mut self.servos {
            s.step(dt);
        }
    }

    /// Answers one instruction packet: writes the status packets into `out` and lists them in
    /// `replies`. A packet that does not decode gets no answer (as on a real bus).
    ///
    /// # Errors
    /// The packet's [`CodecError`]; nothing was executed.
    pub fn handle(&mut self, packet: &[u8], out: &mut [u8], replies: &mut Replies) -> Result<(), CodecError> {
        replies.clear();
        let line = self.line_baud;
        for s in &mut self.servos {
            s.off_baud = line.is_some_and(|b| b != s.baud());
        }
        let mut buf = [0u8; MAX_PACKET];
        let (p, _) = protocol::decode(packet, &mut buf)?;
        if p.instruction == instruction::STATUS {
            return Ok(());
        }
        self.instructions += 1;
        let mut w = Writer {
            out,
            used: 0,
            replies,
        };
        self.execute(p.id, p.instruction, p.params, &mut w);
        Ok(())
    }

    /// The board's answer to an instruction it does not carry out (Reg Write, Action).
    fn board_refuses(&self, id: u8, w: &mut Writer<'_, '_>) {
        if let Some(b) = self
            .board
            .as_ref()
            .filter(|b| b.id() == id && b.status_return_level() >= 2)
        {
            w.board_status(b, status_error::INSTRUCTION, &[]);
        }
    }

    fn execute(&mut self, id: u8, inst: u8, params: &[u8], w: &mut Writer<'_, '_>) {
        // Any instruction meant for a servo resets its watchdog timer.
        for s in &mut self.servos {
            if s.hears(id) {
                s.since_packet = 0.0;
            }
        }
        let broadcast = id == BROADCAST_ID;
        match inst {
            instruction::PING => {
                for s in self
                    .servos
                    .iter()
                    .filter(|s| s.speaks_protocol_2() && (broadcast || s.id() == id))
                {
                    let m = s.model.model_number.to_le_bytes();
                    w.status(s, 0, &[m[0], m[1], FIRMWARE_VERSION]);
                }
                if let Some(b) = self.board.as_ref().filter(|b| b.hears(id)) {
                    let m = b.model_number().to_le_bytes();
                    w.board_status(b, 0, &[m[0], m[1], crate::sensor_board::OPENCR_OP3_FIRMWARE]);
                }
            }
            instruction::READ if !broadcast => {
                let Some(s) = self.servos.iter_mut().find(|s| s.answers(id)) else {
                    if let Some(b) = self.board.as_ref().filter(|b| b.id() == id) {
                        board_read(b, params, w);
                    }
                    return;
                };
                if s.table[usize::from(addr::STATUS_RETURN_LEVEL)] == 0 {
                    return;
                }
                match (params.len() == 4).then(|| (le16(&params[0..]), usize::from(le16(&params[2..])))) {
                    Some((a, n)) => {
                        s.note_reply(a, n);
                        match s.read(a, n) {
                            Some(data) => w.status(s, 0, data),
                            None => w.status(s, UNDEFINED_ADDRESS_ERROR, &[]),
                        }
                    }
                    None => w.status(s, status_error::DATA_LENGTH, &[]),
                }
            }
            instruction::WRITE => {
                if params.len() < 3 {
                    if let Some(s) = self.servos.iter().find(|s| s.answers(id)) {
                        w.status(s, status_error::DATA_LENGTH, &[]);
                    }
                    return;
                }
                let a = le16(params);
                for s in self.servos.iter_mut().filter(|s| s.hears(id)) {
                    // Answered in the protocol the packet came in (a write of Protocol Type
                    // takes effect after it), at the Status Return Level the write leaves.
                    let answers = s.answers(id);
                    let e = s.write(a, &params[2..]);
                    if answers && s.table[usize::from(addr::STATUS_RETURN_LEVEL)] >= 2 {
                        w.status(s, e, &[]);
                    }
                }
                if let Some(b) = self.board.as_mut().filter(|b| b.hears(id)) {
                    let e = b.write(a, &params[2..]);
                    if b.id() == id && b.status_return_level() >= 2 {
                        w.board_status(b, e, &[]);
                    }
                }
            }
            instruction::REG_WRITE => {
                // Held, not applied, until Action; the Registered Instruction flag says so.
                if params.len() < 3 || params.len() - 2 > 128 {
                    if let Some(s) = self.servos.iter().find(|s| s.answers(id)) {
                        w.status(s, status_error::DATA_LENGTH, &[]);
                    }
                    return;
                }
                let a = le16(params);
                for s in self.servos.iter_mut().filter(|s| s.hears(id)) {
                    let mut data = heapless::Vec::new();
                    let _ = data.extend_from_slice(&params[2..]);
                    s.registered = Some((a, data));
                    s.table[usize::from(REGISTERED_INSTRUCTION)] = 1;
                    if s.answers(id) && s.table[usize::from(addr::STATUS_RETURN_LEVEL)] >= 2 {
                        w.status(s, 0, &[]);
                    }
                }
                self.board_refuses(id, w);
            }
            instruction::ACTION => {
                for s in self.servos.iter_mut().filter(|s| s.hears(id)) {
                    // Action with nothing registered: Instruction Error (the e-manual's
                    // "Action without Reg Write", as Protocol 1.0 servos answered it).
                    let e = match s.registered.take() {
                        Some((a, data)) => s.write(a, &data),
                        None => status_error::INSTRUCTION,
                    };
                    s.table[usize::from(REGISTERED_INSTRUCTION)] = 0;
                    if s.answers(id) && s.table[usize::from(addr::STATUS_RETURN_LEVEL)] >= 2 {
                        w.status(s, e, &[]);
                    }
                }
                self.board_refuses(id, w);
            }
            instruction::REBOOT => {
                for s in self.servos.iter_mut().filter(|s| s.hears(id)) {
                    // Only a read or a ping is answered below Status Return Level 2.
                    if s.answers(id) && s.table[usize::from(addr::STATUS_RETURN_LEVEL)] >= 2 {
                        w.status(s, 0, &[]);
                    }
                    s.table[usize::from(addr::HARDWARE_ERROR_STATUS)] = 0;
                    s.clear_ram();
                }
                if let Some(b) = self.board.as_mut().filter(|b| b.hears(id)) {
                    if b.id() == id && b.status_return_level() >= 2 {
                        w.board_status(b, 0, &[]);
                    }
                    b.reboot();
                }
            }
            instruction::FACTORY_RESET => {
                // 0xFF resets everything, 0x01 all but the id, 0x02 all but id and baud. A
                // broadcast 0xFF is ignored (firmware 42 and later): it would renumber the bus.
                let option = params.first().copied().unwrap_or(0xFF);
                if broadcast && option == 0xFF {
                    return;
                }
                for s in self.servos.iter_mut().filter(|s| s.hears(id)) {
                    let (sid, baud) = (s.id(), s.table[usize::from(addr::BAUD_RATE)]);
                    if s.answers(id) && s.table[usize::from(addr::STATUS_RETURN_LEVEL)] >= 2 {
                        w.status(s, 0, &[]);
                    }
                    s.factory_defaults(if option == 0xFF { 1 } else { sid });
                    if option == 0x02 {
                        s.table[usize::from(addr::BAUD_RATE)] = baud;
                    }
                }
                if let Some(b) = self.board.as_mut().filter(|b| b.hears(id)) {
                    if b.id() == id && b.status_return_level() >= 2 {
                        w.board_status(b, 0, &[]);
                    }
                    b.reset(option != 0xFF);
                }
            }
            instruction::SYNC_WRITE if broadcast && params.len() >= 4 => {
                let (a, n) = (le16(params), usize::from(le16(&params[2..])));
                if n == 0 {
                    return;
                }
                for chunk in params[4..].chunks_exact(1 + n) {
                    for s in self.servos.iter_mut().filter(|s| s.answers(chunk[0])) {
                        let _ = s.write(a, &chunk[1..]);
                    }
                    if let Some(b) = self.board.as_mut().filter(|b| b.id() == chunk[0]) {
                        let _ = b.write(a, &chunk[1..]);
                    }
                }
            }
            instruction::SYNC_READ if broadcast && params.len() >= 4 => {
                let (a, n) = (le16(params), usize::from(le16(&params[2..])));
                for &sid in &params[4..] {
                    if let Some(b) = self.board.as_ref().filter(|b| b.id() == sid) {
                        board_read_at(b, a, n, w);
                    }
                    for s in self.servos.iter_mut().filter(|s| s.answers(sid)) {
                        if s.table[usize::from(addr::STATUS_RETURN_LEVEL)] == 0 {
                            continue;
                        }
                        s.note_reply(a, n);
                        match s.read(a, n) {
                            Some(data) => w.status(s, 0, data),
                            None => w.status(s, UNDEFINED_ADDRESS_ERROR, &[]),
                        }
                    }
                }
            }
            instruction::FAST_SYNC_READ if broadcast && params.len() >= 4 => {
                let (a, n) = (le16(params), usize::from(le16(&params[2..])));
                let ids = &params[4..];
                w.fast_chain(&mut self.servos, None, ids.len(), |k| (ids[k], a, n));
            }
            instruction::FAST_BULK_READ if broadcast => {
                let items = &params[..params.len() / 5 * 5];
                w.fast_chain(&mut self.servos, self.board.as_ref(), items.len() / 5, |k| {
                    let item = &items[5 * k..5 * k + 5];
                    (item[0], le16(&item[1..]), usize::from(le16(&item[3..])))
                });
            }
            instruction::BULK_READ if broadcast => {
                for item in params.chunks_exact(5) {
                    let (sid, a, n) = (item[0], le16(&item[1..]), usize::from(le16(&item[3..])));
                    if let Some(b) = self.board.as_ref().filter(|b| b.id() == sid) {
                        board_read_at(b, a, n, w);
                    }
                    for s in self.servos.iter_mut().filter(|s| s.answers(sid)) {
                        if s.table[usize::from(addr::STATUS_RETURN_LEVEL)] == 0 {
                            continue;
                        }
                        s.note_reply(a, n);
                        match s.read(a, n) {
                            Some(data) => w.status(s, 0, data),
                            None => w.status(s, UNDEFINED_ADDRESS_ERROR, &[]),
                        }
                    }
                }
            }
            instruction::BULK_WRITE if broadcast => {
                let mut rest = params;
                while rest.len() >= 5 {
                    let (sid, a, n) = (rest[0], le16(&rest[1..]), usize::from(le16(&rest[3..])));
                    if rest.len() < 5 + n {
                        break;
                    }
                    for s in self.servos.iter_mut().filter(|s| s.answers(sid)) {
                        let _ = s.write(a, &rest[5..5 + n]);
                    }
                    if let Some(b) = self.board.as_mut().filter(|b| b.id() == sid) {
                        let _ = b.write(a, &rest[5..5 + n]);
                    }
                    rest = &rest[5 + n..];
                }
            }
            _ => {
                if !broadcast {
                    if let Some(s) = self.servos.iter().find(|s| s.answers(id)) {
                        w.status(s, status_error::INSTRUCTION, &[]);
                    } else if let Some(b) = self.board.as_ref().filter(|b| b.id() == id) {
                        w.board_status(b, status_error::INSTRUCTION, &[]);
                    }
                }
            }
        }
    }
}

/// A Read to the board: its answer, as a servo's (Data Length Error for a malformed one).
fn board_read(b: &SensorBoard, params: &[u8], w: &mut Writer<'_, '_>) {
    if params.len() == 4 {
        board_read_at(b, le16(params), usize::from(le16(&params[2..])), w);
    } else if b.status_return_level() > 0 {
        w.board_status(b, status_error::DATA_LENGTH, &[]);
    }
}

/// The board's answer to a read of `n` bytes at `a` (Data Range Error past its table).
fn board_read_at(b: &SensorBoard, a: u16, n: usize, w: &mut Writer<'_, '_>) {
    if b.status_return_level() == 0 {
        return;
    }
    match b.read(a, n) {
        Some(data) => w.board_status(b, 0, data),
        None => w.board_status(b, status_error::DATA_RANGE, &[]),
    }
}

fn le16(b: &[u8]) -> u16 {
    u16::from_le_bytes([b[0], b[1]])
}

struct Writer<'o, 'r> {
    out: &'o mut [u8],
    used: usize,
    replies: &'r mut Replies,
}

impl Writer<'_, '_> {
    /// Appends the one status packet of a Fast Sync or Fast Bulk Read: header, broadcast id,
    /// length, STATUS, then per listed servo that answers (in the listed order) its error, id,
    /// its `n` data bytes from its address and a CRC of the packet up to there — the last of
    /// which is the packet's own CRC. Not byte-stuffed (each servo appends to the stream as it
    /// passes). The first answering servo's return delay precedes it. `entry(k)` is the k-th
    /// of `count` listed (id, address, length).
    fn fast_chain(
        &mut self,
        servos: &mut [VirtualServo],
        board: Option<&SensorBoard>,
        count: usize,
        entry: impl Fn(usize) -> (u8, u16, usize),
    ) {
        let start = self.used;
        let out = &mut self.out[start..];
        let mut at = 8;
        let mut first: Option<(u8, u32)> = None;
        // Where each block's data ends (its CRC follows).
        let mut ends = [0u16; 256];
        let mut blocks = 0;
        for k in 0..count {
            let (sid, a, n) = entry(k);
            if at + 4 + n > out.len() || blocks == ends.len() {
                continue;
            }
            let (error, data, delay_us) = if let Some(s) = servos.iter_mut().find(|s| s.answers(sid)) {
                if s.table[usize::from(addr::STATUS_RETURN_LEVEL)] == 0 {
                    continue;
                }
                s.note_reply(a, n);
                let alert = s.alert();
                let delay = s.return_delay_us();
                match s.read(a, n) {
                    Some(d) => (alert, Some(d), delay),
                    None => (UNDEFINED_ADDRESS_ERROR | alert, None, delay),
                }
            } else if let Some(b) = board.filter(|b| b.id() == sid && b.status_return_level() > 0) {
                // A sensor board on the bus (the OP3's OpenCR) adds its block as a servo does.
                match b.read(a, n) {
                    Some(d) => (0, Some(d), b.return_delay_us()),
                    None => (status_error::DATA_RANGE, None, b.return_delay_us()),
                }
            } else {
                continue;
            };
            out[at] = error;
            out[at + 1] = sid;
            match data {
                Some(d) => out[at + 2..at + 2 + n].copy_from_slice(d),
                None => out[at + 2..at + 2 + n].fill(0),
            }
            first.get_or_insert((sid, delay_us));
            ends[blocks] = (at + 2 + n) as u16;
            blocks += 1;
            // Error, id, data, and room for the block's CRC.
            at += 4 + n;
        }
        let Some((id, delay_us)) = first else {
            return;
        };
        // The CRCs run over the header onwards, length included: written once it is known.
        let length = (at - 7) as u16;
        out[..4].copy_from_slice(&protocol::HEADER);
        out[4] = BROADCAST_ID;
        out[5..7].copy_from_slice(&length.to_le_bytes());
        out[7] = instruction::STATUS;
        for &end in &ends[..blocks] {
            let end = usize::from(end);
            let crc = protocol::crc16(&out[..end]);
            out[end..end + 2].copy_from_slice(&crc.to_le_bytes());
        }
        let reply = Reply {
            id,
            start,
            len: at,
            delay_us,
        };
        if self.replies.push(reply).is_ok() {
            self.used += at;
        }
    }

    /// Appends a status packet from `s` (dropped silently when the buffer is full: the host
    /// then sees a timeout, as with a real collision).
    fn status(&mut self, s: &VirtualServo, error: u8, data: &[u8]) {
        self.status_from(s.id(), error | s.alert(), s.return_delay_us(), data);
    }

    /// Appends a status packet from the sensor board.
    fn board_status(&mut self, b: &SensorBoard, error: u8, data: &[u8]) {
        self.status_from(b.id(), error, b.return_delay_us(), data);
    }

    fn status_from(&mut self, id: u8, error: u8, delay_us: u32, data: &[u8]) {
        let mut params = [0u8; MAX_PACKET];
        if data.len() + 1 > params.len() {
            return;
        }
        params[0] = error;
        params[1..=data.len()].copy_from_slice(data);
        if let Ok(n) = protocol::encode(
            id,
            instruction::STATUS,
            &params[..=data.len()],
            &mut self.out[self.used..],
        ) {
            let reply = Reply {
                id,
                start: self.used,
                len: n,
                delay_us,
            };
            if self.replies.push(reply).is_ok() {
                self.used += n;
            }
        }
    }
}

/// Cuts a byte stream into packets: skips garbage before a header, waits for the rest of a
/// packet, drops packets that fail to decode.
#[derive(Clone, Debug)]
pub struct Receiver {
    buf: [u8; MAX_PACKET],
    len: usize,
    broken: usize,
}

impl Default for Receiver {
    fn default() -> Self {
        Receiver {
            buf: [0; MAX_PACKET],
            len: 0,
            broken: 0,
        }
    }
}

/// What [`Receiver::next_packet`] found.
#[derive(Debug, PartialEq, Eq)]
pub enum Received<'a> {
    /// A whole packet (raw, still stuffed), CRC not yet checked.
    Packet(&'a [u8]),
    /// More bytes are needed.
    Pending,
}

impl Receiver {
    /// Appends bytes; on overflow the oldest bytes are dropped.
    pub fn push(&mut self, bytes: &[u8]) {
        for &b in bytes {
            if self.len == self.buf.len() {
                self.buf.copy_within(1.., 0);
                self.len -= 1;
            }
            self.buf[self.len] = b;
            self.len += 1;
        }
    }

    /// Drops everything buffered (and the count of [`Receiver::take_broken`]).
    pub fn clear(&mut self) {
        self.len = 0;
        self.broken = 0;
    }

    /// Header bytes (0xFF) thrown away since the last call or [`Receiver::clear`]: the start of
    /// a packet that broke off. Line noise that cannot begin a header does not count. A host
    /// must not trust a reply found after one: a valid but old packet may follow a cut one.
    pub fn take_broken(&mut self) -> usize {
        core::mem::take(&mut self.broken)
    }

    /// Bytes buffered.
    #[must_use]
    pub fn pending(&self) -> usize {
        self.len
    }

    /// The next complete packet. Call [`Receiver::consume`] with its length after use.
    pub fn next_packet(&mut self) -> Received<'_> {
        loop {
            let skip = protocol::find_header(&self.buf[..self.len]);
            self.discard(skip);
            match protocol::packet_len(&self.buf[..self.len]) {
                Ok(n) if n > MAX_PACKET => self.discard(1),
                Ok(n) if n <= self.len => return Received::Packet(&self.buf[..n]),
                Ok(_) | Err(CodecError::Incomplete) => return Received::Pending,
                Err(_) => self.discard(1),
            }
        }
    }

    /// Throws away `n` bytes that are no packet, counting header bytes among them.
    fn discard(&mut self, n: usize) {
        let n = n.min(self.len);
        self.broken += self.buf[..n].iter().filter(|&&b| b == 0xFF).count();
        self.consume(n);
    }

    /// Removes `n` bytes from the front.
    pub fn consume(&mut self, n: usize) {
        let n = n.min(self.len);
        self.buf.copy_within(n..self.len, 0);
        self.len -= n;
    }
}

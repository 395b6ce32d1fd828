//! A humanoid's sensor board on the servos' bus: the OP3's OpenCR with ROBOTIS's OP3 firmware,
//! a Protocol 2.0 device (model number 0x7400, ID 200 from the factory) whose 51-byte control
//! table holds the IMU — gyro, accelerometer, roll/pitch/yaw —, the buttons, the supply voltage
//! and its LEDs. The OP3 framework bulk-reads it with the servos every 8 ms.
//!
//! [`SensorBoard`] is its device side (what the virtual chain answers for it);
//! [`ImuReading::decode`] is the host side's decoding of a read of its IMU items. Scale factors
//! are the framework's: gyro ±32,800 raw to ±2,000 °/s, accelerometer ±32,768 raw to ±2 g,
//! angles in 0.1°. Axes are the board's own: the framework negates x and y to get the robot's
//! body axes (see [`ImuReading::to_body`]).

use crate::math::Real;

/// The OP3 firmware's model number.
pub const OPENCR_OP3_MODEL_NUMBER: u16 = 0x7400;
/// Its firmware version.
pub const OPENCR_OP3_FIRMWARE: u8 = 2;
/// Its factory ID.
pub const OPENCR_OP3_ID: u8 = 200;
/// Bytes of control table.
pub const BOARD_TABLE_LEN: usize = 51;

/// Control-table addresses.
pub mod board_addr {
    /// Model Number (2 bytes, read only).
    pub const MODEL_NUMBER: u16 = 0;
    /// Firmware Version (read only).
    pub const FIRMWARE_VERSION: u16 = 2;
    /// ID.
    pub const ID: u16 = 3;
    /// Baud Rate code (the X-series codes: 4 = 2 Mbps).
    pub const BAUD_RATE: u16 = 4;
    /// Return Delay Time, 2 µs units.
    pub const RETURN_DELAY_TIME: u16 = 5;
    /// Status Return Level.
    pub const STATUS_RETURN_LEVEL: u16 = 16;
    /// Roll, pitch and yaw offsets (2 bytes each, signed, 0.1°).
    pub const ROLL_OFFSET: u16 = 18;
    /// Power to the servos (1: on).
    pub const DYNAMIXEL_POWER: u16 = 24;
    /// LEDs (bit per LED).
    pub const LED: u16 = 25;
    /// RGB LED (2 bytes).
    pub const LED_RGB: u16 = 26;
    /// Buzzer (2 bytes).
    pub const BUZZER: u16 = 28;
    /// Buttons (bit per button, read only).
    pub const BUTTON: u16 = 30;
    /// Supply voltage, 0.1 V (read only).
    pub const PRESENT_VOLTAGE: u16 = 31;
    /// Gyro x, y, z (2 bytes each, signed, read only).
    pub const GYRO: u16 = 32;
    /// Accelerometer x, y, z (2 bytes each, signed, read only).
    pub const ACC: u16 = 38;
    /// Roll, pitch, yaw (2 bytes each, signed, 0.1°, read only).
    pub const RPY: u16 = 44;
    /// IMU calibration requests (bits, cleared when done).
    pub const IMU_CONTROL: u16 = 50;
}

/// Gyro °/s per raw unit.
pub const GYRO_DPS_PER_UNIT: Real = 2000.0 / 32800.0;
/// Accelerometer g per raw unit.
pub const ACC_G_PER_UNIT: Real = 2.0 / 32768.0;
/// Degrees per raw angle unit.
pub const ANGLE_DEG_PER_UNIT: Real = 0.1;

/// Bytes from the gyro's first to the yaw's last (one read gets the IMU).
pub const IMU_BYTES: usize = 18;

/// What the IMU measures, in the board's axes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImuReading {
    /// Angular velocity, °/s.
    pub gyro_dps: [Real; 3],
    /// Specific force (gravity up when at rest), g.
    pub acc_g: [Real; 3],
    /// Roll, pitch, yaw, degrees.
    pub rpy_deg: [Real; 3],
}

impl ImuReading {
    /// Decodes [`IMU_BYTES`] read from [`board_addr::GYRO`]; `None` when too short.
    #[must_use]
    pub fn decode(bytes: &[u8]) -> Option<ImuReading> {
        if bytes.len() < IMU_BYTES {
            return None;
        }
        let at = |k: usize| Real::from(i16::from_le_bytes([bytes[2 * k], bytes[2 * k + 1]]));
        Some(ImuReading {
            gyro_dps: [0, 1, 2].map(|k| at(k) * GYRO_DPS_PER_UNIT),
            acc_g: [3, 4, 5].map(|k| at(k) * ACC_G_PER_UNIT),
            rpy_deg: [6, 7, 8].map(|k| at(k) * ANGLE_DEG_PER_UNIT),
        })
    }

    /// The reading in the robot's body axes (the OP3 framework negates the board's x and y).
    #[must_use]
    pub fn to_body(&self) -> ImuReading {
        let flip = |v: [Real; 3]| [-v[0], -v[1], v[2]];
        ImuReading {
            gyro_dps: flip(self.gyro_dps),
            acc_g: flip(self.acc_g),
            rpy_deg: self.rpy_deg,
        }
    }
}

/// Why a write was refused: the status packet's error code.
const ACCESS_ERROR: u8 = crate::servo::status_error::ACCESS;
const RANGE_ERROR: u8 = crate::servo::status_error::DATA_RANGE;

/// The board's device side.
#[derive(Clone, Debug)]
pub struct SensorBoard {
    table: [u8; BOARD_TABLE_LEN],
}

impl Default for SensorBoard {
    fn default() -> Self {
        SensorBoard::new(OPENCR_OP3_ID)
    }
}

impl SensorBoard {
    /// A board at its factory values with `id`, the IMU level and still, 12 V supply.
    #[must_use]
    pub fn new(id: u8) -> SensorBoard {
        let mut b = SensorBoard {
            table: [0; BOARD_TABLE_LEN],
        };
        b.factory_reset(id);
        b
    }

    fn factory_reset(&mut self, id: u8) {
        self.table = [0; BOARD_TABLE_LEN];
        self.table[0..2].copy_from_slice(&OPENCR_OP3_MODEL_NUMBER.to_le_bytes());
        self.table[usize::from(board_addr::FIRMWARE_VERSION)] = OPENCR_OP3_FIRMWARE;
        self.table[usize::from(board_addr::ID)] = id;
        self.table[usize::from(board_addr::BAUD_RATE)] = 4;
        self.table[usize::from(board_addr::STATUS_RETURN_LEVEL)] = 2;
        self.clear_ram();
    }

    /// RAM at power-on: servos powered, LEDs off, 12 V, level and still.
    fn clear_ram(&mut self) {
        for a in usize::from(board_addr::DYNAMIXEL_POWER)..BOARD_TABLE_LEN {
            self.table[a] = 0;
        }
        self.table[usize::from(board_addr::DYNAMIXEL_POWER)] = 1;
        self.table[usize::from(board_addr::PRESENT_VOLTAGE)] = 120;
        self.set_imu(&ImuReading {
            acc_g: [0.0, 0.0, 1.0],
            ..ImuReading::default()
        });
    }

    /// Its ID.
    #[must_use]
    pub fn id(&self) -> u8 {
        self.table[usize::from(board_addr::ID)]
    }

    /// Its model number.
    #[must_use]
    pub fn model_number(&self) -> u16 {
        OPENCR_OP3_MODEL_NUMBER
    }

    /// Status Return Level: 0 answers nothing but a ping, 1 reads and pings, 2 everything.
    #[must_use]
    pub fn status_return_level(&self) -> u8 {
        self.table[usize::from(board_addr::STATUS_RETURN_LEVEL)]
    }

    /// Its return delay, µs.
    #[must_use]
    pub fn return_delay_us(&self) -> u32 {
        2 * u32::from(self.table[usize::from(board_addr::RETURN_DELAY_TIME)])
    }

    /// Whether an instruction to `id` is its (broadcast included).
    #[must_use]
    pub fn hears(&self, id: u8) -> bool {
        id == self.id() || id == crate::protocol::BROADCAST_ID
    }

    /// Sets the IMU registers from a reading in the board's axes (saturating at the sensor's
    /// range).
    pub fn set_imu(&mut self, r: &ImuReading) {
        let raw = |v: Real, per_unit: Real| {
            let x = crate::math::real::round(v / per_unit);
            x.clamp(Real::from(i16::MIN), Real::from(i16::MAX)) as i16
        };
        for k in 0..3 {
            self.put(
                board_addr::GYRO + 2 * k as u16,
                raw(r.gyro_dps[k], GYRO_DPS_PER_UNIT),
            );
            self.put(board_addr::ACC + 2 * k as u16, raw(r.acc_g[k], ACC_G_PER_UNIT));
            self.put(
                board_addr::RPY + 2 * k as u16,
                raw(r.rpy_deg[k], ANGLE_DEG_PER_UNIT),
            );
        }
    }

    /// The IMU registers as a reading in the board's axes.
    #[must_use]
    pub fn imu(&self) -> ImuReading {
        let start = usize::from(board_addr::GYRO);
        ImuReading::decode(&self.table[start..start + IMU_BYTES]).unwrap_or_default()
    }

    /// Sets the supply voltage (volts).
    pub fn set_voltage(&mut self, volts: Real) {
        let v = crate::math::real::round(volts * 10.0).clamp(0.0, 255.0);
        self.table[usize::from(board_addr::PRESENT_VOLTAGE)] = v as u8;
    }

    fn put(&mut self, a: u16, v: i16) {
        let a = usize::from(a);
        self.table[a..a + 2].copy_from_slice(&v.to_le_bytes());
    }

    /// `n` bytes from `a`; `None` past the table.
    #[must_use]
    pub fn read(&self, a: u16, n: usize) -> Option<&[u8]> {
        let start = usize::from(a);
        let end = start.checked_add(n)?;
        (end <= BOARD_TABLE_LEN).then(|| &self.table[start..end])
    }

    /// Writes `data` at `a`; returns the status error (0: done). Every byte must be writable:
    /// ID (0–252), Baud Rate (0–7), Return Delay Time, Status Return Level (0–2), the offsets,
    /// power, LEDs, buzzer, IMU Control; anything else answers Access Error and nothing is
    /// written.
    pub fn write(&mut self, a: u16, data: &[u8]) -> u8 {
        let start = usize::from(a);
        let Some(end) = start.checked_add(data.len()).filter(|e| *e <= BOARD_TABLE_LEN) else {
            return RANGE_ERROR;
        };
        if data.is_empty() {
            return RANGE_ERROR;
        }
        let writable = |b: usize| matches!(b, 3..=5 | 16 | 18..=29 | 50);
        if !(start..end).all(writable) {
            return ACCESS_ERROR;
        }
        let value = |addr: u16| data.get(usize::from(addr).wrapping_sub(start)).copied();
        let in_range = value(board_addr::ID).is_none_or(|v| v <= 252)
            && value(board_addr::BAUD_RATE).is_none_or(|v| v <= 7)
            && value(board_addr::STATUS_RETURN_LEVEL).is_none_or(|v| v <= 2);
        if !in_range {
            return RANGE_ERROR;
        }
        self.table[start..end].copy_from_slice(data);
        // Calibration requests finish at once on the virtual board.
        self.table[usize::from(board_addr::IMU_CONTROL)] = 0;
        0
    }

    /// Reboot: RAM to its power-on values.
    pub fn reboot(&mut self) {
        self.clear_ram();
    }

    /// Factory reset: everything to its factory value (`keep_id`: the ID stays).
    pub fn reset(&mut self, keep_id: bool) {
        let id = if keep_id { self.id() } else { OPENCR_OP3_ID };
        self.factory_reset(id);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_imu_round_trips_through_the_table_at_the_frameworks_scales() {
        let mut b = SensorBoard::default();
        assert_eq!(b.id(), 200);
        assert_eq!(b.read(0, 3), Some(&[0x00, 0x74, 2][..]));
        // At rest: 1 g up.
        let rest = b.imu();
        assert!((rest.acc_g[2] - 1.0).abs() < 1e-4, "{rest:?}");
        let r = ImuReading {
            gyro_dps: [100.0, -250.5, 1990.0],
            acc_g: [0.5, -1.25, 0.98],
            rpy_deg: [-3.2, 12.7, 179.9],
        };
        b.set_imu(&r);
        let back = b.imu();
        for k in 0..3 {
            assert!((back.gyro_dps[k] - r.gyro_dps[k]).abs() <= GYRO_DPS_PER_UNIT / 2.0 + 1e-9);
            assert!((back.acc_g[k] - r.acc_g[k]).abs() <= ACC_G_PER_UNIT / 2.0 + 1e-9);
            assert!((back.rpy_deg[k] - r.rpy_deg[k]).abs() <= 0.05 + 1e-9);
        }
        // Beyond the sensor's range: saturated, not wrapped.
        b.set_imu(&ImuReading {
            gyro_dps: [5000.0, -5000.0, 0.0],
            ..r
        });
        assert_eq!(b.read(board_addr::GYRO, 4), Some(&[0xFF, 0x7F, 0x00, 0x80][..]));
        // The body axes: x and y negated.
        let body = back.to_body();
        assert_eq!(body.gyro_dps[0], -back.gyro_dps[0]);
        assert_eq!(body.acc_g[2], back.acc_g[2]);
    }

    #[test]
    fn writes_are_checked_like_the_firmware_does() {
        let mut b = SensorBoard::default();
        // Read-only items and past the table.
        assert_eq!(b.write(board_addr::GYRO, &[1, 2]), ACCESS_ERROR);
        assert_eq!(b.write(0, &[1]), ACCESS_ERROR);
        assert_eq!(b.write(50, &[1, 1]), RANGE_ERROR);
        assert_eq!(b.write(board_addr::STATUS_RETURN_LEVEL, &[3]), RANGE_ERROR);
        // LEDs, the return delay and the ID.
        assert_eq!(b.write(board_addr::LED, &[7, 0x34, 0x12]), 0);
        assert_eq!(b.read(board_addr::LED, 3), Some(&[7, 0x34, 0x12][..]));
        assert_eq!(b.write(board_addr::RETURN_DELAY_TIME, &[10]), 0);
        assert_eq!(b.return_delay_us(), 20);
        assert_eq!(b.write(board_addr::ID, &[201]), 0);
        assert!(b.hears(201) && !b.hears(200) && b.hears(crate::protocol::BROADCAST_ID));
        // Reboot clears RAM, keeps EEPROM; a factory reset brings ID 200 back.
        b.reboot();
        assert_eq!(b.read(board_addr::LED, 1), Some(&[0][..]));
        assert_eq!(b.id(), 201);
        b.reset(false);
        assert_eq!(b.id(), 200);
        assert_eq!(b.return_delay_us(), 0);
    }

    #[test]
    fn a_short_read_does_not_decode() {
        assert!(ImuReading::decode(&[0; IMU_BYTES - 1]).is_none());
        assert!(ImuReading::decode(&[0; IMU_BYTES]).is_some());
    }
}

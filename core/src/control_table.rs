//! The X-series control table item by item, per model: address, size, access, area, factory
//! value and the range a write must respect (ROBOTIS e-manual, firmware 46 and later).
//!
//! [`item_at`] finds the item a byte belongs to; [`for_each_item`] walks a model's table. The
//! virtual servo (the `device` module) takes its factory values, its write checks (Access Error
//! for read-only items and for EEPROM while torque is on, Data Length Error for an item
//! written in part, Data Range Error beyond a range) and its indirect layout from here.
//!
//! Where the e-manual's pages disagree with each other the choice is noted at the item.

use crate::servo::{Family, ServoModel};

/// Who may write an item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Access {
    /// Read only: a write answers Access Error.
    Read,
    /// Read and write.
    ReadWrite,
}

/// The values a write may set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Range {
    /// Any value of the item's size (bit fields, data the firmware does not check).
    Any,
    /// Unsigned, inclusive.
    Unsigned(u32, u32),
    /// Two's complement of the item's size, inclusive.
    Signed(i32, i32),
    /// One of these values.
    OneOf(&'static [u32]),
    /// −v … v, v being the unsigned item at this address (Goal PWM against PWM Limit …).
    WithinLimit(u16),
    /// Min Position Limit … Max Position Limit (Goal Position; beyond: Data Limit Error).
    PositionLimits,
}

/// One control-table item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Item {
    /// The e-manual's name.
    pub name: &'static str,
    /// First byte.
    pub address: u16,
    /// Bytes (1, 2 or 4).
    pub size: u16,
    /// Read only or read-write.
    pub access: Access,
    /// What a write may set.
    pub range: Range,
    /// Value after a factory reset (EEPROM) or at power-on (RAM); `None` where the servo
    /// computes it (present values, goals that follow the present position).
    pub factory: Option<u32>,
}

impl Item {
    /// In the EEPROM area (below 64): writable only while torque is off.
    #[must_use]
    pub fn eeprom(&self) -> bool {
        self.address < EEPROM_END
    }

    /// Whether `value` (the item's bytes as a little-endian unsigned number) is in range;
    /// `register` reads the table for limits held by other items.
    #[must_use]
    pub fn accepts(&self, value: u32, register: impl Fn(u16, u16) -> u32) -> bool {
        let signed = || match self.size {
            1 => i32::from(value as u8 as i8),
            2 => i32::from(value as u16 as i16),
            _ => value as i32,
        };
        match self.range {
            Range::Any => true,
            Range::Unsigned(lo, hi) => (lo..=hi).contains(&value),
            Range::Signed(lo, hi) => (lo..=hi).contains(&signed()),
            Range::OneOf(values) => values.contains(&value),
            Range::WithinLimit(limit) => {
                let limit = register(limit, self.size.min(4)) as i32;
                (-limit..=limit).contains(&signed())
            }
            Range::PositionLimits => {
                let (lo, hi) = (register(52, 4) as i32, register(48, 4) as i32);
                (lo..=hi).contains(&signed())
            }
        }
    }
}

/// Firmware version the virtual servos report.
pub const FIRMWARE_VERSION: u8 = 48;

/// First RAM address; below it, EEPROM.
pub const EEPROM_END: u16 = 64;

/// A run of Indirect Address items and the Indirect Data bytes they map.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndirectBlock {
    /// Indirect Address of the first (2 bytes each).
    pub address: u16,
    /// Indirect Data of the first (1 byte each).
    pub data: u16,
    /// How many.
    pub count: u16,
    /// The number of the first (Indirect Address 1, 29 …).
    pub first: u16,
}

const INDIRECT_X330: [IndirectBlock; 1] = [IndirectBlock {
    address: 168,
    data: 208,
    count: 20,
    first: 1,
}];
const INDIRECT_X430: [IndirectBlock; 2] = [
    IndirectBlock {
        address: 168,
        data: 224,
        count: 28,
        first: 1,
    },
    IndirectBlock {
        address: 578,
        data: 634,
        count: 28,
        first: 29,
    },
];

/// The model's Indirect Address/Data blocks.
#[must_use]
pub fn indirect_blocks(model: &ServoModel) -> &'static [IndirectBlock] {
    match model.family {
        Family::X330 => &INDIRECT_X330,
        _ => &INDIRECT_X430,
    }
}

/// The block whose Indirect Data holds byte `address`, if any.
#[must_use]
pub fn indirect_data_block(model: &ServoModel, address: usize) -> Option<&'static IndirectBlock> {
    indirect_blocks(model)
        .iter()
        .find(|b| (usize::from(b.data)..usize::from(b.data + b.count)).contains(&address))
}

/// One past the model's last control-table byte.
#[must_use]
pub fn table_end(model: &ServoModel) -> u16 {
    indirect_blocks(model)
        .iter()
        .map(|b| b.data + b.count)
        .max()
        .unwrap_or(EEPROM_END)
}

/// The Baud Rate codes a model accepts (0 = 9,600 … 6 = 4 Mbps, 7 = 4.5 Mbps).
fn highest_baud_code(model: &ServoModel) -> u32 {
    if model.max_baud >= 4_500_000 {
        7
    } else {
        6
    }
}

const OPERATING_MODES: [u32; 6] = [0, 1, 3, 4, 5, 16];
const OPERATING_MODES_XL430: [u32; 4] = [1, 3, 4, 16];

/// A value that may depend on the model.
#[derive(Clone, Copy)]
enum Value {
    Fixed(u32),
    ModelNumber,
    TemperatureLimit,
    MaxVoltageLimit,
    MinVoltageLimit,
    CurrentLimit,
    VelocityLimit,
    VelocityIGain,
    VelocityPGain,
    PositionDGain,
    PositionPGain,
    Shutdown,
    /// Computed by the servo (present values).
    Live,
}

/// A range that may depend on the model.
#[derive(Clone, Copy)]
enum Spec {
    Is(Range),
    BaudCodes,
    OperatingModes,
    ProtocolTypes,
    Volts,
    UpToCurrentLimit,
    UpToVelocityMax,
}

/// Which models have an item.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Present {
    All,
    /// Models with current sensing (all but the XL430).
    CurrentSensing,
    /// XL330/XC330.
    X330,
    /// XM540/XH540.
    X540,
}

/// An item as the table lists it, model-dependent parts unresolved.
#[derive(Clone, Copy)]
struct Row(&'static str, u16, u16, Access, Spec, Value, Present);

const GAIN: Spec = Spec::Is(Range::Unsigned(0, 16_383));

/// The X-series items other than the indirect ones, in address order.
#[rustfmt::skip]
const ROWS: &[Row] = {
    use Access::{Read as R, ReadWrite as RW};
    use Present::{All, CurrentSensing, X330, X540};
    use Range::{Any, Signed, Unsigned, WithinLimit};
    use Value::{Fixed, Live};
    &[
        Row("Model Number", 0, 2, R, Spec::Is(Any), Value::ModelNumber, All),
        Row("Model Information", 2, 4, R, Spec::Is(Any), Fixed(0), All),
        Row("Firmware Version", 6, 1, R, Spec::Is(Any), Fixed(FIRMWARE_VERSION as u32), All),
        Row("ID", 7, 1, RW, Spec::Is(Unsigned(0, 252)), Fixed(1), All),
        Row("Baud Rate", 8, 1, RW, Spec::BaudCodes, Fixed(1), All),
        Row("Return Delay Time", 9, 1, RW, Spec::Is(Unsigned(0, 254)), Fixed(250), All),
        // Bits: reverse, time-based profile, torque on by goal update (firmware 46+).
        Row("Drive Mode", 10, 1, RW, Spec::Is(Unsigned(0, 13)), Fixed(0), All),
        Row("Operating Mode", 11, 1, RW, Spec::OperatingModes, Fixed(3), All),
        // 253 and above switch it off (the factory 255 included).
        Row("Secondary(Shadow) ID", 12, 1, RW, Spec::Is(Unsigned(0, 255)), Fixed(255), All),
        Row("Protocol Type", 13, 1, RW, Spec::ProtocolTypes, Fixed(2), All),
        Row("Homing Offset", 20, 4, RW, Spec::Is(Signed(-1_044_479, 1_044_479)), Fixed(0), All),
        Row("Moving Threshold", 24, 4, RW, Spec::Is(Unsigned(0, 1023)), Fixed(10), All),
        Row("Temperature Limit", 31, 1, RW, Spec::Is(Unsigned(0, 100)), Value::TemperatureLimit, All),
        // The XM430-W350 page gives 110–300 with a factory Min of 95: the 24 V models' range
        // copied; 95–160 as on its siblings' pages.
        Row("Max Voltage Limit", 32, 2, RW, Spec::Volts, Value::MaxVoltageLimit, All),
        Row("Min Voltage Limit", 34, 2, RW, Spec::Volts, Value::MinVoltageLimit, All),
        Row("PWM Limit", 36, 2, RW, Spec::Is(Unsigned(0, 885)), Fixed(885), All),
        Row("Current Limit", 38, 2, RW, Spec::UpToCurrentLimit, Value::CurrentLimit, CurrentSensing),
        Row("Velocity Limit", 44, 4, RW, Spec::UpToVelocityMax, Value::VelocityLimit, All),
        Row("Max Position Limit", 48, 4, RW, Spec::Is(Unsigned(0, 4095)), Fixed(4095), All),
        Row("Min Position Limit", 52, 4, RW, Spec::Is(Unsigned(0, 4095)), Fixed(0), All),
        Row("External Port Mode 1", 56, 1, RW, Spec::Is(Unsigned(0, 3)), Fixed(3), X540),
        Row("External Port Mode 2", 57, 1, RW, Spec::Is(Unsigned(0, 3)), Fixed(3), X540),
        Row("External Port Mode 3", 58, 1, RW, Spec::Is(Unsigned(0, 3)), Fixed(3), X540),
        Row("Startup Configuration", 60, 1, RW, Spec::Is(Unsigned(0, 3)), Fixed(0), All),
        Row("PWM Slope", 62, 1, RW, Spec::Is(Unsigned(1, 255)), Fixed(140), X330),
        Row("Shutdown", 63, 1, RW, Spec::Is(Any), Value::Shutdown, All),
        Row("Torque Enable", 64, 1, RW, Spec::Is(Unsigned(0, 1)), Fixed(0), All),
        Row("LED", 65, 1, RW, Spec::Is(Unsigned(0, 1)), Fixed(0), All),
        Row("Status Return Level", 68, 1, RW, Spec::Is(Unsigned(0, 2)), Fixed(2), All),
        Row("Registered Instruction", 69, 1, R, Spec::Is(Any), Fixed(0), All),
        Row("Hardware Error Status", 70, 1, R, Spec::Is(Any), Fixed(0), All),
        Row("Velocity I Gain", 76, 2, RW, GAIN, Value::VelocityIGain, All),
        Row("Velocity P Gain", 78, 2, RW, GAIN, Value::VelocityPGain, All),
        Row("Position D Gain", 80, 2, RW, GAIN, Value::PositionDGain, All),
        Row("Position I Gain", 82, 2, RW, GAIN, Fixed(0), All),
        Row("Position P Gain", 84, 2, RW, GAIN, Value::PositionPGain, All),
        Row("Feedforward 2nd Gain", 88, 2, RW, GAIN, Fixed(0), All),
        Row("Feedforward 1st Gain", 90, 2, RW, GAIN, Fixed(0), All),
        // 0 switches it off; 1–127 arm it (20 ms units).
        Row("Bus Watchdog", 98, 1, RW, Spec::Is(Unsigned(0, 127)), Fixed(0), All),
        Row("Goal PWM", 100, 2, RW, Spec::Is(WithinLimit(36)), Fixed(885), All),
        Row("Goal Current", 102, 2, RW, Spec::Is(WithinLimit(38)), Value::CurrentLimit, CurrentSensing),
        Row("Goal Velocity", 104, 4, RW, Spec::Is(WithinLimit(44)), Fixed(0), All),
        Row("Profile Acceleration", 108, 4, RW, Spec::Is(Unsigned(0, 32_767)), Fixed(0), All),
        Row("Profile Velocity", 112, 4, RW, Spec::Is(Unsigned(0, 32_767)), Fixed(0), All),
        Row("Goal Position", 116, 4, RW, Spec::Is(Range::PositionLimits), Live, All),
        Row("Realtime Tick", 120, 2, R, Spec::Is(Any), Live, All),
        Row("Moving", 122, 1, R, Spec::Is(Any), Fixed(0), All),
        Row("Moving Status", 123, 1, R, Spec::Is(Any), Live, All),
        Row("Present PWM", 124, 2, R, Spec::Is(Any), Live, All),
        Row("Present Current", 126, 2, R, Spec::Is(Any), Live, CurrentSensing),
        // The XL430's item at 126: 0.1 % of the maximum torque.
        Row("Present Load", 126, 2, R, Spec::Is(Any), Live, All),
        Row("Present Velocity", 128, 4, R, Spec::Is(Any), Live, All),
        Row("Present Position", 132, 4, R, Spec::Is(Any), Live, All),
        Row("Velocity Trajectory", 136, 4, R, Spec::Is(Any), Live, All),
        Row("Position Trajectory", 140, 4, R, Spec::Is(Any), Live, All),
        Row("Present Input Voltage", 144, 2, R, Spec::Is(Any), Live, All),
        Row("Present Temperature", 146, 1, R, Spec::Is(Any), Live, All),
        Row("Backup Ready", 147, 1, R, Spec::Is(Any), Fixed(0), All),
        Row("External Port Data 1", 152, 2, RW, Spec::Is(Any), Fixed(0), X540),
        Row("External Port Data 2", 154, 2, RW, Spec::Is(Any), Fixed(0), X540),
        Row("External Port Data 3", 156, 2, RW, Spec::Is(Any), Fixed(0), X540),
    ]
};

impl Row {
    fn present(&self, model: &ServoModel) -> bool {
        let current = model.family != Family::Xl430;
        match self.6 {
            Present::All if self.0 == "Present Load" => !current,
            Present::All => true,
            Present::CurrentSensing => current,
            Present::X330 => model.family == Family::X330,
            Present::X540 => model.family == Family::X540,
        }
    }

    fn resolve(&self, m: &ServoModel) -> Item {
        let range = match self.4 {
            Spec::Is(r) => r,
            Spec::BaudCodes => Range::Unsigned(0, highest_baud_code(m)),
            Spec::OperatingModes if m.family == Family::Xl430 => Range::OneOf(&OPERATING_MODES_XL430),
            Spec::OperatingModes => Range::OneOf(&OPERATING_MODES),
            Spec::ProtocolTypes if m.family == Family::X330 => Range::Unsigned(2, 22),
            Spec::ProtocolTypes => Range::Unsigned(1, 2),
            Spec::Volts => Range::Unsigned(u32::from(m.voltage_range.0), u32::from(m.voltage_range.1)),
            Spec::UpToCurrentLimit => Range::Unsigned(0, u32::from(m.current_limit)),
            Spec::UpToVelocityMax => Range::Unsigned(0, u32::from(m.velocity_limit.1)),
        };
        let factory = match self.5 {
            Value::Fixed(v) => Some(v),
            Value::ModelNumber => Some(u32::from(m.model_number)),
            Value::TemperatureLimit => Some(u32::from(m.temperature_limit)),
            Value::MaxVoltageLimit => Some(u32::from(m.voltage_limits.0)),
            Value::MinVoltageLimit => Some(u32::from(m.voltage_limits.1)),
            Value::CurrentLimit => Some(u32::from(m.current_limit)),
            Value::VelocityLimit => Some(u32::from(m.velocity_limit.0)),
            Value::VelocityIGain => Some(u32::from(m.velocity_i_gain)),
            Value::VelocityPGain => Some(u32::from(m.velocity_p_gain)),
            Value::PositionDGain => Some(u32::from(m.position_d_gain)),
            Value::PositionPGain => Some(u32::from(m.position_p_gain)),
            Value::Shutdown => Some(if m.family == Family::X330 { 53 } else { 52 }),
            Value::Live => None,
        };
        Item {
            name: self.0,
            address: self.1,
            size: self.2,
            access: self.3,
            range,
            factory,
        }
    }
}

/// The item that byte `address` belongs to on `model`, indirect ones included (named
/// "Indirect Address" / "Indirect Data"); `None` for reserved bytes and beyond the table.
#[must_use]
pub fn item_at(model: &ServoModel, address: u16) -> Option<Item> {
    if let Some(r) = ROWS
        .iter()
        .find(|r| (r.1..r.1.saturating_add(r.2)).contains(&address) && r.present(model))
    {
        return Some(r.resolve(model));
    }
    let end = table_end(model);
    for b in indirect_blocks(model) {
        if (b.address..b.address + 2 * b.count).contains(&address) {
            let k = (address - b.address) / 2;
            return Some(Item {
                name: "Indirect Address",
                address: b.address + 2 * k,
                size: 2,
                access: Access::ReadWrite,
                range: Range::Unsigned(u32::from(EEPROM_END), u32::from(end - 1)),
                factory: Some(u32::from(b.data + k)),
            });
        }
        if (b.data..b.data + b.count).contains(&address) {
            return Some(Item {
                name: "Indirect Data",
                address,
                size: 1,
                access: Access::ReadWrite,
                range: Range::Any,
                factory: Some(0),
            });
        }
    }
    None
}

/// Every item of the model, indirect ones included, in address order: calls `f` for each.
pub fn for_each_item(model: &ServoModel, mut f: impl FnMut(Item)) {
    let mut a = 0;
    let end = table_end(model);
    while a < end {
        match item_at(model, a) {
            Some(i) => {
                f(i);
                a = i.address + i.size;
            }
            None => a += 1,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::servo::MODELS;

    #[test]
    fn items_do_not_overlap_and_fit_the_table() {
        for m in &MODELS {
            let mut last_end = 0;
            let mut count = 0;
            for_each_item(m, |i| {
                assert!(i.address >= last_end, "{} overlaps on {}", i.name, m.name);
                assert!(matches!(i.size, 1 | 2 | 4));
                last_end = i.address + i.size;
                count += 1;
            });
            assert!(last_end <= table_end(m));
            let indirect: u16 = indirect_blocks(m).iter().map(|b| 2 * b.count).sum();
            assert!(count > usize::from(indirect), "{}: {count} items", m.name);
        }
    }

    #[test]
    fn factory_values_are_inside_their_ranges() {
        for m in &MODELS {
            let register = |a: u16, n: u16| {
                item_at(m, a)
                    .filter(|i| i.size == n)
                    .and_then(|i| i.factory)
                    .unwrap_or(0)
            };
            for_each_item(m, |i| {
                if let (Some(v), Access::ReadWrite) = (i.factory, i.access) {
                    assert!(i.accepts(v, register), "{} {} = {v}", m.name, i.name);
                }
            });
        }
    }

    #[test]
    fn signed_ranges_read_twos_complement() {
        let m = &MODELS[2];
        let homing = item_at(m, 20).unwrap();
        assert!(homing.accepts((-1_044_479i32) as u32, |_, _| 0));
        assert!(!homing.accepts((-1_044_480i32) as u32, |_, _| 0));
        let pwm = item_at(m, 100).unwrap();
        let limit = |a: u16, _| if a == 36 { 885 } else { 0 };
        assert!(pwm.accepts(u32::from((-885i16) as u16), limit));
        assert!(!pwm.accepts(u32::from((-886i16) as u16), limit));
        assert!(!pwm.accepts(886, limit));
    }
}

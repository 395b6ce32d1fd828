//! The X-series control table item by item, per model: address, size, access, area, factory
//! value and the range a write must respect (ROBOTIS e-manual, firmware 46 and later).
//!
//! [`items`] lists one model's items; [`item_at`] finds the item a byte belongs to. The
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

/// The model's items other than the indirect ones, in address order.
#[must_use]
pub fn base_items(model: &ServoModel) -> heapless::Vec<Item, 64> {
    use Access::{Read as R, ReadWrite as RW};
    let fam = model.family;
    let has_current = fam != Family::Xl430;
    let item = |name, address, size, access, range, factory| Item {
        name,
        address,
        size,
        access,
        range,
        factory,
    };
    let gain = Range::Unsigned(0, 16_383);
    let (vl, vl_max) = model.velocity_limit;
    let (v_lo, v_hi) = model.voltage_range;
    let mut v = heapless::Vec::new();
    let mut add = |i: Item, present: bool| {
        if present {
            let _ = v.push(i);
        }
    };
    add(
        item(
            "Model Number",
            0,
            2,
            R,
            Range::Any,
            Some(u32::from(model.model_number)),
        ),
        true,
    );
    add(item("Model Information", 2, 4, R, Range::Any, Some(0)), true);
    add(
        item(
            "Firmware Version",
            6,
            1,
            R,
            Range::Any,
            Some(u32::from(FIRMWARE_VERSION)),
        ),
        true,
    );
    add(item("ID", 7, 1, RW, Range::Unsigned(0, 252), Some(1)), true);
    add(
        item(
            "Baud Rate",
            8,
            1,
            RW,
            Range::Unsigned(0, highest_baud_code(model)),
            Some(1),
        ),
        true,
    );
    add(
        item("Return Delay Time", 9, 1, RW, Range::Unsigned(0, 254), Some(250)),
        true,
    );
    // Bits: reverse, time-based profile, torque on by goal update (firmware 46+).
    add(
        item("Drive Mode", 10, 1, RW, Range::Unsigned(0, 13), Some(0)),
        true,
    );
    let modes: &'static [u32] = if fam == Family::Xl430 {
        &OPERATING_MODES_XL430
    } else {
        &OPERATING_MODES
    };
    add(
        item("Operating Mode", 11, 1, RW, Range::OneOf(modes), Some(3)),
        true,
    );
    // 253 and above switch it off (the factory 255 included).
    add(
        item(
            "Secondary(Shadow) ID",
            12,
            1,
            RW,
            Range::Unsigned(0, 255),
            Some(255),
        ),
        true,
    );
    let protocols = if fam == Family::X330 {
        Range::Unsigned(2, 22)
    } else {
        Range::Unsigned(1, 2)
    };
    add(item("Protocol Type", 13, 1, RW, protocols, Some(2)), true);
    add(
        item(
            "Homing Offset",
            20,
            4,
            RW,
            Range::Signed(-1_044_479, 1_044_479),
            Some(0),
        ),
        true,
    );
    add(
        item("Moving Threshold", 24, 4, RW, Range::Unsigned(0, 1023), Some(10)),
        true,
    );
    add(
        item(
            "Temperature Limit",
            31,
            1,
            RW,
            Range::Unsigned(0, 100),
            Some(u32::from(model.temperature_limit)),
        ),
        true,
    );
    // The XM430-W350 page gives 110–300 with a factory Min of 95: the 24 V models' range
    // copied; 95–160 as on its siblings' pages.
    let volts = Range::Unsigned(u32::from(v_lo), u32::from(v_hi));
    add(
        item(
            "Max Voltage Limit",
            32,
            2,
            RW,
            volts,
            Some(u32::from(model.voltage_limits.0)),
        ),
        true,
    );
    add(
        item(
            "Min Voltage Limit",
            34,
            2,
            RW,
            volts,
            Some(u32::from(model.voltage_limits.1)),
        ),
        true,
    );
    add(
        item("PWM Limit", 36, 2, RW, Range::Unsigned(0, 885), Some(885)),
        true,
    );
    let cl = u32::from(model.current_limit);
    add(
        item("Current Limit", 38, 2, RW, Range::Unsigned(0, cl), Some(cl)),
        has_current,
    );
    add(
        item(
            "Velocity Limit",
            44,
            4,
            RW,
            Range::Unsigned(0, u32::from(vl_max)),
            Some(u32::from(vl)),
        ),
        true,
    );
    add(
        item(
            "Max Position Limit",
            48,
            4,
            RW,
            Range::Unsigned(0, 4095),
            Some(4095),
        ),
        true,
    );
    add(
        item("Min Position Limit", 52, 4, RW, Range::Unsigned(0, 4095), Some(0)),
        true,
    );
    for (k, name) in [
        "External Port Mode 1",
        "External Port Mode 2",
        "External Port Mode 3",
    ]
    .into_iter()
    .enumerate()
    {
        add(
            item(name, 56 + k as u16, 1, RW, Range::Unsigned(0, 3), Some(3)),
            fam == Family::X540,
        );
    }
    add(
        item("Startup Configuration", 60, 1, RW, Range::Unsigned(0, 3), Some(0)),
        true,
    );
    add(
        item("PWM Slope", 62, 1, RW, Range::Unsigned(1, 255), Some(140)),
        fam == Family::X330,
    );
    let shutdown = if fam == Family::X330 { 53 } else { 52 };
    add(item("Shutdown", 63, 1, RW, Range::Any, Some(shutdown)), true);
    add(
        item("Torque Enable", 64, 1, RW, Range::Unsigned(0, 1), Some(0)),
        true,
    );
    add(item("LED", 65, 1, RW, Range::Unsigned(0, 1), Some(0)), true);
    add(
        item("Status Return Level", 68, 1, RW, Range::Unsigned(0, 2), Some(2)),
        true,
    );
    add(
        item("Registered Instruction", 69, 1, R, Range::Any, Some(0)),
        true,
    );
    add(item("Hardware Error Status", 70, 1, R, Range::Any, Some(0)), true);
    add(
        item(
            "Velocity I Gain",
            76,
            2,
            RW,
            gain,
            Some(u32::from(model.velocity_i_gain)),
        ),
        true,
    );
    add(
        item(
            "Velocity P Gain",
            78,
            2,
            RW,
            gain,
            Some(u32::from(model.velocity_p_gain)),
        ),
        true,
    );
    add(
        item(
            "Position D Gain",
            80,
            2,
            RW,
            gain,
            Some(u32::from(model.position_d_gain)),
        ),
        true,
    );
    add(item("Position I Gain", 82, 2, RW, gain, Some(0)), true);
    add(
        item(
            "Position P Gain",
            84,
            2,
            RW,
            gain,
            Some(u32::from(model.position_p_gain)),
        ),
        true,
    );
    add(item("Feedforward 2nd Gain", 88, 2, RW, gain, Some(0)), true);
    add(item("Feedforward 1st Gain", 90, 2, RW, gain, Some(0)), true);
    // 0 switches it off; 1–127 arm it (20 ms units).
    add(
        item("Bus Watchdog", 98, 1, RW, Range::Unsigned(0, 127), Some(0)),
        true,
    );
    add(
        item("Goal PWM", 100, 2, RW, Range::WithinLimit(36), Some(885)),
        true,
    );
    add(
        item("Goal Current", 102, 2, RW, Range::WithinLimit(38), Some(cl)),
        has_current,
    );
    add(
        item("Goal Velocity", 104, 4, RW, Range::WithinLimit(44), Some(0)),
        true,
    );
    add(
        item(
            "Profile Acceleration",
            108,
            4,
            RW,
            Range::Unsigned(0, 32_767),
            Some(0),
        ),
        true,
    );
    add(
        item(
            "Profile Velocity",
            112,
            4,
            RW,
            Range::Unsigned(0, 32_767),
            Some(0),
        ),
        true,
    );
    add(
        item("Goal Position", 116, 4, RW, Range::PositionLimits, None),
        true,
    );
    add(item("Realtime Tick", 120, 2, R, Range::Any, None), true);
    add(item("Moving", 122, 1, R, Range::Any, Some(0)), true);
    add(item("Moving Status", 123, 1, R, Range::Any, None), true);
    add(item("Present PWM", 124, 2, R, Range::Any, None), true);
    let load = if has_current {
        "Present Current"
    } else {
        "Present Load"
    };
    add(item(load, 126, 2, R, Range::Any, None), true);
    add(item("Present Velocity", 128, 4, R, Range::Any, None), true);
    add(item("Present Position", 132, 4, R, Range::Any, None), true);
    add(item("Velocity Trajectory", 136, 4, R, Range::Any, None), true);
    add(item("Position Trajectory", 140, 4, R, Range::Any, None), true);
    add(item("Present Input Voltage", 144, 2, R, Range::Any, None), true);
    add(item("Present Temperature", 146, 1, R, Range::Any, None), true);
    add(item("Backup Ready", 147, 1, R, Range::Any, Some(0)), true);
    for (k, name) in [
        "External Port Data 1",
        "External Port Data 2",
        "External Port Data 3",
    ]
    .into_iter()
    .enumerate()
    {
        add(
            item(name, 152 + 2 * k as u16, 2, RW, Range::Any, Some(0)),
            fam == Family::X540,
        );
    }
    v
}

/// The item that byte `address` belongs to, indirect ones included (named "Indirect
/// Address" / "Indirect Data"); `None` for reserved bytes and beyond the table.
#[must_use]
pub fn item_at(model: &ServoModel, base: &[Item], address: u16) -> Option<Item> {
    if let Some(i) = base
        .iter()
        .find(|i| (i.address..i.address + i.size).contains(&address))
    {
        return Some(*i);
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
    let base = base_items(model);
    let mut a = 0;
    let end = table_end(model);
    while a < end {
        match item_at(model, &base, a) {
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
            let base = base_items(m);
            let register = |a: u16, n: u16| {
                base.iter()
                    .find(|i| i.address == a && i.size == n)
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
        let base = base_items(m);
        let homing = item_at(m, &base, 20).unwrap();
        assert!(homing.accepts((-1_044_479i32) as u32, |_, _| 0));
        assert!(!homing.accepts((-1_044_480i32) as u32, |_, _| 0));
        let pwm = item_at(m, &base, 100).unwrap();
        let limit = |a: u16, _| if a == 36 { 885 } else { 0 };
        assert!(pwm.accepts(u32::from((-885i16) as u16), limit));
        assert!(!pwm.accepts(u32::from((-886i16) as u16), limit));
        assert!(!pwm.accepts(886, limit));
    }
}

//! Every model's virtual servo against its control table, item by item: factory values,
//! range edges, read-only and EEPROM locking, plus Homing Offset, Secondary ID and Protocol
//! Type as the e-manual describes them.

use marionette_core::control_table::{self, Access, Item, Range};
use marionette_core::device::{Chain, Replies, VirtualServo, MAX_PACKET, UNDEFINED_ADDRESS_ERROR};
use marionette_core::protocol::{self, instruction, BROADCAST_ID};
use marionette_core::servo::{addr, status_error, ServoModel, MODELS};

/// Sends one instruction; the replies as (id, error, data).
fn send(chain: &mut Chain, id: u8, inst: u8, params: &[u8]) -> Vec<(u8, u8, Vec<u8>)> {
    let mut packet = [0u8; MAX_PACKET];
    let n = protocol::encode(id, inst, params, &mut packet).unwrap();
    let mut out = [0u8; 4 * MAX_PACKET];
    let mut replies = Replies::new();
    chain.handle(&packet[..n], &mut out, &mut replies).unwrap();
    replies
        .iter()
        .map(|r| {
            let mut buf = [0u8; MAX_PACKET];
            let (p, _) = protocol::decode(&out[r.start..r.start + r.len], &mut buf).unwrap();
            let (error, data) = p.status().unwrap();
            (p.id, error, data.to_vec())
        })
        .collect()
}

fn write(chain: &mut Chain, id: u8, address: u16, data: &[u8]) -> Option<u8> {
    let mut params = address.to_le_bytes().to_vec();
    params.extend_from_slice(data);
    send(chain, id, instruction::WRITE, &params).first().map(|r| r.1)
}

fn read(chain: &mut Chain, id: u8, address: u16, n: u16) -> Option<(u8, u32)> {
    let mut params = address.to_le_bytes().to_vec();
    params.extend_from_slice(&n.to_le_bytes());
    send(chain, id, instruction::READ, &params).first().map(|r| {
        let v = r.2.iter().rev().fold(0u32, |acc, &b| (acc << 8) | u32::from(b));
        (r.1, v)
    })
}

fn chain_of(model: &'static ServoModel) -> Chain {
    let mut chain = Chain::new();
    chain.add(VirtualServo::new(1, model, 2048)).unwrap();
    chain
}

fn le(v: u32, size: u16) -> Vec<u8> {
    v.to_le_bytes()[..usize::from(size)].to_vec()
}

/// Items whose writes change how the servo talks (id, baud, protocol, status level) or
/// arm it: checked for their range edges only beyond the range.
fn changes_the_link(i: &Item) -> bool {
    matches!(i.address, 7 | 8 | 13 | 64 | 68 | 98)
}

#[test]
fn every_item_of_every_model_reads_its_factory_value_and_keeps_its_range() {
    for model in &MODELS {
        let mut chain = chain_of(model);
        let mut checked = 0;
        control_table::for_each_item(model, |i| {
            let what = format!("{} {} ({})", model.name, i.name, i.address);
            if let Some(v) = i.factory {
                assert_eq!(
                    read(&mut chain, 1, i.address, i.size),
                    Some((0, v)),
                    "{what}: factory value"
                );
            }
            let value = read(&mut chain, 1, i.address, i.size).unwrap().1;
            if i.access == Access::Read {
                assert_eq!(
                    write(&mut chain, 1, i.address, &le(value, i.size)),
                    Some(status_error::ACCESS),
                    "{what}"
                );
                return;
            }
            // Beyond the range (where one byte more exists), and its edges inside.
            let (lo, hi) = match i.range {
                Range::Unsigned(lo, hi) => (lo as i64, hi as i64),
                Range::Signed(lo, hi) => (i64::from(lo), i64::from(hi)),
                _ => return,
            };
            let max = (1i64 << (8 * i.size)) - 1;
            if hi < max && !matches!(i.range, Range::Signed(..)) {
                let e = write(&mut chain, 1, i.address, &le((hi + 1) as u32, i.size));
                assert_eq!(
                    e,
                    Some(status_error::DATA_RANGE),
                    "{what}: {} beyond {hi}",
                    hi + 1
                );
            }
            if let Range::Signed(lo, _) = i.range {
                let e = write(&mut chain, 1, i.address, &le((lo - 1) as u32, i.size));
                assert_eq!(e, Some(status_error::DATA_RANGE), "{what}: below {lo}");
            }
            if !changes_the_link(&i) {
                for edge in [lo, hi] {
                    assert_eq!(
                        write(&mut chain, 1, i.address, &le(edge as u32, i.size)),
                        Some(0),
                        "{what} = {edge}"
                    );
                    assert_eq!(
                        read(&mut chain, 1, i.address, i.size).unwrap().1,
                        le_u32(edge, i.size),
                        "{what}"
                    );
                }
                assert_eq!(
                    write(&mut chain, 1, i.address, &le(value, i.size)),
                    Some(0),
                    "{what}: restore"
                );
            }
            checked += 1;
        });
        assert!(checked >= 20, "{}: {checked} items checked", model.name);
        // EEPROM locked while torque is on, RAM not.
        assert_eq!(write(&mut chain, 1, addr::TORQUE_ENABLE, &[1]), Some(0));
        control_table::for_each_item(model, |i| {
            if i.access == Access::ReadWrite && i.eeprom() {
                let v = read(&mut chain, 1, i.address, i.size).unwrap().1;
                let e = write(&mut chain, 1, i.address, &le(v, i.size));
                assert_eq!(
                    e,
                    Some(status_error::ACCESS),
                    "{} {} with torque on",
                    model.name,
                    i.name
                );
            }
        });
        assert_eq!(write(&mut chain, 1, 84, &le(500, 2)), Some(0));
    }
}

fn le_u32(v: i64, size: u16) -> u32 {
    let bits = 8 * u32::from(size);
    (v as u64 & ((1u64 << bits) - 1)) as u32
}

#[test]
fn limits_held_by_other_items_bound_the_goals() {
    let model = &MODELS[2];
    let mut chain = chain_of(model);
    assert_eq!(write(&mut chain, 1, 36, &le(300, 2)), Some(0));
    assert_eq!(write(&mut chain, 1, 100, &le(300, 2)), Some(0));
    assert_eq!(
        write(&mut chain, 1, 100, &le((-301i32) as u32, 2)),
        Some(status_error::DATA_RANGE)
    );
    assert_eq!(
        write(&mut chain, 1, 104, &le(201, 4)),
        Some(status_error::DATA_RANGE)
    );
    assert_eq!(write(&mut chain, 1, 104, &le((-200i32) as u32, 4)), Some(0));
    assert_eq!(write(&mut chain, 1, 48, &le(3000, 4)), Some(0));
    assert_eq!(
        write(&mut chain, 1, addr::GOAL_POSITION, &le(3001, 4)),
        Some(status_error::DATA_LIMIT)
    );
    // Extended Position Control Mode: the position limits do not apply.
    assert_eq!(write(&mut chain, 1, addr::OPERATING_MODE, &[4]), Some(0));
    assert_eq!(write(&mut chain, 1, addr::GOAL_POSITION, &le(9000, 4)), Some(0));
    // Reserved bytes inside a write are skipped; a write of reserved bytes alone is refused
    // as real X-series firmware refuses it (UNDEFINED_ADDRESS_ERROR: Data Range Error), and so
    // is a write past the table's end.
    assert_eq!(write(&mut chain, 1, 14, &[1, 2]), Some(UNDEFINED_ADDRESS_ERROR));
    assert_eq!(UNDEFINED_ADDRESS_ERROR, status_error::DATA_RANGE);
    assert_eq!(write(&mut chain, 1, 2000, &[1]), Some(UNDEFINED_ADDRESS_ERROR));
    assert_eq!(write(&mut chain, 1, 24, &[5, 0, 0, 0, 9, 9, 9, 60]), Some(0));
    assert_eq!(read(&mut chain, 1, 24, 8).map(|r| r.1), Some(5));
    assert_eq!(read(&mut chain, 1, 31, 1), Some((0, 60)));
}

#[test]
fn homing_offset_shifts_present_and_goal() {
    let mut chain = chain_of(&MODELS[2]);
    let present = read(&mut chain, 1, addr::PRESENT_POSITION, 4).unwrap().1 as i32;
    assert_eq!(write(&mut chain, 1, 20, &le(1000, 4)), Some(0));
    assert_eq!(
        read(&mut chain, 1, addr::PRESENT_POSITION, 4).unwrap().1 as i32,
        present + 1000
    );
    // A goal in the offset frame moves the horn to goal − offset.
    assert_eq!(write(&mut chain, 1, addr::TORQUE_ENABLE, &[1]), Some(0));
    assert_eq!(write(&mut chain, 1, addr::GOAL_POSITION, &le(3500, 4)), Some(0));
    for _ in 0..400 {
        chain.step(0.005);
    }
    assert_eq!(chain.servo(1).unwrap().present_tick(), 2500);
    assert_eq!(read(&mut chain, 1, addr::PRESENT_POSITION, 4).unwrap().1, 3500);
}

#[test]
fn secondary_id_executes_without_answering_and_protocol_type_silences() {
    let mut chain = Chain::new();
    for id in 1..=3 {
        chain.add(VirtualServo::new(id, &MODELS[2], 2048)).unwrap();
    }
    for id in [1, 2] {
        assert_eq!(write(&mut chain, id, 12, &[10]), Some(0));
    }
    // A write to the secondary id: both take it, neither answers.
    assert!(send(&mut chain, 10, instruction::WRITE, &[65, 0, 1]).is_empty());
    assert_eq!(read(&mut chain, 1, 65, 1), Some((0, 1)));
    assert_eq!(read(&mut chain, 2, 65, 1), Some((0, 1)));
    assert_eq!(read(&mut chain, 3, 65, 1), Some((0, 0)));
    assert!(send(&mut chain, 10, instruction::PING, &[]).is_empty());
    // 255 switches it off again.
    assert_eq!(write(&mut chain, 1, 12, &[255]), Some(0));
    let _ = send(&mut chain, 10, instruction::WRITE, &[65, 0, 0]);
    assert_eq!(read(&mut chain, 1, 65, 1), Some((0, 1)));
    // Protocol Type 1: silent to Protocol 2.0 from then on, the others unaffected.
    assert_eq!(write(&mut chain, 3, 13, &[1]), Some(0));
    assert!(read(&mut chain, 3, 0, 2).is_none());
    let found: Vec<u8> = send(&mut chain, BROADCAST_ID, instruction::PING, &[])
        .iter()
        .map(|r| r.0)
        .collect();
    assert_eq!(found, vec![1, 2]);
}

#[test]
fn indirect_layouts_follow_the_model() {
    // XL330: Indirect Address 1–20 at 168, data at 208; X430: 1–28 at 168/224, 29–56 at 578/634.
    for (model, data1, last_data) in [(&MODELS[0], 208u16, 227u16), (&MODELS[2], 224, 661)] {
        let mut chain = chain_of(model);
        assert_eq!(read(&mut chain, 1, 168, 2), Some((0, u32::from(data1))));
        // Indirect addresses reach RAM only (64 and up).
        assert_eq!(
            write(&mut chain, 1, 168, &le(u32::from(addr::ID), 2)),
            Some(status_error::DATA_RANGE)
        );
        assert_eq!(
            write(&mut chain, 1, 168, &le(u32::from(addr::STATUS_RETURN_LEVEL), 2)),
            Some(0)
        );
        assert_eq!(read(&mut chain, 1, data1, 1), Some((0, 2)));
        assert!(read(&mut chain, 1, last_data, 1).is_some_and(|r| r.0 == 0));
        assert_eq!(
            read(&mut chain, 1, last_data + 1, 1).map(|r| r.0),
            Some(status_error::DATA_RANGE)
        );
    }
}

/// The OP3's sensor board on the servos' bus: it answers pings, reads, writes, Sync and Bulk
/// Read in the listed order with the servos, and instructions it does not know with an
/// Instruction Error.
#[test]
fn the_sensor_board_answers_on_the_servos_bus() {
    use marionette_core::sensor_board::{board_addr, ImuReading, SensorBoard, IMU_BYTES};
    let mut chain = chain_of(&MODELS[0]);
    chain.add(VirtualServo::new(2, &MODELS[0], 1000)).unwrap();
    let mut board = SensorBoard::default();
    let tilt = ImuReading {
        gyro_dps: [10.0, -20.0, 30.0],
        acc_g: [0.0, 0.17, 0.98],
        rpy_deg: [10.0, 0.0, 90.0],
    };
    board.set_imu(&tilt);
    chain.set_board(board);
    // A broadcast ping finds the servos and the board (model 0x7400).
    let pings = send(&mut chain, BROADCAST_ID, instruction::PING, &[]);
    assert_eq!(pings.iter().map(|p| p.0).collect::<Vec<_>>(), vec![1, 2, 200]);
    assert_eq!(pings[2].2[..2], [0x00, 0x74]);
    // Its IMU in one read.
    let imu = read_bytes(&mut chain, 200, board_addr::GYRO, IMU_BYTES as u16);
    let got = ImuReading::decode(&imu).unwrap();
    assert!(
        (got.rpy_deg[0] - 10.0).abs() < 1e-9 && (got.acc_g[1] - 0.17).abs() < 1e-4,
        "{got:?}"
    );
    // Bulk Read: servo 2's position, the board's IMU, servo 1's position — in that order.
    let mut params = vec![2];
    params.extend_from_slice(&addr::PRESENT_POSITION.to_le_bytes());
    params.extend_from_slice(&4u16.to_le_bytes());
    params.push(200);
    params.extend_from_slice(&board_addr::GYRO.to_le_bytes());
    params.extend_from_slice(&(IMU_BYTES as u16).to_le_bytes());
    params.push(1);
    params.extend_from_slice(&addr::PRESENT_POSITION.to_le_bytes());
    params.extend_from_slice(&4u16.to_le_bytes());
    let replies = send(&mut chain, BROADCAST_ID, instruction::BULK_READ, &params);
    assert_eq!(replies.iter().map(|r| r.0).collect::<Vec<_>>(), vec![2, 200, 1]);
    assert_eq!(replies[1].2, imu);
    // Writes: its LEDs yes, its gyro no, past its table a range error.
    assert_eq!(write(&mut chain, 200, board_addr::LED, &[3]), Some(0));
    assert_eq!(
        write(&mut chain, 200, board_addr::GYRO, &[0, 0]),
        Some(status_error::ACCESS)
    );
    assert_eq!(
        read(&mut chain, 200, 50, 2).map(|r| r.0),
        Some(status_error::DATA_RANGE)
    );
    // Sync Read at the board's address works for the board alone.
    let mut params = board_addr::PRESENT_VOLTAGE.to_le_bytes().to_vec();
    params.extend_from_slice(&1u16.to_le_bytes());
    params.push(200);
    let replies = send(&mut chain, BROADCAST_ID, instruction::SYNC_READ, &params);
    assert_eq!(replies, vec![(200, 0, vec![120])]);
    // An instruction it does not carry out.
    let replies = send(&mut chain, 200, instruction::REG_WRITE, &[25, 0, 1]);
    assert_eq!(replies, vec![(200, status_error::INSTRUCTION, vec![])]);
    // Reboot clears its LEDs.
    send(&mut chain, 200, instruction::REBOOT, &[]);
    assert_eq!(read(&mut chain, 200, board_addr::LED, 1), Some((0, 0)));
}

fn read_bytes(chain: &mut Chain, id: u8, address: u16, n: u16) -> Vec<u8> {
    let mut params = address.to_le_bytes().to_vec();
    params.extend_from_slice(&n.to_le_bytes());
    send(chain, id, instruction::READ, &params).remove(0).2
}

#[test]
fn action_without_a_registered_write_answers_instruction_error() {
    let mut chain = chain_of(&MODELS[2]);
    // Nothing registered: Instruction Error, nothing changes.
    let replies = send(&mut chain, 1, instruction::ACTION, &[]);
    assert_eq!(replies.first().map(|r| r.1), Some(status_error::INSTRUCTION));
    assert_eq!(read(&mut chain, 1, 69, 1), Some((0, 0)));
    // A registered write: Action applies it, answers no error, and the flag clears.
    let mut params = 112u16.to_le_bytes().to_vec();
    params.extend_from_slice(&le(10, 4));
    assert_eq!(
        send(&mut chain, 1, instruction::REG_WRITE, &params)
            .first()
            .map(|r| r.1),
        Some(0)
    );
    assert_eq!(read(&mut chain, 1, 69, 1), Some((0, 1)));
    assert_eq!(
        send(&mut chain, 1, instruction::ACTION, &[]).first().map(|r| r.1),
        Some(0)
    );
    assert_eq!(read(&mut chain, 1, 112, 4), Some((0, 10)));
    assert_eq!(read(&mut chain, 1, 69, 1), Some((0, 0)));
    // Again, with nothing registered any more.
    let replies = send(&mut chain, 1, instruction::ACTION, &[]);
    assert_eq!(replies.first().map(|r| r.1), Some(status_error::INSTRUCTION));
}

/// The thermal model: a servo holding a heavy load warms towards its Temperature Limit and,
/// there, raises its overheating error and drops torque (Shutdown's factory bits); an unloaded
/// warm servo cools towards the air with the model's time constant; Present Temperature
/// reads it.
#[test]
fn a_loaded_servo_heats_to_its_limit_and_shuts_down_and_an_idle_one_cools() {
    use marionette_core::device::{AMBIENT_C, CONTINUOUS_CURRENT_SHARE, THERMAL_TIME_CONSTANT_S};
    use marionette_core::servo::hardware_error;
    let model = &MODELS[2];
    let mut chain = chain_of(model);
    assert_eq!(write(&mut chain, 1, addr::TORQUE_ENABLE, &[1]), Some(0));
    // At the continuous share it settles at the limit: after one time constant it has come
    // 1 − 1/e of the way.
    let servo = chain.servo_mut(1).unwrap();
    servo.set_load(CONTINUOUS_CURRENT_SHARE * model.stall_torque_nm);
    let dt = 0.01;
    let steps = (THERMAL_TIME_CONSTANT_S / dt) as usize;
    for _ in 0..steps {
        chain.servo_mut(1).unwrap().step(dt);
    }
    let rise = chain.servo_mut(1).unwrap().temperature() - AMBIENT_C;
    let full = f64::from(model.temperature_limit) - AMBIENT_C;
    assert!(
        (rise / full - (1.0 - (-1.0f64).exp())).abs() < 0.01,
        "{rise} of {full}"
    );
    let (_, celsius) = read(&mut chain, 1, addr::PRESENT_TEMPERATURE, 1).unwrap();
    assert!((f64::from(celsius) - (AMBIENT_C + rise)).abs() <= 0.5);
    // Twice the continuous current heats it to its limit: overheating, torque off.
    chain
        .servo_mut(1)
        .unwrap()
        .set_load(2.0 * CONTINUOUS_CURRENT_SHARE * model.stall_torque_nm);
    let mut seconds = 0.0;
    while chain.servo_mut(1).unwrap().hardware_error() == 0 && seconds < 600.0 {
        chain.servo_mut(1).unwrap().step(dt);
        seconds += dt;
    }
    let servo = chain.servo_mut(1).unwrap();
    assert_eq!(
        servo.hardware_error(),
        hardware_error::OVERHEATING,
        "after {seconds} s"
    );
    assert!((servo.temperature() - f64::from(model.temperature_limit)).abs() < 0.1);
    assert_eq!(read(&mut chain, 1, addr::TORQUE_ENABLE, 1).unwrap().1, 0);
    // Idle (torque off, no current), it cools: down 1 − 1/e of the way in a time constant.
    let servo = chain.servo_mut(1).unwrap();
    let from = servo.temperature();
    for _ in 0..steps {
        servo.step(dt);
    }
    let left = (servo.temperature() - AMBIENT_C) / (from - AMBIENT_C);
    assert!((left - (-1.0f64).exp()).abs() < 0.01, "{left}");
}

//! The robot's attitude from its IMU board, read over the bus each tick, and gyro feedback on
//! the legs as ROBOTIS's OP3 walking module applies it: each leg joint offset by
//! `0.05 × gain × rate`, the body's angular rate about that joint's axis (rad/s), with the
//! module's gains (hip roll 0.35, knee 0.3, ankle pitch 0.9, ankle roll 0.7). The sign follows
//! from the legs' kinematics: a leg's joints have the foot on their child side, so turning a
//! joint by `q` about its axis `a` turns the body above a planted foot by `−q·a`; an offset of
//! `+k·(a·ω)` turns the body against its rate `ω`.
//!
//! The offsets ride on the goals sent ([`crate::command::CommandStage::set_correction`]), not
//! on the path the look-ahead plans from. A leg in the air gets the opposite offset
//! ([`SWING_LEG_SHARE`]): what turns the body over a planted foot only swings a lifted one
//! off its path, and turned back it keeps the swing foot where the plan has it while the
//! body above turns.
//!
//! The board is read in the servos' position read where the bus can merge it
//! ([`ServoBus::merge_into_reads`]: one Bulk Read, the board's block last, as the OP3
//! framework reads its OpenCR; one Fast Bulk Read where the profile reads fast), else with a
//! Read of its own. The reading is low-pass filtered
//! (α = 0.4 on each new sample, as the framework's OpenCR module does), a read that fails any
//! check is not used (the last good one stands and the failure is counted; after
//! [`STALE_READS`] failures in a row the feedback stops until a read succeeds, so a board
//! that stopped answering leaves no stale rate in the legs), and nothing here allocates.

use serde::Serialize;

use crate::bus::ServoBus;
use crate::command::CommandStage;
use crate::retarget::Setup;
use crate::rig::{JointSource, Rig};
use crate::robot::RobotPose;
use crate::sensor_board::{board_addr, ImuReading, IMU_BYTES};
use crate::servo::MAX_SERVOS;

/// Weight of a new IMU sample in the filtered reading (the framework's OpenCR module).
pub const IMU_FILTER: f64 = 0.4;

/// Scale of ROBOTIS's walking-module gains: offset (rad) = this × gain × rate (rad/s).
pub const GYRO_FEEDBACK_SCALE: f64 = 0.05;

/// ROBOTIS's gains per leg joint (hip yaw, hip roll, hip pitch, knee, ankle pitch, ankle roll).
pub const LEG_GYRO_GAINS: [f64; 6] = [0.0, 0.35, 0.0, 0.3, 0.9, 0.7];

/// Failed reads in a row after which the last good reading is too old to feed back.
pub const STALE_READS: u32 = 3;

/// What a leg's offsets are multiplied by while its foot is in the air (the plan's contact).
pub const SWING_LEG_SHARE: f64 = -1.0;

/// What the IMU side of a run measured (the `imu` block of the stats JSON).
#[derive(Clone, Debug, Default, Serialize, PartialEq)]
pub struct ImuReport {
    /// The board's id.
    pub board_id: u8,
    /// Reads that passed every check.
    pub reads_ok: u64,
    /// Reads that failed (timeout, CRC, an error status…): not used.
    pub reads_failed: u64,
    /// Whether the board was read in the servos' position read (a Bulk or Fast Bulk Read)
    /// rather than with a Read of its own.
    pub merged: bool,
    /// Ticks whose feedback was left out because the last [`STALE_READS`] reads or more had
    /// failed.
    pub stale_ticks: u64,
    /// Whether the legs got the gyro feedback.
    pub feedback: bool,
    /// The torso's largest tilt from level (its z axis against the vertical, from roll and
    /// pitch), degrees.
    pub max_tilt_deg: f64,
    /// The largest body rate read, °/s.
    pub max_rate_dps: f64,
    /// The largest feedback offset given to a joint, degrees.
    pub max_offset_deg: f64,
}

/// The IMU board's reading and the legs' gyro feedback.
#[derive(Debug)]
pub struct Balance {
    board: u8,
    buf: [u8; IMU_BYTES],
    /// The filtered reading, body axes (`None` before the first good read).
    reading: Option<ImuReading>,
    /// Per servo: rad of offset per rad/s of body rate about x, y, z (zero for servos without
    /// feedback).
    weights: [[f64; 3]; MAX_SERVOS],
    /// Per servo, the leg it moves (0 left, 1 right), if any.
    leg: [Option<usize>; MAX_SERVOS],
    feedback: bool,
    /// Whether the bus reads the board with the positions (asked at the first read).
    merged: Option<bool>,
    /// Failed reads since the last good one.
    failures_in_row: u32,
    report: ImuReport,
}

impl Balance {
    /// Reads the board `board`; with `feedback`, the legs of `setup`'s map get the gyro
    /// feedback through `rig`'s servos.
    #[must_use]
    pub fn new(board: u8, setup: &Setup, rig: &Rig, feedback: bool) -> Balance {
        let mut weights = [[0.0; 3]; MAX_SERVOS];
        let mut leg_of = [None; MAX_SERVOS];
        let mut any = false;
        if feedback {
            // Joint axes in the torso's frame at the zero pose.
            let robot = &setup.robot;
            let mut pose = RobotPose::default();
            let zeros = vec![0.0; robot.joints().len()];
            robot.forward(glam::DVec3::ZERO, glam::DQuat::IDENTITY, &zeros, &mut pose);
            let torso = robot
                .bodies()
                .iter()
                .position(|b| b.parent.is_none())
                .unwrap_or(0);
            let to_torso = pose.rot[torso].inverse();
            for (side, leg) in setup.map.legs.iter().enumerate() {
                for (k, &j) in leg.joints.iter().enumerate() {
                    let gain = LEG_GYRO_GAINS[k];
                    if gain == 0.0 {
                        continue;
                    }
                    let joint = &robot.joints()[j];
                    let axis = to_torso * (pose.rot[joint.body] * joint.axis);
                    for (servo, m) in rig.servos.iter().enumerate() {
                        if m.source == JointSource::Joint(j) && servo < MAX_SERVOS {
                            weights[servo] = (axis * (GYRO_FEEDBACK_SCALE * gain)).to_array();
                            leg_of[servo] = Some(side);
                            any = true;
                        }
                    }
                }
            }
        }
        Balance {
            board,
            buf: [0; IMU_BYTES],
            reading: None,
            weights,
            leg: leg_of,
            feedback: any,
            merged: None,
            failures_in_row: 0,
            report: ImuReport {
                board_id: board,
                ..ImuReport::default()
            },
        }
    }

    /// Reads the IMU: what the last position read brought with it, or one Read of its items
    /// where the bus cannot merge them; a failed read leaves the last good reading.
    pub fn read(&mut self, bus: &mut dyn ServoBus) {
        let merged = *self
            .merged
            .get_or_insert_with(|| bus.merge_into_reads(self.board, board_addr::GYRO, IMU_BYTES as u16));
        let raw = if merged {
            match bus.take_merged(&mut self.buf) {
                // No position read came in since (the first tick): nothing to count.
                None => return,
                Some(ok) => ok,
            }
        } else {
            bus.read(self.board, board_addr::GYRO, &mut self.buf).is_ok()
        };
        let fresh = raw
            .then(|| ImuReading::decode(&self.buf))
            .flatten()
            .map(|r| r.to_body())
            .filter(|r| {
                r.gyro_dps
                    .iter()
                    .chain(&r.acc_g)
                    .chain(&r.rpy_deg)
                    .all(|v| v.is_finite())
            });
        let Some(new) = fresh else {
            self.report.reads_failed += 1;
            self.failures_in_row = self.failures_in_row.saturating_add(1);
            return;
        };
        self.report.reads_ok += 1;
        self.failures_in_row = 0;
        let blend = |old: [f64; 3], new: [f64; 3]| [0, 1, 2].map(|k| old[k] + IMU_FILTER * (new[k] - old[k]));
        let r = match self.reading {
            None => new,
            Some(old) => ImuReading {
                gyro_dps: blend(old.gyro_dps, new.gyro_dps),
                acc_g: blend(old.acc_g, new.acc_g),
                rpy_deg: new.rpy_deg,
            },
        };
        // From level: the body's z against the vertical, cos = cos(roll)·cos(pitch).
        let (roll, pitch) = (r.rpy_deg[0].to_radians(), r.rpy_deg[1].to_radians());
        let tilt = (roll.cos() * pitch.cos()).clamp(-1.0, 1.0).acos().to_degrees();
        self.report.max_tilt_deg = self.report.max_tilt_deg.max(tilt);
        let rate = r.gyro_dps.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        self.report.max_rate_dps = self.report.max_rate_dps.max(rate);
        self.reading = Some(r);
    }

    /// The filtered reading in body axes, once a read has succeeded.
    #[must_use]
    pub fn reading(&self) -> Option<&ImuReading> {
        self.reading.as_ref()
    }

    /// The gyro feedback per servo of `rig` as goal ticks, with the feet on the floor as
    /// `contact` says (left, right), into `out`; zero without feedback or before a read.
    pub fn offsets(&mut self, rig: &Rig, contact: [bool; 2], out: &mut [f64]) {
        out.fill(0.0);
        let (true, Some(r)) = (self.feedback, self.reading) else {
            return;
        };
        if self.failures_in_row >= STALE_READS {
            self.report.stale_ticks += 1;
            return;
        }
        let rate = r.gyro_dps.map(f64::to_radians);
        let mut largest = self.report.max_offset_deg;
        for (servo, (w, m)) in self.weights.iter().zip(&rig.servos).enumerate() {
            let mut rad = w[0] * rate[0] + w[1] * rate[1] + w[2] * rate[2];
            if self.leg[servo].is_some_and(|side| !contact[side]) {
                rad *= SWING_LEG_SHARE;
            }
            if let Some(o) = out.get_mut(servo) {
                *o = rad * m.ticks_per_radian();
                largest = largest.max(rad.abs().to_degrees());
            }
        }
        self.report.max_offset_deg = largest;
    }

    /// Sets [`Balance::offsets`] as `stage`'s correction: riding on the goals sent, not on
    /// the planned path. Allocates nothing.
    pub fn correct(&mut self, rig: &Rig, contact: [bool; 2], stage: &mut CommandStage) {
        let mut ticks = [0.0; MAX_SERVOS];
        let len = rig.servos.len().min(MAX_SERVOS);
        self.offsets(rig, contact, &mut ticks[..len]);
        stage.set_correction(&ticks[..len]);
    }

    /// What it measured.
    #[must_use]
    pub fn report(&self) -> ImuReport {
        ImuReport {
            feedback: self.feedback,
            merged: self.merged == Some(true),
            ..self.report.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profile;

    fn op3() -> (Setup, Rig) {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let profile = Profile::load(&root.join("firmware-profile/robotis-op3.toml")).unwrap();
        let skeleton = crate::formats::asf::load(&root.join("data/cmu/16.asf"))
            .unwrap()
            .skeleton;
        let setup = Setup::new(&profile, &skeleton).unwrap();
        let rig = setup.rig.clone();
        (setup, rig)
    }

    #[test]
    fn a_pitch_rate_moves_the_pitch_joints_and_a_roll_rate_the_roll_joints() {
        let (setup, rig) = op3();
        let mut b = Balance::new(200, &setup, &rig, true);
        let name = |k: usize| match rig.servos[k].source {
            JointSource::Joint(j) => setup.robot.joints()[j].name.to_string(),
            _ => String::new(),
        };
        for (axis, moved) in [(1, ["knee", "ank_pitch"]), (0, ["hip_roll", "ank_roll"])] {
            let mut r = ImuReading::default();
            r.gyro_dps[axis] = 57.295_779_513_082_32; // 1 rad/s
            b.reading = Some(r);
            let mut ticks = vec![0.0; rig.servos.len()];
            b.offsets(&rig, [true; 2], &mut ticks);
            let angles: Vec<f64> = ticks
                .iter()
                .zip(&rig.servos)
                .map(|(t, m)| t / m.ticks_per_radian())
                .collect();
            for (k, a) in angles.iter().enumerate() {
                let n = name(k);
                let expected = moved.iter().any(|m| n.ends_with(m));
                assert_eq!(a.abs() > 1e-3, expected, "{n}: {a}");
                if n.ends_with("ank_pitch") && axis == 1 {
                    // 0.05 × 0.9 rad per rad/s.
                    assert!((a.abs() - 0.045).abs() < 1e-3, "{n}: {a}");
                }
            }
            // The left foot in the air: its leg's offsets turned round, the right's as before.
            let mut swinging = vec![0.0; rig.servos.len()];
            b.offsets(&rig, [false, true], &mut swinging);
            for (k, (s, t)) in swinging.iter().zip(&ticks).enumerate() {
                let n = name(k);
                let expected = if n.starts_with('l') { -t } else { *t };
                assert!((s - expected).abs() < 1e-12, "{n}: {s} against {t}");
            }
        }
        // Without feedback, or before a read, nothing moves.
        let mut off = Balance::new(200, &setup, &rig, false);
        off.reading = b.reading;
        let mut ticks = vec![1.0; rig.servos.len()];
        off.offsets(&rig, [true; 2], &mut ticks);
        assert!(ticks.iter().all(|a| *a == 0.0));
    }

    #[test]
    fn reads_that_fail_leave_the_last_good_one_and_are_counted() {
        use crate::bus::virtual_chain::chain_for;
        let (setup, rig) = op3();
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let profile = Profile::load(&root.join("firmware-profile/robotis-op3.toml")).unwrap();
        let mut chain = chain_for(profile.bus_section(), |_| 2048);
        let level = ImuReading {
            gyro_dps: [0.0, 30.0, 0.0],
            acc_g: [0.0, 0.0, 1.0],
            rpy_deg: [3.0, 4.0, 0.0],
        };
        chain.board_mut().unwrap().set_imu(&level);
        let mut bus = crate::bus::packet::PacketBus::new(
            crate::bus::virtual_chain::InProcess::new(chain, profile.bus.baud),
            std::time::Duration::from_millis(2),
        );
        let ids: Vec<u8> = profile.servos.iter().map(|s| s.id).collect();
        let mut positions = vec![0i32; ids.len()];
        let mut b = Balance::new(200, &setup, &rig, true);
        // The first read asks the bus to merge the board into the position read; nothing
        // was read with the positions yet, so nothing is counted.
        b.read(&mut bus);
        assert!(b.reading().is_none());
        assert_eq!((b.report().reads_ok, b.report().reads_failed), (0, 0));
        bus.read_positions(&ids, &mut positions).unwrap();
        assert!(positions.iter().all(|p| *p == 2048), "{positions:?}");
        b.read(&mut bus);
        let r = *b.reading().unwrap();
        // Body axes: the board's x and y negated.
        assert!((r.gyro_dps[1] + 30.0).abs() < 0.1, "{r:?}");
        let report = b.report();
        assert_eq!(
            (report.reads_ok, report.reads_failed, report.merged),
            (1, 0, true)
        );
        // acos(cos 3° · cos 4°) = 4.999°.
        assert!((report.max_tilt_deg - 4.999).abs() < 0.01, "{report:?}");
        // A board that does not answer: the positions still come, the read fails, the
        // reading stays — and after STALE_READS failures in a row it is no longer fed back.
        let mut missing = Balance::new(201, &setup, &rig, true);
        missing.reading = Some(r);
        missing.read(&mut bus);
        let mut offsets = vec![0.0; rig.servos.len()];
        for k in 1..=STALE_READS {
            bus.read_positions(&ids, &mut positions).unwrap();
            missing.read(&mut bus);
            assert_eq!(missing.report().reads_failed, u64::from(k));
            assert_eq!(missing.reading(), Some(&r));
            missing.offsets(&rig, [true; 2], &mut offsets);
            let fed = offsets.iter().any(|o| *o != 0.0);
            assert_eq!(fed, k < STALE_READS, "after {k} failed reads");
        }
        assert_eq!(missing.report().stale_ticks, 1);
        // The board answers again: fed back again.
        assert!(bus.merge_into_reads(200, board_addr::GYRO, IMU_BYTES as u16));
        bus.read_positions(&ids, &mut positions).unwrap();
        missing.read(&mut bus);
        missing.offsets(&rig, [true; 2], &mut offsets);
        assert!(offsets.iter().any(|o| *o != 0.0));
        assert_eq!(missing.report().reads_ok, 1);
    }
}

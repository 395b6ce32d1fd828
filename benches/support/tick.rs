//! One whole control-loop tick set up for the benches (`benches/control.rs`,
//! `benches/instructions.rs`): the CMU puppet's 28 servos at 500 Hz playing the bundled walk
//! (its frames) or following it (its four limb targets), with or without the look-ahead, and
//! the OP3 walking the same clip on its plan at 125 Hz with its IMU's gyro fed back to the legs;
//! on a bus that only encodes (no I/O), so that what is measured is the loop's own work.

#![allow(dead_code)]

use std::path::Path;
use std::sync::Arc;

use marionette::bus::{BusError, PingInfo, ServoBus};
use marionette::control::input::{input_channel, Input, InputSender, Payload};
use marionette::control::sources::{clip_track, ClipPlayer, TrackFrame};
use marionette::control::{Controller, Follower, Solve};
use marionette::formats::{amc, asf};
use marionette::profile::Profile;
use marionette::protocol::{encode, instruction, BROADCAST_ID};
use marionette::rig::ServoMap;
use marionette::schedule::{Clock, Tick};
use marionette::session::{self, ImuUse, Lead, RigDrive, SessionSpec};
use marionette::skeleton::MAX_CHANNELS;

/// Encodes every Sync Write into a packet and answers reads with the last goals written.
pub struct EncodeBus {
    packet: [u8; 4096],
    params: [u8; 4096],
    last: [u8; 4096],
    /// Bytes of the last Sync Write packet.
    pub bytes: usize,
}

impl EncodeBus {
    pub fn new() -> Self {
        EncodeBus {
            packet: [0; 4096],
            params: [0; 4096],
            last: [0; 4096],
            bytes: 0,
        }
    }
}

impl ServoBus for EncodeBus {
    fn ping(&mut self, id: u8) -> Result<PingInfo, BusError> {
        Err(BusError::Timeout { id })
    }
    fn scan(&mut self) -> Result<Vec<PingInfo>, BusError> {
        Ok(Vec::new())
    }
    fn read(&mut self, id: u8, _: u16, out: &mut [u8]) -> Result<(), BusError> {
        // The IMU board's block: a body turning slowly, tilted a little.
        for (k, b) in out.iter_mut().enumerate() {
            *b = if id == IMU_BOARD && k % 2 == 0 {
                17 + 9 * k as u8
            } else {
                0
            };
        }
        Ok(())
    }
    fn write(&mut self, _: u8, _: u16, _: &[u8]) -> Result<(), BusError> {
        Ok(())
    }
    fn sync_write(&mut self, address: u16, len: u16, ids: &[u8], data: &[u8]) -> Result<(), BusError> {
        let l = usize::from(len);
        self.params[..2].copy_from_slice(&address.to_le_bytes());
        self.params[2..4].copy_from_slice(&len.to_le_bytes());
        let mut n = 4;
        for (k, id) in ids.iter().enumerate() {
            self.params[n] = *id;
            self.params[n + 1..n + 1 + l].copy_from_slice(&data[k * l..(k + 1) * l]);
            n += 1 + l;
        }
        self.last[..data.len()].copy_from_slice(data);
        self.bytes = encode(
            BROADCAST_ID,
            instruction::SYNC_WRITE,
            &self.params[..n],
            &mut self.packet,
        )
        .map_err(|_| BusError::Malformed {
            id: 0,
            what: "encode",
        })?;
        Ok(())
    }
    fn sync_read(&mut self, _: u16, len: u16, ids: &[u8], out: &mut [u8]) -> Result<(), BusError> {
        let n = ids.len() * usize::from(len);
        out[..n].copy_from_slice(&self.last[..n]);
        Ok(())
    }
    fn reboot(&mut self, _: u8) -> Result<(), BusError> {
        Ok(())
    }
}

/// A clock that reads each tick's deadline, a microsecond later at every reading, and never
/// waits: the same tick sees the same times in every run.
pub struct SteppedClock {
    now_ns: u64,
}

impl Clock for SteppedClock {
    fn now_ns(&mut self) -> u64 {
        self.now_ns += 1_000;
        self.now_ns
    }
    fn wait_until(&mut self, deadline_ns: u64) {
        self.now_ns = self.now_ns.max(deadline_ns);
    }
}

/// What the loop does each tick.
#[derive(Clone, Copy, Debug)]
pub enum Kind {
    /// AMC frames on the puppet: FK and the rig's mapping.
    Play,
    /// The four limbs' targets on the puppet: limb IK with the windowed swivel search.
    Follow,
    /// AMC frames on the OP3, walking on its plan (`marionette play --walk --imu feedback`):
    /// the plan's frames interpolated, the IMU board read, its gyro fed back to the legs.
    Op3Walk,
}

/// The OP3's IMU board (its OpenCR) on the bus.
const IMU_BOARD: u8 = 200;

/// A controller ready to tick, its bus, the sender of its inputs and one input per tick (the
/// walk over and over).
pub struct TickBench {
    pub controller: Controller,
    pub bus: EncodeBus,
    pub sender: InputSender,
    pub inputs: Vec<Input>,
    next: usize,
    index: u64,
    period_ns: u64,
}

impl TickBench {
    /// `lookahead`: every servo led by the profile's lags. `real_time`: the fidelity on a
    /// thread of its own (as `marionette play` runs), otherwise in the tick (as a lockstep run).
    pub fn new(kind: Kind, lookahead: bool, real_time: bool) -> Self {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let skel = Arc::new(asf::load(&root.join("data/cmu/16.asf")).unwrap().skeleton);
        let motion = Arc::new(amc::load(&skel, &root.join("data/cmu/16_15.amc")).unwrap());
        let walk = matches!(kind, Kind::Op3Walk);
        let rate_hz = if walk { 125.0 } else { 500.0 };
        let profile_file = if walk {
            "robotis-op3.toml"
        } else {
            "cmu-puppet.toml"
        };
        let profile = Profile::load(&root.join("firmware-profile").join(profile_file)).unwrap();
        let names: Vec<String> = ["lradius", "rradius", "ltibia", "rtibia"]
            .iter()
            .map(|s| (*s).to_string())
            .collect();
        let (sender, port) = input_channel(4);
        let solve = match kind {
            Kind::Follow => Solve::Follow(Box::new(Follower::new(&skel, &names).unwrap())),
            Kind::Play | Kind::Op3Walk => Solve::Frames,
        };
        let spec = SessionSpec {
            rate_hz,
            lead: if lookahead { Lead::Profile } else { Lead::Off },
            walk,
            imu: if walk { ImuUse::Feedback } else { ImuUse::Off },
            // No effector errors in metres: the tick's own work.
            scale: 0.0,
            ..SessionSpec::default()
        };
        let drive = RigDrive::new(
            &spec,
            &profile,
            Arc::clone(&skel),
            Some(&motion),
            &mut std::io::sink(),
        )
        .unwrap();
        let present: Vec<i32> = drive.rig.servos.iter().map(ServoMap::rest_tick).collect();
        let controller = session::controller(&spec, &profile, drive, &present, port, solve, real_time);
        let track = clip_track(&skel, &motion, &names, TrackFrame::Limb).unwrap();
        let mut player = ClipPlayer::new(Arc::clone(&skel), Arc::clone(&motion), rate_hz, true);
        let n = skel.channel_count();
        let mut buf = [0.0; MAX_CHANNELS];
        let inputs = (0..1000u64)
            .map(|k| match kind {
                Kind::Follow => {
                    let (_, t) = &track.samples[k as usize % track.samples.len()];
                    Input {
                        seq: k,
                        due_ns: 0,
                        made_ns: 0,
                        payload: Payload::Targets(t.clone()),
                    }
                }
                Kind::Play | Kind::Op3Walk => {
                    let t = player.next_sample(&mut buf[..n]).unwrap();
                    Input::frame(k, 0, 0, &buf[..n], t)
                }
            })
            .collect();
        TickBench {
            controller,
            bus: EncodeBus::new(),
            sender,
            inputs,
            next: 0,
            index: 0,
            period_ns: (1e9 / rate_hz) as u64,
        }
    }

    /// The next input, cloned from the prepared ones.
    pub fn next_input(&mut self) -> Input {
        self.next = (self.next + 1) % self.inputs.len();
        self.inputs[self.next].clone()
    }

    /// Sends `input` and runs one tick on `clock`, due now.
    pub fn tick(&mut self, input: Input, clock: &mut dyn Clock) {
        self.sender.send_newest(input).unwrap();
        let now = clock.now_ns();
        let tick = Tick {
            index: self.index,
            deadline_ns: now,
            woke_ns: now,
            skipped: 0,
        };
        self.index += 1;
        let _ = self.controller.tick(&tick, &mut self.bus, clock);
    }

    /// A stepped clock at this bench's next deadline.
    pub fn stepped_clock(&self) -> SteppedClock {
        SteppedClock {
            now_ns: self.index * self.period_ns,
        }
    }

    /// The next `n` inputs, prepared before they are measured.
    pub fn take_inputs(&mut self, n: usize) -> Vec<Input> {
        (0..n).map(|_| self.next_input()).collect()
    }

    /// Runs one tick for each of `inputs` on a stepped clock, one period apart.
    pub fn run_stepped(&mut self, inputs: Vec<Input>) {
        for input in inputs {
            let mut clock = self.stepped_clock();
            self.tick(input, &mut clock);
        }
    }
}

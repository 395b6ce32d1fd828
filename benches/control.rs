//! One whole control-loop tick: newest input → 4-limb analytic IK (windowed swivel
//! search) + FK → rig mapping → command limits → Sync Write packet encoded (CRC, stuffing) →
//! present positions read back, on a bus that only encodes (no I/O), so the figure is the
//! loop's own work. Also the AMC playback tick. `cargo bench --bench control`
//!
//! With the look-ahead the same ticks plan every servo's goal path; `lookahead`
//! times the planning of the puppet's 28 servos alone.
//!
//! The jitter comparison with a naive `thread::sleep` loop is `cargo bench --bench jitter`.

use criterion::{criterion_group, criterion_main, Criterion};
use marionette::bus::{BusError, PingInfo, ServoBus};
use marionette::clock::SystemClock;
use marionette::control::input::{input_channel, Input, Payload};
use marionette::control::sources::{clip_track, ClipPlayer, TrackFrame};
use marionette::control::{Follower, Solve};
use marionette::formats::{amc, asf};
use marionette::profile::Profile;
use marionette::protocol::{encode, instruction, BROADCAST_ID};
use marionette::rig::ServoMap;
use marionette::schedule::{Clock, Tick};
use marionette::session::{self, Lead, RigDrive, SessionSpec};
use marionette::skeleton::MAX_CHANNELS;
use std::path::Path;
use std::sync::Arc;

#[path = "support/planner.rs"]
mod planner;

/// Encodes every Sync Write into a packet and answers reads with the last goals written.
struct EncodeBus {
    packet: [u8; 4096],
    params: [u8; 4096],
    last: [u8; 4096],
    bytes: usize,
}

impl ServoBus for EncodeBus {
    fn ping(&mut self, id: u8) -> Result<PingInfo, BusError> {
        Err(BusError::Timeout { id })
    }
    fn scan(&mut self) -> Result<Vec<PingInfo>, BusError> {
        Ok(Vec::new())
    }
    fn read(&mut self, _: u8, _: u16, out: &mut [u8]) -> Result<(), BusError> {
        out.fill(0);
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

fn data(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu").join(name)
}

fn bench(c: &mut Criterion) {
    let skel = Arc::new(asf::load(&data("16.asf")).unwrap().skeleton);
    let motion = Arc::new(amc::load(&skel, &data("16_15.amc")).unwrap());
    let profile =
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("firmware-profile/cmu-puppet.toml"))
            .unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let present: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let names: Vec<String> = ["lradius", "rradius", "ltibia", "rtibia"]
        .iter()
        .map(|s| (*s).to_string())
        .collect();
    let track = clip_track(&skel, &motion, &names, TrackFrame::Limb).unwrap();
    let mut g = c.benchmark_group("control_tick");
    for (follow, lookahead) in [(false, false), (true, false), (false, true), (true, true)] {
        let (tx, port) = input_channel(4);
        let solve = if follow {
            Solve::Follow(Box::new(Follower::new(&skel, &names).unwrap()))
        } else {
            Solve::Frames
        };
        // As a real-time run (the fidelity accumulated on a thread of its own), with or without
        // the look-ahead led by the profile's lags.
        let spec = SessionSpec {
            rate_hz: 500.0,
            lead: if lookahead { Lead::Profile } else { Lead::Off },
            // No effector errors in metres: the tick's own work.
            scale: 0.0,
            ..SessionSpec::default()
        };
        let drive = RigDrive {
            skeleton: Arc::clone(&skel),
            rig: rig.clone(),
            retarget: None,
            balance: None,
            rest_pose: None,
            start_pose: None,
        };
        let mut ctl = session::controller(&spec, &profile, drive, &present, port, solve, true);
        let mut bus = EncodeBus {
            packet: [0; 4096],
            params: [0; 4096],
            last: [0; 4096],
            bytes: 0,
        };
        let mut clock = SystemClock::new(0);
        let mut player = ClipPlayer::new(Arc::clone(&skel), Arc::clone(&motion), 500.0, true);
        // Inputs prepared outside the measurement: one per tick, the walk over and over.
        let n = skel.channel_count();
        let mut buf = [0.0; MAX_CHANNELS];
        let inputs: Vec<Input> = (0..1000u64)
            .map(|k| {
                if follow {
                    let (_, t) = &track.samples[k as usize % track.samples.len()];
                    Input {
                        seq: k,
                        due_ns: 0,
                        made_ns: 0,
                        payload: Payload::Targets(t.clone()),
                    }
                } else {
                    let t = player.next_sample(&mut buf[..n]).unwrap();
                    Input::frame(k, 0, 0, &buf[..n], t)
                }
            })
            .collect();
        let next = std::cell::Cell::new(0usize);
        let mut k = 0u64;
        let name = match (follow, lookahead) {
            (false, false) => "play",
            (true, false) => "follow_4_limbs",
            (false, true) => "play_lookahead",
            (true, true) => "follow_4_limbs_lookahead",
        };
        g.bench_function(name, |b| {
            b.iter_batched_ref(
                || {
                    next.set(next.get() + 1);
                    inputs[next.get() % inputs.len()].clone()
                },
                |msg| {
                    tx.send_newest(msg.clone()).unwrap();
                    let now = clock.now_ns();
                    let tick = Tick {
                        index: k,
                        deadline_ns: now,
                        woke_ns: now,
                        skipped: 0,
                    };
                    k += 1;
                    ctl.tick(&tick, &mut bus, &mut clock)
                },
                criterion::BatchSize::SmallInput,
            );
        });
        assert!(next.get() == 0 || bus.bytes > 0, "the ticks wrote goals");
    }
    g.finish();

    // The planner alone: 28 servos over a full preview of the walk.
    let (mut look, mut stage, preview) = planner::walk_planner(&skel, &motion, &profile, &rig);
    // Following the walk: each iteration is the next tick, its targets commanded (every 100
    // ticks the time starts over, the stage where it was).
    let mut tick = 0u64;
    c.bench_function("lookahead/plan_28_servos", |b| {
        b.iter(|| {
            tick = (tick + 1) % 100;
            let now = 2_000_000 * (tick + 1);
            let targets = look.targets(&rig, &stage, &preview, now, 0.002, None);
            let first = targets[0];
            let _ = stage.command_planned(&rig, targets, 0.002);
            first
        });
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

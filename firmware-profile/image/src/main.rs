//! marionette's control tick on a Cortex-M4 (`thumbv7em-none-eabihf`), the rig and skeleton
//! compiled in as const data (`build.rs`).
//!
//! Per tick: one input in (a clip frame, or four limb targets), the core functions the host's
//! loop uses — analytic limb IK with the swivel search, forward kinematics, the rig's mapping,
//! the command stage — and the Sync Write packet of the goals out. Under QEMU the input and
//! output are host files through semihosting (`firmware-in.bin`, `firmware-out.bin`; the
//! formats are in `tests/firmware_qemu.rs`); on a board they would be the UARTs.
//!
//! A panic stops the servos' stream: the handler writes one Sync Write that turns every
//! servo's torque off, then stops.
//!
//! The core runs in f32 (the `single-precision` feature, on by default: the FPU of a Cortex-M4
//! or of the OpenCR's STM32F7 is single precision) or in f64 (`--no-default-features`: in
//! software on such chips, in hardware on a Cortex-M7 with a double-precision FPU). Built for
//! the host (`--target x86_64-unknown-linux-gnu`), the same tick reads and writes the same
//! files through std: the reference the chip's goals are compared with, bit for bit.
#![cfg_attr(target_os = "none", no_std, no_main)]
#![deny(unsafe_code)]

#[cfg(target_os = "none")]
use cortex_m::peripheral::{syst::SystClkSource, SYST};
#[cfg(target_os = "none")]
use cortex_m_semihosting::debug;
use marionette_core::command::CommandStage;
use marionette_core::fk::fk64_step;
use marionette_core::ik::{Limb, Swivel};
use marionette_core::math::{consts::PI, Real, RealMat3, RealVec3};
use marionette_core::protocol::{encode, instruction, BROADCAST_ID};
use marionette_core::servo::addr;
use marionette_core::skeleton::MAX_CHANNELS;

#[cfg_attr(not(target_os = "none"), path = "host_std.rs")]
mod host;
#[cfg(target_os = "none")]
mod stack;
/// No stack painting on the host.
#[cfg(not(target_os = "none"))]
mod stack {
    pub struct Painted;
    pub fn paint() -> Painted {
        Painted
    }
    pub fn used(_: Painted) -> usize {
        0
    }
}

#[allow(clippy::all, missing_docs, unused_parens)]
mod data {
    use glam::{Mat3, Vec3};
    use marionette_core::math::{EulerOrder, Real, RealMat3, RealVec3};
    use marionette_core::rig::{JointSource, Rig, ServoMap};
    use marionette_core::servo::MODELS;
    use marionette_core::skeleton::{Bone, BoneName, BoneSpec, Dof, Limit, RootSpec, Skeleton, Units};

    const fn name(n: &str) -> BoneName {
        match BoneName::new(n) {
            Some(b) => b,
            None => panic!("bone name too long"),
        }
    }

    include!(concat!(env!("OUT_DIR"), "/rig_data.rs"));
}

/// The most servos the image's buffers hold.
const MAX_SERVOS: usize = 32;
/// The limbs of the targets mode: the effector bones (each the tip of a two-bone limb).
const EFFECTORS: [&str; 4] = ["lradius", "rradius", "ltibia", "rtibia"];
/// How far the swivel search looks around the previous swivel in a stream (the host's
/// `SWIVEL_WINDOW`), radians.
const SWIVEL_WINDOW: Real = 40.0 * PI / 180.0;
/// Longest Sync Write of goals: header, instruction, address, length, 5 bytes a servo, CRC —
/// doubled for byte stuffing.
const MAX_PACKET: usize = 2 * (14 + 5 * MAX_SERVOS);

/// Written before the torque-off packet when the image panics.
#[cfg(target_os = "none")]
const PANICKED: u32 = 0xFFFF_FFFE;

/// The input's header: what follows and at what rate.
struct Header {
    targets: bool,
    /// A test of the stop path: panic after the first tick.
    panic_after_one: bool,
    rate_hz: Real,
    ticks: u32,
}

#[cfg(target_os = "none")]
#[cortex_m_rt::entry]
fn main() -> ! {
    let code = match run() {
        Ok(()) => debug::EXIT_SUCCESS,
        Err(()) => debug::EXIT_FAILURE,
    };
    debug::exit(code);
    #[allow(clippy::empty_loop)]
    loop {}
}

/// The host build: the same tick on the same files (no instruction counts).
#[cfg(not(target_os = "none"))]
fn main() {
    std::process::exit(i32::from(run().is_err()));
}

/// SysTick's current value (it counts down); 0 on the host.
fn now() -> u32 {
    #[cfg(target_os = "none")]
    {
        SYST::get_current()
    }
    #[cfg(not(target_os = "none"))]
    {
        0
    }
}

/// Starts SysTick on the system clock, free-running over its 24 bits.
#[cfg(target_os = "none")]
fn start_clock() -> Result<(), ()> {
    let mut core = cortex_m::Peripherals::take().ok_or(())?;
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(0x00FF_FFFF);
    core.SYST.clear_current();
    core.SYST.enable_counter();
    Ok(())
}

/// The tick's state, once: a static (counted in .bss) on the chip.
fn take_state() -> Option<&'static mut State> {
    let state = State {
        limbs: heapless::Vec::new(),
        stage: CommandStage::new(0),
        channels: [0.0; MAX_CHANNELS],
        angles: [0.0; MAX_SERVOS],
        packet: [0; MAX_PACKET],
    };
    #[cfg(target_os = "none")]
    {
        cortex_m::singleton!(: State = state)
    }
    #[cfg(not(target_os = "none"))]
    {
        Some(Box::leak(Box::new(state)))
    }
}

fn run() -> Result<(), ()> {
    let stack = stack::paint();
    let skeleton = &data::SKELETON;
    let rig = &data::RIG;
    let n = skeleton.channel_count();
    let servos = rig.len();
    if servos > MAX_SERVOS || n > MAX_CHANNELS {
        return Err(());
    }
    let mut input = host::File::open("firmware-in.bin\0", host::READ)?;
    let mut output = host::File::open("firmware-out.bin\0", host::WRITE)?;
    let header = read_header(&mut input)?;
    let dt = 1.0 / header.rate_hz;

    // Instructions per tick: QEMU runs with `-icount shift=0` (one instruction, one ns of
    // virtual time) and SysTick counts the 25 MHz system clock: 40 instructions a count.
    #[cfg(target_os = "none")]
    start_clock()?;

    // The tick's state, dimensioned for MAX_SERVOS servos and MAX_CHANNELS channels (32 bones
    // with the feature `bones-32`).
    let state = take_state().ok_or(())?;
    if header.targets {
        for e in EFFECTORS {
            let lower = skeleton.find(e).ok_or(())?;
            let upper = skeleton.bones()[lower].parent().ok_or(())?;
            let limb = Limb::new(skeleton, upper, lower, None).map_err(|_| ())?;
            state.limbs.push((limb, None)).map_err(|_| ())?;
        }
    }
    // The servos stand at their rest ticks (a board would read them first).
    state.stage = CommandStage::new(servos);
    let mut rest = [0i32; MAX_SERVOS];
    for (r, s) in rest.iter_mut().zip(&rig.servos) {
        *r = s.rest_tick();
    }
    state.stage.start_from(rig, &rest[..servos]);
    for _ in 0..header.ticks {
        // One tick's input: the frame's channels, or the limbs' targets (root frame).
        let mut targets = [RealVec3::ZERO; 4];
        if header.targets {
            for t in targets.iter_mut().take(state.limbs.len()) {
                let mut v = [0.0; 3];
                read_f64s(&mut input, &mut v)?;
                *t = RealVec3::from_array(v);
            }
        } else {
            read_f64s(&mut input, &mut state.channels[..n])?;
        }
        let mut stamps = [0u32; 5];
        stamps[0] = now();
        solve(&mut state.limbs, &targets, &mut state.channels[..n]);
        stamps[1] = now();
        rig.joint_angles(skeleton, &state.channels[..n], &[], &mut state.angles[..servos]);
        stamps[2] = now();
        // Refused (an angle not finite): the last command stands.
        let _ = state.stage.command(rig, &state.angles[..servos], dt);
        stamps[3] = now();
        let len = sync_write_goals(state.stage.last(), &mut state.packet);
        stamps[4] = now();
        // Per tick: SysTick counts of the solve, the mapping, the command stage and the
        // encoding (it counts down), the worst limb's residual, the packet.
        for w in stamps.windows(2) {
            output.write_all(&(w[0].wrapping_sub(w[1]) & 0x00FF_FFFF).to_le_bytes())?;
        }
        let residual = f64::from(worst_residual(&state.limbs, &targets, &state.channels[..n]));
        output.write_all(&residual.to_le_bytes())?;
        output.write_all(&(len as u32).to_le_bytes())?;
        output.write_all(&state.packet[..len])?;
        if header.panic_after_one {
            drop(output);
            panic!("the stop path's test");
        }
    }
    // The end: the stack's deepest use, bytes (after a zero-length marker).
    output.write_all(&u32::MAX.to_le_bytes())?;
    output.write_all(&(stack::used(stack) as u32).to_le_bytes())?;
    Ok(())
}

/// What the tick keeps between ticks.
struct State {
    limbs: heapless::Vec<(Limb, Option<Real>), 4>,
    stage: CommandStage,
    channels: [Real; MAX_CHANNELS],
    angles: [Real; MAX_SERVOS],
    packet: [u8; MAX_PACKET],
}

/// Reads little-endian f64s into `out` (rounded to [`Real`]), a few at a time.
fn read_f64s(input: &mut host::File, out: &mut [Real]) -> Result<(), ()> {
    let mut buf = [0u8; 64];
    for chunk in out.chunks_mut(8) {
        let bytes = &mut buf[..8 * chunk.len()];
        input.read_exact(bytes)?;
        for (v, b) in chunk.iter_mut().zip(bytes.chunks_exact(8)) {
            *v = f64_at(b, 0) as Real;
        }
    }
    Ok(())
}

/// The limbs' IK, each swivel searched around the last (the host loop's `Swivel::Track`).
fn solve(limbs: &mut [(Limb, Option<Real>)], targets: &[RealVec3; 4], channels: &mut [Real]) {
    let skeleton = &data::SKELETON;
    for ((limb, swivel), target) in limbs.iter_mut().zip(targets) {
        let search = match *swivel {
            Some(previous) => Swivel::Track {
                previous,
                window: SWIVEL_WINDOW,
            },
            None => Swivel::Auto { previous: None },
        };
        let s = limb.solve(skeleton, channels, *target, search);
        *swivel = Some(s.swivel);
    }
}

/// The largest distance of a limb's tip from its target after the solve (forward kinematics
/// down the limb's chain), file units.
fn worst_residual(limbs: &[(Limb, Option<Real>)], targets: &[RealVec3; 4], channels: &[Real]) -> Real {
    let skeleton = &data::SKELETON;
    let mut worst: Real = 0.0;
    for ((limb, _), target) in limbs.iter().zip(targets) {
        let mut chain: heapless::Vec<usize, 16> = heapless::Vec::new();
        let mut b = Some(limb.lower);
        while let Some(i) = b {
            if chain.push(i).is_err() {
                return Real::NAN;
            }
            b = skeleton.bones()[i].parent();
        }
        let mut parent: Option<(RealMat3, RealVec3)> = None;
        for &i in chain.iter().rev() {
            let (frame, _, tip) = fk64_step(skeleton, channels, i, parent.as_ref().map(|(f, t)| (f, *t)));
            parent = Some((frame, tip));
        }
        if let Some((_, tip)) = parent {
            worst = worst.max((tip - *target).length());
        }
    }
    worst
}

/// The goals as one Sync Write to Goal Position (4 bytes a servo); returns the packet's length.
fn sync_write_goals(goals: &[i32], out: &mut [u8]) -> usize {
    let mut params = [0u8; 4 + 5 * MAX_SERVOS];
    params[..2].copy_from_slice(&addr::GOAL_POSITION.to_le_bytes());
    params[2..4].copy_from_slice(&4u16.to_le_bytes());
    let mut at = 4;
    for (&id, g) in data::IDS.iter().zip(goals) {
        params[at] = id;
        params[at + 1..at + 5].copy_from_slice(&g.to_le_bytes());
        at += 5;
    }
    encode(BROADCAST_ID, instruction::SYNC_WRITE, &params[..at], out).unwrap_or(0)
}

/// One Sync Write that turns every servo's torque off.
#[cfg(target_os = "none")]
fn torque_off(out: &mut [u8]) -> usize {
    let mut params = [0u8; 4 + 2 * MAX_SERVOS];
    params[..2].copy_from_slice(&addr::TORQUE_ENABLE.to_le_bytes());
    params[2..4].copy_from_slice(&1u16.to_le_bytes());
    let mut at = 4;
    for &id in data::IDS.iter().take(MAX_SERVOS) {
        params[at] = id;
        params[at + 1] = 0;
        at += 2;
    }
    encode(BROADCAST_ID, instruction::SYNC_WRITE, &params[..at], out).unwrap_or(0)
}

fn read_header(input: &mut host::File) -> Result<Header, ()> {
    let mut h = [0u8; 20];
    input.read_exact(&mut h)?;
    if &h[..4] != b"MRNT" {
        return Err(());
    }
    // (In Real at once: no f64 arithmetic on the chip.)
    let rate_hz = f64_at(&h, 4) as Real;
    let ticks = u32::from_le_bytes([h[12], h[13], h[14], h[15]]);
    let (targets, panic_after_one) = match h[16] {
        0 => (false, false),
        1 => (true, false),
        2 => (false, true),
        _ => return Err(()),
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(());
    }
    Ok(Header {
        targets,
        panic_after_one,
        rate_hz,
        ticks,
    })
}

fn f64_at(bytes: &[u8], at: usize) -> f64 {
    let mut b = [0u8; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    f64::from_le_bytes(b)
}

/// Stops the servos' stream: torque off on the bus (here the output file), then stop.
#[cfg(target_os = "none")]
#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    let mut packet = [0u8; 2 * (14 + 2 * MAX_SERVOS)];
    let len = torque_off(&mut packet);
    if let Ok(mut out) = host::File::open("firmware-out.bin\0", host::APPEND) {
        let _ = out.seek_end();
        let _ = out.write_all(&PANICKED.to_le_bytes());
        let _ = out.write_all(&(len as u32).to_le_bytes());
        let _ = out.write_all(&packet[..len]);
    }
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

//! The firmware image (`firmware-profile/image`, thumbv7em-none-eabihf) in QEMU's MPS2 AN386
//! (a Cortex-M4): the bundled walk as clip frames and as four-limb targets, every goal it
//! writes compared with this (host) build of the same core functions on the same input.
//!
//! Input file (`firmware-in.bin`, little-endian): `MRNT`, rate (f64), ticks (u32), mode (u8:
//! 0 frames, 1 targets, 2 frames and a panic after the first tick), 3 bytes of padding; then per tick the frame's channels (f64 each,
//! radians and file units) or four targets (x, y, z f64 each, root frame, effectors
//! lradius, rradius, ltibia, rtibia). Output (`firmware-out.bin`) per tick: SysTick counts of
//! the solve, the mapping, the command stage and the encoding (u32 each; 40 instructions a
//! count under `-icount shift=0`), the worst limb residual (f64, file units), the Sync Write's
//! length (u32) and bytes; at the end `u32::MAX` and the stack's deepest use (u32, bytes) —
//! or, after a panic, `0xFFFF_FFFE`, the length and bytes of a torque-off Sync Write.

use std::path::{Path, PathBuf};
use std::process::Command;

use marionette::command::CommandStage;
use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, asf};
use marionette::ik::{Limb, Swivel};
use marionette::profile::Profile;
use marionette::protocol::{decode, instruction};
use marionette::rig::ServoMap;

const EFFECTORS: [&str; 4] = ["lradius", "rradius", "ltibia", "rtibia"];
const SWIVEL_WINDOW: f64 = 40.0 * std::f64::consts::PI / 180.0;
const RATE_HZ: f64 = 120.0;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Builds the image (cargo, for the Cortex-M target) and returns its path: for the Cortex-M4
/// (single-precision FPU: the core's f64 maths in software), or with `cpu` for another core
/// (`cortex-m7`: a double-precision FPU, as on STM32F76x/H7 or i.MX RT).
fn image(cpu: Option<&str>) -> PathBuf {
    let target_dir = root().join(match cpu {
        None => "target/firmware-image".to_string(),
        Some(c) => format!("target/firmware-image-{c}"),
    });
    // From its directory, so that its `.cargo/config.toml` (target, linker script) applies.
    let mut cargo = Command::new(env!("CARGO"));
    cargo
        .args(["build", "--release", "--target-dir"])
        .arg(&target_dir)
        .current_dir(root().join("firmware-profile/image"));
    if let Some(c) = cpu {
        cargo.env(
            // (Added to the config's flags.)
            "CARGO_TARGET_THUMBV7EM_NONE_EABIHF_RUSTFLAGS",
            format!("-C target-cpu={c}"),
        );
    }
    assert!(
        cargo.status().expect("cargo runs").success(),
        "the firmware image builds"
    );
    target_dir.join("thumbv7em-none-eabihf/release/marionette-firmware-image")
}

/// The image's footprint from its ELF section headers: (flash, static RAM, per section).
fn footprint(elf: &[u8]) -> (u64, u64, Vec<(String, u64)>) {
    let u16_at = |at: usize| u64::from(u16::from_le_bytes([elf[at], elf[at + 1]]));
    let u32_at = |at: usize| u64::from(u32::from_le_bytes(elf[at..at + 4].try_into().unwrap()));
    assert_eq!(&elf[..5], b"\x7fELF\x01", "a 32-bit ELF");
    let (shoff, shentsize, shnum, shstrndx) = (
        u32_at(0x20) as usize,
        u16_at(0x2e) as usize,
        u16_at(0x30),
        u16_at(0x32),
    );
    let header = |i: u64| shoff + i as usize * shentsize;
    let strtab = u32_at(header(shstrndx) + 0x10) as usize;
    let (mut flash, mut ram, mut sections) = (0, 0, Vec::new());
    for i in 0..shnum {
        let h = header(i);
        let (name_at, kind, flags, size) =
            (u32_at(h) as usize, u32_at(h + 4), u32_at(h + 8), u32_at(h + 0x14));
        let name: String = elf[strtab + name_at..]
            .iter()
            .take_while(|&&b| b != 0)
            .map(|&b| b as char)
            .collect();
        // Allocated sections only: flash holds what has contents (code, read-only data and the
        // initial values of .data), RAM what is writable (.data and .bss).
        if flags & 2 == 0 || size == 0 {
            continue;
        }
        let (write, nobits) = (flags & 1 != 0, kind == 8);
        if !nobits {
            flash += size;
        }
        if write {
            ram += size;
        }
        sections.push((name, size));
    }
    (flash, ram, sections)
}

/// What one run of the image wrote: per tick the SysTick counts of its stages (solve, mapping,
/// command stage, encoding), the worst limb residual and the goals; the stack's deepest use.
struct Run {
    counts: Vec<[u32; 4]>,
    residuals: Vec<f64>,
    goals: Vec<Vec<(u8, i32)>>,
    stack_bytes: u32,
}

/// Runs an image on `input`: whether it exited with success, and what it wrote.
fn qemu(image: &Path, machine: &str, input: &[u8], name: &str) -> (bool, Vec<u8>) {
    let dir = root().join("target/firmware-image/runs").join(name);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("firmware-in.bin"), input).unwrap();
    let _ = std::fs::remove_file(dir.join("firmware-out.bin"));
    let out = Command::new("qemu-system-arm")
        .args(["-M", machine, "-nographic", "-monitor", "none", "-serial", "none"])
        .args([
            "-semihosting-config",
            "enable=on,target=native",
            "-icount",
            "shift=0",
        ])
        .arg("-kernel")
        .arg(image)
        .current_dir(&dir)
        .output()
        .expect("qemu-system-arm runs (Debian: apt-get install qemu-system-arm; .ci/run installs it)");
    (
        out.status.success(),
        std::fs::read(dir.join("firmware-out.bin")).unwrap_or_default(),
    )
}

fn run_in_qemu(image: &Path, machine: &str, input: &[u8], name: &str) -> Run {
    let (ok, bytes) = qemu(image, machine, input, name);
    assert!(ok, "the image exits with success");
    let mut run = Run {
        counts: Vec::new(),
        residuals: Vec::new(),
        goals: Vec::new(),
        stack_bytes: 0,
    };
    let mut at = 0;
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap());
    loop {
        if u32_at(at) == u32::MAX {
            run.stack_bytes = u32_at(at + 4);
            assert_eq!(at + 8, bytes.len(), "the end marker ends the output");
            break;
        }
        run.counts.push([0, 1, 2, 3].map(|k| u32_at(at + 4 * k)));
        run.residuals
            .push(f64::from_le_bytes(bytes[at + 16..at + 24].try_into().unwrap()));
        let len = u32_at(at + 24) as usize;
        let packet = &bytes[at + 28..at + 28 + len];
        let mut params = [0u8; 1024];
        let (p, used) = decode(packet, &mut params).unwrap();
        assert_eq!((used, p.instruction), (len, instruction::SYNC_WRITE));
        assert_eq!(&p.params[..4], &[116, 0, 4, 0], "Goal Position, 4 bytes");
        run.goals.push(
            p.params[4..]
                .chunks(5)
                .map(|c| (c[0], i32::from_le_bytes(c[1..5].try_into().unwrap())))
                .collect(),
        );
        at += 28 + len;
    }
    run
}

/// Instructions (40 a SysTick count) per tick: p50, p99 and max of the whole tick, and the
/// p50 of each stage.
fn instructions(run: &Run) -> String {
    let pct = |mut v: Vec<u64>, q: usize| {
        v.sort_unstable();
        v[(v.len() * q / 100).min(v.len() - 1)]
    };
    let total: Vec<u64> = run
        .counts
        .iter()
        .map(|c| c.iter().map(|&x| u64::from(x) * 40).sum())
        .collect();
    let stage = |k: usize| pct(run.counts.iter().map(|c| u64::from(c[k]) * 40).collect(), 50);
    format!(
        "p50 {} p99 {} max {} (p50 of solve {}, mapping {}, command {}, Sync Write {}); stack {} bytes",
        pct(total.clone(), 50),
        pct(total.clone(), 99),
        pct(total, 100),
        stage(0),
        stage(1),
        stage(2),
        stage(3),
        run.stack_bytes
    )
}

fn header(ticks: usize, targets: bool) -> Vec<u8> {
    let mut h = b"MRNT".to_vec();
    h.extend_from_slice(&RATE_HZ.to_le_bytes());
    h.extend_from_slice(&(ticks as u32).to_le_bytes());
    h.extend_from_slice(&[u8::from(targets), 0, 0, 0]);
    h
}

/// The host build's goals for the walk, as frames and as four-limb targets, and the inputs.
struct Reference {
    frames_input: Vec<u8>,
    frames_goals: Vec<Vec<(u8, i32)>>,
    targets_input: Vec<u8>,
    targets_goals: Vec<Vec<(u8, i32)>>,
    /// The worst limb residual of each targets tick (forward kinematics of the whole pose).
    residuals: Vec<f64>,
}

fn reference() -> Reference {
    let skel = asf::load(&root().join("data/cmu/16.asf")).unwrap().skeleton;
    let motion = amc::load(&skel, &root().join("data/cmu/16_15.amc")).unwrap();
    let profile = Profile::load(&root().join("firmware-profile/cmu-puppet.toml")).unwrap();
    let rig = profile.rig(Some(&skel)).unwrap();
    let ids = profile.ids();
    let n = skel.channel_count();
    let frames: Vec<Vec<f64>> = (0..motion.len())
        .map(|f| marionette::motion::frame_to_radians(&skel, motion.frame(f)))
        .collect();
    let rest: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let dt = 1.0 / RATE_HZ;
    let named =
        |goals: &[i32]| -> Vec<(u8, i32)> { ids.iter().copied().zip(goals.iter().copied()).collect() };

    // Clip frames: mapping and command stage.
    let mut frames_input = header(frames.len(), false);
    let mut frames_goals = Vec::new();
    let mut stage = CommandStage::new(rig.len());
    stage.start_from(&rig, &rest);
    let mut angles = vec![0.0; rig.len()];
    for f in &frames {
        for c in &f[..n] {
            frames_input.extend_from_slice(&c.to_le_bytes());
        }
        rig.joint_angles(&skel, &f[..n], &[], &mut angles);
        let _ = stage.command(&rig, &angles, dt);
        frames_goals.push(named(stage.last()));
    }

    // Four-limb targets: the walk's wrists and ankles in the root's frame, solved as the
    // host loop solves them (each swivel searched around the last).
    let limbs: Vec<usize> = EFFECTORS.iter().map(|e| skel.find(e).unwrap()).collect();
    let mut solvers: Vec<(Limb, Option<f64>)> = limbs
        .iter()
        .map(|&l| {
            (
                Limb::new(&skel, skel.bones()[l].parent().unwrap(), l, None).unwrap(),
                None,
            )
        })
        .collect();
    let mut pose = Pose64::default();
    let mut channels = vec![0.0; n];
    let mut stage = CommandStage::new(rig.len());
    stage.start_from(&rig, &rest);
    let mut targets_input = header(frames.len(), true);
    let (mut targets_goals, mut residuals) = (Vec::new(), Vec::new());
    for f in &frames {
        let mut c = f.clone();
        c[..skel.root().order.len()].fill(0.0);
        fk64(&skel, &c, &mut pose);
        let targets = [0, 1, 2, 3].map(|k| pose.tip[limbs[k]]);
        for v in &targets {
            for x in [v.x, v.y, v.z] {
                targets_input.extend_from_slice(&x.to_le_bytes());
            }
        }
        for ((limb, swivel), target) in solvers.iter_mut().zip(&targets) {
            let search = match *swivel {
                Some(previous) => Swivel::Track {
                    previous,
                    window: SWIVEL_WINDOW,
                },
                None => Swivel::Auto { previous: None },
            };
            *swivel = Some(limb.solve(&skel, &mut channels, *target, search).swivel);
        }
        rig.joint_angles(&skel, &channels, &[], &mut angles);
        let _ = stage.command(&rig, &angles, dt);
        targets_goals.push(named(stage.last()));
        fk64(&skel, &channels, &mut pose);
        residuals.push(
            limbs
                .iter()
                .zip(&targets)
                .map(|(&l, target)| (pose.tip[l] - *target).length())
                .fold(0.0f64, f64::max),
        );
    }
    Reference {
        frames_input,
        frames_goals,
        targets_input,
        targets_goals,
        residuals,
    }
}

/// Runs an image on both inputs and checks every goal and residual against the host's.
fn check(image: &Path, machine: &str, r: &Reference) {
    let (flash, ram, sections) = footprint(&std::fs::read(image).unwrap());
    println!("{machine}: flash {flash} bytes, static RAM {ram} bytes; sections {sections:?}");
    let run = run_in_qemu(image, machine, &r.frames_input, &format!("{machine}-frames"));
    assert_eq!(run.goals.len(), r.frames_goals.len());
    for (k, (got, want)) in run.goals.iter().zip(&r.frames_goals).enumerate() {
        assert_eq!(got, want, "{machine}, frame {k}");
    }
    println!(
        "{machine}: instructions per tick (QEMU -icount), frames: {}",
        instructions(&run)
    );

    let run = run_in_qemu(image, machine, &r.targets_input, &format!("{machine}-targets"));
    assert_eq!(run.goals.len(), r.targets_goals.len());
    for (k, (got, want)) in run.goals.iter().zip(&r.targets_goals).enumerate() {
        assert_eq!(got, want, "{machine}, targets tick {k}");
    }
    // The board's residuals (forward kinematics down each limb) are the host's. (Not zero:
    // some of the capture's wrist and ankle positions lie outside what the ASF's joint limits
    // let a limb reach.)
    let gap = run
        .residuals
        .iter()
        .zip(&r.residuals)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f64, f64::max);
    assert!(
        gap < 1e-9,
        "{machine}: the board's residuals are the host's: {gap}"
    );
    let mut sorted = run.residuals.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "{machine}: limb residual (file units) p50 {:.1e}, max {:.3}",
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1]
    );
    println!(
        "{machine}: instructions per tick (QEMU -icount), four-limb targets: {}",
        instructions(&run)
    );
}

#[test]
fn the_image_in_qemu_writes_the_host_builds_goals() {
    // A profile the std loader refuses stops the image's build with the same message.
    let dir = root().join("target/firmware-image/runs");
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad-profile.toml");
    let good = std::fs::read_to_string(root().join("firmware-profile/cmu-puppet.toml")).unwrap();
    std::fs::write(&bad, good.replacen("baud = 4_000_000", "baud = \"fast\"", 1)).unwrap();
    let out = Command::new(env!("CARGO"))
        .args(["build", "--release", "--target-dir"])
        .arg(root().join("target/firmware-image"))
        .env("MARIONETTE_PROFILE", &bad)
        .current_dir(root().join("firmware-profile/image"))
        .output()
        .expect("cargo runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    let want = Profile::load(&bad).unwrap_err().to_string();
    assert!(
        !out.status.success() && stderr.contains(&want),
        "{want}\n{stderr}"
    );
    assert!(want.contains("bad-profile.toml:28:"), "file:line:column: {want}");

    let r = reference();
    // The Cortex-M4 (MPS2 AN386): f64 in software.
    check(&image(None), "mps2-an386", &r);
    // A Cortex-M7 with a double-precision FPU (MPS2 AN500).
    check(&image(Some("cortex-m7")), "mps2-an500", &r);

    // A panic stops the servos' stream: after the first tick's goals, one Sync Write of
    // Torque Enable 0 to every servo, and the image exits with failure.
    let mut input = r.frames_input.clone();
    input[16] = 2;
    let (ok, bytes) = qemu(&image(None), "mps2-an386", &input, "panic");
    assert!(!ok, "a panic ends the run with failure");
    let first = 28 + u32::from_le_bytes(bytes[24..28].try_into().unwrap()) as usize;
    assert_eq!(
        &bytes[first..first + 4],
        &0xFFFF_FFFEu32.to_le_bytes(),
        "the panic's marker"
    );
    let len = u32::from_le_bytes(bytes[first + 4..first + 8].try_into().unwrap()) as usize;
    assert_eq!(bytes.len(), first + 8 + len);
    let mut params = [0u8; 256];
    let (p, _) = decode(&bytes[first + 8..], &mut params).unwrap();
    assert_eq!(p.instruction, instruction::SYNC_WRITE);
    assert_eq!(&p.params[..4], &[64, 0, 1, 0], "Torque Enable, 1 byte");
    let profile = Profile::load(&root().join("firmware-profile/cmu-puppet.toml")).unwrap();
    let off: Vec<u8> = profile.ids().iter().flat_map(|&id| [id, 0]).collect();
    assert_eq!(&p.params[4..], &off[..], "every servo's torque off");
}

//! The firmware image (`firmware-profile/image`, thumbv7em-none-eabihf) in QEMU's MPS2 AN386
//! (a Cortex-M4): the bundled walk as clip frames and as four-limb targets.
//!
//! The image's core runs in f32 (the M4's FPU is single precision): every goal it writes is
//! compared bit for bit with the same image code built for the host (x86-64, also f32), and
//! with this crate's f64 host path within a stated number of ticks. The f64 image, on a
//! Cortex-M7 with a double-precision FPU (MPS2 AN500), writes the f64 host path's goals bit
//! for bit.
//!
//! Input file (`firmware-in.bin`, little-endian): `MRNT`, rate (f64), ticks (u32), mode (u8:
//! 0 frames, 1 targets, 2 frames and a panic after the first tick), 3 bytes of padding; then per tick the frame's channels (f64 each,
//! radians and file units) or four targets (x, y, z f64 each, root frame, effectors
//! lradius, rradius, ltibia, rtibia). Output (`firmware-out.bin`) per tick: SysTick counts of
//! the solve, the mapping, the command stage and the encoding (u32 each; 40 instructions a
//! count under `-icount shift=0`), the worst limb residual (f64, file units), the Sync Write's
//! length (u32) and bytes; at the end `u32::MAX` and the stack's deepest use (u32, bytes) —
//! or, after a panic, `0xFFFF_FFFE`, the length and bytes of a torque-off Sync Write.

mod common;

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

/// The core's precision in an image.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Precision {
    /// f32 (the image's default feature `single-precision`).
    Single,
    /// f64 (`--no-default-features --features bones-32`).
    Double,
}

/// The image's build directory, shared by every variant and by CI's lint of the image: the
/// variants differ in features, flags and target only, so they share the host-built loaders
/// (`marionette` in release, the build step's dependency) instead of building them three times.
fn image_target_dir() -> PathBuf {
    root().join("target/firmware-image")
}

/// Copies a just-built image to a path of its own (the next variant's build writes over cargo's).
fn keep(built: &Path, variant: &str) -> PathBuf {
    let dir = image_target_dir().join("variants");
    std::fs::create_dir_all(&dir).unwrap();
    let kept = dir.join(variant);
    std::fs::copy(built, &kept).expect("the built image is there");
    kept
}

/// Builds the image (cargo, for the Cortex-M target) and returns its path: for the Cortex-M4
/// (single-precision FPU), or with `cpu` for another core (`cortex-m7`: a double-precision
/// FPU, as on STM32F76x/H7 or i.MX RT).
fn image(cpu: Option<&str>, precision: Precision) -> PathBuf {
    // From its directory, so that its `.cargo/config.toml` (target, linker script) applies.
    let mut cargo = Command::new(env!("CARGO"));
    cargo
        .args(["build", "--release", "--target-dir"])
        .arg(image_target_dir())
        .current_dir(root().join("firmware-profile/image"));
    if precision == Precision::Double {
        cargo.args(["--no-default-features", "--features", "bones-32"]);
    }
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
    let variant = format!(
        "{}-{}",
        cpu.unwrap_or("cortex-m4"),
        if precision == Precision::Double {
            "f64"
        } else {
            "f32"
        }
    );
    keep(
        &image_target_dir().join("thumbv7em-none-eabihf/release/marionette-firmware-image"),
        &variant,
    )
}

/// The same image code built for the host (f32): the bit-for-bit reference of the f32 image.
fn host_image() -> PathBuf {
    let rustc = Command::new("rustc").arg("-vV").output().expect("rustc runs");
    let host = String::from_utf8_lossy(&rustc.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        .expect("rustc -vV names the host");
    let status = Command::new(env!("CARGO"))
        .args(["build", "--release", "--target", &host, "--target-dir"])
        .arg(image_target_dir())
        .current_dir(root().join("firmware-profile/image"))
        .status()
        .expect("cargo runs");
    assert!(status.success(), "the image builds for the host");
    keep(
        &image_target_dir()
            .join(&host)
            .join("release/marionette-firmware-image"),
        "host-f32",
    )
}

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

/// Runs an image on `input` in QEMU's `machine` (or, for `None`, a host build of the image
/// directly): whether it exited with success, and what it wrote.
fn execute(image: &Path, machine: Option<&str>, input: &[u8], name: &str) -> (bool, Vec<u8>) {
    let dir = root().join("target/firmware-image/runs").join(name);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("firmware-in.bin"), input).unwrap();
    let _ = std::fs::remove_file(dir.join("firmware-out.bin"));
    let out = match machine {
        Some(machine) => {
            common::needs_program("qemu-system-arm", "qemu-system-arm");
            Command::new("qemu-system-arm")
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
                .expect("qemu-system-arm runs")
        }
        None => Command::new(image)
            .current_dir(&dir)
            .output()
            .expect("the host image runs"),
    };
    (
        out.status.success(),
        std::fs::read(dir.join("firmware-out.bin")).unwrap_or_default(),
    )
}

fn run_image(image: &Path, machine: Option<&str>, input: &[u8], name: &str) -> Run {
    let (ok, bytes) = execute(image, machine, input, name);
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
/// The `q`th percentile of `v`.
fn percentile(mut v: Vec<u64>, q: usize) -> u64 {
    v.sort_unstable();
    v[(v.len() * q / 100).min(v.len() - 1)]
}

/// Each tick's instructions (SysTick counts of 40 instructions each, all stages).
fn tick_instructions(run: &Run) -> Vec<u64> {
    run.counts
        .iter()
        .map(|c| c.iter().map(|&x| u64::from(x) * 40).sum())
        .collect()
}

fn instructions(run: &Run) -> String {
    let pct = percentile;
    let total = tick_instructions(run);
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

/// What an image wrote on both inputs.
struct Runs {
    frames: Run,
    targets: Run,
}

/// Runs an image (in QEMU's `machine`, or on the host for `None`) on both inputs; prints its
/// footprint and instruction counts.
fn run_both(image: &Path, machine: Option<&str>, label: &str, r: &Reference) -> Runs {
    if machine.is_some() {
        let (flash, ram, sections) = footprint(&std::fs::read(image).unwrap());
        println!("{label}: flash {flash} bytes, static RAM {ram} bytes; sections {sections:?}");
    }
    let frames = run_image(image, machine, &r.frames_input, &format!("{label}-frames"));
    let targets = run_image(image, machine, &r.targets_input, &format!("{label}-targets"));
    assert_eq!(frames.goals.len(), r.frames_goals.len(), "{label}");
    assert_eq!(targets.goals.len(), r.targets_goals.len(), "{label}");
    if machine.is_some() {
        println!(
            "{label}: instructions per tick (QEMU -icount), frames: {}",
            instructions(&frames)
        );
        println!(
            "{label}: instructions per tick (QEMU -icount), four-limb targets: {}",
            instructions(&targets)
        );
    }
    let mut sorted = targets.residuals.clone();
    sorted.sort_by(f64::total_cmp);
    println!(
        "{label}: limb residual (file units) p50 {:.1e}, max {:.3}",
        sorted[sorted.len() / 2],
        sorted[sorted.len() - 1]
    );
    Runs { frames, targets }
}

/// Every goal of `got` equals `want`'s, and every residual within `residual_tolerance` (0:
/// the same bits).
fn assert_equal(label: &str, got: &Runs, want: &Runs, residual_tolerance: f64) {
    for (k, (g, w)) in got.frames.goals.iter().zip(&want.frames.goals).enumerate() {
        assert_eq!(g, w, "{label}, frame {k}");
    }
    for (k, (g, w)) in got.targets.goals.iter().zip(&want.targets.goals).enumerate() {
        assert_eq!(g, w, "{label}, targets tick {k}");
    }
    for (k, (g, w)) in got
        .targets
        .residuals
        .iter()
        .zip(&want.targets.residuals)
        .enumerate()
    {
        assert!(
            (g - w).abs() <= residual_tolerance,
            "{label}, residual of targets tick {k}: {g} {w}"
        );
    }
}

/// The largest difference, in ticks, between two runs' goals, and how many goals differ.
fn tick_gap(got: &[Vec<(u8, i32)>], want: &[Vec<(u8, i32)>]) -> (i32, usize, usize) {
    let (mut worst, mut differ, mut all) = (0, 0, 0);
    for (g, w) in got.iter().zip(want) {
        assert_eq!(g.len(), w.len());
        for ((gi, gv), (wi, wv)) in g.iter().zip(w) {
            assert_eq!(gi, wi, "the same servo ids in the same order");
            worst = worst.max((gv - wv).abs());
            differ += usize::from(gv != wv);
            all += 1;
        }
    }
    (worst, differ, all)
}

/// Builds the default image with the environment variable `var` (`MARIONETTE_PROFILE`,
/// `MARIONETTE_ASF`) naming `file`: whether it built, and cargo's stderr.
fn build_image_with(var: &str, file: &Path) -> (bool, String) {
    let out = Command::new(env!("CARGO"))
        .args(["build", "--release", "--target-dir"])
        .arg(image_target_dir())
        .env(var, file)
        .current_dir(root().join("firmware-profile/image"))
        .output()
        .expect("cargo runs");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_image_in_qemu_writes_the_host_builds_goals() {
    // A profile the std loader refuses stops the image's build with the same message.
    let dir = root().join("target/firmware-image/runs");
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad-profile.toml");
    let good = std::fs::read_to_string(root().join("firmware-profile/cmu-puppet.toml")).unwrap();
    std::fs::write(&bad, good.replacen("baud = 4_000_000", "baud = \"fast\"", 1)).unwrap();
    let (built, stderr) = build_image_with("MARIONETTE_PROFILE", &bad);
    let want = Profile::load(&bad).unwrap_err().to_string();
    assert!(!built && stderr.contains(&want), "{want}\n{stderr}");
    assert!(want.contains("bad-profile.toml:28:"), "file:line:column: {want}");
    // A skeleton of more bones than the image has room for (32, the feature `bones-32`) stops
    // its build, saying how to get room for 64: the walk's skeleton with two more fingers.
    let big = dir.join("33-bones.asf");
    let asf = std::fs::read_to_string(root().join("data/cmu/16.asf")).unwrap();
    let extra: String = ["lfingers2", "rfingers2"]
        .iter()
        .enumerate()
        .map(|(k, name)| {
            format!("  begin\r\n     id {}\r\n     name {name}\r\n     direction 0 -1 0\r\n     length 0.5\r\n     axis 0 0 0 XYZ\r\n  end\r\n", 31 + k)
        })
        .collect();
    let asf = asf
        .replacen(":hierarchy", &format!("{extra}:hierarchy"), 1)
        .replacen("lhand lfingers", "lhand lfingers\r\n    lfingers lfingers2", 1)
        .replacen("rhand rfingers", "rhand rfingers\r\n    rfingers rfingers2", 1);
    std::fs::write(&big, asf).unwrap();
    assert_eq!(
        asf::load(&big).unwrap().skeleton.bones().len(),
        33,
        "the host loads the 33-bone skeleton"
    );
    let (built, stderr) = build_image_with("MARIONETTE_ASF", &big);
    assert!(
        !built
            && stderr
                .contains("33-bones.asf: 33 bones (the root included); the image is built for at most 32")
            && stderr.contains("--no-default-features --features single-precision"),
        "{stderr}"
    );

    let r = reference();
    let host_f64 = Runs {
        frames: Run {
            counts: Vec::new(),
            residuals: Vec::new(),
            goals: r.frames_goals.clone(),
            stack_bytes: 0,
        },
        targets: Run {
            counts: Vec::new(),
            residuals: r.residuals.clone(),
            goals: r.targets_goals.clone(),
            stack_bytes: 0,
        },
    };

    // The Cortex-M4 (MPS2 AN386), f32: bit for bit the same image code on the host.
    let m4_image = image(None, Precision::Single);
    // The image's budget, with capacity for 32 bones and 32 servos compiled in: 64 KiB of
    // flash, 16 KiB of static RAM (the sizes are the linker's, the same on every machine).
    let (flash, ram, _) = footprint(&std::fs::read(&m4_image).unwrap());
    assert!(
        flash <= 64 * 1024,
        "the M4 image's flash, {flash} bytes, fits 64 KiB"
    );
    assert!(
        ram <= 16 * 1024,
        "the M4 image's static RAM, {ram} bytes, fits 16 KiB"
    );
    let m4 = run_both(&m4_image, Some("mps2-an386"), "cortex-m4 f32", &r);
    // The tick's budget: 50,000 instructions at p50 for four limbs (an instruction count under
    // `-icount shift=0`, the same on every machine: not a time).
    let four_limb_p50 = percentile(tick_instructions(&m4.targets), 50);
    assert!(
        four_limb_p50 <= 50_000,
        "the M4's four-limb tick, {four_limb_p50} instructions at p50, fits 50,000"
    );
    let host_f32 = run_both(&host_image(), None, "host f32", &r);
    assert_equal("cortex-m4 f32 against the host's f32 build", &m4, &host_f32, 0.0);
    // Against the f64 host path: clip frames go through the mapping and the command stage
    // only (one rounding of each angle to f32), four-limb targets through the f32 limb solver.
    let (frames_gap, frames_differ, frames_all) = tick_gap(&m4.frames.goals, &host_f64.frames.goals);
    let (targets_gap, targets_differ, targets_all) = tick_gap(&m4.targets.goals, &host_f64.targets.goals);
    // Residuals: where the f64 host reaches the target, the f32 limb reaches it within 1e-4
    // file units (6 µm; 7.2e-6 measured: f32's resolution over a leg's length); where it
    // cannot (a captured wrist or ankle outside what the joint limits allow), both stop at
    // nearly the same closest point.
    let (mut reached_worst, mut reached, mut apart_worst) = ((0.0f64, 0), 0, 0.0f64);
    for (k, (f32_residual, f64_residual)) in m4.targets.residuals.iter().zip(&r.residuals).enumerate() {
        if *f64_residual < 1e-6 {
            if *f32_residual > reached_worst.0 {
                reached_worst = (*f32_residual, k);
            }
            reached += 1;
        } else {
            apart_worst = apart_worst.max((f32_residual - f64_residual).abs());
        }
    }
    println!(
        "cortex-m4 f32 against the f64 host: frames {frames_differ} of {frames_all} goals differ, \
         by at most {frames_gap} tick; targets {targets_differ} of {targets_all}, by at most \
         {targets_gap}; residual at most {:.1e} file units (tick {}) where the host reaches \
         the target ({reached} ticks), within {apart_worst:.1e} of the host's elsewhere",
        reached_worst.0, reached_worst.1
    );
    assert!(
        frames_gap <= 1,
        "clip frames: within one tick of the f64 host ({frames_gap})"
    );
    assert!(
        targets_gap <= 1,
        "four-limb targets: within one tick of the f64 host ({targets_gap})"
    );
    assert!(
        reached > 0 && reached_worst.0 < 1e-4,
        "reached targets: {reached_worst:?}"
    );
    assert!(apart_worst < 1e-2, "unreachable targets: {apart_worst}");

    // A Cortex-M7 with a double-precision FPU (MPS2 AN500), f64: bit for bit the host's f64.
    let m7 = run_both(
        &image(Some("cortex-m7"), Precision::Double),
        Some("mps2-an500"),
        "cortex-m7 f64",
        &r,
    );
    // (The residuals within 1e-9: the image finds each tip down its limb, the host from the
    // whole pose.)
    assert_equal("cortex-m7 f64 against the f64 host", &m7, &host_f64, 1e-9);

    // A panic stops the servos' stream: after the first tick's goals, one Sync Write of
    // Torque Enable 0 to every servo, and the image exits with failure.
    let mut input = r.frames_input.clone();
    input[16] = 2;
    let (ok, bytes) = execute(&m4_image, Some("mps2-an386"), &input, "panic");
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

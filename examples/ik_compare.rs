//! The IK method comparison (the IK assignment's report): seeded random reachable
//! targets — FK of random angles inside the ASF limits — for a CMU arm (lhumerus + lradius) and
//! leg (lfemur + ltibia), each solved from the rest pose by the analytic limb solver, CCD,
//! Jacobian transpose, pseudoinverse, damped least squares, conjugate gradient, and the `k`
//! crate's `JacobianIkSolver` on the same chain, in the same run.
//!
//! ```text
//! cargo run --release --example ik_compare -- [--targets N] [--seed S] [--max-iterations N]
//! ```
//!
//! Prints a Markdown table (BENCHMARKS.md, "Inverse kinematics against `k`", holds its figures).

use std::fmt::Write as _;
use std::io::Write as _;
use std::time::Instant;

#[path = "../benches/support/k_model.rs"]
mod k_model;

use glam::DVec3;
use k::nalgebra::Isometry3;
use marionette::bus::faults::Rng;
use marionette::fk::{fk64, Pose64};
use marionette::formats::asf;
use marionette::ik::{Limb, Swivel};
use marionette::ik_numeric::{chain_mask, Constraint, Method, Settings, Solver};
use marionette::skeleton::Skeleton;

const TOLERANCE: f64 = 1e-3;

struct Row {
    name: &'static str,
    success: usize,
    iterations: Vec<f64>,
    micros: Vec<f64>,
    errors: Vec<f64>,
    violations: usize,
}

impl Row {
    fn new(name: &'static str) -> Row {
        Row {
            name,
            success: 0,
            iterations: Vec::new(),
            micros: Vec::new(),
            errors: Vec::new(),
            violations: 0,
        }
    }

    fn add(&mut self, error: f64, iterations: Option<usize>, micros: f64, within: bool) {
        self.success += usize::from(error <= TOLERANCE);
        if let Some(i) = iterations {
            self.iterations.push(i as f64);
        }
        self.micros.push(micros);
        self.errors.push(error);
        self.violations += usize::from(!within);
    }
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * p).round() as usize]
}

fn uniform(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

/// Whether every rotation DOF of `bones` is inside its ASF limits (1e-9 rad slack).
fn within_limits(skel: &Skeleton, bones: &[usize], channels: &[f64]) -> bool {
    bones.iter().all(|&b| {
        let bone = &skel.bones()[b];
        bone.dofs().iter().enumerate().all(|(k, d)| {
            let l = bone.limits()[k];
            let x = channels[bone.first_channel() + k];
            !d.is_rotation() || (x >= f64::from(l.min) - 1e-9 && x <= f64::from(l.max) + 1e-9)
        })
    })
}

fn run(
    out: &mut String,
    skel: &Skeleton,
    upper: &str,
    lower: &str,
    targets: usize,
    seed: u64,
    max_iterations: usize,
) {
    let (u, l) = (skel.find(upper).unwrap(), skel.find(lower).unwrap());
    let limb = Limb::new(skel, u, l, None).unwrap();
    let mask = chain_mask(skel, u, l);
    let mut solver = Solver::new(skel, &mask, false);
    let (arm, k_channels) = k_model::limb_chain(skel, u, l);
    let k_solver = k::JacobianIkSolver::new(TOLERANCE, 0.005, 0.5, max_iterations);
    let position_only = k::Constraints {
        rotation_x: false,
        rotation_y: false,
        rotation_z: false,
        ..k::Constraints::default()
    };
    let methods = [
        ("CCD", Method::Ccd),
        ("Jacobian transpose", Method::Transpose),
        ("pseudoinverse", Method::Pseudoinverse),
        ("damped least squares", Method::DampedLeastSquares),
        ("conjugate gradient", Method::ConjugateGradient),
    ];
    let mut rows: Vec<Row> = vec![Row::new("analytic + swivel search")];
    rows.extend(methods.iter().map(|(n, _)| Row::new(n)));
    rows.push(Row::new("`k` 0.32 JacobianIkSolver"));
    let mut rng = Rng::new(seed);
    let n = skel.channel_count();
    let mut goal = vec![0.0; n];
    let mut ch = vec![0.0; n];
    let mut pose = Pose64::default();
    for _ in 0..targets {
        goal.iter_mut().for_each(|x| *x = 0.0);
        for b in [u, l] {
            let bone = &skel.bones()[b];
            for (kk, d) in bone.dofs().iter().enumerate() {
                if d.is_rotation() {
                    let lim = bone.limits()[kk];
                    goal[bone.first_channel() + kk] =
                        uniform(&mut rng, f64::from(lim.min), f64::from(lim.max));
                }
            }
        }
        fk64(skel, &goal, &mut pose);
        let target = pose.tip[l];
        let error_of = |ch: &[f64], pose: &mut Pose64| {
            fk64(skel, ch, pose);
            (pose.tip[l] - target).length()
        };

        ch.iter_mut().for_each(|x| *x = 0.0);
        let t = Instant::now();
        let s = limb.solve(skel, &mut ch, target, Swivel::Auto { previous: None });
        let us = t.elapsed().as_secs_f64() * 1e6;
        let e = error_of(&ch, &mut pose);
        std::hint::black_box(s);
        rows[0].add(e, None, us, within_limits(skel, &[u, l], &ch));

        for (m, (_, method)) in methods.iter().enumerate() {
            ch.iter_mut().for_each(|x| *x = 0.0);
            let settings = Settings {
                method: *method,
                max_iterations,
                ..Settings::default()
            };
            let constraint = [Constraint {
                bone: l,
                position: target,
                axes: None,
            }];
            let t = Instant::now();
            let out = solver.solve(skel, &constraint, &mut ch, &settings);
            let us = t.elapsed().as_secs_f64() * 1e6;
            let e = error_of(&ch, &mut pose);
            rows[m + 1].add(e, Some(out.iterations), us, within_limits(skel, &[u, l], &ch));
        }

        arm.set_joint_positions_clamped(&vec![0.0; arm.dof()]);
        let goal_iso = Isometry3::translation(target.x, target.y, target.z);
        let t = Instant::now();
        let _ =
            k::InverseKinematicsSolver::solve_with_constraints(&k_solver, &arm, &goal_iso, &position_only);
        let us = t.elapsed().as_secs_f64() * 1e6;
        ch.iter_mut().for_each(|x| *x = 0.0);
        for (q, &c) in arm.joint_positions().iter().zip(&k_channels) {
            ch[c] = *q;
        }
        let e = error_of(&ch, &mut pose);
        let end = arm.end_transform().translation.vector;
        let k_fk = (DVec3::new(end.x, end.y, end.z) - pose.tip[l]).length();
        assert!(k_fk < 1e-6, "the k chain disagrees with fk64 by {k_fk}");
        let last = rows.len() - 1;
        rows[last].add(e, None, us, within_limits(skel, &[u, l], &ch));
    }

    writeln!(
        out,
        "\n### {upper} + {lower} ({} DOF), {targets} targets, seed {seed}, cap {max_iterations} iterations\n",
        solver.variables()
    )
    .unwrap();
    writeln!(out, "| method | success ≤ 1e-3 | mean / max iterations | p50 / p99 time (µs) | mean / max final error | limit violations |").unwrap();
    writeln!(out, "|---|---|---|---|---|---|").unwrap();
    let k_p50 = percentile(&mut rows.last().unwrap().micros.clone(), 0.5);
    for r in &mut rows {
        let its = if r.iterations.is_empty() {
            "—".to_string()
        } else {
            let mean = r.iterations.iter().sum::<f64>() / r.iterations.len() as f64;
            let max = r.iterations.iter().cloned().fold(0.0, f64::max);
            format!("{mean:.1} / {max:.0}")
        };
        let mean_e = r.errors.iter().sum::<f64>() / r.errors.len() as f64;
        let max_e = r.errors.iter().cloned().fold(0.0, f64::max);
        let p50 = percentile(&mut r.micros, 0.5);
        let p99 = percentile(&mut r.micros, 0.99);
        writeln!(
            out,
            "| {} | {:.2} % ({}/{}) | {} | {:.2} / {:.2} (k ÷ this: {:.1}×) | {:.1e} / {:.1e} | {} |",
            r.name,
            100.0 * r.success as f64 / targets as f64,
            r.success,
            targets,
            its,
            p50,
            p99,
            k_p50 / p50,
            mean_e,
            max_e,
            r.violations
        )
        .unwrap();
    }
}

fn main() {
    let mut targets = 10_000;
    let mut seed = 2026;
    let mut max_iterations = 100;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |what: &str| -> u64 {
            args.next()
                .and_then(|v| v.parse().ok())
                .unwrap_or_else(|| panic!("{what} needs a whole number"))
        };
        match a.as_str() {
            "--targets" => targets = value("--targets") as usize,
            "--seed" => seed = value("--seed"),
            "--max-iterations" => max_iterations = value("--max-iterations") as usize,
            other => {
                eprintln!("unknown argument {other}; usage: ik_compare [--targets N] [--seed S] [--max-iterations N]");
                std::process::exit(2);
            }
        }
    }
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/cmu/16.asf");
    let skel = asf::load(&path).expect("bundled 16.asf").skeleton;
    let mut out = String::new();
    writeln!(out, "IK method comparison — `cargo run --release --example ik_compare -- --targets {targets} --seed {seed} --max-iterations {max_iterations}`").unwrap();
    writeln!(out, "Start: rest pose; success: tip within {TOLERANCE} units (inches × 0.45 of the CMU ASF) of the target; limits: ASF limits ±1e-9 rad.").unwrap();
    run(
        &mut out,
        &skel,
        "lhumerus",
        "lradius",
        targets,
        seed,
        max_iterations,
    );
    run(
        &mut out,
        &skel,
        "lfemur",
        "ltibia",
        targets,
        seed + 1,
        max_iterations,
    );
    // A closed pipe (`| head`) is not an error worth a panic.
    let _ = std::io::stdout().write_all(out.as_bytes());
}

//! Writes the two slow balance clips of `data/generated/` for subject 16's skeleton:
//! `squat.amc` (stand, squat to 70° of knee bend over 2.5 s, rise, stand; 8 s) and
//! `weight_shift.amc` (stand, shift the pelvis 12 cm over the left foot, across to the right,
//! back to the middle; 10 s). The feet stay flat where they are: every frame's hip, knee and
//! ankle angles are solved with the skeleton's own forward kinematics.
//!
//! `cargo run --release --example balance_clips` (rewrites the files; they are committed).

use std::path::Path;

use marionette::fk::{fk64, Pose64};
use marionette::formats::{amc, asf};
use marionette::motion::{frame_to_radians, Motion};
use marionette::skeleton::{Dof, Skeleton};

const FPS: f64 = 120.0;

/// The channel of `bone`'s `dof`.
fn channel(s: &Skeleton, bone: &str, dof: Dof) -> usize {
    let b = s.find(bone).unwrap_or_else(|| panic!("no bone {bone}"));
    let k = s.bones()[b]
        .dofs()
        .iter()
        .position(|d| *d == dof)
        .unwrap_or_else(|| panic!("{bone} has no {dof:?}"));
    s.bones()[b].first_channel() + k
}

struct Kin<'a> {
    s: &'a Skeleton,
    pose: Pose64,
}

impl Kin<'_> {
    fn at(&mut self, frame: &[f64]) -> &Pose64 {
        fk64(self.s, &frame_to_radians(self.s, frame), &mut self.pose);
        &self.pose
    }
}

/// Golden-section minimum of `f` on [a, b].
fn minimise(mut f: impl FnMut(f64) -> f64, a: f64, b: f64) -> f64 {
    marionette::ik::golden(&mut f, a, b, 1e-7)
}

/// Moves each leg's hip (rx, rz) and knee (rx) so its ankle is back where it stood (Newton
/// steps with a numerical Jacobian), then turns each foot (rx, rz) flat again.
fn plant(kin: &mut Kin<'_>, f: &mut [f64], ankles0: &[glam::DVec3; 2], feet0: &[glam::DMat3; 2]) {
    let s = kin.s;
    for (idx, side) in ["l", "r"].iter().enumerate() {
        let tib = s.find(&format!("{side}tibia")).unwrap();
        let cs = [
            channel(s, &format!("{side}femur"), Dof::Rx),
            channel(s, &format!("{side}femur"), Dof::Rz),
            channel(s, &format!("{side}tibia"), Dof::Rx),
        ];
        for _ in 0..300 {
            let here = kin.at(f).tip[tib];
            let miss = ankles0[idx] - here;
            if miss.length() < 1e-6 {
                break;
            }
            let mut cols = [glam::DVec3::ZERO; 3];
            for (k, c) in cs.iter().enumerate() {
                f[*c] += 0.01;
                cols[k] = (kin.at(f).tip[tib] - here) / 0.01;
                f[*c] -= 0.01;
            }
            let j = glam::DMat3::from_cols(cols[0], cols[1], cols[2]);
            // Damped least squares.
            let jt = j.transpose();
            let step = (jt * j + glam::DMat3::IDENTITY * 1e-4).inverse() * (jt * miss);
            for (k, c) in cs.iter().enumerate() {
                f[*c] += step[k].clamp(-5.0, 5.0);
            }
        }
        let foot = s.find(&format!("{side}foot")).unwrap();
        for dof in [Dof::Rx, Dof::Rz] {
            let c = channel(s, &format!("{side}foot"), dof);
            let mut g = f.to_vec();
            let best = minimise(
                |a| {
                    g[c] = a;
                    let p = kin.at(&g);
                    let d = p.frame[foot] * feet0[idx].transpose();
                    -(d.x_axis.x + d.y_axis.y + d.z_axis.z)
                },
                -80.0,
                80.0,
            );
            f[c] = best;
        }
    }
}

fn smooth(t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn main() {
    let file = asf::load(Path::new("data/cmu/16.asf")).expect("16.asf");
    let s = &file.skeleton;
    let n = s.channel_count();
    let mut kin = Kin {
        s,
        pose: Pose64::default(),
    };
    let ty = channel(s, "root", Dof::Ty);
    let tx = channel(s, "root", Dof::Tx);
    let tz = channel(s, "root", Dof::Tz);
    let lfoot = s.find("lfoot").unwrap();
    let rfoot = s.find("rfoot").unwrap();
    let ltib = s.find("ltibia").unwrap();
    let rtib = s.find("rtibia").unwrap();
    // Standing: the rest pose, lifted so the lower ankle is 2 units above y = 0.
    let mut stand = vec![0.0; n];
    let low = {
        let p = kin.at(&stand);
        p.tip[ltib].y.min(p.tip[rtib].y)
    };
    stand[ty] = 2.0 - low;
    let (ankles0, feet0) = {
        let p = kin.at(&stand);
        ([p.tip[ltib], p.tip[rtib]], [p.frame[lfoot], p.frame[rfoot]])
    };
    let units_per_m = 1.0 / f64::from(s.units().meters_per_unit());

    // Squat: knee bend k, hips flexed k/2; the ankle angle keeps each foot flat, the root
    // moves (up/down and forward/back) so the ankles stay where they stood.
    let mut squat = Motion::new(n, FPS);
    let total = 8.0;
    for i in 0..=(total * FPS) as usize {
        let t = i as f64 / FPS;
        let k = 70.0
            * if t < 1.5 {
                0.0
            } else if t < 4.0 {
                smooth((t - 1.5) / 2.5)
            } else if t < 6.5 {
                1.0 - smooth((t - 4.0) / 2.5)
            } else {
                0.0
            };
        let mut f = stand.clone();
        for side in ["l", "r"] {
            f[channel(s, &format!("{side}tibia"), Dof::Rx)] = k;
            f[channel(s, &format!("{side}femur"), Dof::Rx)] = -0.5 * k;
        }
        // The pelvis goes down with the knees (a little back, as people squat).
        let bend = k.to_radians();
        f[ty] -= 0.25 * (1.0 - bend.cos()) * 2.0 * units_per_m * 0.42;
        f[tz] -= 0.06 * units_per_m * (k / 70.0);
        plant(&mut kin, &mut f, &ankles0, &feet0);
        squat.push_frame(&f);
    }

    // Weight shift: the pelvis moves sideways by d (over the left foot, across to the right,
    // back); both hips roll so each ankle stays where it stood, both ankles roll back so the
    // feet stay flat.
    let mut shift = Motion::new(n, FPS);
    let total = 10.0;
    let amplitude = 0.12 * units_per_m;
    for i in 0..=(total * FPS) as usize {
        let t = i as f64 / FPS;
        let d = amplitude
            * if t < 1.5 {
                0.0
            } else if t < 3.5 {
                smooth((t - 1.5) / 2.0)
            } else if t < 7.5 {
                1.0 - 2.0 * smooth((t - 3.5) / 4.0)
            } else if t < 9.0 {
                -1.0 + smooth((t - 7.5) / 1.5)
            } else {
                0.0
            };
        let mut f = stand.clone();
        // The subject's left is +x in CMU's rest pose.
        f[tx] += d;
        // The pelvis lowers a little as the legs lean.
        f[ty] -= 0.6 * d.abs();
        plant(&mut kin, &mut f, &ankles0, &feet0);
        shift.push_frame(&f);
    }

    for (name, m) in [("squat", &squat), ("weight_shift", &shift)] {
        let path = format!("data/generated/{name}.amc");
        amc::save(s, m, Path::new(&path)).expect("write");
        // Check: the ankles stay where they stood (units → mm).
        let mut worst: f64 = 0.0;
        for k in 0..m.len() {
            let p = kin.at(m.frame(k));
            for (tib, a0) in [(ltib, ankles0[0]), (rtib, ankles0[1])] {
                let e = (p.tip[tib] - a0).length();
                if e > worst && std::env::var("DEBUG").is_ok() {
                    eprintln!("{k} {tib} {:?}", p.tip[tib] - a0);
                }
                worst = worst.max(e);
            }
        }
        println!(
            "{path}: {} frames, {:.1} s; the ankles move at most {:.1} mm",
            m.len(),
            m.len() as f64 / FPS,
            worst / units_per_m * 1000.0
        );
    }
}

//! Compares the third-party BVH conversion of a CMU clip with the AMC pose, joint by joint.
//! `cargo run --release --example bvh_vs_amc [ASF AMC BVH SKIP_FRAMES INCHES_PER_BVH_UNIT]`
use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf, bvh};
use marionette::skeleton::MAX_CHANNELS;
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let skip: usize = args.get(4).map_or(0, |v| v.parse().unwrap());
    let (a, m, b) = if args.len() >= 4 {
        (args[1].clone(), args[2].clone(), args[3].clone())
    } else {
        ("data/cmu/16.asf".into(), "data/cmu/16_15.amc".into(), "data/cmu/16_15.bvh".into())
    };
    let file = asf::load(Path::new(&a)).unwrap();
    let s = &file.skeleton;
    let motion = amc::load(s, Path::new(&m)).unwrap();
    // Import the BVH in ASF units so positions compare directly.
    let inches_per_asf_unit = 1.0 / f64::from(s.units().length);
    let cm_per_unit = inches_per_asf_unit * 2.54;
    let bvh_inches: f64 = args.get(5).map_or(1.0 / 2.54, |v| v.parse().unwrap());
    let (bfile, bmotion) = bvh::load(Path::new(&b), bvh_inches).unwrap();
    let cm_per_bvh_unit = bvh_inches * 2.54;
    let bs = &bfile.skeleton;
    println!("frames: amc {} bvh {}", motion.len(), bmotion.len());
    // Rest-pose bone lengths.
    for bone in s.bones().iter().skip(1) {
        if let Some(j) = find(bs, bone.name()) {
            // The BVH bone named like an ASF bone starts where the ASF bone starts.
            let bl = bs.bones()[j].length() as f64 * cm_per_bvh_unit;
            let al = bone.length() as f64 * cm_per_unit;
            if (bl - al).abs() > 0.05 {
                println!("length {:<10} asf {:7.3} cm  bvh {:7.3} cm", bone.name(), al, bl);
            }
        }
    }
    let mut c1 = [0.0f32; MAX_CHANNELS];
    let mut c2 = [0.0f32; MAX_CHANNELS];
    let (mut p1, mut p2) = (Pose::new(), Pose::new());
    let mut worst: Vec<(f64, String)> = Vec::new();
    let mut per_frame = vec![0.0f64; motion.len()];
    for f in 0..motion.len().min(bmotion.len() - skip) {
        motion.channels_into(s, f, &mut c1);
        bmotion.channels_into(bs, f + skip, &mut c2);
        forward_kinematics(s, &c1, &mut p1).unwrap();
        forward_kinematics(bs, &c2, &mut p2).unwrap();
        for (i, bone) in s.bones().iter().enumerate().skip(1) {
            if let Some(j) = find(bs, bone.name()) {
                let d = (p1.start[i].as_dvec3() * cm_per_unit - p2.start[j].as_dvec3() * cm_per_bvh_unit).length();
                per_frame[f] = per_frame[f].max(d);
                worst.push((d, format!("frame {} {} start", f + 1, bone.name())));
                if s.children(i).next().is_none() {
                    let d = (p1.tip[i].as_dvec3() * cm_per_unit - p2.tip[j].as_dvec3() * cm_per_bvh_unit).length();
                    worst.push((d, format!("frame {} {} tip", f + 1, bone.name())));
                }
            }
        }
    }
    let mut per_joint: std::collections::BTreeMap<String, (f64, usize)> = Default::default();
    for (d, n) in &worst {
        let joint = n.split_whitespace().nth(2).unwrap_or("").to_string() + " " + n.split_whitespace().nth(3).unwrap_or("");
        let e = per_joint.entry(joint).or_default();
        e.0 += d;
        e.1 += 1;
    }
    let mut pj: Vec<(f64, String)> = per_joint.into_iter().map(|(k, (s, n))| (s / n as f64, k)).collect();
    pj.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap());
    for (d, k) in pj.iter().take(6) {
        println!("mean over clip {k:<18} {d:6.3} cm");
    }
    let mut sorted = per_frame.clone();
    sorted.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let q = |p: f64| sorted[((sorted.len() - 1) as f64 * p) as usize];
    println!("per-frame worst joint: p50 {:.3} cm, p90 {:.3} cm, p99 {:.3} cm, max {:.3} cm", q(0.5), q(0.9), q(0.99), q(1.0));
    let bad: Vec<usize> = (0..per_frame.len()).filter(|&f| per_frame[f] > 1.0).map(|f| f + 1).collect();
    println!("frames with a joint > 1 cm off: {} {:?}", bad.len(), &bad[..bad.len().min(20)]);
    worst.sort_by(|a, b| b.0.partial_cmp(&a.0).unwrap());
    let mean = worst.iter().map(|w| w.0).sum::<f64>() / worst.len() as f64;
    println!("{} joint positions compared, mean {:.4} cm", worst.len(), mean);
    for (d, n) in worst.iter().take(8) {
        println!("{n:<24} {d:6.2} cm");
    }
}

/// CMU BVH conversions name joints either like the ASF bones or like this.
fn find(bs: &marionette::skeleton::Skeleton, asf_name: &str) -> Option<usize> {
    const MAP: &[(&str, &str)] = &[
        ("lhipjoint", "LHipJoint"), ("lfemur", "LeftUpLeg"), ("ltibia", "LeftLeg"), ("lfoot", "LeftFoot"),
        ("ltoes", "LeftToeBase"), ("rhipjoint", "RHipJoint"), ("rfemur", "RightUpLeg"), ("rtibia", "RightLeg"),
        ("rfoot", "RightFoot"), ("rtoes", "RightToeBase"), ("lowerback", "LowerBack"), ("upperback", "Spine"),
        ("thorax", "Spine1"), ("lowerneck", "Neck"), ("upperneck", "Neck1"), ("head", "Head"),
        ("lclavicle", "LeftShoulder"), ("lhumerus", "LeftArm"), ("lradius", "LeftForeArm"), ("lwrist", "LeftHand"),
        ("lhand", "LeftFingerBase"), ("lfingers", "LeftHandIndex1"), ("lthumb", "LThumb"),
        ("rclavicle", "RightShoulder"), ("rhumerus", "RightArm"), ("rradius", "RightForeArm"), ("rwrist", "RightHand"),
        ("rhand", "RightFingerBase"), ("rfingers", "RightHandIndex1"), ("rthumb", "RThumb"),
    ];
    bs.find(asf_name).or_else(|| MAP.iter().find(|(a, _)| *a == asf_name).and_then(|(_, b)| bs.find(b)))
}

//! How far a third-party BVH conversion of a CMU clip is from the AMC pose, joint by joint.
//!
//! `cargo run --release --example bvh_vs_amc -- [ASF AMC BVH [SKIP_FRAMES [INCHES_PER_BVH_UNIT]]]`
//!
//! Defaults: the bundled walk 16_15 and its BVH (centimetres). For 01_01 (ASF units, one extra
//! leading frame): `… data/cmu/01.asf data/cmu/01_01.amc data/cmu/01_01.bvh 1 2.2222222`.
//! Joints are matched by name (ASF names, or the Hips/LeftUpLeg/… names of other CMU
//! conversions); a BVH joint sits where the ASF bone of the same name starts.

use marionette::fk::{forward_kinematics, Pose};
use marionette::formats::{amc, asf, bvh};
use marionette::retarget::CMU_BVH_NAMES;
use marionette::skeleton::{Skeleton, MAX_CHANNELS};
use std::collections::BTreeMap;
use std::path::Path;

fn find(bvh_skeleton: &Skeleton, asf_name: &str) -> Option<usize> {
    bvh_skeleton.find(asf_name).or_else(|| {
        let (_, other) = CMU_BVH_NAMES.iter().find(|(a, _)| *a == asf_name)?;
        bvh_skeleton.find(other)
    })
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.to_string());
    let asf_path = arg(0, "data/cmu/16.asf");
    let amc_path = arg(1, "data/cmu/16_15.amc");
    let bvh_path = arg(2, "data/cmu/16_15.bvh");
    let skip: usize = arg(3, "0").parse()?;
    let bvh_inches: f64 = arg(4, &(1.0 / 2.54).to_string()).parse()?;

    let file = asf::load(Path::new(&asf_path))?;
    let s = &file.skeleton;
    let motion = amc::load(s, Path::new(&amc_path))?;
    let (bfile, bmotion) = bvh::load(Path::new(&bvh_path), bvh_inches)?;
    let bs = &bfile.skeleton;
    let cm_asf = f64::from(s.units().meters_per_unit()) * 100.0;
    let cm_bvh = bvh_inches * 2.54;
    println!(
        "frames: AMC {}, BVH {} (skipping {skip})",
        motion.len(),
        bmotion.len()
    );

    let pairs: Vec<(usize, usize)> = (1..s.len())
        .filter_map(|i| find(bs, s.bones()[i].name()).map(|j| (i, j)))
        .collect();
    println!("{} of {} ASF bones have a BVH joint", pairs.len(), s.len() - 1);
    for &(i, j) in &pairs {
        let (a, b) = (
            f64::from(s.bones()[i].length()) * cm_asf,
            f64::from(bs.bones()[j].length()) * cm_bvh,
        );
        if (a - b).abs() > 0.05 {
            println!(
                "  length of {:<10} ASF {a:7.3} cm, BVH {b:7.3} cm",
                s.bones()[i].name()
            );
        }
    }

    let (mut c1, mut c2) = ([0.0f32; MAX_CHANNELS], [0.0f32; MAX_CHANNELS]);
    let (mut p1, mut p2) = (Pose::new(), Pose::new());
    let mut per_frame = Vec::new();
    let mut per_joint: BTreeMap<&str, f64> = BTreeMap::new();
    let frames = motion.len().min(bmotion.len().saturating_sub(skip));
    for f in 0..frames {
        motion.channels_into(s, f, &mut c1);
        bmotion.channels_into(bs, f + skip, &mut c2);
        forward_kinematics(s, &c1, &mut p1)?;
        forward_kinematics(bs, &c2, &mut p2)?;
        let mut worst = 0.0f64;
        for &(i, j) in &pairs {
            let d = (p1.start[i].as_dvec3() * cm_asf - p2.start[j].as_dvec3() * cm_bvh).length();
            worst = worst.max(d);
            *per_joint.entry(s.bones()[i].name()).or_default() += d / frames as f64;
        }
        per_frame.push(worst);
    }
    let mut sorted = per_frame.clone();
    sorted.sort_by(f64::total_cmp);
    let q = |p: f64| sorted[((sorted.len() - 1) as f64 * p) as usize];
    println!(
        "worst joint per frame: p50 {:.3} cm, p90 {:.3} cm, p99 {:.3} cm, max {:.3} cm",
        q(0.5),
        q(0.9),
        q(0.99),
        q(1.0)
    );
    let bad: Vec<usize> = (0..per_frame.len())
        .filter(|&f| per_frame[f] > 1.0)
        .map(|f| f + 1)
        .collect();
    println!(
        "frames with a joint more than 1 cm off: {} {:?}",
        bad.len(),
        &bad[..bad.len().min(24)]
    );
    let mut joints: Vec<(&str, f64)> = per_joint.into_iter().collect();
    joints.sort_by(|a, b| b.1.total_cmp(&a.1));
    for (name, mean) in joints.iter().take(6) {
        println!("  mean distance of {name:<10} {mean:6.3} cm");
    }
    Ok(())
}

//! Walking on the robot's own feet: a clip's footsteps within the OP3's reach and speed, the
//! centre of mass from the ZMP preview, the legs on that plan, and `retarget --walk`.

mod common;

use std::path::{Path, PathBuf};
use std::process::Stdio;

use marionette::footstep::contact;
use marionette::formats::{amc, asf};
use marionette::motion::Motion;
use marionette::profile::Profile;
use marionette::retarget::walk::{self, retarget_walking, WalkPlan};
use marionette::retarget::{ClipRetarget, Options, Setup};
use marionette::skeleton::Skeleton;

fn repo(p: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(p)
}

fn walk_of(asf_name: &str, amc_name: &str) -> (Setup, ClipRetarget, WalkPlan) {
    let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
    let s: Skeleton = asf::load(&common::data(asf_name)).unwrap().skeleton;
    let mut m: Motion = amc::load(&s, &common::data(amc_name)).unwrap();
    // As `retarget --walk` and `play --walk` take it: dropouts filled, the last frame held.
    marionette::motion::dropouts::repair(&s, &mut m);
    let m = marionette::retarget::walk::settled(&m);
    let setup = Setup::new(&profile, &s).unwrap();
    let (walked, plan) = retarget_walking(&setup, &s, &m, Options::default()).unwrap();
    (setup, walked, plan)
}

/// Every step lands within the limits of the stance foot it is planned from, after a swing the
/// servos can make; some foot is always on the floor.
fn assert_feasible(plan: &WalkPlan) {
    let l = plan.limits;
    let steps = &plan.footsteps;
    for (k, s) in steps.iter().enumerate().skip(2) {
        let other = 1 - s.side;
        let stance = contact(steps, other, s.land_s)
            .unwrap_or_else(|| panic!("step {k}: no stance foot at {}", s.land_s));
        let (rel, turn) = stance.at.relative(&s.at);
        let sign = if s.side == 0 { 1.0 } else { -1.0 };
        let e = 1e-9;
        assert!(
            rel.x <= l.forward + e && rel.x >= -l.backward - e,
            "step {k}: {rel}"
        );
        assert!(
            rel.y * sign >= l.width_min - e && rel.y * sign <= l.width_max + e,
            "step {k}: {rel}"
        );
        assert!(turn.abs() <= l.turn + e, "step {k}: turn {turn}");
        let before = steps[..k].iter().rev().find(|p| p.side == s.side).unwrap();
        let swing = s.land_s - before.lift_s;
        assert!(swing >= l.swing_min_s - e, "step {k}: swing {swing} s");
        let distance = (s.at.centre - before.at.centre).length();
        assert!(
            distance <= (swing - l.swing_min_s) * l.foot_speed + 1e-4,
            "step {k}: {distance} m in {swing} s"
        );
        let stood = s.land_s - stance.land_s;
        assert!(stood >= 0.0);
    }
    for p in &plan.samples {
        assert!(p.stance.contact.iter().any(|c| *c), "no foot down at {}", p.t);
    }
}

#[test]
fn the_bundled_walk_becomes_steps_the_op3_can_take_with_the_zmp_inside_its_feet() {
    let (setup, walked, plan) = walk_of("16.asf", "16_15.amc");
    let report = plan.report();
    println!(
        "16_15: {} steps, {} substituted, {} left out; travel {:.3} m planned, {:.3} m in the clip; ZMP margin {:.1} mm, tracking {:.1} mm",
        report.footsteps, report.substituted_steps, report.dropped_steps, report.planned_travel_m, report.clip_travel_m,
        report.zmp_margin_mm.planned_min, report.zmp_tracking_max_mm
    );
    assert!(report.footsteps >= 6, "{report:?}");
    // Left and right in turn after the starting stance.
    for w in plan.footsteps[2..].windows(2) {
        assert_ne!(w[0].side, w[1].side);
    }
    assert_feasible(&plan);
    assert!(report.zmp_margin_mm.planned_min >= 25.0, "{report:?}");
    assert!(report.zmp_tracking_max_mm <= 10.0, "{report:?}");
    assert!(report.planned_travel_m >= 0.4, "{report:?}");
    assert_eq!(plan.samples.len(), walked.frames.len());

    // The legs on the plan: soles on their footprints while down, lifted clear in a swing,
    // never below the floor; the robot's centre of mass over the planned one.
    let clearance = setup
        .retargeter(&walk_skeleton(), walked.floor, Options::default())
        .swing_clearance();
    let mut highest = [0.0f64; 2];
    let mut com_sq = 0.0;
    for (f, p) in walked.frames.iter().zip(&plan.samples) {
        for (side, high) in highest.iter_mut().enumerate() {
            let (print, _) = p.stance.soles[side];
            if p.stance.contact[side] {
                let miss = (f.sole[side].truncate() - print.centre).length();
                assert!(
                    miss < 1e-3 && f.sole[side].z.abs() < 1e-6,
                    "at {}: sole {} off by {miss}",
                    p.t,
                    side
                );
            } else {
                *high = high.max(f.sole[side].z);
            }
        }
        assert!(f.lowest_sole >= -1e-9, "at {}: {}", p.t, f.lowest_sole);
        com_sq += (f.com.truncate() - p.stance.com).length_squared();
    }
    let com_rms = (com_sq / walked.frames.len() as f64).sqrt();
    println!(
        "swing heights {highest:?} (clearance {clearance:.3}), centre of mass off the plan by {:.2} mm RMS",
        com_rms * 1e3
    );
    assert!(highest.iter().all(|h| *h >= 0.9 * clearance), "{highest:?}");
    assert!(com_rms < 2e-3, "{com_rms}");

    // Every joint, the legs' too, within its servo's speed: the swings that would ask the knee
    // for more are lifted lower, none below the lowest share, and the report says which.
    assert_eq!(
        walked.report.continuity.steps_over_velocity_limit,
        Some(0),
        "{:?}",
        walked.report.continuity
    );
    let pace = &plan.pace;
    let lowered = pace.clearance.iter().filter(|s| s.1 < 1.0).count();
    assert!(lowered >= 1 && lowered == report.lowered_swings, "{pace:?}");
    assert!(pace.clearance.iter().all(|s| s.1 >= walk::MIN_CLEARANCE_SHARE));
    assert!(pace.speed.iter().all(|s| s.1 >= walk::MIN_FOOT_SPEED_SHARE));
    let lowest = report.lowest_clearance_mm;
    assert!(lowest >= 1e3 * clearance * walk::MIN_CLEARANCE_SHARE - 1e-9 && lowest < report.clearance_mm);
    let ratios = walk::swing_speed_ratios(&setup, &plan, &walked.frames);
    assert!(ratios.len() >= report.footsteps - 1, "{ratios:?}");
    assert!(ratios.iter().all(|r| r.1 <= 1.0), "{ratios:?}");
    // Each paced swing is one the plan has, by its landing.
    for (land, _) in pace.clearance.iter().chain(&pace.speed) {
        assert!(plan.footsteps.iter().any(|s| s.land_s == *land), "{land}");
    }

    // The same clip plans the same way twice.
    let (_, again, plan2) = walk_of("16.asf", "16_15.amc");
    assert_eq!(plan.footsteps, plan2.footsteps);
    assert!(walked.frames.iter().zip(&again.frames).all(|(a, b)| a.q == b.q));
}

fn walk_skeleton() -> Skeleton {
    asf::load(&common::data("16.asf")).unwrap().skeleton
}

#[test]
fn a_jumping_clip_is_planned_without_a_flight() {
    let (_, _, plan) = walk_of("01.asf", "01_01.amc");
    let report = plan.report();
    println!(
        "01_01: {} steps, {} substituted, {} left out; ZMP margin {:.1} mm",
        report.footsteps, report.substituted_steps, report.dropped_steps, report.zmp_margin_mm.planned_min
    );
    assert_feasible(&plan);
    assert!(report.substituted_steps + report.dropped_steps > 0, "{report:?}");
    assert!(report.zmp_margin_mm.planned_min >= 10.0, "{report:?}");
    let changed: Vec<_> = report
        .footstep_list
        .iter()
        .filter(|s| !s.changed.is_empty())
        .collect();
    assert!(!changed.is_empty());
}

#[test]
fn retarget_walk_writes_the_plan_in_its_report_csv_and_picture() {
    let dir = common::tempdir("retarget-walk");
    let (csv, plan, report, plot) = (
        dir.join("q.csv"),
        dir.join("plan.csv"),
        dir.join("report.json"),
        dir.join("walk.png"),
    );
    let out = common::bin()
        .arg("retarget")
        .arg(repo("firmware-profile/robotis-op3.toml"))
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .arg("--walk")
        .arg("-o")
        .arg(&csv)
        .arg("--plan")
        .arg(&plan)
        .arg("--report")
        .arg(&report)
        .arg("--plot")
        .arg(&plot)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.contains("walk: ") && text.contains("planned ZMP:") && text.contains("step limits:"),
        "{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    let w = &json["walk"];
    for key in [
        "footsteps",
        "substituted_steps",
        "dropped_steps",
        "planned_travel_m",
        "clip_travel_m",
        "footstep_plan",
        "limits",
    ] {
        assert!(!w[key].is_null(), "no {key} in {w}");
    }
    assert!(w["zmp_margin_mm"]["planned_min"].as_f64().unwrap() > 0.0);
    assert_eq!(
        w["footstep_plan"].as_array().unwrap().len(),
        w["footsteps"].as_u64().unwrap() as usize + 2
    );
    let rows = std::fs::read_to_string(&plan).unwrap();
    let mut lines = rows.lines();
    assert!(lines
        .next()
        .unwrap()
        .starts_with("time,left_down,right_down,zmp_ref_x"));
    assert_eq!(lines.count(), json["frames"].as_u64().unwrap() as usize);
    assert!(std::fs::metadata(&plot).unwrap().len() > 10_000);

    // A plan needs the legs: refused with --upper-body, and --plan alone is refused.
    for extra in [&["--walk", "--upper-body"][..], &["--plan", "x.csv"][..]] {
        let out = common::bin()
            .arg("retarget")
            .arg(repo("firmware-profile/robotis-op3.toml"))
            .arg(common::data("16.asf"))
            .arg(common::data("16_15.amc"))
            .arg("-o")
            .arg(&csv)
            .args(extra)
            .stdin(Stdio::null())
            .output()
            .unwrap();
        assert_eq!(out.status.code(), Some(2), "{extra:?}");
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `play --walk` of the OP3 on the bundled walk with `extra`: its output and stats JSON.
fn play_walk(extra: &[&str]) -> (String, serde_json::Value) {
    let dir = common::tempdir("walk-play");
    let stats = dir.join("stats.json");
    let out = common::bin()
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(["play", "firmware-profile/robotis-op3.toml"])
        .arg(common::data("16.asf"))
        .arg(common::data("16_15.amc"))
        .args(["--walk", "--stats-json"])
        .arg(&stats)
        .args(extra)
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v = serde_json::from_str(&std::fs::read_to_string(&stats).unwrap()).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (text, v)
}

#[test]
fn play_walks_the_op3_on_its_plan_on_the_virtual_chain_without_allocating() {
    let (text, v) = play_walk(&["--rate", "250", "--imu", "feedback"]);
    assert!(text.contains("walking on a plan: "), "{text}");
    assert_eq!(v["allocations_in_tick"].as_u64(), Some(0), "{v}");
    assert_eq!(v["commands_refused"].as_u64(), Some(0));
    let r = &v["retarget"];
    // The plan's frames played between each other (joints interpolated): a planted sole
    // moves by micrometres at most.
    assert!(r["foot_slide_mm"]["max"].as_f64().unwrap() < 0.05, "{r}");
    assert!(r["walk"]["footsteps"].as_u64().unwrap() >= 6, "{r}");
    assert!(
        r["walk"]["zmp_margin_mm"]["planned_min"].as_f64().unwrap() > 25.0,
        "{r}"
    );
}

#[test]
fn walking_reads_the_op3s_imu_board_every_tick_when_asked_without_allocating() {
    for mode in ["off", "read", "feedback"] {
        let feedback = mode == "feedback";
        let (text, v) = play_walk(&["--rate", "125", "--imu", mode]);
        assert_eq!(v["allocations_in_tick"].as_u64(), Some(0), "{v}");
        let imu = &v["imu"];
        if mode == "off" {
            // Open loop: the board is not read (a transaction a tick saved).
            assert!(text.contains("IMU board at id 200: not read"), "{text}");
            assert!(imu.is_null(), "{imu}");
            continue;
        }
        assert!(text.contains("IMU board at id 200: read every tick"), "{text}");
        assert_eq!(imu["board_id"].as_u64(), Some(200), "{imu}");
        assert_eq!(imu["feedback"].as_bool(), Some(feedback), "{imu}");
        // In the servos' position read (a Bulk Read, the board's block last).
        assert_eq!(imu["merged"].as_bool(), Some(true), "{imu}");
        // One good read a tick (the virtual board: level and still), but on the ticks whose
        // read slot is the health watch's.
        assert_eq!(imu["reads_failed"].as_u64(), Some(0), "{imu}");
        let health_slots = v["health"]["reads"].as_u64().unwrap();
        assert!(
            imu["reads_ok"].as_u64().unwrap() + health_slots + 1 >= v["ticks"].as_u64().unwrap(),
            "{imu} {}",
            v["ticks"]
        );
        assert!(imu["max_tilt_deg"].as_f64().unwrap() < 0.1, "{imu}");
    }
}

/// The walk planned as a stream: with a look-ahead window of the preview (1.6 s) and a little
/// more the centre of mass is the offline plan's; shorter windows drift from it, and the
/// window a live input needs is the one that keeps it within a millimetre.
#[test]
fn a_streamed_plan_with_two_seconds_of_window_is_the_offline_plan() {
    use marionette::retarget::walk::streamed_com;
    let profile = Profile::load(&repo("firmware-profile/robotis-op3.toml")).unwrap();
    let s: Skeleton = asf::load(&common::data("16.asf")).unwrap().skeleton;
    let mut m: Motion = amc::load(&s, &common::data("16_15.amc")).unwrap();
    marionette::motion::dropouts::repair(&s, &mut m);
    let m = marionette::retarget::walk::settled(&m);
    let setup = Setup::new(&profile, &s).unwrap();
    let kinematic = marionette::retarget::retarget_clip(&setup, &s, &m, Options::default());
    let retargeter = setup.retargeter(&s, kinematic.floor, Options::default());
    let plan = marionette::retarget::walk::plan_walk(
        &setup,
        &retargeter,
        &kinematic,
        f64::INFINITY,
        &walk::SwingPace::default(),
    )
    .unwrap();
    let mut deviation = Vec::new();
    for window in [3.0, 2.0, 1.6, 1.0, 0.5] {
        let com = streamed_com(&setup, &retargeter, &kinematic, &plan, window).unwrap();
        assert_eq!(com.len(), plan.samples.len());
        let worst = com
            .iter()
            .zip(&plan.samples)
            .map(|(c, p)| (*c - p.stance.com).length() * 1000.0)
            .fold(0.0, f64::max);
        println!("window {window} s: the centre of mass at most {worst:.4} mm from the offline plan's");
        deviation.push(worst);
    }
    assert!(deviation[0] < 1e-6, "{deviation:?}");
    assert!(deviation[1] < 0.01, "{deviation:?}");
    assert!(deviation[3] < 2.0, "{deviation:?}");
    assert!(deviation[4] > deviation[3], "{deviation:?}");
}

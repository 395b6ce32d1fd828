//! The picture of a retargeting run: the human (scaled to the robot) and the robot side by side
//! at a few frames, seen from the front and to one side, above the direction-error curves per
//! limb and the centre of mass's margin inside the support polygon.

use glam::DVec3;
use plotters::prelude::*;

use super::{ClipRetarget, Setup};
use crate::fk::{fk64, Pose64};
use crate::motion::{frame_to_radians, Motion};
use crate::plot::{Area, Picture, Rendered};
use crate::robot::RobotPose;
use crate::skeleton::Skeleton;

/// What to draw.
pub struct RetargetPicture<'a> {
    /// Title.
    pub title: String,
    /// The human skeleton and clip.
    pub skeleton: &'a Skeleton,
    /// The clip.
    pub motion: &'a Motion,
    /// The robot and map.
    pub setup: &'a Setup,
    /// The run.
    pub run: &'a ClipRetarget,
    /// The walking plan the legs followed, drawn from above.
    pub plan: Option<&'a super::walk::WalkPlan>,
}

impl Picture for RetargetPicture<'_> {
    fn render<DB: DrawingBackend<ErrorType: 'static>>(&self, area: &Area<DB>) -> Rendered {
        render(self, area)
    }
}

/// Screen coordinates of a world point seen from the front, turned 30° to the robot's left.
fn view(p: DVec3) -> (f64, f64) {
    let phi = 30f64.to_radians();
    let right = DVec3::new(-phi.sin(), phi.cos(), 0.0);
    (p.dot(right), p.z)
}

type Segments = Vec<(DVec3, DVec3)>;

/// A labelled, coloured curve.
type Curve = (&'static str, RGBColor, Vec<(f64, f64)>);

/// Stick figures of frame `i`: the human (in the robot's world, at the robot's scale) and the
/// robot.
fn figures(pic: &RetargetPicture<'_>, r: &super::Retargeter, i: usize) -> (Segments, Segments) {
    let setup = pic.setup;
    let mut pose = Pose64::default();
    fk64(
        pic.skeleton,
        &frame_to_radians(pic.skeleton, pic.motion.frame(i)),
        &mut pose,
    );
    let human = (0..pic.skeleton.len())
        .filter(|&b| pic.skeleton.bones()[b].parent().is_some())
        .map(|b| {
            (
                r.human_point_in_world(pose.start[b]),
                r.human_point_in_world(pose.tip[b]),
            )
        })
        .collect();
    let f = &pic.run.frames[i];
    let mut rp = RobotPose::default();
    let (p, q) = r.model_placement(f.base_pos, f.base_rot);
    setup.robot.forward(p, q, &f.q, &mut rp);
    let mut robot: Segments = setup
        .robot
        .bodies()
        .iter()
        .enumerate()
        .filter_map(|(k, b)| b.parent.map(|parent| (rp.pos[parent], rp.pos[k])))
        .collect();
    for arm in setup.map.arms.iter().flatten() {
        let b = setup.robot.joints()[arm.joints[2]].body;
        robot.push((rp.pos[b], rp.pos[b] + rp.rot[b] * arm.tip));
    }
    for leg in &setup.map.legs {
        let b = setup.robot.joints()[leg.joints[5]].body;
        let [hx, hy] = leg.sole_half;
        let c: Vec<DVec3> = [(1.0, 1.0), (1.0, -1.0), (-1.0, -1.0), (-1.0, 1.0)]
            .iter()
            .map(|(a, s)| rp.pos[b] + rp.rot[b] * (leg.sole_centre + DVec3::new(a * hx, s * hy, 0.0)))
            .collect();
        for k in 0..4 {
            robot.push((c[k], c[(k + 1) % 4]));
        }
    }
    (human, robot)
}

fn render<DB: DrawingBackend<ErrorType: 'static>>(pic: &RetargetPicture<'_>, root: &Area<DB>) -> Rendered {
    root.fill(&WHITE)?;
    let root = root.titled(&pic.title, ("sans-serif", 22))?;
    let (top, bottom) = root.split_vertically(480);
    let n = pic.run.frames.len();
    // The run's retargeter, for the human's points in the robot's world.
    let r = pic
        .setup
        .retargeter(pic.skeleton, pic.run.floor, super::Options::default());
    let shown: Vec<usize> = (0..3).map(|k| (k * n.saturating_sub(1)) / 2).collect();
    let panels = top.split_evenly((1, shown.len()));
    for (panel, &i) in panels.iter().zip(&shown) {
        let (human, robot) = figures(pic, &r, i);
        // Side by side: the human to the left of the robot, each centred on its own pelvis
        // (a robot walking on a plan takes steps of its own size).
        let centre = view(pic.run.frames[i].base_pos).0;
        let human_centre = human.first().map_or(centre, |(a, _)| view(*a).0);
        let width = 0.31;
        let shift = |p: DVec3, dx: f64| {
            let (x, y) = view(p);
            (x - if dx < 0.0 { human_centre } else { centre } + dx, y)
        };
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!("frame {i} ({:.2} s)", pic.run.times[i]),
                ("sans-serif", 15),
            )
            .margin(6)
            .build_cartesian_2d(-width..width, -0.03..0.55)?;
        chart.draw_series(std::iter::once(PathElement::new(
            vec![(-width, 0.0), (width, 0.0)],
            RGBColor(160, 160, 160).stroke_width(1),
        )))?;
        chart.draw_series(human.iter().map(|(a, b)| {
            PathElement::new(
                vec![shift(*a, -0.15), shift(*b, -0.15)],
                RGBColor(40, 90, 200).stroke_width(3),
            )
        }))?;
        chart.draw_series(robot.iter().map(|(a, b)| {
            PathElement::new(
                vec![shift(*a, 0.15), shift(*b, 0.15)],
                RGBColor(210, 90, 30).stroke_width(3),
            )
        }))?;
        let f = &pic.run.frames[i];
        // Where the human's hands are, placed on the robot at its arm scale: the hands' targets.
        chart.draw_series(
            f.hand_target
                .iter()
                .filter(|t| t.is_finite())
                .map(|t| Circle::new(shift(*t, 0.15), 5, RGBColor(40, 90, 200).stroke_width(2))),
        )?;
        let com = shift(DVec3::new(f.com.x, f.com.y, 0.0), 0.15);
        chart.draw_series(std::iter::once(Circle::new(com, 4, BLACK.filled())))?;
        chart.draw_series(std::iter::once(Text::new(
            format!(
                "{}{}",
                if f.planted[0] { "L" } else { "·" },
                if f.planted[1] { "R" } else { "·" }
            ),
            (0.11, 0.52),
            ("sans-serif", 13),
        )))?;
    }

    let (left, right) = bottom.split_horizontally(760);
    let times = &pic.run.times;
    let t1 = times.last().copied().unwrap_or(1.0).max(1e-3);
    let curves: Vec<Curve> = super::LIMBS
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let colour = [
                RGBColor(40, 90, 200),
                RGBColor(120, 170, 240),
                RGBColor(200, 60, 40),
                RGBColor(240, 150, 110),
                RGBColor(60, 150, 60),
            ][k];
            let pts = pic
                .run
                .frames
                .iter()
                .zip(times)
                .filter(|(f, _)| f.limb_error_sq[k].1 > 0)
                .map(|(f, t)| {
                    (
                        *t,
                        (f.limb_error_sq[k].0 / f64::from(f.limb_error_sq[k].1)).sqrt(),
                    )
                })
                .collect();
            (*name, colour, pts)
        })
        .collect();
    let ymax = curves
        .iter()
        .flat_map(|c| c.2.iter().map(|p| p.1))
        .fold(5.0f64, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(&left)
        .caption(
            "direction error per limb (RMS over its segments, deg)",
            ("sans-serif", 16),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..t1, 0.0..ymax)?;
    chart.configure_mesh().x_desc("time (s)").y_desc("deg").draw()?;
    for (name, colour, pts) in curves {
        if pts.is_empty() {
            continue;
        }
        chart
            .draw_series(LineSeries::new(pts, colour.stroke_width(2)))?
            .label(name.replace('_', " "))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;

    if let Some(plan) = pic.plan {
        return draw_plan(plan, &right);
    }
    let margins: Vec<(f64, f64)> = pic
        .run
        .frames
        .iter()
        .zip(times)
        .filter(|(f, _)| f.com_margin.is_finite())
        .map(|(f, t)| (*t, f.com_margin * 1000.0))
        .collect();
    let (lo, hi) = margins
        .iter()
        .fold((0.0f64, 10.0f64), |(a, b), p| (a.min(p.1), b.max(p.1)));
    let mut chart = ChartBuilder::on(&right)
        .caption(
            "centre of mass inside the support polygon (mm)",
            ("sans-serif", 16),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d(0.0..t1, (lo - 5.0)..(hi * 1.1))?;
    chart.configure_mesh().x_desc("time (s)").y_desc("mm").draw()?;
    chart.draw_series(LineSeries::new(
        vec![(0.0, 0.0), (t1, 0.0)],
        RGBColor(200, 0, 0).stroke_width(1),
    ))?;
    chart.draw_series(
        margins
            .iter()
            .map(|p| Circle::new(*p, 1, RGBColor(60, 60, 60).filled())),
    )?;
    Ok(())
}

/// The walking plan from above: the clip's footprints (grey), the plan's (orange; red when
/// substituted), the ZMP reference, the planned ZMP and the planned centre of mass.
fn draw_plan<DB: DrawingBackend<ErrorType: 'static>>(
    plan: &super::walk::WalkPlan,
    area: &Area<DB>,
) -> Rendered {
    let prints = |f: &marionette_core::footstep::Footstep, clip: bool| {
        let p = if clip { f.clip } else { f.at };
        p.corners(plan.sole_half[f.side]).map(|c| (c.x, c.y)).to_vec()
    };
    let mut pts: Vec<(f64, f64)> = plan
        .footsteps
        .iter()
        .flat_map(|f| prints(f, true).into_iter().chain(prints(f, false)))
        .collect();
    pts.extend(plan.samples.iter().map(|s| (s.stance.com.x, s.stance.com.y)));
    let (x0, x1, y0, y1) = pts.iter().fold(
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY),
        |(a, b, c, d), p| (a.min(p.0), b.max(p.0), c.min(p.1), d.max(p.1)),
    );
    if !(x0.is_finite() && y0.is_finite()) {
        return Ok(());
    }
    // Equal scales on both axes: the span that fills the panel's shape.
    let (w, h) = area.dim_in_pixel();
    let aspect = f64::from(w.saturating_sub(70).max(1)) / f64::from(h.saturating_sub(80).max(1));
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let half_y = (0.5 * (y1 - y0) + 0.02).max(0.5 * (x1 - x0 + 0.04) / aspect);
    let half_x = half_y * aspect;
    let mut chart = ChartBuilder::on(area)
        .caption(
            "the plan from above: footprints, ZMP and centre of mass (m)",
            ("sans-serif", 16),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d((cx - half_x)..(cx + half_x), (cy - half_y)..(cy + half_y))?;
    chart.configure_mesh().x_desc("x (m)").y_desc("y (m)").draw()?;
    let grey = RGBColor(170, 170, 170);
    for f in &plan.footsteps {
        let mut clip = prints(f, true);
        clip.push(clip[0]);
        chart.draw_series(std::iter::once(PathElement::new(clip, grey.stroke_width(1))))?;
    }
    for f in &plan.footsteps {
        let colour = if f.changed.any() {
            RGBColor(200, 30, 30)
        } else {
            RGBColor(230, 130, 40)
        };
        let mut at = prints(f, false);
        at.push(at[0]);
        chart.draw_series(std::iter::once(PathElement::new(at, colour.stroke_width(2))))?;
    }
    type Path = fn(&super::walk::PlanSample) -> (f64, f64);
    let paths: [(&str, RGBColor, u32, Path); 3] = [
        ("ZMP reference", RGBColor(120, 120, 220), 1, |s| {
            (s.zmp_ref.x, s.zmp_ref.y)
        }),
        ("planned ZMP", RGBColor(200, 0, 0), 2, |s| (s.zmp.x, s.zmp.y)),
        ("planned centre of mass", BLACK, 2, |s| {
            (s.stance.com.x, s.stance.com.y)
        }),
    ];
    for (label, colour, width, get) in paths {
        chart
            .draw_series(LineSeries::new(
                plan.samples.iter().map(get),
                colour.stroke_width(width),
            ))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

//! How well simulated servos followed their commands: per-servo RMS, maximum and lag of the
//! angle error, end-effector position error, torque saturation, and pictures of them.

use plotters::prelude::*;
use serde::Serialize;

use super::footsteps::{footstep_error, FootstepError};
use super::plant::{Sample, Torso};
use crate::plot::{Area, Picture, Rendered};
use crate::retarget::walk::WalkReport;

/// Longest lag searched, seconds.
const MAX_LAG_S: f64 = 0.3;

/// One servo's tracking.
#[derive(Clone, Debug, Serialize)]
pub struct ServoTracking {
    /// Servo name.
    pub name: String,
    /// RMS of simulated − commanded angle, degrees.
    pub rms_deg: f64,
    /// Largest |simulated − commanded|, degrees.
    pub max_deg: f64,
    /// The delay that best aligns the simulated angle with the commanded one, ms.
    pub lag_ms: f64,
    /// RMS once that delay is taken out, degrees.
    pub rms_after_lag_deg: f64,
    /// Range of the commanded angle over the run, degrees.
    pub commanded_range_deg: f64,
    /// Physics steps at the torque limit.
    pub saturated_steps: u64,
    /// End to end, from the loop: RMS of the present position against the source angle (the
    /// input mapped through the rig), degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_rms_deg: Option<f64>,
    /// The lag of the present position behind the source that aligns them best, ms.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source_lag_ms: Option<f64>,
}

/// One effector site's position error.
#[derive(Clone, Debug, Serialize)]
pub struct EffectorTracking {
    /// Site name.
    pub name: String,
    /// RMS distance between the simulated site and the site at the commanded angles, mm.
    pub rms_mm: f64,
    /// Largest such distance, mm.
    pub max_mm: f64,
}

/// The whole run's tracking.
#[derive(Clone, Debug, Serialize)]
pub struct TrackingReport {
    /// Samples analysed (1 kHz of simulated time, while torque was on).
    pub samples: usize,
    /// Simulated seconds.
    pub duration_s: f64,
    /// Physics steps.
    pub physics_steps: u64,
    /// RMS over all servos and samples, degrees.
    pub rms_deg: f64,
    /// Largest error of any servo, degrees.
    pub max_deg: f64,
    /// Physics steps × servos at the torque limit, over all servos.
    pub saturated_steps: u64,
    /// Of those, the ones in the first second of the run (the move to the first pose).
    pub saturated_steps_first_s: u64,
    /// Per servo.
    pub servos: Vec<ServoTracking>,
    /// Per effector site.
    pub effectors: Vec<EffectorTracking>,
    /// A floating base's lowest height, metres (absent for a fixed base).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub torso_min_height_m: Option<f64>,
    /// A floating base's largest tilt from upright, degrees.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub torso_max_tilt_deg: Option<f64>,
    /// Whether the robot fell: its torso below [`FELL_HEIGHT`] of the height it started at, or
    /// tilted past [`FELL_TILT_DEG`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fell: Option<bool>,
    /// When it first counted as fallen, seconds from the first sample.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fell_at_s: Option<f64>,
    /// Horizontal distance of a floating base from where it started to where it ended, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub torso_travel_m: Option<f64>,
    /// The measured ZMP (the floor forces' centre of pressure) inside the hull of the floor
    /// contacts: the smallest margin before the fall, mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub zmp_margin_mm: Option<MeasuredMargin>,
    /// A walk: the plan's footsteps (the starting feet not counted).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub footsteps: Option<usize>,
    /// A walk: the plan's steps changed from the clip's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub substituted_steps: Option<u32>,
    /// A walk: how far the plan moves the centre of mass, metres.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub planned_travel_m: Option<f64>,
    /// A walk: where each foot landed against its planned footprint
    /// ([`super::footsteps::footstep_error`]), up to a fall.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub footstep_error_mm: Option<FootstepError>,
}

/// The smallest margins of the ZMP inside the support polygon.
#[derive(Clone, Copy, Debug, Default, Serialize, PartialEq)]
pub struct MeasuredMargin {
    /// Measured: over the samples with at least three floor contacts, up to a fall, mm.
    pub measured_min: f64,
    /// A walk: the plan's (the cart-table's ZMP in the planned feet), mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub planned_min: Option<f64>,
}

/// Writes a floating base's samples as CSV: time, torso position and tilt, centre of mass,
/// centre of pressure and its margin, floor force.
///
/// # Errors
/// Writing failed.
pub fn write_trace(mut w: impl std::io::Write, samples: &[Sample]) -> std::io::Result<()> {
    writeln!(
        w,
        "time,torso_x,torso_y,torso_z,tilt_deg,com_x,com_y,com_z,cop_x,cop_y,cop_margin,floor_force"
    )?;
    for s in samples {
        let Some(t) = s.torso else { continue };
        let [cx, cy] = t.pressure_centre.unwrap_or([f64::NAN; 2]);
        writeln!(
            w,
            "{:.4},{:.5},{:.5},{:.5},{:.2},{:.5},{:.5},{:.5},{:.5},{:.5},{:.5},{:.2}",
            s.time,
            t.pos[0],
            t.pos[1],
            t.pos[2],
            t.tilt_deg,
            t.com[0],
            t.com[1],
            t.com[2],
            cx,
            cy,
            t.pressure_margin.unwrap_or(f64::NAN),
            t.floor_force
        )?;
    }
    Ok(())
}

/// A floating base lower than this share of its starting height has fallen.
pub const FELL_HEIGHT: f64 = 0.6;

/// A floating base tilted further than this (degrees) has fallen.
pub const FELL_TILT_DEG: f64 = 45.0;

impl TrackingReport {
    /// Adds a walk's figures: its plan's, and where the feet landed — `soles` the left and
    /// right sole sites' indices in `samples`' site positions.
    pub fn add_walk(&mut self, walk: &WalkReport, samples: &[Sample], soles: Option<[usize; 2]>) {
        self.footsteps = Some(walk.footsteps);
        self.substituted_steps = Some(walk.substituted_steps);
        self.planned_travel_m = Some(walk.planned_travel_m);
        let planned_min = Some(walk.zmp_margin_mm.planned_min);
        match &mut self.zmp_margin_mm {
            Some(m) => m.planned_min = planned_min,
            None => {
                self.zmp_margin_mm = Some(MeasuredMargin {
                    measured_min: f64::NAN,
                    planned_min,
                });
            }
        }
        let Some(soles) = soles else { return };
        let t0 = samples.iter().find(|s| s.torso.is_some()).map_or(0.0, |s| s.time);
        let until = self.fell_at_s.map_or(f64::INFINITY, |f| t0 + f);
        let tracks = soles.map(|site| {
            samples
                .iter()
                .filter_map(|s| s.site_pos.get(site).map(|p| (s.time, *p)))
                .collect::<Vec<_>>()
        });
        self.footstep_error_mm = footstep_error([&tracks[0], &tracks[1]], &walk.footstep_list, until);
    }

    /// Analyses recorded samples. `names` and `saturated` are per servo, `sites` per effector.
    #[must_use]
    pub fn new(
        samples: &[Sample],
        names: &[String],
        saturated: &[u64],
        sites: &[String],
        steps: u64,
    ) -> TrackingReport {
        let n = names.len();
        let dt = match samples {
            [a, b, ..] => b.time - a.time,
            _ => 0.001,
        };
        let mut servos = Vec::with_capacity(n);
        let (mut sum_sq, mut count, mut worst) = (0.0, 0usize, 0.0f64);
        for (k, name) in names.iter().enumerate() {
            let cmd: Vec<f64> = samples.iter().map(|s| s.commanded[k]).collect();
            let sim: Vec<f64> = samples.iter().map(|s| s.simulated[k]).collect();
            let (ss, c, mx) = error_stats(&cmd, &sim, 0);
            sum_sq += ss;
            count += c;
            worst = worst.max(mx);
            let max_shift = ((MAX_LAG_S / dt.max(1e-6)) as usize).min(samples.len() / 2);
            let (best, best_ss, best_c) = (0..=max_shift)
                .map(|d| {
                    let (ss, c, _) = error_stats(&cmd, &sim, d);
                    (d, ss, c)
                })
                .filter(|(_, _, c)| *c > 0)
                .min_by(|a, b| (a.1 / a.2 as f64).total_cmp(&(b.1 / b.2 as f64)))
                .unwrap_or((0, 0.0, 1));
            let finite = cmd.iter().filter(|x| x.is_finite());
            let (lo, hi) = finite.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                (l.min(*x), h.max(*x))
            });
            servos.push(ServoTracking {
                name: name.clone(),
                rms_deg: rms(ss, c).to_degrees(),
                max_deg: mx.to_degrees(),
                lag_ms: best as f64 * dt * 1e3,
                rms_after_lag_deg: rms(best_ss, best_c).to_degrees(),
                commanded_range_deg: if hi >= lo { (hi - lo).to_degrees() } else { 0.0 },
                saturated_steps: saturated.get(k).copied().unwrap_or(0),
                source_rms_deg: None,
                source_lag_ms: None,
            });
        }
        let effectors = sites
            .iter()
            .enumerate()
            .map(|(j, name)| {
                let e: Vec<f64> = samples
                    .iter()
                    .filter(|s| s.commanded.iter().all(|c| c.is_finite()))
                    .map(|s| s.effector_error[j])
                    .collect();
                let ss: f64 = e.iter().map(|x| x * x).sum();
                EffectorTracking {
                    name: name.clone(),
                    rms_mm: rms(ss, e.len()) * 1e3,
                    max_mm: e.iter().copied().fold(0.0, f64::max) * 1e3,
                }
            })
            .collect();
        let torso: Vec<(f64, Torso)> = samples
            .iter()
            .filter_map(|s| s.torso.map(|t| (s.time, t)))
            .collect();
        let (mut torso_min_height_m, mut torso_max_tilt_deg, mut fell) = (None, None, None);
        let (mut fell_at_s, mut torso_travel_m, mut zmp_margin_mm) = (None, None, None);
        if let (Some((t0, first)), Some((_, last))) = (torso.first(), torso.last()) {
            let start = first.pos[2];
            let fallen = |t: &Torso| t.pos[2] < FELL_HEIGHT * start || t.tilt_deg > FELL_TILT_DEG;
            torso_min_height_m = Some(torso.iter().map(|t| t.1.pos[2]).fold(f64::INFINITY, f64::min));
            torso_max_tilt_deg = Some(torso.iter().map(|t| t.1.tilt_deg).fold(0.0, f64::max));
            fell_at_s = torso.iter().find(|t| fallen(&t.1)).map(|t| t.0 - t0);
            fell = Some(fell_at_s.is_some());
            let until = fell_at_s.map_or(f64::INFINITY, |f| t0 + f);
            zmp_margin_mm = torso
                .iter()
                .filter(|t| t.0 < until)
                .filter_map(|t| t.1.pressure_margin)
                .map(|m| m * 1e3)
                .reduce(f64::min)
                .map(|measured_min| MeasuredMargin {
                    measured_min,
                    planned_min: None,
                });
            torso_travel_m = Some((last.pos[0] - first.pos[0]).hypot(last.pos[1] - first.pos[1]));
        }
        TrackingReport {
            torso_min_height_m,
            torso_max_tilt_deg,
            fell,
            fell_at_s,
            torso_travel_m,
            zmp_margin_mm,
            footsteps: None,
            substituted_steps: None,
            planned_travel_m: None,
            footstep_error_mm: None,
            samples: samples.len(),
            duration_s: samples.last().map_or(0.0, |s| s.time) - samples.first().map_or(0.0, |s| s.time),
            physics_steps: steps,
            rms_deg: rms(sum_sq, count).to_degrees(),
            max_deg: worst.to_degrees(),
            saturated_steps: saturated.iter().sum(),
            saturated_steps_first_s: 0,
            servos,
            effectors,
        }
    }
}

impl TrackingReport {
    /// Adds the loop's end-to-end figures per servo (matched by name).
    pub fn add_fidelity(&mut self, fidelity: &crate::control::fidelity::FidelityReport) {
        for s in &mut self.servos {
            if let Some(f) = fidelity.servos.iter().find(|f| f.name == s.name) {
                s.source_rms_deg = Some(f.rms_deg);
                s.source_lag_ms = Some(f.lag_ms);
            }
        }
    }
}

impl std::fmt::Display for TrackingReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "simulated tracking over {:.2} s ({} samples, {} physics steps): RMS {:.2}°, max {:.2}°, {} steps at a torque limit ({} in the first second)",
            self.duration_s,
            self.samples,
            self.physics_steps,
            self.rms_deg,
            self.max_deg,
            self.saturated_steps,
            self.saturated_steps_first_s
        )?;
        writeln!(
            f,
            "  {:<16} {:>8} {:>8} {:>8} {:>10} {:>9} {:>9} {:>10} {:>9}",
            "servo", "rms °", "max °", "lag ms", "rms-lag °", "range °", "sat steps", "source °", "src lag"
        )?;
        for s in &self.servos {
            let opt =
                |v: Option<f64>, prec: usize| v.map_or_else(|| "-".to_string(), |x| format!("{x:.prec$}"));
            writeln!(
                f,
                "  {:<16} {:>8.2} {:>8.2} {:>8.0} {:>10.2} {:>9.1} {:>9} {:>10} {:>9}",
                s.name,
                s.rms_deg,
                s.max_deg,
                s.lag_ms,
                s.rms_after_lag_deg,
                s.commanded_range_deg,
                s.saturated_steps,
                opt(s.source_rms_deg, 2),
                opt(s.source_lag_ms, 0)
            )?;
        }
        if !self.effectors.is_empty() {
            let list: Vec<String> = self
                .effectors
                .iter()
                .map(|e| format!("{} {:.1}/{:.1}", e.name, e.rms_mm, e.max_mm))
                .collect();
            writeln!(f, "  effector error rms/max mm: {}", list.join(", "))?;
        }
        if let (Some(h), Some(t), Some(fell)) = (self.torso_min_height_m, self.torso_max_tilt_deg, self.fell)
        {
            writeln!(
                f,
                "  torso: lowest {:.3} m, largest tilt {t:.1}°, travelled {:.3} m{}",
                h,
                self.torso_travel_m.unwrap_or(0.0),
                match (fell, self.fell_at_s) {
                    (true, Some(at)) => format!(" — FELL at {at:.2} s"),
                    (true, None) => " — FELL".to_string(),
                    _ => ", did not fall".to_string(),
                }
            )?;
        }
        if let (Some(n), Some(planned)) = (self.footsteps, self.planned_travel_m) {
            let landed = self.footstep_error_mm.as_ref().map_or_else(
                || "the soles are not sites: where they landed is not measured".to_string(),
                |e| {
                    format!(
                        "{} landed {:.1} mm rms, {:.1} mm at most from their footprints{}{}",
                        e.matched,
                        e.rms,
                        e.max,
                        if e.extra_stances > 0 {
                            format!(", stances off the plan: {}", e.extra_stances)
                        } else {
                            String::new()
                        },
                        if e.missed > 0 {
                            format!(", footsteps not taken: {}", e.missed)
                        } else {
                            String::new()
                        }
                    )
                },
            );
            writeln!(f, "  walk: {n} footsteps planned over {planned:.3} m; {landed}")?;
        }
        Ok(())
    }
}

fn rms(sum_sq: f64, count: usize) -> f64 {
    if count == 0 {
        0.0
    } else {
        (sum_sq / count as f64).sqrt()
    }
}

/// Sum of squares, count and largest |sim(t) − cmd(t − shift)| over samples where both are
/// finite.
fn error_stats(cmd: &[f64], sim: &[f64], shift: usize) -> (f64, usize, f64) {
    let (mut ss, mut c, mut mx) = (0.0, 0, 0.0f64);
    for (i, s) in sim.iter().enumerate().skip(shift) {
        let e = s - cmd[i - shift];
        if e.is_finite() {
            ss += e * e;
            c += 1;
            mx = mx.max(e.abs());
        }
    }
    (ss, c, mx)
}

/// Commanded (dashed) and simulated (solid) angles over time for the chosen servos (by
/// index), one panel each, and the per-servo RMS bar chart below; drawn with
/// [`crate::plot::draw`].
pub struct TrackingPicture<'a> {
    /// The recorded samples.
    pub samples: &'a [Sample],
    /// The report of the same run.
    pub report: &'a TrackingReport,
    /// Servo indices to draw.
    pub chosen: &'a [usize],
    /// The source angles the loop had each tick (simulated time in seconds, radians per servo),
    /// drawn beside commanded and simulated; empty when not recorded.
    pub source: &'a [(f64, Vec<f64>)],
}

impl TrackingPicture<'_> {
    /// Width and height of the picture, pixels: a panel per chosen servo above the bars.
    #[must_use]
    pub fn size(&self) -> (u32, u32) {
        (1200, 230 * self.chosen.len().max(1) as u32 + 380)
    }
}

impl Picture for TrackingPicture<'_> {
    fn render<DB: DrawingBackend<ErrorType: 'static>>(&self, area: &Area<DB>) -> Rendered {
        paint(area, self.samples, self.report, self.chosen, self.source)
    }
}

fn paint<DB: DrawingBackend<ErrorType: 'static>>(
    root: &Area<DB>,
    samples: &[Sample],
    report: &TrackingReport,
    chosen: &[usize],
    source: &[(f64, Vec<f64>)],
) -> Rendered {
    root.fill(&WHITE)?;
    let (top, bottom) = root.split_vertically(230 * chosen.len().max(1) as u32);
    let panels = top.split_evenly((chosen.len().max(1), 1));
    let t0 = samples.first().map_or(0.0, |s| s.time);
    let t1 = samples.last().map_or(1.0, |s| s.time).max(t0 + 1e-3);
    for (panel, &k) in panels.iter().zip(chosen) {
        let Some(s) = report.servos.get(k) else { continue };
        let values = samples
            .iter()
            .flat_map(|x| [x.commanded[k], x.simulated[k]])
            .chain(source.iter().filter_map(|(_, a)| a.get(k).copied()))
            .filter(|v| v.is_finite())
            .map(f64::to_degrees);
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| {
            (l.min(v), h.max(v))
        });
        let (lo, hi) = if hi > lo {
            (lo - 2.0, hi + 2.0)
        } else {
            (-10.0, 10.0)
        };
        let mut chart = ChartBuilder::on(panel)
            .caption(
                format!(
                    "{}: RMS {:.2}°, max {:.2}°, lag {:.0} ms",
                    s.name, s.rms_deg, s.max_deg, s.lag_ms
                ),
                ("sans-serif", 18),
            )
            .margin(8)
            .x_label_area_size(28)
            .y_label_area_size(50)
            .build_cartesian_2d(t0..t1, lo..hi)?;
        chart
            .configure_mesh()
            .x_desc("simulated time, s")
            .y_desc("angle, °")
            .draw()?;
        let cmd: Vec<(f64, f64)> = samples
            .iter()
            .filter(|x| x.commanded[k].is_finite())
            .map(|x| (x.time, x.commanded[k].to_degrees()))
            .collect();
        chart
            .draw_series(DashedLineSeries::new(cmd, 6, 4, RED.stroke_width(2)))?
            .label("commanded")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED));
        chart
            .draw_series(LineSeries::new(
                samples.iter().map(|x| (x.time, x.simulated[k].to_degrees())),
                BLUE.stroke_width(2),
            ))?
            .label("simulated")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLUE));
        let src: Vec<(f64, f64)> = source
            .iter()
            .filter_map(|(t, a)| a.get(k).filter(|v| v.is_finite()).map(|v| (*t, v.to_degrees())))
            .filter(|(t, _)| (t0..=t1).contains(t))
            .collect();
        if !src.is_empty() {
            let green = RGBColor(30, 150, 60);
            chart
                .draw_series(LineSeries::new(src, green.stroke_width(2)))?
                .label("source (the clip through the rig)")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], green));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
    }
    let n = report.servos.len();
    let top_rms = report.servos.iter().map(|s| s.rms_deg).fold(0.5, f64::max) * 1.15;
    let mut chart = ChartBuilder::on(&bottom)
        .caption(
            format!("RMS tracking error per servo (all: {:.2}°)", report.rms_deg),
            ("sans-serif", 18),
        )
        .margin(8)
        .x_label_area_size(90)
        .y_label_area_size(50)
        .build_cartesian_2d(-0.5..n as f64 - 0.5, 0.0..top_rms)?;
    let names: Vec<String> = report.servos.iter().map(|s| s.name.clone()).collect();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .y_desc("RMS, °")
        .x_labels(n.max(1))
        .x_label_style(("sans-serif", 12).into_font().transform(FontTransform::Rotate90))
        .x_label_formatter(&|v| {
            let i = v.round();
            if (v - i).abs() < 0.01 && i >= 0.0 {
                names.get(i as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        })
        .draw()?;
    chart.draw_series(report.servos.iter().enumerate().map(|(i, s)| {
        let x = i as f64;
        Rectangle::new([(x - 0.35, 0.0), (x + 0.35, s.rms_deg)], BLUE.mix(0.6).filled())
    }))?;
    Ok(())
}

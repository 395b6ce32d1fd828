//! The picture of a connection: top view (x–z) of the root paths of both inputs and the
//! result with the seam marked, beside the matching distance curve with its minimum.

use super::clip::heading;
use super::Motion;
use crate::plot::{Area, Picture, Rendered};
use crate::skeleton::Skeleton;
use plotters::prelude::*;
use std::ops::Range;

/// What to draw.
pub struct ConnectionPlot<'a> {
    /// Title.
    pub title: String,
    /// Input clips with their labels (drawn as captured).
    pub inputs: Vec<(&'a str, &'a Motion)>,
    /// The result.
    pub result: &'a Motion,
    /// The result's transition frames.
    pub seam: Range<usize>,
    /// The matching distance curve and its label.
    pub distances: &'a [f64],
    /// What the curve's x axis counts.
    pub distance_axis: String,
    /// The chosen minimum.
    pub best: usize,
}

fn path(skeleton: &Skeleton, m: &Motion) -> Vec<(f64, f64)> {
    (0..m.len())
        .map(|i| {
            let p = heading(skeleton, m, i).1;
            (p.x, p.z)
        })
        .collect()
}

/// A [`ConnectionPlot`] over its skeleton, drawn with [`crate::plot::draw`].
pub struct ConnectionPicture<'a> {
    /// The clips' skeleton.
    pub skeleton: &'a Skeleton,
    /// What to draw.
    pub plot: &'a ConnectionPlot<'a>,
}

impl ConnectionPicture<'_> {
    /// Width and height of the picture, pixels.
    pub const SIZE: (u32, u32) = (1400, 640);
}

impl Picture for ConnectionPicture<'_> {
    fn render<DB: DrawingBackend<ErrorType: 'static>>(&self, area: &Area<DB>) -> Rendered {
        render(self.skeleton, self.plot, area)
    }
}

fn bounds(points: impl Iterator<Item = (f64, f64)>) -> ((f64, f64), (f64, f64)) {
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for (x, y) in points {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    // Equal scales on both axes, with a margin.
    let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let half = ((x1 - x0).max(y1 - y0) / 2.0).max(1.0) * 1.08;
    ((cx - half, cx + half), (cy - half, cy + half))
}

fn render<DB: DrawingBackend<ErrorType: 'static>>(
    skeleton: &Skeleton,
    plot: &ConnectionPlot<'_>,
    root: &Area<DB>,
) -> Rendered {
    root.fill(&WHITE)?;
    let root = root.titled(&plot.title, ("sans-serif", 22))?;
    let (left, right) = root.split_horizontally(640);

    let result_path = path(skeleton, plot.result);
    let input_paths: Vec<(&str, Vec<(f64, f64)>)> =
        plot.inputs.iter().map(|(l, m)| (*l, path(skeleton, m))).collect();
    let all = result_path
        .iter()
        .chain(input_paths.iter().flat_map(|(_, p)| p.iter()))
        .copied();
    let ((x0, x1), (z0, z1)) = bounds(all);
    let mut top = ChartBuilder::on(&left)
        .caption("root path, top view (x–z, file units)", ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(52)
        .build_cartesian_2d(x0..x1, z0..z1)?;
    top.configure_mesh().x_desc("x").y_desc("z").draw()?;
    let colours = [RGBColor(120, 150, 220), RGBColor(230, 160, 80)];
    for ((label, p), colour) in input_paths.iter().zip(colours) {
        top.draw_series(LineSeries::new(
            p.iter().copied(),
            colour.mix(0.7).stroke_width(5),
        ))?
        .label(format!("input {label}"))
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(4)));
    }
    top.draw_series(LineSeries::new(
        result_path.iter().copied(),
        BLACK.stroke_width(1),
    ))?
    .label("result")
    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLACK));
    let seam_points: Vec<(f64, f64)> = plot
        .seam
        .clone()
        .filter(|&i| i < result_path.len())
        .map(|i| result_path[i])
        .collect();
    top.draw_series(seam_points.iter().map(|&p| Circle::new(p, 3, RED.filled())))?
        .label(format!("seam ({} frames)", plot.seam.len()))
        .legend(|(x, y)| Circle::new((x + 9, y), 3, RED.filled()));
    // The frames on either side of the seam.
    let ends = [plot.seam.start.checked_sub(1), Some(plot.seam.end)];
    let ends: Vec<(f64, f64)> = ends
        .into_iter()
        .flatten()
        .filter_map(|i| result_path.get(i).copied())
        .collect();
    top.draw_series(ends.iter().map(|&p| Cross::new(p, 7, RED.stroke_width(2))))?
        .label("last frame before / first after")
        .legend(|(x, y)| Cross::new((x + 9, y), 5, RED.stroke_width(2)));
    top.configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;

    let d = plot.distances;
    let max = d.iter().copied().fold(0.0f64, f64::max).max(1e-9);
    let mut curve = ChartBuilder::on(&right)
        .caption("matching window distance (eq. 11)", ("sans-serif", 16))
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(0f64..(d.len().max(2) - 1) as f64, 0f64..max * 1.05)?;
    curve
        .configure_mesh()
        .x_desc(plot.distance_axis.as_str())
        .y_desc("distance")
        .draw()?;
    curve.draw_series(LineSeries::new(
        d.iter().enumerate().map(|(i, v)| (i as f64, *v)),
        BLUE.stroke_width(2),
    ))?;
    if let Some(v) = d.get(plot.best) {
        curve
            .draw_series(std::iter::once(Circle::new(
                (plot.best as f64, *v),
                6,
                RED.filled(),
            )))?
            .label(format!(
                "chosen minimum: window at {} (distance {v:.4})",
                plot.best
            ))
            .legend(|(x, y)| Circle::new((x + 9, y), 4, RED.filled()));
        curve
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
    }
    Ok(())
}

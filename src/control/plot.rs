//! The latency picture of a run: one histogram curve per measured stage on a logarithmic time
//! axis, with the period marked.

use plotters::prelude::*;

use super::stats::{Histogram, LoopStats, Stage};
use crate::plot::{Area, Picture, Rendered};

/// The latency histograms of a run's statistics, drawn with [`crate::plot::draw`].
pub struct Histograms<'a>(pub &'a LoopStats);

impl Histograms<'_> {
    /// Width and height of the picture, pixels.
    pub const SIZE: (u32, u32) = (1200, 700);
}

impl Picture for Histograms<'_> {
    fn render<DB: DrawingBackend<ErrorType: 'static>>(&self, area: &Area<DB>) -> Rendered {
        render(self.0, area)
    }
}

fn render<DB: DrawingBackend<ErrorType: 'static>>(stats: &LoopStats, area: &Area<DB>) -> Rendered {
    area.fill(&WHITE)?;
    let period_us = 1e6 / stats.rate_hz;
    let mut series: Vec<(&str, &Histogram)> = vec![
        ("tick compute", &stats.tick_compute),
        ("period error", &stats.period_error),
    ];
    for s in [Stage::Solve, Stage::Encode, Stage::BusWrite, Stage::BusRead] {
        series.push((s.name(), stats.stage(s)));
    }
    let curves: Vec<Vec<(f64, f64)>> = series.iter().map(|(_, h)| rebin(h)).collect();
    let mut lo = f64::INFINITY;
    let mut hi: f64 = period_us * 1.5;
    let mut top = 0.01f64;
    for c in &curves {
        for &(us, f) in c {
            lo = lo.min(us);
            hi = hi.max(us);
            top = top.max(f);
        }
    }
    let lo = if lo.is_finite() { lo.max(0.01) * 0.8 } else { 0.01 };
    let mut chart = ChartBuilder::on(area)
        .caption(
            format!(
                "loop at {} Hz: {} ticks, {} deadline misses — latency histograms",
                stats.rate_hz, stats.ticks, stats.deadline_misses
            ),
            ("sans-serif", 22),
        )
        .margin(16)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d((lo..hi * 1.2).log_scale(), 0.0..top * 1.1)?;
    chart
        .configure_mesh()
        .x_desc("µs (log scale)")
        .y_desc("fraction of ticks (8 bins per doubling)")
        .label_style(("sans-serif", 14))
        .draw()?;
    let colours = [RED, BLUE, GREEN, MAGENTA, CYAN, BLACK];
    for (((name, h), colour), points) in series.iter().zip(colours).zip(curves) {
        if h.count() == 0 {
            continue;
        }
        let p = h.summary_us();
        chart
            .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
            .label(format!(
                "{name}: p50 {:.1} p99 {:.1} max {:.1} µs",
                p.p50, p.p99, p.max
            ))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    chart
        .draw_series(LineSeries::new(
            vec![(period_us, 0.0), (period_us, top * 1.1)],
            BLACK.mix(0.5).stroke_width(1),
        ))?
        .label(format!("period {period_us:.0} µs"))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5)));
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}

/// The histogram in 8 bins per doubling (≥ 0.01 µs): (bin centre µs, fraction of the values).
fn rebin(h: &Histogram) -> Vec<(f64, f64)> {
    let n = h.count().max(1) as f64;
    let mut bins: std::collections::BTreeMap<i64, u64> = std::collections::BTreeMap::new();
    for (v, c) in h.buckets() {
        let us = (v as f64 / 1000.0).max(0.01);
        *bins.entry((us.log2() * 8.0).floor() as i64).or_default() += u64::from(c);
    }
    bins.into_iter()
        .map(|(b, c)| (((b as f64 + 0.5) / 8.0).exp2(), c as f64 / n))
        .collect()
}

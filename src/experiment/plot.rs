//! PNG plots for the experiments (plotters, bitmap backend). Text uses the
//! bundled DejaVu Sans, so no system fonts are needed.

use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        // The bundled font is known-good; a failure leaves text unrendered
        // rather than aborting the experiment.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            include_bytes!("../../assets/DejaVuSans.ttf"),
        );
    });
}

/// One curve: legend name, colour, points.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// Colour (RGB).
    pub color: RGBColor,
    /// (x, y) points.
    pub points: Vec<(f64, f64)>,
    /// Draw markers as well as the line.
    pub markers: bool,
}

fn range(points: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in points.filter(|v| v.is_finite() && (!log || *v > 0.0)) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (if log { 1e-3 } else { 0.0 }, 1.0);
    }
    if log {
        (lo / 1.5, hi * 1.5)
    } else {
        let pad = ((hi - lo) * 0.05).max(1e-12);
        (lo - pad, hi + pad)
    }
}

/// Error of a plot.
pub type PlotResult = Result<(), String>;

/// A line plot of several series, with linear or logarithmic axes.
pub fn line_plot(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    log_x: bool,
    log_y: bool,
) -> PlotResult {
    register_font();
    let root = BitMapBackend::new(path, (1000, 700)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let (x0, x1) = range(series.iter().flat_map(|s| s.points.iter().map(|p| p.0)), log_x);
    let (y0, y1) = range(series.iter().flat_map(|s| s.points.iter().map(|p| p.1)), log_y);
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 18))
                .axis_desc_style(("sans-serif", 20))
                .draw()
                .map_err(|e| e.to_string())?;
            for s in series {
                let color = s.color;
                chart
                    .draw_series(LineSeries::new(s.points.iter().copied(), color.stroke_width(2)))
                    .map_err(|e| e.to_string())?
                    .label(s.name.clone())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
                if s.markers {
                    chart
                        .draw_series(s.points.iter().map(|&p| Circle::new(p, 4, color.filled())))
                        .map_err(|e| e.to_string())?;
                }
            }
            chart
                .configure_series_labels()
                .label_font(("sans-serif", 18))
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| e.to_string())?;
        }};
    }
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(55)
        .y_label_area_size(90);
    match (log_x, log_y) {
        (false, false) => draw!(builder.build_cartesian_2d(x0..x1, y0..y1).map_err(|e| e.to_string())?),
        (true, false) => draw!(builder
            .build_cartesian_2d((x0..x1).log_scale(), y0..y1)
            .map_err(|e| e.to_string())?),
        (false, true) => draw!(builder
            .build_cartesian_2d(x0..x1, (y0..y1).log_scale())
            .map_err(|e| e.to_string())?),
        (true, true) => {
            draw!(builder
                .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
                .map_err(|e| e.to_string())?)
        }
    }
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}

/// Panels of (left-axis series, right-axis series) sharing the x axis, one
/// panel per row — the layout of the paper's Fig. 5.
pub fn dual_axis_panels(
    path: &Path,
    panels: &[(String, Series, Series)],
    x_label: &str,
    left_label: &str,
    right_label: &str,
) -> PlotResult {
    register_font();
    let root = BitMapBackend::new(path, (1100, 420 * panels.len().max(1) as u32)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let areas = root.split_evenly((panels.len().max(1), 1));
    // Common ranges so the panels compare at a glance.
    let (x0, x1) = range(panels.iter().flat_map(|p| p.1.points.iter().map(|q| q.0)), false);
    let (l0, l1) = range(panels.iter().flat_map(|p| p.1.points.iter().map(|q| q.1)), false);
    let (r0, r1) = range(panels.iter().flat_map(|p| p.2.points.iter().map(|q| q.1)), false);
    for (area, (title, left, right)) in areas.iter().zip(panels) {
        let mut chart = ChartBuilder::on(area)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(50)
            .y_label_area_size(85)
            .right_y_label_area_size(85)
            .build_cartesian_2d(x0..x1, l0..l1)
            .map_err(|e| e.to_string())?
            .set_secondary_coord(x0..x1, r0..r1);
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(left_label)
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 18))
            .draw()
            .map_err(|e| e.to_string())?;
        chart
            .configure_secondary_axes()
            .y_desc(right_label)
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 18))
            .draw()
            .map_err(|e| e.to_string())?;
        let (lc, rc) = (left.color, right.color);
        chart
            .draw_series(LineSeries::new(left.points.iter().copied(), lc.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(left.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], lc.stroke_width(3)));
        chart
            .draw_secondary_series(LineSeries::new(right.points.iter().copied(), rc.stroke_width(2)))
            .map_err(|e| e.to_string())?
            .label(right.name.clone())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], rc.stroke_width(3)));
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font(("sans-serif", 16))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|e| e.to_string())?;
    }
    root.present().map_err(|e| e.to_string())?;
    Ok(())
}

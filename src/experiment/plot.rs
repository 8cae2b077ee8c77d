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

/// A tick label on a logarithmic axis: only at 1, 2 and 5 times a power of
/// ten (plotters puts ticks at every integer multiple, whose labels run
/// into each other: "8.09.010.0"), written short ("0.01", "2", "50").
pub fn log_tick_label(v: f64) -> String {
    if !(v.is_finite() && v > 0.0) {
        return String::new();
    }
    let decade = 10f64.powf(v.log10().floor());
    let m = v / decade;
    let near = |x: f64| (m - x).abs() < 1e-6 * x;
    if !(near(1.0) || near(2.0) || near(5.0) || near(10.0)) {
        return String::new();
    }
    let rounded = (m.round() * decade * 1e12).round() / 1e12;
    format!("{rounded}")
}

/// Where the legend covers the fewest data: the corner (a box about
/// `w` × `h` of the plot, in axis fractions; `x`, `y` the axis ranges,
/// `log` whether each is logarithmic) with the fewest points of the series
/// and of their segments sampled along.
pub fn legend_corner(
    series: &[Series],
    x: (f64, f64),
    y: (f64, f64),
    log: (bool, bool),
    w: f64,
    h: f64,
) -> SeriesLabelPosition {
    let frac = |v: f64, (lo, hi): (f64, f64), log: bool| {
        if log {
            (v.ln() - lo.ln()) / (hi.ln() - lo.ln())
        } else {
            (v - lo) / (hi - lo)
        }
    };
    let mut pts = Vec::new();
    for s in series {
        let p: Vec<(f64, f64)> = s
            .points
            .iter()
            .map(|&(a, b)| (frac(a, x, log.0), frac(b, y, log.1)))
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .collect();
        for k in 0..p.len() {
            pts.push(p[k]);
            if k + 1 < p.len() {
                for j in 1..20 {
                    let t = j as f64 / 20.0;
                    pts.push((p[k].0 + t * (p[k + 1].0 - p[k].0), p[k].1 + t * (p[k + 1].1 - p[k].1)));
                }
            }
        }
    }
    let corners = [
        (SeriesLabelPosition::UpperRight, 1.0 - w, 1.0 - h),
        (SeriesLabelPosition::UpperLeft, 0.0, 1.0 - h),
        (SeriesLabelPosition::LowerLeft, 0.0, 0.0),
        (SeriesLabelPosition::LowerRight, 1.0 - w, 0.0),
    ];
    let count = |(x0, y0): (f64, f64)| {
        pts.iter()
            .filter(|(a, b)| (x0..=x0 + w).contains(a) && (y0..=y0 + h).contains(b))
            .count()
    };
    corners
        .into_iter()
        .min_by_key(|&(_, x0, y0)| count((x0, y0)))
        .map(|c| c.0)
        .unwrap_or(SeriesLabelPosition::UpperRight)
}

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
    // The legend box: about 20 px a series plus margins, 300 px wide, as a
    // share of the plot area (about 880 × 590 px).
    let legend_h = ((series.len() as f64 * 24.0 + 20.0) / 590.0).min(0.9);
    let corner = legend_corner(series, (x0, x1), (y0, y1), (log_x, log_y), 300.0 / 880.0, legend_h);
    let x_fmt = |v: &f64| if log_x { log_tick_label(*v) } else { format!("{v}") };
    let y_fmt = |v: &f64| if log_y { log_tick_label(*v) } else { format!("{v}") };
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart;
            chart
                .configure_mesh()
                .x_desc(x_label)
                .y_desc(y_label)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&y_fmt)
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
                .position(corner.clone())
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

/// Draws onto an RGB image (`rgb`, `width` × `height`, as
/// [`crate::mesh::render::render_surface`] makes it) a title line at the top
/// and a vertical colour bar at the right for a scalar from `vmin` to `vmax`
/// in the renderer's colour map, with its `label` (name and unit) and five
/// tick values. The surface's colours are also shaded by the light, so the
/// bar shows the unshaded colours.
pub fn annotate_render(
    rgb: &mut [u8],
    width: u32,
    height: u32,
    title: &str,
    label: &str,
    vmin: f64,
    vmax: f64,
) -> Result<(), String> {
    register_font();
    if rgb.len() != (width * height * 3) as usize {
        return Err(format!(
            "image buffer has {} bytes, {width}×{height} needs {}",
            rgb.len(),
            width * height * 3
        ));
    }
    let root = BitMapBackend::with_buffer(rgb, (width, height)).into_drawing_area();
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    let text = ("sans-serif", 15).into_font().color(&BLACK);
    root.draw(&Text::new(title.to_string(), (10, 8), text.clone()))
        .map_err(e)?;
    let (w, h) = (width as i32, height as i32);
    let (x0, x1) = (w - 95, w - 75);
    let (y0, y1) = (40, h - 40);
    let span = (y1 - y0).max(1);
    for y in y0..=y1 {
        let t = (y1 - y) as f64 / span as f64;
        let [r, g, b] = crate::mesh::render::colormap(t);
        root.draw(&PathElement::new(vec![(x0, y), (x1, y)], RGBColor(r, g, b)))
            .map_err(e)?;
    }
    root.draw(&Rectangle::new([(x0, y0), (x1, y1)], BLACK.stroke_width(1)))
        .map_err(e)?;
    for k in 0..=4 {
        let t = k as f64 / 4.0;
        let y = y1 - (t * span as f64).round() as i32;
        let v = vmin + t * (vmax - vmin);
        root.draw(&PathElement::new(vec![(x1, y), (x1 + 4, y)], BLACK))
            .map_err(e)?;
        root.draw(&Text::new(
            format!("{v:.3}"),
            (x1 + 7, y - 7),
            ("sans-serif", 13).into_font(),
        ))
        .map_err(e)?;
    }
    root.draw(&Text::new(
        label.to_string(),
        (x0 - 30, y1 + 10),
        ("sans-serif", 13).into_font(),
    ))
    .map_err(e)?;
    root.present().map_err(|e| e.to_string())
}

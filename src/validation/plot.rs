//! PNG figures for the validation report (plotters, bitmap backend, the DejaVu Sans font
//! embedded in the binary so that no system font is needed).

use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};
use std::path::Path;
use std::sync::Once;

static FONT: &[u8] = include_bytes!(concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/validation/assets/DejaVuSans.ttf"
));

/// Registers the embedded font as "sans-serif" (once; also used by `pmpm plot`).
pub(crate) fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // the font is a valid TTF compiled in; a failure would show as missing text only
        let _ = register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A line through the points.
    Line,
    /// A thin line (many-point noisy data such as experiments).
    Thin,
    /// Circles, no line (tables).
    Markers,
}

/// One series of a panel.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend text.
    pub label: String,
    /// (x, y) points.
    pub points: Vec<(f64, f64)>,
    /// Colour.
    pub color: RGBColor,
    /// Line or markers.
    pub kind: Kind,
}

impl Series {
    /// A line.
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Self {
            label: label.into(),
            points,
            color,
            kind: Kind::Line,
        }
    }
    /// A thin line.
    pub fn thin(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Self {
            label: label.into(),
            points,
            color,
            kind: Kind::Thin,
        }
    }
    /// Markers.
    pub fn markers(label: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Self {
            label: label.into(),
            points,
            color,
            kind: Kind::Markers,
        }
    }
}

/// One chart.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    /// Caption.
    pub title: String,
    /// Axis descriptions.
    pub x_label: String,
    /// Axis descriptions.
    pub y_label: String,
    /// The data.
    pub series: Vec<Series>,
    /// Fixed ranges (auto from the data, padded 5%, when None).
    pub x_range: Option<(f64, f64)>,
    /// Fixed ranges.
    pub y_range: Option<(f64, f64)>,
    /// Legend in the upper left instead of the upper right.
    pub legend_left: bool,
    /// Legend in the lower part.
    pub legend_low: bool,
}

/// Colours that stay apart in print: experiment/table black, projection blue shades, explicit
/// red shades, further runs green/orange/purple.
pub mod colors {
    use plotters::style::RGBColor;
    /// Reference data.
    pub const REF: RGBColor = RGBColor(0, 0, 0);
    /// Second reference series.
    pub const REF2: RGBColor = RGBColor(150, 150, 150);
    /// Projection, finest.
    pub const PROJ: RGBColor = RGBColor(31, 119, 180);
    /// Projection, medium.
    pub const PROJ2: RGBColor = RGBColor(100, 170, 230);
    /// Projection, coarse.
    pub const PROJ3: RGBColor = RGBColor(170, 210, 245);
    /// Explicit, finest.
    pub const EXPL: RGBColor = RGBColor(214, 39, 40);
    /// Explicit, medium.
    pub const EXPL2: RGBColor = RGBColor(240, 120, 110);
    /// Explicit, coarse.
    pub const EXPL3: RGBColor = RGBColor(250, 185, 175);
    /// Other.
    pub const GREEN: RGBColor = RGBColor(44, 160, 44);
    /// Other.
    pub const ORANGE: RGBColor = RGBColor(255, 127, 14);
}

/// Tick labels: short, scientific when small or large (also used by `pmpm plot`).
pub(crate) fn tick(v: &f64) -> String {
    let a = v.abs();
    if a < 1e-12 {
        // round-off at a tick meant to be zero
        "0".into()
    } else if !(1e-3..1e4).contains(&a) {
        format!("{v:.1e}")
    } else {
        let s = format!("{v:.4}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    }
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in vals.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo <= 1e-300 + 1e-12 * hi.abs() {
        let d = if hi.abs() > 0.0 { 0.1 * hi.abs() } else { 1.0 };
        return (lo - d, hi + d);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// Writes `panels` into one PNG, `cols` panels across, each `w` x `h` pixels.
pub fn save(path: &Path, panels: &[Panel], cols: usize, w: u32, h: u32) -> Result<(), String> {
    register();
    let cols = cols.max(1);
    let rows = panels.len().div_ceil(cols);
    let size = (w * cols as u32, h * rows as u32);
    let root = BitMapBackend::new(path, size).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let areas = root.split_evenly((rows, cols));
    for (panel, area) in panels.iter().zip(areas.iter()) {
        draw(panel, area).map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

fn draw(
    p: &Panel,
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
) -> Result<(), Box<dyn std::error::Error>> {
    let xr = p
        .x_range
        .unwrap_or_else(|| range(p.series.iter().flat_map(|s| s.points.iter().map(|q| q.0))));
    let yr = p
        .y_range
        .unwrap_or_else(|| range(p.series.iter().flat_map(|s| s.points.iter().map(|q| q.1))));
    let mut chart = ChartBuilder::on(area)
        .caption(&p.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(75)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(205, 205, 205))
        .draw()?;
    let inside = |q: &(f64, f64)| {
        q.0.is_finite()
            && q.1.is_finite()
            && q.0 >= xr.0
            && q.0 <= xr.1
            && q.1 >= yr.0
            && q.1 <= yr.1
    };
    for s in &p.series {
        let c = s.color;
        match s.kind {
            Kind::Line | Kind::Thin => {
                let width = if s.kind == Kind::Line { 2 } else { 1 };
                // clip to the ranges (plotters draws outside otherwise)
                let pts: Vec<(f64, f64)> = s
                    .points
                    .iter()
                    .filter(|q| q.0.is_finite() && q.1.is_finite())
                    .map(|q| (q.0.clamp(xr.0, xr.1), q.1.clamp(yr.0, yr.1)))
                    .collect();
                chart
                    .draw_series(LineSeries::new(pts, c.stroke_width(width)))?
                    .label(s.label.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 22, y)], c.stroke_width(3))
                    });
            }
            Kind::Markers => {
                chart
                    .draw_series(
                        s.points
                            .iter()
                            .filter(|q| inside(q))
                            .map(|q| Circle::new(*q, 4, c.filled())),
                    )?
                    .label(s.label.as_str())
                    .legend(move |(x, y)| Circle::new((x + 11, y), 4, c.filled()));
            }
        }
    }
    if p.series.iter().all(|s| s.label.is_empty()) {
        // nothing to name (`pmpm plot`'s one-series panels)
        return Ok(());
    }
    let pos = match (p.legend_left, p.legend_low) {
        (false, false) => SeriesLabelPosition::UpperRight,
        (true, false) => SeriesLabelPosition::UpperLeft,
        (false, true) => SeriesLabelPosition::LowerRight,
        (true, true) => SeriesLabelPosition::LowerLeft,
    };
    chart
        .configure_series_labels()
        .position(pos)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(120, 120, 120))
        .label_font(("sans-serif", 14))
        .draw()?;
    Ok(())
}

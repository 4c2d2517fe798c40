//! Plots for railview's reports, drawn with [`plotters`].
//!
//! - [`Chart`]: plain data for one panel: a title, two [`Axis`]es (label with its unit,
//!   linear or log scale, optional fixed range), [`Series`] (points, lines, dashed lines,
//!   bars, a Pareto front) and vertical [`Marker`]s; a legend in a column of its own names
//!   every named series and marker.
//! - [`Figure`]: one or more charts stacked as panels under an optional title.
//! - [`svg`] writes a figure for the HTML report; [`png`] rasterises the same drawing. Text in
//!   PNGs is laid out with a font compiled into the binary (Ubuntu Light from
//!   `epaint_default_fonts`), so a fresh machine without system fonts draws the same pixels.
//!
//! ```
//! use charts::{Axis, Chart, Figure, Series};
//! let chart = Chart::new("PSNR against database size")
//!     .x(Axis::log("database size (MB)"))
//!     .y(Axis::linear("PSNR, worst 5 % of views (dB)"))
//!     .series(Series::points("configurations", vec![(1.2, 30.0), (4.0, 33.5), (9.0, 34.0)]))
//!     .series(Series::front("Pareto front", vec![(1.2, 30.0), (4.0, 33.5), (9.0, 34.0)]));
//! let fig = Figure::single(chart);
//! let svg = charts::svg(&fig).unwrap();
//! assert!(svg.contains("PSNR against database size"));
//! let png = charts::png(&fig).unwrap();
//! assert!(png.starts_with(b"\x89PNG"));
//! ```

use std::ops::Range;
use std::sync::OnceLock;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;

/// Errors of drawing a figure.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ChartError {
    /// The plotting backend failed (a font could not lay out text, a size of zero, …).
    #[error("drawing `{chart}`: {message}")]
    Draw { chart: String, message: String },
    #[error("encoding the PNG: {0}")]
    Png(String),
}

/// How an axis maps values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    Linear,
    /// Base-10 logarithmic; non-positive values are left out. The range is widened to whole
    /// decades, so it always has labelled ticks.
    Log,
    /// Logarithmic when the positive values plotted span more than a factor of 20 (and
    /// none is zero or negative), else linear.
    Auto,
}

/// One axis: its label (with the unit, e.g. `"frame time (ms)"`), its scale and, if given,
/// its range; otherwise the range covers every finite value plotted, padded 5 %.
#[derive(Clone, Debug, PartialEq)]
pub struct Axis {
    pub label: String,
    pub scale: Scale,
    pub range: Option<(f64, f64)>,
}

impl Axis {
    pub fn linear(label: impl Into<String>) -> Axis {
        Axis {
            label: label.into(),
            scale: Scale::Linear,
            range: None,
        }
    }
    pub fn log(label: impl Into<String>) -> Axis {
        Axis {
            label: label.into(),
            scale: Scale::Log,
            range: None,
        }
    }
    /// Log where the values span decades, linear otherwise ([`Scale::Auto`]).
    pub fn auto(label: impl Into<String>) -> Axis {
        Axis {
            label: label.into(),
            scale: Scale::Auto,
            range: None,
        }
    }
    /// A fixed range.
    pub fn range(mut self, lo: f64, hi: f64) -> Axis {
        self.range = Some((lo, hi));
        self
    }
}

/// How a series is drawn.
#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    /// A filled circle per point.
    Points,
    /// Points joined in the order given.
    Line,
    /// Points joined by a dashed line.
    DashedLine,
    /// Bars `(x_start, x_end, height)` from zero (or the axis' lower end on a log axis).
    Bars(Vec<(f64, f64, f64)>),
    /// A Pareto front: its points ringed and joined by a staircase in the order of x.
    Front,
}

/// A named series; `color` indexes [`PALETTE`] (default: the series' position).
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub name: String,
    pub kind: Kind,
    pub points: Vec<(f64, f64)>,
    pub color: Option<usize>,
}

impl Series {
    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            name: name.into(),
            kind: Kind::Points,
            points,
            color: None,
        }
    }
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            kind: Kind::Line,
            ..Series::points(name, points)
        }
    }
    pub fn dashed(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            kind: Kind::DashedLine,
            ..Series::points(name, points)
        }
    }
    pub fn bars(name: impl Into<String>, bars: Vec<(f64, f64, f64)>) -> Series {
        Series {
            kind: Kind::Bars(bars),
            ..Series::points(name, Vec::new())
        }
    }
    pub fn front(name: impl Into<String>, points: Vec<(f64, f64)>) -> Series {
        Series {
            kind: Kind::Front,
            ..Series::points(name, points)
        }
    }
    /// Draw in [`PALETTE`]`[i % len]`.
    pub fn color(mut self, i: usize) -> Series {
        self.color = Some(i);
        self
    }

    /// Every value this series puts on the axes (bars: both ends and the height).
    fn values(&self) -> Vec<(f64, f64)> {
        match &self.kind {
            Kind::Bars(b) => b
                .iter()
                .flat_map(|&(x0, x1, h)| [(x0, h), (x1, h)])
                .collect(),
            _ => self.points.clone(),
        }
    }
}

/// A vertical line across the plot at `x`, named in the legend.
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    pub x: f64,
    pub name: String,
    pub color: usize,
    pub dashed: bool,
}

/// One panel.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x: Axis,
    pub y: Axis,
    pub series: Vec<Series>,
    pub markers: Vec<Marker>,
}

impl Chart {
    pub fn new(title: impl Into<String>) -> Chart {
        Chart {
            title: title.into(),
            x: Axis::linear("x"),
            y: Axis::linear("y"),
            series: Vec::new(),
            markers: Vec::new(),
        }
    }
    pub fn x(mut self, axis: Axis) -> Chart {
        self.x = axis;
        self
    }
    pub fn y(mut self, axis: Axis) -> Chart {
        self.y = axis;
        self
    }
    pub fn series(mut self, s: Series) -> Chart {
        self.series.push(s);
        self
    }
    pub fn marker(mut self, m: Marker) -> Chart {
        self.markers.push(m);
        self
    }
}

/// Panels stacked top to bottom, `width × panel_height` pixels each.
#[derive(Clone, Debug, PartialEq)]
pub struct Figure {
    pub panels: Vec<Chart>,
    pub width: u32,
    pub panel_height: u32,
}

impl Figure {
    /// One chart at the default size (720 × 440).
    pub fn single(chart: Chart) -> Figure {
        Figure {
            panels: vec![chart],
            width: 720,
            panel_height: 440,
        }
    }
    /// Several panels of `panel_height` pixels, 720 wide.
    pub fn stacked(panels: Vec<Chart>, panel_height: u32) -> Figure {
        Figure {
            panels,
            width: 720,
            panel_height,
        }
    }
    fn size(&self) -> (u32, u32) {
        (
            self.width.max(64),
            self.panel_height.max(64) * self.panels.len().max(1) as u32,
        )
    }
}

/// Tableau 10: distinct for the common kinds of colour blindness, and what most plotting
/// tools use, so readers know it.
pub const PALETTE: [(u8, u8, u8); 10] = [
    (31, 119, 180),
    (255, 127, 14),
    (44, 160, 44),
    (214, 39, 40),
    (148, 103, 189),
    (140, 86, 75),
    (227, 119, 194),
    (127, 127, 127),
    (188, 189, 34),
    (23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    let (r, g, b) = PALETTE[i % PALETTE.len()];
    RGBColor(r, g, b)
}

const FONT: &str = "sans-serif";

/// Register the compiled-in font once; plotters lays out text (SVG too) with it.
fn fonts() -> Result<(), ChartError> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, epaint_default_fonts::UBUNTU_LIGHT)
            .is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(ChartError::Draw {
            chart: String::new(),
            message: "the compiled-in font does not parse".into(),
        })
    }
}

/// The figure as an SVG document.
pub fn svg(fig: &Figure) -> Result<String, ChartError> {
    fonts()?;
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, fig.size()).into_drawing_area();
        draw_figure(&root, fig)?;
        root.present().map_err(|e| draw_err("figure", e))?;
    }
    Ok(out)
}

/// The figure as PNG bytes (RGB8).
pub fn png(fig: &Figure) -> Result<Vec<u8>, ChartError> {
    fonts()?;
    let (w, h) = fig.size();
    let mut buf = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        draw_figure(&root, fig)?;
        root.present().map_err(|e| draw_err("figure", e))?;
    }
    let img = image::RgbImage::from_raw(w, h, buf)
        .ok_or_else(|| ChartError::Png("buffer size does not match the image".into()))?;
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .map_err(|e| ChartError::Png(e.to_string()))?;
    Ok(out.into_inner())
}

fn draw_err(chart: &str, e: impl std::fmt::Display) -> ChartError {
    ChartError::Draw {
        chart: chart.to_string(),
        message: e.to_string(),
    }
}

fn draw_figure<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    fig: &Figure,
) -> Result<(), ChartError> {
    root.fill(&WHITE).map_err(|e| draw_err("figure", e))?;
    let areas = root.split_evenly((fig.panels.len().max(1), 1));
    for (chart, area) in fig.panels.iter().zip(&areas) {
        let chart = &concrete(chart);
        let entries = legend_entries(chart);
        // The legend gets a column of its own on the right, so it never hides data.
        let (plot, legend) = if entries.is_empty() {
            (area.clone(), None)
        } else {
            let longest = entries
                .iter()
                .map(|e| e.0.chars().count())
                .max()
                .unwrap_or(0);
            let w = area.dim_in_pixel().0 as i32;
            let col = (longest as i32 * 8 + 44).clamp(90, w * 2 / 5);
            let (a, b) = area.split_horizontally(w - col);
            (a, Some(b))
        };
        let x = resolve(&chart.x, chart, |p| p.0);
        let y = resolve(&chart.y, chart, |p| p.1);
        let r = match (chart.x.scale, chart.y.scale) {
            (Scale::Log, Scale::Log) => draw_chart(&plot, chart, x.log_scale(), y.log_scale()),
            (Scale::Log, _) => draw_chart(&plot, chart, x.log_scale(), y),
            (_, Scale::Log) => draw_chart(&plot, chart, x, y.log_scale()),
            _ => draw_chart(&plot, chart, x, y),
        };
        r.map_err(|m| draw_err(&chart.title, m))?;
        if let Some(col) = legend {
            draw_legend(&col, &entries).map_err(|m| draw_err(&chart.title, m))?;
        }
    }
    Ok(())
}

/// The chart with [`Scale::Auto`] axes decided from its data.
fn concrete(chart: &Chart) -> Chart {
    let mut c = chart.clone();
    let decide = |axis: &mut Axis, pick: &dyn Fn((f64, f64)) -> f64| {
        if axis.scale != Scale::Auto {
            return;
        }
        let vals: Vec<f64> = chart
            .series
            .iter()
            .flat_map(|s| s.values())
            .map(pick)
            .filter(|v| v.is_finite())
            .collect();
        let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        axis.scale = if lo > 0.0 && hi / lo > 20.0 {
            Scale::Log
        } else {
            Scale::Linear
        };
    };
    decide(&mut c.x, &|p| p.0);
    decide(&mut c.y, &|p| p.1);
    c
}

/// `(name, glyph, colour)` of every named series and marker, in order.
fn legend_entries(chart: &Chart) -> Vec<(String, Kind, RGBColor)> {
    let mut v: Vec<(String, Kind, RGBColor)> = chart
        .series
        .iter()
        .enumerate()
        .filter(|(_, s)| !s.name.is_empty())
        .map(|(i, s)| (s.name.clone(), s.kind.clone(), color(s.color.unwrap_or(i))))
        .collect();
    v.extend(
        chart
            .markers
            .iter()
            .filter(|m| !m.name.is_empty())
            .map(|m| {
                let kind = if m.dashed {
                    Kind::DashedLine
                } else {
                    Kind::Line
                };
                (m.name.clone(), kind, color(m.color))
            }),
    );
    v
}

fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, Kind, RGBColor)],
) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let (x0, mut y) = (6, 52);
    for (name, kind, c) in entries {
        area.draw(&legend_glyph::<DB>(kind, *c, x0, y)).map_err(e)?;
        area.draw(&Text::new(
            name.clone(),
            (x0 + 26, y - 8),
            (FONT, 15).into_font().color(&BLACK),
        ))
        .map_err(e)?;
        y += 20;
    }
    Ok(())
}

/// The range an axis shows: fixed, or the finite values (positive ones on a log axis) padded
/// 5 % (a log axis widened to whole decades).
fn resolve(axis: &Axis, chart: &Chart, pick: impl Fn((f64, f64)) -> f64) -> Range<f64> {
    let log = axis.scale == Scale::Log;
    let usable = |v: f64| v.is_finite() && (!log || v > 0.0);
    let (lo, hi) = match axis.range {
        Some((a, b)) if usable(a) && usable(b) && a < b => (a, b),
        _ => {
            // Only points drawn: both coordinates finite (positive on log axes).
            let drawn = |p: &(f64, f64)| {
                let fine = |v: f64, s: Scale| v.is_finite() && (s != Scale::Log || v > 0.0);
                fine(p.0, chart.x.scale) && fine(p.1, chart.y.scale)
            };
            let mut vals: Vec<f64> = chart
                .series
                .iter()
                .flat_map(|s| s.values())
                .filter(drawn)
                .map(&pick)
                .collect();
            if std::ptr::eq(axis, &chart.x) {
                vals.extend(chart.markers.iter().map(|m| m.x).filter(|v| usable(*v)));
            }
            let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            if !(lo.is_finite() && hi.is_finite()) {
                if log {
                    (1.0, 10.0)
                } else {
                    (0.0, 1.0)
                }
            } else if log {
                (lo, hi)
            } else {
                let pad = ((hi - lo) * 0.05).max(hi.abs().max(1e-9) * 1e-3);
                (lo - pad, hi + pad)
            }
        }
    };
    if log {
        // Just outside whole decades: plotters puts a tick at each power of ten strictly
        // inside the range as computed in floating point.
        let a = 10f64.powf(lo.log10().floor()) * (1.0 - 1e-9);
        let mut b = 10f64.powf(hi.log10().ceil()) * (1.0 + 1e-9);
        if b <= a {
            b = a * 10.0;
        }
        a..b
    } else {
        lo..hi
    }
}

/// Font size of a chart's title: [`TITLE_SIZE`], or smaller where that would be wider than
/// the area it is centred over (a long title beside a wide legend column: its ends would fall
/// off the picture), down to [`MIN_TITLE_SIZE`]. Keeps [`TITLE_PAD`] pixels free either side
/// and a sixteenth of the width to spare: a browser draws the SVG's text in its own
/// sans-serif, which may run wider than the compiled-in font (DejaVu Sans by about 3 %).
fn title_size<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, title: &str) -> u32 {
    let room = area.dim_in_pixel().0.saturating_sub(2 * TITLE_PAD);
    let fits = |size: u32| {
        let style = TextStyle::from((FONT, size).into_font());
        area.estimate_text_size(title, &style)
            .is_ok_and(|(w, _)| w + w / 16 <= room)
    };
    (MIN_TITLE_SIZE..=TITLE_SIZE)
        .rev()
        .find(|&size| fits(size))
        .unwrap_or(MIN_TITLE_SIZE)
}

/// A chart title's font size where it fits ([`title_size`]).
const TITLE_SIZE: u32 = 24;
const MIN_TITLE_SIZE: u32 = 12;
/// Pixels kept free left and right of a title.
const TITLE_PAD: u32 = 4;

/// A tick label: up to four significant digits, thousands as k/M/G.
pub fn tick_label(v: f64) -> String {
    let a = v.abs();
    let (scaled, suffix) = if a >= 1e9 {
        (v / 1e9, "G")
    } else if a >= 1e6 {
        (v / 1e6, "M")
    } else if a >= 1e4 {
        (v / 1e3, "k")
    } else {
        (v, "")
    };
    let digits = if scaled.abs() >= 100.0 || scaled == scaled.round() {
        0
    } else if scaled.abs() >= 10.0 {
        1
    } else if scaled.abs() >= 1.0 {
        2
    } else {
        3
    };
    let mut s = format!("{scaled:.digits$}");
    if s.contains('.') {
        s = s.trim_end_matches('0').trim_end_matches('.').to_string();
    }
    if s == "-0" {
        s = "0".into();
    }
    format!("{s}{suffix}")
}

fn draw_chart<DB, X, Y>(
    area: &DrawingArea<DB, Shift>,
    chart: &Chart,
    x: X,
    y: Y,
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let mut ctx = ChartBuilder::on(area)
        .caption(&chart.title, (FONT, title_size(area, &chart.title)))
        .margin(12)
        .x_label_area_size(52)
        .y_label_area_size(72)
        .build_cartesian_2d(x, y)
        .map_err(e)?;
    let y_range = ctx.y_range();
    ctx.configure_mesh()
        .x_desc(chart.x.label.as_str())
        .y_desc(chart.y.label.as_str())
        .axis_desc_style((FONT, 18))
        .label_style((FONT, 16))
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .max_light_lines(4)
        .light_line_style(RGBColor(238, 238, 238))
        .bold_line_style(RGBColor(205, 205, 205))
        .draw()
        .map_err(e)?;
    let x_log = chart.x.scale == Scale::Log;
    let y_log = chart.y.scale == Scale::Log;
    let ok = |p: &(f64, f64)| {
        p.0.is_finite() && p.1.is_finite() && (!x_log || p.0 > 0.0) && (!y_log || p.1 > 0.0)
    };
    for (i, s) in chart.series.iter().enumerate() {
        let c = color(s.color.unwrap_or(i));
        let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(ok).collect();
        match &s.kind {
            Kind::Points => {
                ctx.draw_series(pts.iter().map(|&p| Circle::new(p, 4, c.filled())))
                    .map_err(e)?;
            }
            Kind::Line => {
                ctx.draw_series(LineSeries::new(pts.iter().copied(), c.stroke_width(2)))
                    .map_err(e)?;
            }
            Kind::DashedLine => {
                ctx.draw_series(DashedLineSeries::new(
                    pts.iter().copied(),
                    6,
                    4,
                    c.stroke_width(2),
                ))
                .map_err(e)?;
            }
            Kind::Bars(bars) => {
                let base = if y_log { y_range.start } else { 0.0 };
                ctx.draw_series(
                    bars.iter()
                        .filter(|b| ok(&(b.0, b.2)) && ok(&(b.1, b.2)))
                        .map(|&(x0, x1, h)| Rectangle::new([(x0, base), (x1, h)], c.filled())),
                )
                .map_err(e)?;
            }
            Kind::Front => {
                let mut sorted = pts.clone();
                sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
                let mut stairs = Vec::new();
                for (k, p) in sorted.iter().enumerate() {
                    if k > 0 {
                        stairs.push((p.0, sorted[k - 1].1));
                    }
                    stairs.push(*p);
                }
                ctx.draw_series(LineSeries::new(stairs, c.stroke_width(2)))
                    .map_err(e)?;
                ctx.draw_series(sorted.iter().map(|&p| Circle::new(p, 7, c.stroke_width(2))))
                    .map_err(e)?;
            }
        }
    }
    for m in &chart.markers {
        if !(m.x.is_finite() && (!x_log || m.x > 0.0)) {
            continue;
        }
        let c = color(m.color);
        let line = vec![(m.x, y_range.start), (m.x, y_range.end)];
        if m.dashed {
            ctx.draw_series(DashedLineSeries::new(line, 5, 4, c.stroke_width(2)))
                .map_err(e)?;
        } else {
            ctx.draw_series(LineSeries::new(line, c.stroke_width(2)))
                .map_err(e)?;
        }
    }
    Ok(())
}

fn legend_glyph<DB: DrawingBackend>(
    kind: &Kind,
    c: RGBColor,
    x: i32,
    y: i32,
) -> DynElement<'static, DB, (i32, i32)> {
    match kind {
        Kind::Points => Circle::new((x + 10, y), 4, c.filled()).into_dyn(),
        Kind::Front => Circle::new((x + 10, y), 6, c.stroke_width(2)).into_dyn(),
        Kind::Bars(_) => Rectangle::new([(x + 2, y - 5), (x + 18, y + 5)], c.filled()).into_dyn(),
        Kind::Line => PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)).into_dyn(),
        Kind::DashedLine => plotters::element::DashedPathElement::new(
            vec![(x, y), (x + 22, y)],
            5,
            4,
            c.stroke_width(2),
        )
        .into_dyn(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Figure {
        Figure::single(
            Chart::new("Error against size")
                .x(Axis::log("database size (MB)"))
                .y(Axis::linear("PSNR (dB)"))
                .series(Series::points(
                    "configurations",
                    vec![(0.5, 28.0), (3.0, 31.0), (40.0, 33.0), (f64::NAN, 1.0)],
                ))
                .series(Series::front(
                    "Pareto front",
                    vec![(0.5, 28.0), (40.0, 33.0)],
                ))
                .marker(Marker {
                    x: 3.0,
                    name: "chosen".into(),
                    color: 3,
                    dashed: true,
                }),
        )
    }

    #[test]
    fn svg_has_title_axis_labels_ticks_and_legend() {
        let s = svg(&sample()).unwrap();
        for text in [
            "Error against size",
            "database size (MB)",
            "PSNR (dB)",
            "configurations",
            "Pareto front",
            "chosen",
        ] {
            assert!(s.contains(text), "{text} missing");
        }
        // Decade ticks of the log axis, from 0.1 to 100.
        for tick in [">\n0.1\n<", ">\n1\n<", ">\n10\n<", ">\n100\n<"] {
            assert!(s.contains(tick), "tick {tick} missing");
        }
    }

    #[test]
    fn png_draws_text_and_series_without_system_fonts() {
        let bytes = png(&sample()).unwrap();
        let img = image::load_from_memory(&bytes).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (720, 440));
        let (r, g, b) = PALETTE[0];
        let series = img.pixels().filter(|p| p.0 == [r, g, b]).count();
        assert!(series > 50, "{series} pixels of the first series");
        // Text is anti-aliased grey-to-black: many dark pixels that are no series colour.
        let dark = img.pixels().filter(|p| p.0.iter().all(|&c| c < 80)).count();
        assert!(dark > 500, "{dark} dark pixels");
    }

    #[test]
    fn stacked_panels_and_bars_draw() {
        let panel = |t: &str| {
            Chart::new(t)
                .x(Axis::linear("time (s)"))
                .y(Axis::linear("fraction").range(0.0, 1.0))
                .series(Series::line("a", vec![(0.0, 0.0), (1.0, 0.5)]))
                .series(Series::dashed("a needed", vec![(0.0, 0.2), (1.0, 0.9)]).color(0))
        };
        let fig = Figure::stacked(vec![panel("one"), panel("two")], 200);
        let s = svg(&fig).unwrap();
        assert!(s.contains(">\none\n<") && s.contains(">\ntwo\n<"));
        let bars = Figure::single(
            Chart::new("histogram")
                .x(Axis::log("depth (m)"))
                .y(Axis::linear("weight"))
                .series(Series::bars(
                    "pixels",
                    vec![(1.0, 2.0, 3.0), (2.0, 4.0, 1.0)],
                )),
        );
        assert!(png(&bars).unwrap().len() > 100);
    }

    /// Regression: a title wider than its panel's plot area (the legend column takes up to
    /// two fifths of the width) was centred over the plot area anyway, so its first letters
    /// fell off the picture's left edge (the walk figure's "… streaming at unlimited
    /// bandwidth" panel).
    #[test]
    fn a_long_title_stays_whole_beside_a_wide_legend() {
        let panel = |title: &str| {
            let mut c = Chart::new(title)
                .x(Axis::linear("time since the walk started (s)"))
                .y(Axis::linear("fraction of visible pixels").range(0.0, 1.02));
            for (i, name) in ["naive", "ach+prefetch", "visibility+prefetch"]
                .iter()
                .enumerate()
            {
                c = c
                    .series(
                        Series::line(format!("{name}: quality"), vec![(0.0, 0.1), (3.0, 0.9)])
                            .color(i),
                    )
                    .series(
                        Series::dashed(
                            format!("{name}: at the level needed"),
                            vec![(0.0, 0.2), (3.0, 1.0)],
                        )
                        .color(i),
                    );
            }
            c
        };
        let fig = Figure::stacked(
            vec![
                panel("castle / main: streaming at 2 Mbit/s"),
                panel("castle / main: streaming at unlimited bandwidth"),
            ],
            360,
        );
        let img = image::load_from_memory(&png(&fig).unwrap())
            .unwrap()
            .to_rgb8();
        let dark = |x: u32, y: u32| img.get_pixel(x, y).0.iter().all(|&c| c < 160);
        for (k, top) in [(0, 0), (1, fig.panel_height)] {
            // The title band: above the plot, whose frame starts below the caption.
            let band = top..top + 36;
            let inked: Vec<u32> = (0..img.width())
                .filter(|&x| band.clone().any(|y| dark(x, y)))
                .collect();
            assert!(inked.len() > 100, "panel {k}: no title drawn");
            let (first, last) = (inked[0], inked[inked.len() - 1]);
            assert!(
                first >= 4,
                "panel {k}: the title touches the left edge (first ink at x = {first})"
            );
            assert!(
                last < img.width() - 4,
                "panel {k}: the title touches the right edge (last ink at x = {last})"
            );
        }
    }

    #[test]
    fn empty_and_degenerate_data_still_draw() {
        let fig = Figure::single(
            Chart::new("nothing")
                .x(Axis::log("bytes"))
                .series(Series::points("none", vec![(0.0, 1.0), (-3.0, 2.0)])),
        );
        assert!(svg(&fig).is_ok());
        let one = Figure::single(Chart::new("one").series(Series::points("p", vec![(5.0, 5.0)])));
        assert!(png(&one).is_ok());
    }

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.0), "0");
        assert_eq!(tick_label(2.5), "2.5");
        assert_eq!(tick_label(30.0), "30");
        assert_eq!(tick_label(12_500.0), "12.5k");
        assert_eq!(tick_label(3_000_000.0), "3M");
        assert_eq!(tick_label(0.125), "0.125");
        assert_eq!(tick_label(-1.5), "-1.5");
    }
}

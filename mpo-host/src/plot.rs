//! `curve.png`: evaluation return (mean and +-1 std band) against environment steps.
//!
//! plotters is built without its system font stack (no fontconfig/freetype); text is drawn
//! with a TrueType font read at run time from the usual Debian location. Without one, the
//! curve is skipped with an error the caller reports as a warning: the CSV holds the data.

use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::metrics::MetricsRow;

/// Fonts tried, in order.
const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
];

fn register_font() -> bool {
    static DONE: OnceLock<bool> = OnceLock::new();
    *DONE.get_or_init(|| {
        for p in FONT_PATHS {
            if let Ok(bytes) = std::fs::read(p) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return true;
                }
            }
        }
        false
    })
}

/// One curve: a label and `(env_steps, mean, std)` points.
pub type Series = (String, Vec<(u64, f64, f64)>);

/// Draws the learning curve of `rows` into `path`.
pub fn write_curve(path: &Path, title: &str, rows: &[MetricsRow]) -> Result<(), String> {
    let points = rows
        .iter()
        .map(|r| (r.env_steps, r.eval_return_mean, r.eval_return_std))
        .collect();
    write_curves(path, title, &[(String::new(), points)], None, None)
}

/// The mean over runs (`mpo plot --mean`): at each evaluation step that every one of `series`
/// has, the mean of their evaluation returns and the population standard deviation of those
/// returns over the runs (the spread across seeds, not the episodes'). Steps some run lacks
/// are left out, so each point averages the same runs. `None` when no step is shared.
pub fn mean_over_runs(series: &[Series]) -> Option<Vec<(u64, f64, f64)>> {
    let (_, first) = series.first()?;
    let at = |pts: &[(u64, f64, f64)], x: u64| pts.iter().find(|p| p.0 == x).map(|p| p.1);
    let mut out: Vec<(u64, f64, f64)> = Vec::new();
    for &(x, _, _) in first {
        if out.iter().any(|p| p.0 == x) {
            continue;
        }
        let values: Option<Vec<f64>> = series.iter().map(|(_, p)| at(p, x)).collect();
        let Some(v) = values else { continue };
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|m| (m - mean) * (m - mean)).sum::<f64>() / n;
        out.push((x, mean, var.sqrt()));
    }
    (!out.is_empty()).then_some(out)
}

/// One chart of a grid (`mpo plot --by-task`): its title, its curves and, when given, a
/// dashed horizontal line at a target return.
pub struct Panel {
    /// The panel's caption (the task).
    pub title: String,
    /// Its curves, one per run.
    pub series: Vec<Series>,
    /// Where to draw the target line, if anywhere.
    pub target: Option<f64>,
    /// The step axis's end when the runs stop before it (the task's budget).
    pub budget: Option<u64>,
    /// The mean over the runs ([`mean_over_runs`]), labelled: when given, it is the panel's
    /// bold curve with its band, and the runs are drawn as thin lines behind it.
    pub mean: Option<Series>,
    /// The metrics column drawn when it is not the evaluation return (`mpo plot --metric`):
    /// the y axis's label, and an axis fitted to the data instead of the return's 0-1000.
    pub metric: Option<String>,
}

/// Draws several learning curves (e.g. seeds) into one chart, with a legend when labelled,
/// and their `mean` over runs when given.
pub fn write_curves(
    path: &Path,
    title: &str,
    series: &[Series],
    mean: Option<Series>,
    metric: Option<&str>,
) -> Result<(), String> {
    if !register_font() {
        return Err(format!("no TrueType font found (tried {FONT_PATHS:?})"));
    }
    let root = BitMapBackend::new(path, (900, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| x.to_string())?;
    let panel = Panel {
        title: title.to_string(),
        series: series.to_vec(),
        target: None,
        budget: None,
        mean,
        metric: metric.map(str::to_string),
    };
    draw_panel(&root, &panel, 22)?;
    root.present().map_err(|x| x.to_string())
}

/// Rows and columns of the grid of `n` panels: up to three in a row, so ten tasks make four
/// rows that still read on a laptop screen.
fn grid_shape(n: usize) -> (usize, usize) {
    let cols = n.clamp(1, 3);
    (n.max(1).div_ceil(cols), cols)
}

/// Draws one panel per entry of `panels` in a grid under one title: several tasks' curves at a
/// glance, each on its own step axis.
pub fn write_panels(path: &Path, title: &str, panels: &[Panel]) -> Result<(), String> {
    if !register_font() {
        return Err(format!("no TrueType font found (tried {FONT_PATHS:?})"));
    }
    let (rows, cols) = grid_shape(panels.len());
    // 480 x 320 pixels a panel, and a 40-pixel band for the title.
    let size = (480 * cols as u32, 320 * rows as u32 + 40);
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(|x| x.to_string())?;
    let body = root
        .titled(title, ("sans-serif", 24))
        .map_err(|x| x.to_string())?;
    for (p, area) in panels.iter().zip(body.split_evenly((rows, cols))) {
        draw_panel(&area, p, 16)?;
    }
    root.present().map_err(|x| x.to_string())
}

/// The return axis: the Control Suite's 0-1000 when every curve and band fits in it, else
/// the data's range rounded out to a power of ten near a tenth of its span (Gymnasium's returns: Pendulum-v1's
/// -1500-0, HalfCheetah's thousands).
fn y_range(series: &[Series], mean: Option<&Series>, target: Option<f64>) -> (f64, f64) {
    let (lo, hi) = data_range(series, mean, target);
    if !(lo.is_finite() && hi.is_finite()) || (lo >= 0.0 && hi <= 1000.0) {
        return (0.0, 1000.0);
    }
    let step = 10f64.powf(((hi - lo).max(10.0) / 10.0).log10().floor());
    let (lo, hi) = ((lo / step).floor() * step, (hi / step).ceil() * step);
    (lo.min(0.0), if hi > 0.0 { hi } else { 0.0 })
}

/// Another metric's axis: the data's range with a twentieth of its span on each side (a
/// flat curve gets a unit around it), so a weight growth of 1-3 or a loss near 0.01 reads.
fn metric_range(series: &[Series], mean: Option<&Series>, target: Option<f64>) -> (f64, f64) {
    let (lo, hi) = data_range(series, mean, target);
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let pad = if hi > lo { (hi - lo) / 20.0 } else { 0.5 };
    (lo - pad, hi + pad)
}

/// The smallest and largest value of every curve and band (and the target line).
fn data_range(series: &[Series], mean: Option<&Series>, target: Option<f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, pts) in series.iter().chain(mean) {
        for &(_, m, sd) in pts {
            lo = lo.min(m - sd);
            hi = hi.max(m + sd);
        }
    }
    if let Some(t) = target {
        (lo, hi) = (lo.min(t), hi.max(t));
    }
    (lo, hi)
}

/// One chart in `area`: each series as its mean line, points and +-1 std band, the x axis to
/// the longest series or the budget, the y axis the Control Suite's 0-1000 return range (or
/// the data's, [`y_range`]).
fn draw_panel(
    area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>,
    panel: &Panel,
    caption: u32,
) -> Result<(), String> {
    let Panel {
        title,
        series,
        target,
        budget,
        mean,
        metric,
    } = panel;
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let xmax = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.0))
        .chain(*budget)
        .max()
        .unwrap_or(1)
        .max(1) as f64;
    let (ylo, yhi) = match metric {
        None => y_range(series, mean.as_ref(), *target),
        Some(_) => metric_range(series, mean.as_ref(), *target),
    };
    // As many decimals as the axis's span needs (a return's none, a growth of 1-3 two).
    let decimals = (2.0 - (yhi - ylo).log10().floor()).clamp(0.0, 6.0) as usize;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", caption))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..xmax, ylo..yhi)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("environment steps")
        .y_desc(metric.as_deref().unwrap_or("evaluation return"))
        .label_style(("sans-serif", 14))
        .x_label_formatter(&|x| steps_label(*x))
        .y_label_formatter(&|y| format!("{y:.decimals$}"))
        .draw()
        .map_err(|x| e(&x))?;
    if let &Some(y) = target {
        chart
            .draw_series(DashedLineSeries::new(
                [(0.0, y), (xmax, y)],
                6,
                4,
                BLACK.mix(0.6).stroke_width(1),
            ))
            .map_err(|x| e(&x))?;
    }
    draw_series(&mut chart, series, mean.as_ref(), (ylo, yhi))
}

type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The curves of one chart, and their legend when labelled: each run bold with its band, or,
/// under a `mean`, each run thin and the mean bold in black with its band over runs.
fn draw_series<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    series: &'a [Series],
    mean: Option<&'a Series>,
    y: (f64, f64),
) -> Result<(), String> {
    for (k, s) in series.iter().enumerate() {
        let color = Palette99::pick(k).to_rgba();
        if mean.is_some() {
            draw_thin(chart, s, color)?;
        } else {
            draw_bold(chart, s, color, y)?;
        }
    }
    if let Some(m) = mean {
        draw_bold(chart, m, BLACK.to_rgba(), y)?;
    }
    let labelled = series.iter().chain(mean).any(|(l, _)| !l.is_empty());
    if labelled {
        chart
            .configure_series_labels()
            .position(legend_position(series, y))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|x| x.to_string())?;
    }
    Ok(())
}

/// One run under a mean: a thin line, no band, no points.
fn draw_thin<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    series: &'a Series,
    color: RGBAColor,
) -> Result<(), String> {
    draw_line(chart, series, color.mix(0.55), 1)
}

/// A curve with its +-1 std band, points and legend entry.
fn draw_bold<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    series: &'a Series,
    color: RGBAColor,
    (ylo, yhi): (f64, f64),
) -> Result<(), String> {
    let pts = &series.1;
    let band: Vec<(f64, f64)> = pts
        .iter()
        .map(|&(x, m, s)| (x as f64, (m + s).min(yhi)))
        .chain(
            pts.iter()
                .rev()
                .map(|&(x, m, s)| (x as f64, (m - s).max(ylo))),
        )
        .collect();
    chart
        .draw_series(std::iter::once(Polygon::new(band, color.mix(0.12))))
        .map_err(|x| x.to_string())?;
    draw_line(chart, series, color, 2)?;
    chart
        .draw_series(
            pts.iter()
                .map(|&(x, m, _)| Circle::new((x as f64, m), 3, color.filled())),
        )
        .map_err(|x| x.to_string())?;
    Ok(())
}

/// The mean line of `pts` in `color` and `width`, with its legend entry when labelled.
fn draw_line<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    (label, pts): &'a Series,
    color: RGBAColor,
    width: u32,
) -> Result<(), String> {
    let line = chart
        .draw_series(LineSeries::new(
            pts.iter().map(|&(x, m, _)| (x as f64, m)),
            color.stroke_width(width),
        ))
        .map_err(|x| x.to_string())?;
    if !label.is_empty() {
        line.label(label.as_str()).legend(move |(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(width))
        });
    }
    Ok(())
}

/// An axis label for a step count: `250k`, `1M`, `1.5M`.
fn steps_label(x: f64) -> String {
    if x >= 1e6 {
        format!("{}M", (x / 1e5).round() / 10.0)
    } else {
        format!("{:.0}k", x / 1000.0)
    }
}

/// Where the legend hides the least: learning curves rise to the right, so below them when
/// the later half of the points is mostly above the middle of the range, above them otherwise.
fn legend_position(series: &[Series], (ylo, yhi): (f64, f64)) -> SeriesLabelPosition {
    let xmax = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.0))
        .max()
        .unwrap_or(0);
    let late: Vec<f64> = series
        .iter()
        .flat_map(|(_, p)| p.iter().filter(|q| 2 * q.0 >= xmax).map(|q| q.1))
        .collect();
    let high = late.iter().filter(|&&m| m > (ylo + yhi) / 2.0).count();
    if 2 * high >= late.len() {
        SeriesLabelPosition::LowerRight
    } else {
        SeriesLabelPosition::UpperRight
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(points: &[(f64, f64)]) -> Vec<Series> {
        let pts = points
            .iter()
            .enumerate()
            .map(|(i, &(m, s))| (i as u64, m, s))
            .collect();
        vec![(String::new(), pts)]
    }

    #[test]
    fn the_return_axis_is_the_suites_unless_the_data_leaves_it() {
        assert_eq!(
            y_range(&series(&[(100.0, 50.0), (900.0, 80.0)]), None, None),
            (0.0, 1000.0)
        );
        assert_eq!(y_range(&[], None, None), (0.0, 1000.0));
        // Pendulum-v1: -1283.7 +- 377.6 untrained, -173.2 +- 99.5 trained.
        let p = series(&[(-1283.7, 377.6), (-173.2, 99.5)]);
        assert_eq!(y_range(&p, None, None), (-1700.0, 0.0));
        // HalfCheetah: thousands.
        let h = series(&[(-300.0, 50.0), (9535.0, 100.0)]);
        assert_eq!(y_range(&h, None, Some(12000.0)), (-1000.0, 12000.0));
    }
}

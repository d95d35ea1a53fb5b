//! `curve.png`: evaluation return (mean and +-1 std band) against environment steps.
//!
//! plotters is built without its system font stack (no fontconfig/freetype); text is drawn
//! with a TrueType font read at run time from the usual Debian location. Without one, the
//! curve is skipped with an error the caller reports as a warning: the CSV holds the data.

use std::path::Path;
use std::sync::OnceLock;

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
    write_curves(path, title, &[(String::new(), points)])
}

/// Draws several learning curves (e.g. seeds) into one chart, with a legend when labelled.
pub fn write_curves(path: &Path, title: &str, series: &[Series]) -> Result<(), String> {
    if !register_font() {
        return Err(format!("no TrueType font found (tried {FONT_PATHS:?})"));
    }
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let xmax = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.0))
        .max()
        .unwrap_or(1)
        .max(1) as f64;
    let root = BitMapBackend::new(path, (900, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..xmax, 0f64..1000f64)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("environment steps")
        .y_desc("evaluation return")
        .label_style(("sans-serif", 14))
        .x_label_formatter(&|x| format!("{:.0}k", x / 1000.0))
        .y_label_formatter(&|y| format!("{y:.0}"))
        .draw()
        .map_err(|x| e(&x))?;
    for (k, (label, pts)) in series.iter().enumerate() {
        let color = Palette99::pick(k).to_rgba();
        let band: Vec<(f64, f64)> = pts
            .iter()
            .map(|&(x, m, s)| (x as f64, (m + s).min(1000.0)))
            .chain(
                pts.iter()
                    .rev()
                    .map(|&(x, m, s)| (x as f64, (m - s).max(0.0))),
            )
            .collect();
        chart
            .draw_series(std::iter::once(Polygon::new(band, color.mix(0.12))))
            .map_err(|x| e(&x))?;
        let line = chart
            .draw_series(LineSeries::new(
                pts.iter().map(|&(x, m, _)| (x as f64, m)),
                color.stroke_width(2),
            ))
            .map_err(|x| e(&x))?;
        if !label.is_empty() {
            line.label(label.as_str()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        }
        chart
            .draw_series(
                pts.iter()
                    .map(|&(x, m, _)| Circle::new((x as f64, m), 3, color.filled())),
            )
            .map_err(|x| e(&x))?;
    }
    if series.iter().any(|(l, _)| !l.is_empty()) {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))
}

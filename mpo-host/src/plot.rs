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

/// Draws the learning curve of `rows` into `path`.
pub fn write_curve(path: &Path, title: &str, rows: &[MetricsRow]) -> Result<(), String> {
    if !register_font() {
        return Err(format!("no TrueType font found (tried {FONT_PATHS:?})"));
    }
    let xmax = rows.iter().map(|r| r.env_steps).max().unwrap_or(1).max(1) as f64;
    let root = BitMapBackend::new(path, (900, 540)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..xmax, 0f64..1000f64)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc("environment steps")
        .y_desc("evaluation return")
        .label_style(("sans-serif", 14))
        .x_label_formatter(&|x| format!("{:.0}k", x / 1000.0))
        .y_label_formatter(&|y| format!("{y:.0}"))
        .draw()
        .map_err(|e| e.to_string())?;
    let band: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| {
            (
                r.env_steps as f64,
                (r.eval_return_mean + r.eval_return_std).min(1000.0),
            )
        })
        .chain(rows.iter().rev().map(|r| {
            (
                r.env_steps as f64,
                (r.eval_return_mean - r.eval_return_std).max(0.0),
            )
        }))
        .collect();
    chart
        .draw_series(std::iter::once(Polygon::new(band, BLUE.mix(0.15))))
        .map_err(|e| e.to_string())?;
    chart
        .draw_series(LineSeries::new(
            rows.iter()
                .map(|r| (r.env_steps as f64, r.eval_return_mean)),
            BLUE.stroke_width(2),
        ))
        .map_err(|e| e.to_string())?;
    chart
        .draw_series(
            rows.iter()
                .map(|r| Circle::new((r.env_steps as f64, r.eval_return_mean), 3, BLUE.filled())),
        )
        .map_err(|e| e.to_string())?;
    root.present().map_err(|e| e.to_string())
}

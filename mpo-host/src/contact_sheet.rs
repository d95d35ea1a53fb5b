//! A contact sheet: frames of a rollout side by side in one PNG, each labelled with its step
//! and running return, under a title line. For docs and reports, where a video does not fit.

use std::path::Path;

use crate::caption;
use crate::video::MediaError;

/// Frames per row at most.
pub const COLUMNS: usize = 4;
/// Pixels between tiles and around them.
const GAP: usize = 4;
/// Background (dark grey).
const BACKGROUND: u8 = 32;

/// One frame of the sheet.
#[derive(Clone, Debug)]
pub struct Tile {
    /// RGB, rows from the top.
    pub rgb: Vec<u8>,
    /// Its label (drawn inside the tile's top-left corner).
    pub label: String,
}

/// The sheet as one RGB image: `title` on top, then `tiles` (all `width` x `height`) in rows
/// of at most [`COLUMNS`]. Returns the image and its size.
pub fn compose(
    title: &str,
    tiles: &[Tile],
    width: usize,
    height: usize,
) -> (Vec<u8>, usize, usize) {
    let scale = caption::scale_for(height);
    let columns = tiles.len().clamp(1, COLUMNS);
    let rows = tiles.len().div_ceil(COLUMNS).max(1);
    let title_h = caption::CELL * scale + 2 * GAP;
    let sheet_w = columns * width + (columns + 1) * GAP;
    let sheet_h = title_h + rows * height + rows * GAP;
    let mut sheet = vec![BACKGROUND; sheet_w * sheet_h * 3];
    caption::draw(&mut sheet, sheet_w, sheet_h, GAP, GAP - 1, scale, title);
    for (i, tile) in tiles.iter().enumerate() {
        assert_eq!(tile.rgb.len(), width * height * 3, "tile size");
        let x0 = GAP + (i % COLUMNS) * (width + GAP);
        let y0 = title_h + (i / COLUMNS) * (height + GAP);
        for y in 0..height {
            let dst = ((y0 + y) * sheet_w + x0) * 3;
            sheet[dst..dst + width * 3].copy_from_slice(&tile.rgb[y * width * 3..][..width * 3]);
        }
        caption::draw(
            &mut sheet,
            sheet_w,
            sheet_h,
            x0 + 2,
            y0 + 2,
            scale,
            &tile.label,
        );
    }
    (sheet, sheet_w, sheet_h)
}

/// Writes an RGB image as a PNG.
pub fn write_png(path: &Path, rgb: &[u8], width: usize, height: usize) -> Result<(), MediaError> {
    let err = |e: &dyn std::fmt::Display| MediaError::Write {
        path: path.into(),
        message: e.to_string(),
    };
    let file = std::fs::File::create(path).map_err(|e| err(&e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::High);
    let mut w = enc.write_header().map_err(|e| err(&e))?;
    w.write_image_data(rgb).map_err(|e| err(&e))?;
    w.finish().map_err(|e| err(&e))
}

/// Checks that `path` names a PNG file (before any work is done).
pub fn check_path(path: &Path) -> Result<(), MediaError> {
    match path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
    {
        Some(e) if e == "png" => Ok(()),
        _ => Err(MediaError::UnsupportedExtension {
            path: path.into(),
            supported: ".png",
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_land_in_rows_under_the_title() {
        let (w, h) = (10, 8);
        let tiles: Vec<Tile> = (0..5)
            .map(|i| Tile {
                rgb: vec![50 + i as u8; w * h * 3],
                label: String::new(),
            })
            .collect();
        let (sheet, sw, sh) = compose("", &tiles, w, h);
        assert_eq!(sw, 4 * w + 5 * GAP);
        let title_h = caption::CELL + 2 * GAP;
        assert_eq!(sh, title_h + 2 * h + 2 * GAP);
        let px = |x: usize, y: usize| sheet[(y * sw + x) * 3];
        assert_eq!(px(GAP, title_h), 50);
        assert_eq!(px(GAP + 3 * (w + GAP), title_h + h - 1), 53);
        assert_eq!(px(GAP, title_h + h + GAP), 54);
        assert_eq!(px(0, 0), BACKGROUND);
        assert!(check_path(Path::new("x.PNG")).is_ok());
        assert!(check_path(Path::new("x.gif")).is_err());
    }
}

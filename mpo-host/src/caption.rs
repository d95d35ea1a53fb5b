//! Text on RGB frames: the step and running return on each rendered frame, the labels of a
//! contact sheet.
//!
//! The glyphs are the public-domain 8x8 bitmap font (`font8x8`), compiled in: captions need no
//! font file on the machine and come out the same bits everywhere, so two renders of one
//! rollout give identical files. White on a one-pixel black outline, readable on the
//! Control Suite's dark skybox and light floor alike.

use font8x8::legacy::BASIC_LEGACY;

/// Glyph cell size in font pixels (before scaling).
pub const CELL: usize = 8;

/// A caption scale that keeps text about 1/30 of the image height: 1 up to 359 pixels, 2 up
/// to 599, ...
pub fn scale_for(height: usize) -> usize {
    (height / 240).max(1)
}

/// Width in pixels of `text` at `scale` (one cell per character).
pub fn text_width(text: &str, scale: usize) -> usize {
    text.chars().count() * CELL * scale
}

/// The font's bitmap of `c`; characters outside ASCII draw as '?'.
fn glyph(c: char) -> [u8; 8] {
    let code = if c.is_ascii() {
        c as usize
    } else {
        '?' as usize
    };
    BASIC_LEGACY[code]
}

/// Calls `set(x, y)` for every pixel of `text` drawn with its top-left corner at `(x0, y0)`.
fn for_each_pixel(
    text: &str,
    x0: usize,
    y0: usize,
    scale: usize,
    mut set: impl FnMut(usize, usize),
) {
    for (i, c) in text.chars().enumerate() {
        let rows = glyph(c);
        for (gy, row) in rows.iter().enumerate() {
            for gx in 0..CELL {
                // Bit 0 is the leftmost pixel of a row.
                if row & (1 << gx) == 0 {
                    continue;
                }
                let (px, py) = (x0 + (i * CELL + gx) * scale, y0 + gy * scale);
                for dy in 0..scale {
                    for dx in 0..scale {
                        set(px + dx, py + dy);
                    }
                }
            }
        }
    }
}

/// Draws `text` into an RGB image (`width * height * 3` bytes, rows from the top) with its
/// top-left corner at `(x, y)`: white glyphs on a black outline. Pixels outside the image are
/// skipped.
pub fn draw(
    rgb: &mut [u8],
    width: usize,
    height: usize,
    x: usize,
    y: usize,
    scale: usize,
    text: &str,
) {
    let mut put = |px: usize, py: usize, value: u8| {
        if px < width && py < height {
            let i = (py * width + px) * 3;
            rgb[i..i + 3].fill(value);
        }
    };
    // The outline: every glyph pixel's 8 neighbours in black, then the glyph in white on top.
    for_each_pixel(text, x + 1, y + 1, scale, |px, py| {
        for (dx, dy) in [
            (0, 0),
            (1, 0),
            (2, 0),
            (0, 1),
            (2, 1),
            (0, 2),
            (1, 2),
            (2, 2),
        ] {
            put(px + dx - 1, py + dy - 1, 0);
        }
    });
    for_each_pixel(text, x + 1, y + 1, scale, |px, py| put(px, py, 255));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_white_glyphs_with_a_black_outline_inside_the_image() {
        let (w, h) = (40, 12);
        let mut rgb = vec![100u8; w * h * 3];
        draw(&mut rgb, w, h, 0, 0, 1, "1.0");
        let white = rgb.chunks(3).filter(|p| p == &[255, 255, 255]).count();
        let black = rgb.chunks(3).filter(|p| p == &[0, 0, 0]).count();
        assert!(white > 10 && black > white, "white {white}, black {black}");
        // Nothing outside the three cells (plus the outline) changed.
        for y in 0..h {
            for x in 3 * CELL + 2..w {
                assert_eq!(&rgb[(y * w + x) * 3..][..3], &[100, 100, 100], "({x}, {y})");
            }
        }
        // Text running off the edge is clipped, not a panic.
        draw(&mut rgb, w, h, 35, 8, 2, "return 999.9");
    }

    #[test]
    fn scale_and_width() {
        assert_eq!(scale_for(240), 1);
        assert_eq!(scale_for(480), 2);
        assert_eq!(scale_for(64), 1);
        assert_eq!(text_width("step 10", 2), 7 * 16);
    }
}

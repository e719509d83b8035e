//! Text in the embedded 8x8 bitmap font (`font8x8`'s public-domain basic Latin set): no font
//! files, no shaping, pixel-exact everywhere. Characters outside ASCII draw as `?`.

use super::{Canvas, Rgba};

/// Glyph cell size in font pixels.
pub const GLYPH: u32 = 8;

/// Width of `s` in pixels at `scale`.
pub fn width(s: &str, scale: u32) -> f32 {
    (s.chars().count() as u32 * GLYPH * scale) as f32
}

/// The glyph of `c`: 8 rows, bit 0 of a row is its leftmost pixel.
fn glyph(c: char) -> [u8; 8] {
    let i = if c.is_ascii() { c as usize } else { '?' as usize };
    font8x8::legacy::BASIC_LEGACY[i]
}

/// Draws `s` with its top-left corner at (x, y); returns the width drawn.
pub fn draw(canvas: &mut Canvas, x: f32, y: f32, s: &str, scale: u32, color: Rgba) -> f32 {
    let px = scale as f32;
    for (i, c) in s.chars().enumerate() {
        let gx = x + (i as u32 * GLYPH * scale) as f32;
        for (row, bits) in glyph(c).iter().enumerate() {
            for col in 0..GLYPH {
                if bits & (1 << col) != 0 {
                    canvas.fill_rect(gx + col as f32 * px, y + row as f32 * px, px, px, color);
                }
            }
        }
    }
    width(s, scale)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{INK, WHITE};

    /// The pixels of `s` drawn at scale 1, as rows of '#' and '.'.
    fn ascii_art(s: &str) -> Vec<String> {
        let w = width(s, 1) as u32;
        let mut c = Canvas::new(w, GLYPH, WHITE).unwrap();
        draw(&mut c, 0.0, 0.0, s, 1, INK);
        (0..GLYPH)
            .map(|y| (0..w).map(|x| if c.pixel(x, y) == Some(INK) { '#' } else { '.' }).collect())
            .collect()
    }

    #[test]
    fn letters_have_their_shapes() {
        // A capital I: a bar on top and bottom, a stem in the middle.
        let i = ascii_art("I");
        assert_eq!(i[0], ".####...");
        assert_eq!(i[3], "..##....");
        assert_eq!(i[6], ".####...");
        // A space draws nothing; a non-ASCII character draws like '?'.
        assert!(ascii_art(" ").iter().all(|r| !r.contains('#')));
        assert_eq!(ascii_art("é"), ascii_art("?"));
    }

    #[test]
    fn scale_multiplies_size() {
        assert_eq!(width("abc", 2), 48.0);
        let mut c = Canvas::new(16, 16, WHITE).unwrap();
        draw(&mut c, 0.0, 0.0, "I", 2, INK);
        // Row 0 of 'I' at scale 2 covers pixel rows 0 and 1, columns 2..10.
        assert_eq!(c.pixel(2, 1), Some(INK));
        assert_eq!(c.pixel(9, 0), Some(INK));
        assert_eq!(c.pixel(0, 0), Some(WHITE));
    }
}

//! Rendered views and input frames as 8-bit RGB pictures: colour, depth
//! and relevance, with one colour ramp for every scalar, and pictures
//! placed side by side.

use std::path::Path;

use anyhow::Result;
use latentam::frames::Frame;
use latentam::RenderedView;

/// Pixels whose accumulated opacity is below this show no surface
/// (black), as in the evaluation's coverage.
pub const COVERED_ALPHA: f32 = 0.5;

/// A `width × height` RGB8 picture, row-major.
pub struct Picture {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<u8>,
}

/// A colour in 0..1 (clamped) as 8-bit values.
pub fn to_bytes(c: [f32; 3]) -> [u8; 3] {
    c.map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
}

impl Picture {
    fn from_pixels(width: u32, height: u32, pixels: impl Iterator<Item = [f32; 3]>) -> Self {
        let rgb = pixels.flat_map(to_bytes).collect();
        Picture { width, height, rgb }
    }

    /// Writes the picture as a PNG, whole or not at all.
    pub fn write_png(&self, path: &Path) -> Result<()> {
        crate::png_out::write_rgb(path, self.width, self.height, &self.rgb)
    }

    /// `pictures` left to right on black, `gap` pixels apart, top-aligned.
    pub fn side_by_side(pictures: &[&Picture], gap: u32) -> Picture {
        let height = pictures.iter().map(|p| p.height).max().unwrap_or(0);
        let width = pictures.iter().map(|p| p.width).sum::<u32>()
            + gap * (pictures.len().saturating_sub(1) as u32);
        let mut rgb = vec![0u8; width as usize * height as usize * 3];
        let mut left = 0usize;
        for p in pictures {
            let row = p.width as usize * 3;
            for y in 0..p.height as usize {
                let at = (y * width as usize + left) * 3;
                rgb[at..at + row].copy_from_slice(&p.rgb[y * row..(y + 1) * row]);
            }
            left += p.width as usize + gap as usize;
        }
        Picture { width, height, rgb }
    }
}

pub use latentam_view::heat;

/// The smallest and largest of `values` where `keep` holds; `None` when
/// none is kept.
pub fn range_of(values: &[f32], keep: impl Fn(usize) -> bool) -> Option<(f32, f32)> {
    values
        .iter()
        .enumerate()
        .filter(|&(i, v)| keep(i) && v.is_finite())
        .fold(None, |r, (_, &v)| match r {
            None => Some((v, v)),
            Some((lo, hi)) => Some((lo.min(v), hi.max(v))),
        })
}

/// `values` through the heat ramp over `lo..hi`, black where `keep` does
/// not hold.
pub fn heat_picture(
    width: u32,
    height: u32,
    values: &[f32],
    (lo, hi): (f32, f32),
    keep: impl Fn(usize) -> bool,
) -> Picture {
    let span = (hi - lo).max(1e-6);
    Picture::from_pixels(
        width,
        height,
        values.iter().enumerate().map(|(i, &v)| {
            if keep(i) && v.is_finite() {
                heat((v - lo) / span)
            } else {
                [0.0; 3]
            }
        }),
    )
}

/// The rendered colour (on black where the map has nothing).
pub fn rendered_colour(view: &RenderedView) -> Picture {
    Picture::from_pixels(
        view.width,
        view.height,
        view.rgbd.iter().map(|p| [p[0], p[1], p[2]]),
    )
}

/// The rendered depth in metres per pixel (expected depth: the blended
/// depth over the opacity); NaN where the map covers the pixel too little.
pub fn rendered_depth_m(view: &RenderedView) -> Vec<f32> {
    view.rgbd
        .iter()
        .zip(&view.alpha)
        .map(|(p, &a)| {
            if a >= COVERED_ALPHA {
                p[3] / a
            } else {
                f32::NAN
            }
        })
        .collect()
}

/// A frame's colour image.
pub fn input_colour(frame: &Frame) -> Picture {
    Picture {
        width: frame.color.width,
        height: frame.color.height,
        rgb: frame.color.to_rgb8(),
    }
}

/// A frame's depth in metres per pixel, NaN where invalid.
pub fn input_depth_m(frame: &Frame) -> Vec<f32> {
    let n = frame.depth.width as usize * frame.depth.height as usize;
    (0..n)
        .map(|i| frame.depth.metres(i).unwrap_or(f32::NAN))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn side_by_side_places_each_picture_at_its_offset() {
        let a = Picture {
            width: 2,
            height: 2,
            rgb: vec![10; 12],
        };
        let b = Picture {
            width: 1,
            height: 1,
            rgb: vec![200, 201, 202],
        };
        let c = Picture::side_by_side(&[&a, &b], 3);
        assert_eq!((c.width, c.height), (6, 2));
        let px = |x: usize, y: usize| &c.rgb[(y * 6 + x) * 3..(y * 6 + x) * 3 + 3];
        assert_eq!(px(1, 1), [10, 10, 10]);
        assert_eq!(px(2, 0), [0, 0, 0]);
        assert_eq!(px(5, 0), [200, 201, 202]);
        assert_eq!(px(5, 1), [0, 0, 0]);
    }

    #[test]
    fn heat_runs_from_blue_to_red_and_range_skips_what_is_not_kept() {
        assert!(heat(0.0)[2] > heat(0.0)[0] && heat(1.0)[0] > heat(1.0)[2]);
        assert_eq!(heat(-1.0), heat(0.0));
        let v = [5.0, f32::NAN, -1.0, 9.0];
        assert_eq!(range_of(&v, |i| i != 3), Some((-1.0, 5.0)));
        assert_eq!(range_of(&v, |_| false), None);
        let p = heat_picture(2, 2, &v, (-1.0, 5.0), |i| i != 3);
        assert_eq!(&p.rgb[9..12], [0, 0, 0]);
        assert_eq!(&p.rgb[3..6], [0, 0, 0], "NaN is black");
    }
}

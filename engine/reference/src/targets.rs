//! A keyframe's Stage I inputs from their compact form (kernel
//! `glsl/target_unpack.comp`): the supervision image (RGB bytes over 255 ×
//! the keyframe's exposure gain, millimetre depth in metres, 0, invalid,
//! staying 0) and the chunk's region row of each pixel.

/// `[r, g, b, z]` per pixel from packed RGB bytes (3 per pixel) and
/// millimetre depth: `r = rgb[3i] / (255 · exposure)`, and so on, `z =
/// depth_mm[i] · 0.001`. Computed in f64 and rounded once, so a kernel
/// dividing in f32 is within an ulp or two of it.
pub fn unpack_target(rgb: &[u8], depth_mm: &[u16], exposure: f32) -> Vec<[f32; 4]> {
    let scale = 255.0 * exposure as f64;
    rgb.chunks_exact(3)
        .zip(depth_mm)
        .map(|(c, &d)| {
            [
                (c[0] as f64 / scale) as f32,
                (c[1] as f64 / scale) as f32,
                (c[2] as f64 / scale) as f32,
                (d as f64 * 0.001) as f32,
            ]
        })
        .collect()
}

/// The chunk's region row of each pixel of a view from the view's own
/// rows (`local`, 0xffff: none): `row_base + local[i]`, or `NO_REGION`
/// (0xffffffff) where it names none or the view has no regions
/// (`has_labels` false).
pub fn unpack_labels(local: &[u16], row_base: u32, has_labels: bool) -> Vec<u32> {
    local
        .iter()
        .map(|&l| match (has_labels, l) {
            (true, l) if l != u16::MAX => row_base + l as u32,
            _ => u32::MAX,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_over_255_times_the_gain_and_millimetres_in_metres() {
        let t = unpack_target(&[255, 0, 51, 10, 20, 30], &[1500, 0], 1.0);
        assert_eq!(t[0], [1.0, 0.0, 0.2, 1.5]);
        assert_eq!(t[1][3], 0.0, "no depth stays invalid");
        let bright = unpack_target(&[255, 255, 255], &[1], 2.0);
        assert_eq!(bright[0][..3], [0.5; 3]);
    }

    #[test]
    fn local_rows_move_to_the_chunk_and_none_stays_none() {
        assert_eq!(
            unpack_labels(&[0, 3, u16::MAX], 10, true),
            [10, 13, u32::MAX]
        );
        assert_eq!(unpack_labels(&[0, 3], 10, false), [u32::MAX; 2]);
    }
}

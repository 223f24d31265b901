//! A view's values at the pixels of a grid (kernel
//! `glsl/coverage_grid.comp`): every `stride`-th pixel across and down
//! from `start`, row by row, as seeding looks at a keyframe.

/// The values of a `width`-wide row-major image at the grid's pixels:
/// cell `k` of a grid `cols` wide is pixel `(start[0] + (k % cols) ·
/// stride, start[1] + (k / cols) · stride)`, for `cells` cells.
pub fn gather_grid<T: Copy>(
    image: &[T],
    width: u32,
    stride: u32,
    start: [u32; 2],
    cols: u32,
    cells: u32,
) -> Vec<T> {
    (0..cells)
        .map(|k| {
            let (r, c) = (k / cols, k % cols);
            let (u, v) = (start[0] + c * stride, start[1] + r * stride);
            image[(v * width + u) as usize]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_stride_th_pixel_from_the_start_row_by_row() {
        // A 5 × 4 image whose values name their pixel.
        let image: Vec<(u32, u32)> = (0..20).map(|i| (i % 5, i / 5)).collect();
        let cells = gather_grid(&image, 5, 2, [1, 1], 2, 4);
        assert_eq!(cells, [(1, 1), (3, 1), (1, 3), (3, 3)]);
        assert_eq!(gather_grid(&image, 5, 1, [0, 0], 5, 20), image);
    }
}

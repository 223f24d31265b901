//! A grid of pixels of a view: every `stride`-th pixel across and down from
//! a start pixel. Seeding looks at a keyframe only at such a grid (its
//! candidate pixels), so what the map renders there is all it reads back
//! ([`Rasterizer::render_alpha_rgbd`](super::Rasterizer::render_alpha_rgbd)).

/// Every `stride`-th pixel across and down a view from `start`, cells
/// numbered row by row.
///
/// ```
/// use latentam_core::splat::PixelGrid;
///
/// let grid = PixelGrid { stride: 2, start: [1, 1] };
/// assert_eq!((grid.cols(640), grid.rows(480)), (320, 240));
/// assert_eq!(grid.cell(641, 480, 640), None); // a pixel between cells
/// assert_eq!(grid.cell(3, 1, 640), Some(1));
/// assert_eq!(grid.pixel(320, 640), Some((1, 3)));
/// assert_eq!(PixelGrid::ALL.cells(640, 480), 640 * 480);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PixelGrid {
    /// Pixels from one cell to the next, across and down (at least 1).
    pub stride: u32,
    /// The first cell's pixel `(u, v)`.
    pub start: [u32; 2],
}

impl PixelGrid {
    /// Every pixel.
    pub const ALL: PixelGrid = PixelGrid {
        stride: 1,
        start: [0, 0],
    };

    fn step(&self) -> u32 {
        self.stride.max(1)
    }

    /// Cells across a view `width` pixels wide.
    pub fn cols(&self, width: u32) -> u32 {
        width.saturating_sub(self.start[0]).div_ceil(self.step())
    }

    /// Cells down a view `height` pixels high.
    pub fn rows(&self, height: u32) -> u32 {
        height.saturating_sub(self.start[1]).div_ceil(self.step())
    }

    /// Cells in a `width` × `height` view.
    pub fn cells(&self, width: u32, height: u32) -> u64 {
        self.cols(width) as u64 * self.rows(height) as u64
    }

    /// The cell at pixel `(u, v)` of a view `width` pixels wide; `None`
    /// when the pixel is not one of the grid's (or lies past the view's
    /// width).
    pub fn cell(&self, u: u32, v: u32, width: u32) -> Option<usize> {
        let (du, dv) = (u.checked_sub(self.start[0])?, v.checked_sub(self.start[1])?);
        let s = self.step();
        (u < width && du % s == 0 && dv % s == 0)
            .then(|| (dv / s) as usize * self.cols(width) as usize + (du / s) as usize)
    }

    /// The pixel `(u, v)` of cell `k` in a view `width` pixels wide;
    /// `None` when the grid has no column there.
    pub fn pixel(&self, k: usize, width: u32) -> Option<(u32, u32)> {
        let cols = self.cols(width) as usize;
        (cols > 0).then(|| {
            let s = self.step();
            let (r, c) = ((k / cols) as u32, (k % cols) as u32);
            (self.start[0] + c * s, self.start[1] + r * s)
        })
    }
}

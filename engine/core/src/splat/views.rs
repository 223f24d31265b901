//! A batch of cameras as the kernels see it: per-view constants, and where
//! each view's pixels and tiles start in the batch's flat buffers.

use latentam_shaders::shared::View;

use super::{Camera, TILE_SIZE};
use latentam_base::Result;

/// Where one view's data sits in the batch buffers.
///
/// ```
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(64, 48), Camera::at_origin(32, 32)])?;
/// let second = layout.views[1];
/// assert_eq!(second.first_pixel, 64 * 48);
/// assert_eq!(second.first_tile, 4 * 3);
/// assert_eq!((second.tiles_x, second.tiles_y), (2, 2));
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ViewSlot {
    /// Image width.
    pub width: u32,
    /// Image height.
    pub height: u32,
    /// Index of the view's first pixel in the batch's per-pixel buffers
    /// (row-major within the view).
    pub first_pixel: u64,
    /// Index of the view's first tile in the batch's tile list.
    pub first_tile: u32,
    /// Tiles across.
    pub tiles_x: u32,
    /// Tiles down.
    pub tiles_y: u32,
}

/// The layout of a batch of views.
///
/// ```
/// use latentam_core::splat::{BatchLayout, Camera};
///
/// let layout = BatchLayout::for_cameras(&[Camera::at_origin(64, 48); 3])?;
/// assert_eq!(layout.views.len(), 3);
/// assert_eq!(layout.pixels, 3 * 64 * 48);
/// assert_eq!(layout.tiles, 3 * 4 * 3); // 16×16-pixel tiles
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BatchLayout {
    /// One entry per view, in batch order.
    pub views: Vec<ViewSlot>,
    /// Pixels over all views.
    pub pixels: u64,
    /// Tiles over all views.
    pub tiles: u32,
}

impl BatchLayout {
    /// The layout of a batch of these cameras' views, back to back (errors
    /// for an invalid camera or a batch too large to index).
    pub fn for_cameras(cams: &[Camera]) -> Result<Self> {
        Ok(Self::new(cams)?.0)
    }

    pub(crate) fn new(cams: &[Camera]) -> Result<(Self, Vec<View>)> {
        let mut layout = BatchLayout::default();
        let mut gpu = Vec::with_capacity(cams.len());
        for cam in cams {
            cam.validate()?;
            let (tx, ty) = tiles(cam);
            let slot = ViewSlot {
                width: cam.width,
                height: cam.height,
                first_pixel: layout.pixels,
                first_tile: layout.tiles,
                tiles_x: tx,
                tiles_y: ty,
            };
            let view = cam.world_to_cam();
            let (m, t) = (view.matrix3, view.translation);
            let row = |r: usize| {
                [
                    m.col(0)[r] as f32,
                    m.col(1)[r] as f32,
                    m.col(2)[r] as f32,
                    t[r] as f32,
                ]
            };
            gpu.push(View {
                row0: row(0),
                row1: row(1),
                row2: row(2),
                intrinsics: [cam.fx as f32, cam.fy as f32, cam.cx as f32, cam.cy as f32],
                guard: cam.guard_band().map(|v| v as f32),
                clip: [cam.near as f32, cam.far as f32, 0.0, 0.0],
                size: [cam.width, cam.height, tx, ty],
                offsets: [layout.tiles, layout.pixels as u32, 0, 0],
            });
            layout.pixels += cam.pixels();
            layout.tiles = layout
                .tiles
                .checked_add(tx * ty)
                .filter(|&t| t < 1 << 24)
                .ok_or_else(|| {
                    crate::Error::bad_input(
                        "the views of a batch",
                        "too many tiles (more than 2^24 16x16 tiles)",
                    )
                })?;
            if layout.pixels > u32::MAX as u64 / 8 {
                return Err(crate::Error::bad_input(
                    "the views of a batch",
                    format!("too many pixels ({})", layout.pixels),
                ));
            }
            layout.views.push(slot);
        }
        Ok((layout, gpu))
    }
}

/// Tiles across and down a camera's image ([`TILE_SIZE`] pixels square,
/// the last ones partial).
fn tiles(cam: &Camera) -> (u32, u32) {
    (
        cam.width.div_ceil(TILE_SIZE),
        cam.height.div_ceil(TILE_SIZE),
    )
}

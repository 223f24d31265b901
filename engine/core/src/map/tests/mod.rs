//! Seeding and keyframe selection on hand-made frames of a flat wall, the
//! local window and PLY files, one file per subject; here, the wall frames.

use glam::{DQuat, DVec3};

use super::*;
use latentam_io::{CameraPose, ColorImage, DepthData, DepthImage, Frame, Intrinsics, PixelFormat};

mod keyframes;
mod ply;
mod seeding;
mod window;

const W: u32 = 32;
const H: u32 = 24;

/// A camera at `eye` rotated by `rotation`, seeing a wall at depth `z`
/// everywhere (depth in mm, 0 in the top-left 4×4 block).
fn wall_frame(eye: DVec3, rotation: DQuat, z_mm: u16) -> Frame {
    let n = (W * H) as usize;
    let color: Vec<u8> = (0..n * 3).map(|i| (i * 7 % 251) as u8).collect();
    let depth: Vec<u16> = (0..n)
        .map(|i| {
            if (i as u32 % W) < 4 && (i as u32 / W) < 4 {
                0
            } else {
                z_mm
            }
        })
        .collect();
    Frame {
        stamp_ns: 0,
        pose: CameraPose {
            rotation,
            translation: eye,
        },
        intrinsics: Intrinsics {
            width: W,
            height: H,
            fx: 40.0,
            fy: 40.0,
            cx: 15.5,
            cy: 11.5,
        },
        color: ColorImage {
            width: W,
            height: H,
            format: PixelFormat::Rgb8,
            data: color,
        },
        depth: DepthImage {
            width: W,
            height: H,
            data: DepthData::Units {
                values: depth,
                metres_per_unit: 0.001,
            },
        },
        embeddings: None,
        semantic: None,
    }
}

//! What the mapper's tests share: a small synthetic keyframe and a
//! keyframe rule that takes every frame.

use glam::{DQuat, DVec3};

use crate::map::{KeyframeConfig, KeyframePolicy};
use crate::mapper::MapperConfig;
use latentam_io::{
    encode_floats, CameraPose, ColorImage, DepthData, DepthImage, Dtype, EmbeddingLayout,
    Embeddings, Frame, Intrinsics, LabelImage, PixelFormat,
};

pub(crate) const W: u32 = 48;
pub(crate) const H: u32 = 36;
pub(crate) const DIM: usize = 32;

/// A wall 1.5 m ahead: red left half (region 0), blue right half with a
/// gradient (region 1), each with its own target embedding.
pub(crate) fn keyframe(eye: DVec3) -> Frame {
    let n = (W * H) as usize;
    let mut rgb = Vec::with_capacity(n * 3);
    let mut labels = Vec::with_capacity(n);
    for i in 0..n as u32 {
        let (u, v) = (i % W, i / W);
        if u < W / 2 {
            rgb.extend([200, 40, 30]);
            labels.push(0);
        } else {
            rgb.extend([20, (v * 6) as u8, 220]);
            labels.push(1);
        }
    }
    let mut vectors = vec![0.0f32; 2 * DIM];
    vectors[3] = 1.0;
    vectors[DIM + 17] = 1.0;
    Frame {
        stamp_ns: 0,
        pose: CameraPose {
            rotation: DQuat::IDENTITY,
            translation: eye,
        },
        intrinsics: Intrinsics {
            width: W,
            height: H,
            fx: 50.0,
            fy: 50.0,
            cx: 23.5,
            cy: 17.5,
        },
        color: ColorImage {
            width: W,
            height: H,
            format: PixelFormat::Rgb8,
            data: rgb,
        },
        depth: DepthImage {
            width: W,
            height: H,
            data: DepthData::Units {
                values: vec![1500; n],
                metres_per_unit: 0.001,
            },
        },
        embeddings: Some(Embeddings {
            layout: EmbeddingLayout::Regions(LabelImage {
                width: W,
                height: H,
                labels,
            }),
            count: 2,
            dim: DIM as u32,
            dtype: Dtype::F32,
            data: encode_floats(&vectors, Dtype::F32),
            model: "test".into(),
        }),
        semantic: None,
    }
}

/// Keyframe selection that takes every frame, so a test's frames all train.
pub(crate) fn every_frame_a_keyframe() -> KeyframeConfig {
    KeyframeConfig {
        policy: KeyframePolicy::Interval(1),
        ..Default::default()
    }
}

/// A small map of the fixture's keyframes: every frame a keyframe, a window
/// of 8192 Gaussians, 16 atoms, the fixture's two regions kept.
pub(crate) fn small_map_config() -> MapperConfig {
    MapperConfig {
        keyframes: every_frame_a_keyframe(),
        window_capacity: Some(8192),
        atoms: 16,
        max_regions: 64,
        min_region_pixels: 4,
        ..MapperConfig::default()
    }
}

//! Seeding and keyframe selection on hand-made frames of a flat wall.

use glam::{DQuat, DVec3};

use super::*;
use crate::io::{CameraPose, ColorImage, DepthData, DepthImage, Frame, Intrinsics, PixelFormat};

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

#[test]
fn seeds_lie_on_the_measured_surface_once_per_voxel() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let mut map = GlobalMap::new(0.01);
    let config = SeedingConfig::default();
    let seeds = seed_from_frame(&frame, None, &map, &config, 1);
    // Stride 2 from pixel 1: 16 × 12 candidates, minus the 2 × 2 without depth;
    // at 2 m a 2-pixel step is 10 cm, so every candidate has its own voxel.
    assert_eq!(seeds.len(), 16 * 12 - 4);
    for g in &seeds {
        assert!((g.mean[2] - 2.0).abs() < 1e-5, "{:?}", g.mean);
        let u = (g.mean[0] as f64 / 2.0 * 40.0 + 15.5).round() as u32;
        let v = (g.mean[1] as f64 / 2.0 * 40.0 + 11.5).round() as u32;
        assert_eq!(frame.color.rgb(u, v).map(|c| c as f32 / 255.0), g.color);
        // σ = 0.5 × 2 px × 2 m / 40 px = 5 cm; opacity 0.5.
        assert!((g.log_scale[0] - 0.05f32.ln()).abs() < 1e-5);
        assert_eq!(g.opacity_logit, 0.0);
        assert_eq!(g.quat, [1.0, 0.0, 0.0, 0.0]);
        assert!(
            g.query.iter().any(|&q| q != 0.0),
            "queries are never all zero"
        );
    }
    assert_eq!(
        seed_from_frame(&frame, None, &map, &config, 1),
        seeds,
        "deterministic"
    );
    for g in &seeds {
        map.insert(*g).unwrap();
    }
    // Everything is now occupied: the same view adds nothing.
    assert!(seed_from_frame(&frame, None, &map, &config, 1).is_empty());
}

#[test]
fn only_unexplained_pixels_are_seeded_and_new_seeds_inherit_neighbour_queries() {
    let frame = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let map = GlobalMap::new(0.01);
    let n = (W * H) as usize;
    // The map explains the left half (alpha 1, depth right), not the right
    // half (alpha 0), and gets the depth wrong in the bottom rows.
    let alpha: Vec<f32> = (0..n)
        .map(|i| if (i as u32 % W) < W / 2 { 1.0 } else { 0.0 })
        .collect();
    let depth: Vec<f32> = (0..n)
        .map(|i| {
            if i as u32 / W >= H - 4 {
                3.0 * alpha[i]
            } else {
                2.0 * alpha[i]
            }
        })
        .collect();
    let rendered = RenderedView {
        alpha: &alpha,
        depth: &depth,
    };
    let seeds = seed_from_frame(&frame, Some(rendered), &map, &SeedingConfig::default(), 1);
    // Right half: 8 × 12 candidates; left half bottom 4 rows: 8 × 2.
    assert_eq!(seeds.len(), 8 * 12 + 8 * 2);

    // A dense wall (stride 1 at 0.4 m: 1 cm between pixels): seeds next to
    // existing Gaussians copy their query.
    let near = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 400);
    let dense = SeedingConfig {
        stride: 4,
        ..SeedingConfig::default()
    };
    let mut map = GlobalMap::new(0.01);
    let first = seed_from_frame(&near, None, &map, &dense, 1);
    for g in &first {
        map.insert(*g).unwrap();
    }
    let moved = wall_frame(DVec3::new(0.011, 0.0, 0.0), DQuat::IDENTITY, 400);
    let second = seed_from_frame(&moved, None, &map, &dense, 2);
    assert!(!second.is_empty());
    for g in &second {
        let key = map.key_of(DVec3::from(g.mean.map(f64::from))).unwrap();
        if let Some(n) = key.neighbourhood().find_map(|k| map.get(k)) {
            assert_eq!(g.query, n.query);
        }
    }
}

#[test]
fn keyframes_by_interval_by_overlap_and_only_after_motion() {
    let map = GlobalMap::new(0.01);
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Interval(3),
        min_translation: 0.0,
        min_rotation_deg: 0.0,
    });
    let f = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let picks: Vec<bool> = (0..7).map(|_| sel.decide(&f, &map).keyframe).collect();
    assert_eq!(picks, [true, false, false, true, false, false, true]);

    // With a minimum translation, a camera standing still makes one keyframe.
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Interval(1),
        min_translation: 0.1,
        min_rotation_deg: 5.0,
    });
    let picks: Vec<bool> = (0..4).map(|_| sel.decide(&f, &map).keyframe).collect();
    assert_eq!(picks, [true, false, false, false]);
    let turned = wall_frame(DVec3::ZERO, DQuat::from_rotation_y(0.2), 2000);
    assert!(
        sel.decide(&turned, &map).keyframe,
        "11° of rotation counts as motion"
    );

    // Overlap: a view of what is mapped is not a keyframe, a new wall is.
    // (At 0.5 m the seeds are 2.5 cm apart, the overlap check's points fall
    // between them.)
    let f = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 500);
    let mut map = GlobalMap::new(0.01);
    for g in seed_from_frame(&f, None, &map, &SeedingConfig::default(), 1) {
        map.insert(g);
    }
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Overlap {
            min_overlap: 0.7,
            stride: 2,
        },
        min_translation: 0.0,
        min_rotation_deg: 0.0,
    });
    assert!(sel.decide(&f, &map).keyframe, "the first frame always is");
    let same = sel.decide(&f, &map);
    assert!(!same.keyframe && same.overlap.unwrap() > 0.99, "{same:?}");
    let away = wall_frame(
        DVec3::ZERO,
        DQuat::from_rotation_y(std::f64::consts::PI),
        500,
    );
    let d = sel.decide(&away, &map);
    assert!(d.keyframe && d.overlap.unwrap() < 0.01, "{d:?}");
}

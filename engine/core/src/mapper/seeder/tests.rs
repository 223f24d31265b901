//! The seeder's bookkeeping of guesses against what keyframes measure, and
//! the order in which seeds take their voxels.

use bytemuck::Zeroable;
use glam::DVec3;

use super::*;
use crate::mapper::tests::fixtures::keyframe;
use latentam_io::DepthData;

const W: usize = 48;

fn gaussian_at(mean: [f32; 3]) -> Gaussian {
    Gaussian {
        mean,
        ..Gaussian::zeroed()
    }
}

/// The pixel (column, row) a point in front of the test camera at the
/// origin projects to (fx = fy = 50, cx = 23.5, cy = 17.5).
fn pixel_of(p: [f32; 3]) -> usize {
    let u = (50.0 * p[0] as f64 / p[2] as f64 + 23.5).round() as usize;
    let v = (50.0 * p[1] as f64 / p[2] as f64 + 17.5).round() as usize;
    v * W + u
}

/// The test keyframe (a wall 1.5 m ahead) with no depth where `holes`
/// project.
fn frame_with_holes(holes: &[[f32; 3]]) -> Frame {
    let mut frame = keyframe(DVec3::ZERO);
    let DepthData::Units { values, .. } = &mut frame.depth.data else {
        unreachable!("the test keyframe has depth in millimetres")
    };
    for p in holes {
        values[pixel_of(*p)] = 0;
    }
    frame
}

#[test]
fn seeds_take_voxels_nearest_first_and_unmeasured_ones_are_guesses() {
    let near = [0.0, 0.0, 1.0];
    let far = [0.3, 0.0, 1.5];
    // In the same 1 cm voxel as `near`, but farther from the camera.
    let near_twin = [0.002, 0.002, 1.004];
    let frame = frame_with_holes(&[near]);
    let mut seeder = Seeder::new(SeedingConfig::default());
    let mut global = GlobalMap::new(0.01);
    let seeds = vec![far, near_twin, near]
        .into_iter()
        .map(gaussian_at)
        .collect();
    let keys = seeder.insert(&frame, seeds, &mut global);
    assert_eq!(
        keys.len(),
        2,
        "the twin's voxel was taken by the nearer seed"
    );
    assert_eq!(global.get(keys[0]).unwrap().mean, near);
    assert_eq!(global.get(keys[1]).unwrap().mean, far);
    assert!(seeder.is_guess(&keys[0]), "no depth where it was seeded");
    assert!(!seeder.is_guess(&keys[1]));
    assert!(!seeder.is_superseded(&keys[0]));
}

#[test]
fn a_keyframe_that_measures_a_guess_confirms_it_supersedes_it_or_leaves_it() {
    let floating = [0.0, 0.0, 1.0]; // in front of the 1.5 m wall
    let on_wall = [0.0, 0.1, 1.5];
    let hidden = [0.0, -0.2, 3.0]; // behind it
    let first = frame_with_holes(&[floating, on_wall, hidden]);
    let mut seeder = Seeder::new(SeedingConfig::default());
    let mut global = GlobalMap::new(0.01);
    let seeds = [floating, on_wall, hidden].map(gaussian_at).to_vec();
    let keys = seeder.insert(&first, seeds, &mut global);
    assert_eq!(keys.len(), 3);
    assert!(keys.iter().all(|k| seeder.is_guess(k)));

    // The wall measured everywhere.
    let second = keyframe(DVec3::ZERO);
    seeder.check_guesses(&second, &global);
    let key_of = |p: [f32; 3]| global.key_of(DVec3::from(p.map(f64::from))).unwrap();
    let (floating, on_wall, hidden) = (key_of(floating), key_of(on_wall), key_of(hidden));
    assert!(seeder.is_superseded(&floating) && !seeder.is_guess(&floating));
    assert!(!seeder.is_guess(&on_wall) && !seeder.is_superseded(&on_wall));
    assert!(
        seeder.is_guess(&hidden),
        "nothing says a hidden guess is wrong"
    );

    // Pruning takes the superseded ones, once.
    let taken = seeder.take_superseded();
    assert_eq!(taken.len(), 1);
    assert!(taken.contains(&floating));
    assert!(seeder.take_superseded().is_empty());
}

#[test]
fn guesses_removed_from_the_map_are_forgotten() {
    let hole = [0.1, 0.0, 1.2];
    let frame = frame_with_holes(&[hole]);
    let mut seeder = Seeder::new(SeedingConfig::default());
    let mut global = GlobalMap::new(0.01);
    let keys = seeder.insert(&frame, vec![gaussian_at(hole)], &mut global);
    global.remove(keys[0]);
    seeder.check_guesses(&keyframe(DVec3::ZERO), &global);
    assert!(!seeder.is_guess(&keys[0]) && !seeder.is_superseded(&keys[0]));
}

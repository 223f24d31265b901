//! The map: the CPU global map keyed by voxel, keyframe selection and the
//! seeding of new Gaussians from keyframes.

mod global;
mod keyframes;
mod seeding;
mod voxel;

pub use global::{Gaussian, GlobalMap, OCCUPANCY_VOXELS};
pub use keyframes::{overlap, KeyframeConfig, KeyframeDecision, KeyframePolicy, KeyframeSelector};
pub use seeding::{seed_from_frame, RenderedView, SeedingConfig};
pub use voxel::VoxelKey;

#[cfg(test)]
mod tests;

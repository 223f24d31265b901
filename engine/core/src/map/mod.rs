//! The map: the CPU global map keyed by voxel, the GPU local window paged
//! to and from it, keyframe selection and the seeding of new Gaussians.

mod exposure;
mod gaussian;
mod global;
mod keyframes;
pub mod ply;
mod seeding;
mod spill;
mod voxel;
mod window;

pub use exposure::{relative_exposure, ExposureTrack, EXPOSURE_RANGE};
pub use global::{Block, Gaussian, GlobalMap, SpillCounts, BLOCK_VOXELS, OCCUPANCY_VOXELS};
pub use keyframes::{overlap, KeyframeConfig, KeyframeDecision, KeyframePolicy, KeyframeSelector};
pub use ply::{
    read_ply, unit_quat, write_map_ply, write_map_ply_streamed, write_ply,
    write_ply_without_latents, PlyMap,
};
pub use seeding::{
    seed_from_frame, QueryInit, RegionQueries, SeedingConfig, ViewCoverage, MAX_DEPTH_ERROR,
    MAX_SCALE_FACTOR,
};
pub use voxel::{KeyMap, KeySet, VoxelKey};
pub use window::{
    gaussian_at, push_gaussian, Companion, LocalWindow, Outbox, PendingSync, StagedArrivals,
    SyncPlan,
};

#[cfg(test)]
mod tests;

//! The online mapper (paper §III, Algorithm 1). Built so far: the
//! keyframe history replayed in each Stage I batch.

mod history;

pub use history::{camera_of, History, KeyframeRecord, RegionTargets};

//! The online mapper (paper §III, Algorithm 1). Built so far: the
//! keyframe history replayed in each Stage I batch and the Stage I / II
//! trainer.

mod history;
mod trainer;

pub use history::{camera_of, History, KeyframeRecord, RegionTargets};
pub use trainer::{StageOneReport, Trainer, TrainerConfig};

#[cfg(test)]
mod tests;

//! The online mapper (paper §III, Algorithm 1). Built so far: the
//! keyframe history replayed in each Stage I batch, the Stage I / II
//! trainer and the per-keyframe loop ([`OnlineMapper`]).

pub mod budget;
mod history;
mod online;
mod trainer;

pub use history::{camera_of, History, KeyframeRecord, RegionTargets};
pub use online::{
    Integrated, KeyframeReport, KeyframeTimings, MapperConfig, MapperStats, OnlineMapper,
    PagingReport,
};
pub use trainer::{StageOneReport, Trainer, TrainerConfig};

#[cfg(test)]
mod tests;

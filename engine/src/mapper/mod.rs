//! The online mapper (paper §III, Algorithm 1): the keyframe history
//! replayed in each Stage I batch, the Stage I / II trainer, the
//! per-keyframe loop with window paging and a GPU memory budget
//! ([`OnlineMapper`]), saving and loading its state, and the library
//! façade [`Mapper`].

mod archive;
pub mod budget;
pub mod eval;
mod facade;
mod history;
mod online;
mod persist;
mod trainer;

pub use facade::{Mapper, STATE_FILE};
pub use history::{camera_of, History, KeyframeRecord, RegionTargets};
pub use online::{
    Integrated, KeyframeReport, KeyframeTimings, MapperConfig, MapperStats, OnlineMapper,
    PagingReport,
};
pub use trainer::{StageOneReport, Trainer, TrainerConfig};

#[cfg(test)]
mod tests;

//! The online mapper (paper §III, Algorithm 1): the keyframe history
//! replayed in each Stage I batch, the Stage I / II trainer, the
//! per-keyframe loop with window paging and a GPU memory budget
//! ([`OnlineMapper`]), saving and loading its state ([`SavedState`]), the library
//! façade [`Mapper`], and the configuration written out for users
//! ([`documented_defaults`], [`apply_overrides`]).

mod archive;
pub mod budget;
mod config_doc;
pub mod eval;
mod export;
mod facade;
mod history;
mod online;
mod persist;
mod trainer;

pub use config_doc::{apply_overrides, documented_defaults};
pub use export::{DecoderFile, DECODER_FILE, DECODER_FORMAT, DECODER_VERSION};
pub use facade::{Mapper, STATE_FILE};
pub use history::{camera_of, History, KeyframeRecord, RegionTargets};
pub use online::{
    Integrated, KeyframeReport, KeyframeTimings, MapperConfig, MapperStats, OnlineMapper,
    PagingReport,
};
pub use persist::SavedState;
pub use trainer::{views_per_chunk, StageOneReport, Trainer, TrainerConfig, DEFAULT_CHUNK_PIXELS};

#[cfg(test)]
mod persist_tests;
#[cfg(test)]
mod tests;

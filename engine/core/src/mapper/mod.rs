//! The online mapper (paper §III, Algorithm 1): [`Mapper`], one value of
//! owned parts (the keyframe selector, the dictionary, the seeder, the
//! pager of the global map and its GPU window, the Stage I / II trainer,
//! the keyframe history replayed in each Stage I batch, the exposure
//! track, the progress counters), the route a frame takes through them,
//! saving and loading its state ([`SavedState`]), run folders, evaluation,
//! and the configuration written out for users ([`documented_defaults`],
//! [`apply_overrides`]).

mod archive;
#[doc(hidden)]
pub use archive::{checksum as archive_checksum, join_resealed as archive_join_resealed};
pub mod budget;
pub(crate) mod class_iou;
mod config;
mod config_doc;
mod dictionary;
pub mod eval;
mod export;
mod facade;
mod history;
mod keyframe_report;
mod pager;
mod persist;
pub mod pixel_metrics;
mod preset;
mod progress;
mod relevance_index;
mod route;
mod run_folder;
mod run_report;
mod seeder;
mod snapshot;
mod trainer;
mod views;
mod warm_up;
mod work_report;
mod workspace;

pub use config::MapperConfig;
pub use config_doc::{apply_overrides, documented_defaults};
pub use export::{DecoderFile, DECODER_FILE, DECODER_FORMAT, DECODER_VERSION};
#[cfg(any(test, feature = "testing"))]
pub use facade::Internals;
pub use facade::Mapper;
pub use history::{camera_of, History, KeyframeRecord, RegionTargets, ReplayKey};
pub use keyframe_report::{
    DiskReport, Integrated, KeyframeGpuCalls, KeyframeGpuWork, KeyframeReport, KeyframeTimings,
    MapperStats, PagingReport,
};
pub use persist::SavedState;
pub use preset::Preset;
pub use relevance_index::{IndexSettings, RelevanceIndex};
pub use run_folder::{
    folder_version, new_run_id, read_one_version, RunFolder, RunStaging, RUN_FOLDER_FILES,
    RUN_MARKER, STATE_FILE,
};
pub use run_report::{
    first_keyframe_over_median, Ending, HostWaits, KernelBuilds, PagingPerKeyframe, RunReport,
};
pub use snapshot::MapSnapshot;
pub use trainer::stage_two::StageTwoRun;
pub use trainer::{
    views_per_chunk, ChunkView, KeptTargets, Outputs, StageOneReport, SubmittedStageOne, Trainer,
    TrainerConfig, DEFAULT_CHUNK_PIXELS,
};
pub use views::{Scored, Viewpoint};
pub use warm_up::warm_up;
pub use work_report::{GpuWorkReport, KernelWorkPerKeyframe};

#[cfg(test)]
mod tests;

//! The online mapper (paper §III, Algorithm 1): the keyframe history
//! replayed in each Stage I batch, the Stage I / II trainer, the
//! per-keyframe loop with window paging and a GPU memory budget
//! ([`OnlineMapper`]), saving and loading its state ([`SavedState`]), the library
//! façade [`Mapper`], and the configuration written out for users
//! ([`documented_defaults`], [`apply_overrides`]).

mod archive;
pub mod budget;
pub(crate) mod class_iou;
mod config;
mod config_doc;
pub mod eval;
mod export;
mod facade;
mod history;
mod keyframe_report;
mod log_run;
mod online;
mod persist;
pub mod pixel_metrics;
mod preset;
mod run_folder;
mod run_report;
mod trainer;

pub use config::MapperConfig;
pub use config_doc::{apply_overrides, documented_defaults};
pub use export::{DecoderFile, DECODER_FILE, DECODER_FORMAT, DECODER_VERSION};
pub use facade::Mapper;
pub use history::{camera_of, History, KeyframeRecord, RegionTargets};
pub use keyframe_report::{
    Integrated, KeyframeGpuCalls, KeyframeReport, KeyframeTimings, MapperStats, PagingReport,
};
pub use log_run::{Kept, LogRun, LogRunOptions, RunObserver, Written};
pub use online::OnlineMapper;
pub use persist::SavedState;
pub use preset::Preset;
pub use run_folder::{new_run_id, RunFolder, RunStaging, RUN_FOLDER_FILES, STATE_FILE};
pub use run_report::{Ending, HostWaits, RunReport};
pub use trainer::{views_per_chunk, StageOneReport, Trainer, TrainerConfig, DEFAULT_CHUNK_PIXELS};

#[cfg(test)]
mod persist_tests;
#[cfg(test)]
mod tests;

/// Creates ahead of time the pipeline of every kernel mapping dispatches on
/// `ctx`'s device, so that no keyframe pays for compiling one: all kernels
/// but the rasterizer's blending variants meant for other devices (see
/// [`crate::splat::Rasterizer::blend_kernel_names`]). Returns the number of
/// pipelines ready.
///
/// ```
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// assert!(latentam_core::mapper::warm_up(&ctx)? < latentam_shaders::ALL.len());
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub fn warm_up(ctx: &latentam_gpu::Context) -> crate::Result<usize> {
    use crate::splat::{Rasterizer, RenderSettings};
    // The trainer's and the evaluator's settings: the defaults.
    let used = Rasterizer::blend_kernel_names(ctx.info(), &RenderSettings::default());
    ctx.warm_up_only(|k| !k.name.starts_with("raster_") || used.contains(&k.name))
}

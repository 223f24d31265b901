//! Mapping live, beside a robot's loop: [`LiveMapper`] owns the mapper on
//! a worker thread. The caller only enqueues frames, which never waits
//! for the GPU, reads immutable snapshots published after each keyframe,
//! and asks for renders and saves, which the worker serves between
//! keyframes.
//!
//! ```text
//!  submit ──► bounded queue ──► worker: integrate ─► snapshot (Arc) ──► relevance, readers
//!   (drops by policy, counted)      ▲     between keyframes: render, save (loans)
//! ```

mod handle;
mod keyframe_image;
mod log_run;
mod log_run_types;
mod options;
mod queue;
mod reader;
mod shared;
mod tally;
mod worker;

pub use crate::mapper::{IndexSettings, MapSnapshot, RelevanceIndex};
pub use handle::LiveMapper;
pub use keyframe_image::KeyframeImage;
pub use log_run_types::{Kept, LogRun, LogRunOptions, RunObserver, Written};
pub use options::LiveOptions;
pub use queue::{frame_bytes, DropCounts};
pub use reader::{LiveReader, LiveStatus, Relevance};

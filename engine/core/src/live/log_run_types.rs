//! The types of a log run: how it goes through a log
//! ([`LogRunOptions`]), what it tells the caller as it goes
//! ([`RunObserver`]), what it is when it ends ([`LogRun`]) and whether
//! the run folder took it ([`Written`], [`Kept`]). The run itself is in
//! `log_run.rs`.

use std::path::{Path, PathBuf};

use super::reader::LiveReader;
use crate::mapper::{Ending, KeyframeReport, Mapper, MapperStats, RunReport};
use latentam_base::{Error, Result};
use latentam_io::{IngestReport, McapFrames};

/// How [`LogRun::map`] goes through a log.
///
/// ```no_run
/// # fn f() -> latentam_core::Result<()> {
/// use latentam_core::live::LogRunOptions;
/// // The first 500 frames, saving every 10 keyframes.
/// let options = LogRunOptions { max_frames: Some(500), autosave_every: 10, ..Default::default() };
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, Default)]
pub struct LogRunOptions {
    /// Stop after this many frames of the log (those a resumed run skips
    /// included).
    pub max_frames: Option<usize>,
    /// Write the run folder every this many keyframes while mapping (0:
    /// only at the end, by [`LogRun::write_folder`]), so a crash or a lost
    /// device loses at most this many keyframes.
    pub autosave_every: u64,
    /// Keep mapping when an autosave fails (listed in the report's
    /// `autosave_failures`). By default a failed autosave stops the run:
    /// a folder that cannot be written now will not be written at the
    /// end either, and hours of mapping would be lost without a word.
    pub continue_after_failed_autosave: bool,
    /// A flag that, once set (say from a signal handler), makes the
    /// keyframe in progress skip its remaining optimisation steps, leaving
    /// the map consistent, so that the run can stop and be saved soon;
    /// clear it to map normally again.
    pub hurry: Option<&'static std::sync::atomic::AtomicBool>,
}

/// What a client sees of a run of a log, and what it adds to it. Every
/// method has a default that does nothing, so `&mut ()` observes nothing.
///
/// ```no_run
/// # fn f() -> latentam_core::Result<()> {
/// use latentam_core::live::RunObserver;
/// use latentam_core::mapper::{KeyframeReport, MapperStats};
/// struct Printer;
/// impl RunObserver for Printer {
///     fn frame_done(&mut self, frames: u64, _: &MapperStats, last: Option<&KeyframeReport>) {
///         if let Some(k) = last {
///             eprintln!("frame {frames}: keyframe {} took {:.0} ms", k.index, k.timings.total_ms);
///         }
///     }
/// }
/// # Ok(())
/// # }
/// ```
pub trait RunObserver {
    /// Before the first frame: the log's frame source (its topic plan, its
    /// vocabulary) and the number of frames the run will go through, when
    /// the log's summary says.
    fn started(&mut self, _frames: &McapFrames, _total: Option<usize>) {}

    /// After each frame of the log, mapped or skipped: how many were gone
    /// through, the mapper's statistics after it, and the last keyframe's
    /// report.
    fn frame_done(&mut self, _frames: u64, _stats: &MapperStats, _last: Option<&KeyframeReport>) {}

    /// Asked before each frame: whether to stop here ([`Ending::Interrupted`]).
    /// A keyframe in progress can be cut short too, through
    /// [`LogRunOptions::hurry`].
    fn stop_requested(&mut self) -> bool {
        false
    }

    /// Once mapping starts: a reader of the live map (for a viewer, see
    /// `latentam_view::LiveView`), valid until the run ends.
    fn live_started(&mut self, _reader: &LiveReader) {}

    /// The input looks wrong in a way that does not stop mapping (e.g.
    /// depth in another camera frame than colour): said once per warning,
    /// as soon as it is seen; all are in the report's `ingest.warnings`.
    fn input_warning(&mut self, _warning: &str) {}

    /// An autosave failed; mapping goes on, and the failure is listed in
    /// the report.
    fn autosave_failed(&mut self, _keyframe: u64, _error: &Error) {}

    /// Writes the client's own files into the staged version of the run
    /// folder `dir`, beside the report, before it is swapped in. Each must
    /// be one of [`RUN_FOLDER_FILES`](crate::mapper::RUN_FOLDER_FILES).
    fn write_extra_files(&mut self, _dir: &Path, _report: &RunReport) -> Result<()> {
        Ok(())
    }
}

impl RunObserver for () {}

/// What [`LogRun::write_folder`] did.
///
/// ```no_run
/// # fn f(run: &mut latentam_core::live::LogRun, folder: &latentam_core::mapper::RunFolder) -> latentam_core::Result<()> {
/// use latentam_core::live::Written;
/// match run.write_folder(folder, &mut ())? {
///     Written::Saved(report) => println!("saved {} keyframes", report.keyframes),
///     Written::Kept(why) => eprintln!("folder unchanged: {why}"),
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub enum Written {
    /// The folder now holds this run, described by the report.
    Saved(Box<RunReport>),
    /// The folder was left as it was, for this reason.
    Kept(Kept),
}

/// Why [`LogRun::write_folder`] left the folder as it was.
///
/// ```no_run
/// # fn f(run: &latentam_core::live::LogRun) -> latentam_core::Result<()> {
/// use latentam_core::live::Kept;
/// if let Some(Kept::NothingMapped(why)) = run.not_to_save() {
///     eprintln!("the log gave no map: {why}");
/// }
/// # Ok(())
/// # }
/// ```
#[derive(Debug, Clone, PartialEq)]
pub enum Kept {
    /// A resumed run whose log frames were all mapped already: the folder
    /// holds this map.
    NothingNew,
    /// No keyframe, or no Gaussian, came of the log (the reasons, counted).
    NothingMapped(String),
    /// A keyframe failed part-way: the map is neither before nor after it.
    Broken,
}

impl std::fmt::Display for Kept {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Kept::NothingNew => write!(
                f,
                "no new frame was mapped; the folder keeps the map it holds"
            ),
            Kept::NothingMapped(why) => write!(f, "nothing was mapped ({why})"),
            Kept::Broken => write!(f, "a keyframe failed part-way, so the map cannot be saved"),
        }
    }
}

/// A finished (or stopped) run of a log.
///
/// ```no_run
/// use latentam_io::AssemblyConfig;
/// use latentam_core::live::{LogRun, LogRunOptions, Written};
/// use latentam_core::mapper::{Mapper, RunFolder, STATE_FILE};
///
/// let ctx = latentam_gpu::Context::new(Default::default())?;
/// let folder = RunFolder::lock("out/run")?;
/// // Continue the map saved there, or start one.
/// let mapper = if folder.dir().join(STATE_FILE).exists() {
///     Mapper::load(&ctx, folder.dir())?
/// } else {
///     Mapper::with_context(&ctx, latentam_core::mapper::MapperConfig::default())?
/// };
/// let options = LogRunOptions { autosave_every: 25, ..Default::default() };
/// let mut run = LogRun::map(
///     mapper,
///     "log.mcap".as_ref(),
///     AssemblyConfig::default(),
///     &options,
///     Some(&folder),
///     &mut (),
/// )?;
/// match run.write_folder(&folder, &mut ())? {
///     Written::Saved(report) => println!("{} keyframes", report.keyframes),
///     Written::Kept(why) => println!("kept as it was: {why}"),
/// }
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct LogRun {
    /// The mapper, holding the map.
    pub mapper: Mapper,
    /// The input log (or, for a run from live topics, what names them,
    /// e.g. `ros2:/latentam`).
    pub log: PathBuf,
    /// Frames offered to the mapper in this run.
    pub frames: u64,
    /// Frames skipped because the resumed state had mapped them.
    pub skipped: u64,
    /// Every keyframe mapped in this run.
    pub keyframes: Vec<KeyframeReport>,
    /// Wall time of this run, seconds.
    pub wall_s: f64,
    /// How it ended.
    pub ending: Ending,
    /// What the log held and what of it was skipped.
    pub ingest: IngestReport,
    /// Keyframe count at the last successful autosave.
    pub autosaved_at: Option<u64>,
    /// Autosaves that failed (mapping went on).
    pub autosave_failures: Vec<String>,
    /// Frames that reached the mapper and were not keyframes.
    pub not_keyframes: u64,
}

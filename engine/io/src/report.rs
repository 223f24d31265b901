//! Why messages and frames were not used, counted by reason.

use std::collections::BTreeMap;
use std::fmt;

use latentam_base::Rejection;

/// How often one reason occurred, with its first instance as an example.
///
/// ```
/// # fn f(report: &latentam_io::IngestReport) {
/// for (reason, c) in &report.skipped {
///     eprintln!("{reason}: {} times (first: {})", c.count, c.first);
/// }
/// # }
/// ```
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ReasonCount {
    /// Occurrences.
    pub count: u64,
    /// The detail of the first occurrence.
    pub first: String,
}

/// What the ingest did with a log: messages read, frames produced, and
/// every message or frame not used, by reason. Nothing is dropped without
/// being counted here.
///
/// ```no_run
/// use latentam_io::{AssemblyConfig, McapFrames};
///
/// let mut frames = McapFrames::open("run.mcap".as_ref(), AssemblyConfig::default())?;
/// for frame in &mut frames {
///     let _frame = frame?;
/// }
/// let report = frames.report();
/// if report.total_skipped() > report.frames / 10 {
///     eprintln!("much of the log was not used:\n{report}");
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct IngestReport {
    /// Messages read on the configured topics.
    pub messages: u64,
    /// Frames assembled and handed out.
    pub frames: u64,
    /// Frames that carried embeddings.
    pub frames_with_embeddings: u64,
    /// Messages or frames not used, by reason.
    pub skipped: BTreeMap<&'static str, ReasonCount>,
    /// What was used but looks wrong (each said once), e.g. depth images
    /// in another camera frame than the colour images.
    pub warnings: Vec<String>,
    /// What was done to the input that changes it (each said once), e.g.
    /// depth registered to the colour camera.
    pub notes: Vec<String>,
}

impl IngestReport {
    /// Counts one rejection.
    pub fn count(&mut self, r: &Rejection) {
        self.skipped
            .entry(r.kind)
            .and_modify(|c| c.count += 1)
            .or_insert_with(|| ReasonCount {
                count: 1,
                first: r.detail.clone(),
            });
    }
    /// Records a warning, once.
    pub fn warn(&mut self, warning: String) {
        if !self.warnings.contains(&warning) {
            self.warnings.push(warning);
        }
    }
    /// Records a note, once.
    pub fn note(&mut self, note: String) {
        if !self.notes.contains(&note) {
            self.notes.push(note);
        }
    }
    /// Total of all skips.
    pub fn total_skipped(&self) -> u64 {
        self.skipped.values().map(|c| c.count).sum()
    }
    /// Occurrences of one reason.
    pub fn skipped_for(&self, kind: &str) -> u64 {
        self.skipped.get(kind).map_or(0, |c| c.count)
    }
}

impl fmt::Display for IngestReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{} messages read, {} frames assembled ({} with embeddings), {} skipped",
            self.messages,
            self.frames,
            self.frames_with_embeddings,
            self.total_skipped()
        )?;
        for (kind, c) in &self.skipped {
            writeln!(f, "  {:>6} × {kind} (first: {})", c.count, c.first)?;
        }
        for n in &self.notes {
            writeln!(f, "  note: {n}")?;
        }
        for w in &self.warnings {
            writeln!(f, "  warning: {w}")?;
        }
        Ok(())
    }
}

//! A log: one file or a rosbag2 directory of split files, read as one.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use super::file::LogFile;
use super::records::{channel_of, Channel, Metadata};
use crate::InputError;

/// An opened MCAP log.
///
/// ```no_run
/// use latentam_io::{McapLog, ReadFilter};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// for c in log.channels() {
///     println!("{} ({})", c.topic, c.schema_name);
/// }
/// let mut reader = log.reader(ReadFilter::default());
/// while let Some(done) = reader.next_with(|m| m.data.len()) {
///     println!("{} bytes", done?);
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone)]
pub struct McapLog {
    pub(super) files: Arc<Vec<LogFile>>,
}

/// Natural order of file names, so `run_10.mcap` follows `run_9.mcap`.
fn natural_key(name: &str) -> Vec<(String, u64)> {
    let mut key = Vec::new();
    let mut text = String::new();
    let mut digits = String::new();
    for ch in name.chars() {
        if ch.is_ascii_digit() {
            digits.push(ch);
        } else {
            if !digits.is_empty() {
                key.push((
                    std::mem::take(&mut text),
                    digits.parse().unwrap_or(u64::MAX),
                ));
                digits.clear();
            }
            text.push(ch);
        }
    }
    key.push((text, digits.parse().unwrap_or(0)));
    key
}

impl McapLog {
    /// Opens a `.mcap` file, or a directory holding a rosbag2 recording
    /// split into several `.mcap` files (read in time order).
    pub fn open(path: &Path) -> Result<Self, InputError> {
        let io = |source| InputError::Io {
            path: path.to_path_buf(),
            source,
        };
        let meta = std::fs::metadata(path).map_err(io)?;
        let mut paths = if meta.is_dir() {
            let mut v: Vec<PathBuf> = std::fs::read_dir(path)
                .map_err(io)?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
                .collect();
            v.sort_by_key(|p| natural_key(&p.file_name().unwrap_or_default().to_string_lossy()));
            if v.is_empty() {
                return Err(InputError::Log {
                    path: path.to_path_buf(),
                    reason: "directory holds no .mcap files".into(),
                });
            }
            v
        } else {
            vec![path.to_path_buf()]
        };
        let mut files = Vec::with_capacity(paths.len());
        for p in paths.drain(..) {
            files.push(LogFile::open(p)?);
        }
        // Split files are consecutive in time; order by first message when
        // the summaries say, keeping name order otherwise.
        files.sort_by_key(|f| {
            f.summary
                .as_ref()
                .and_then(|s| s.stats.as_ref())
                .map_or(u64::MAX, |s| s.message_start_time)
        });
        Ok(McapLog {
            files: Arc::new(files),
        })
    }

    /// The files read, in order.
    pub fn files(&self) -> Vec<&Path> {
        self.files.iter().map(|f| f.path.as_path()).collect()
    }

    /// Files that have no usable summary and will be scanned linearly, with
    /// the reason.
    pub fn unindexed_files(&self) -> Vec<(&Path, &str)> {
        self.files
            .iter()
            .filter_map(|f| f.summary_problem.as_deref().map(|p| (f.path.as_path(), p)))
            .collect()
    }

    /// The first error that stopped the scan of a file without a summary
    /// (run by [`McapLog::channels`]): damage before a topic's first
    /// message hides that topic, and this says why.
    pub fn scan_problem(&self) -> Option<&InputError> {
        self.files
            .iter()
            .filter(|f| f.summary.is_none())
            .find_map(|f| f.scanned_channels().1.as_ref())
    }

    /// Every channel named in the summaries (or, for files without one,
    /// found by scanning), one entry per topic.
    pub fn channels(&self) -> Vec<Channel> {
        let mut out: BTreeMap<String, Channel> = BTreeMap::new();
        for f in self.files.iter() {
            match &f.summary {
                Some(s) => {
                    for c in s.channels.values() {
                        out.entry(c.topic.clone()).or_insert_with(|| channel_of(c));
                    }
                }
                None => {
                    for c in &f.scanned_channels().0 {
                        out.entry(c.topic.clone()).or_insert_with(|| c.clone());
                    }
                }
            }
        }
        out.into_values().collect()
    }

    /// First and last message log times (nanoseconds) according to the
    /// summaries, `None` when a file has no statistics.
    pub fn time_range(&self) -> Option<(u64, u64)> {
        let mut range: Option<(u64, u64)> = None;
        for f in self.files.iter() {
            let st = f.summary.as_ref()?.stats.as_ref()?;
            if st.message_count == 0 {
                continue;
            }
            let (a, b) = (st.message_start_time, st.message_end_time);
            range = Some(range.map_or((a, b), |(x, y)| (x.min(a), y.max(b))));
        }
        range
    }

    /// Number of messages on `topic` according to the summaries, `None`
    /// when a file has no statistics (or the counts, being corrupt,
    /// overflow).
    pub fn message_count(&self, topic: &str) -> Option<u64> {
        let mut total: u64 = 0;
        for f in self.files.iter() {
            let s = f.summary.as_ref()?;
            let stats = s.stats.as_ref()?;
            for (id, c) in &s.channels {
                if c.topic == topic {
                    let n = stats.channel_message_counts.get(id).copied().unwrap_or(0);
                    total = total.checked_add(n)?;
                }
            }
        }
        Some(total)
    }

    /// Total messages in the log according to the summaries, `None` when a
    /// file has no statistics (or the counts, being corrupt, overflow).
    pub fn total_messages(&self) -> Option<u64> {
        self.files.iter().try_fold(0u64, |total, f| {
            total.checked_add(f.summary.as_ref()?.stats.as_ref()?.message_count)
        })
    }

    /// The log's metadata records (name → key/value map), e.g. the
    /// `latentam` record converters write.
    pub fn metadata(&self) -> Result<Vec<(String, Metadata)>, InputError> {
        let mut out = Vec::new();
        for f in self.files.iter() {
            let Some(s) = &f.summary else { continue };
            for index in &s.metadata_indexes {
                let m = mcap::read::metadata(&f.map, index).map_err(|e| f.error(e))?;
                out.push((m.name, m.metadata));
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_files_sort_naturally() {
        let mut names = vec!["run_10.mcap", "run_2.mcap", "run_1.mcap"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(names, ["run_1.mcap", "run_2.mcap", "run_10.mcap"]);
    }
}

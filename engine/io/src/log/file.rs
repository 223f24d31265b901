//! One MCAP file of a log: memory-mapped, with its summary (when it has
//! one) and the chunk index read from it.

use std::path::PathBuf;

use super::chunks::PlainChunks;
use super::records::Channel;
use crate::InputError;

pub(super) struct LogFile {
    pub(super) path: PathBuf,
    pub(super) map: memmap2::Mmap,
    pub(super) summary: Option<mcap::Summary>,
    /// What the indexed reader is given instead of `summary`, present with
    /// it: see [`PlainChunks`].
    pub(super) plain: Option<PlainChunks>,
    /// Why the summary could not be used, when it could not.
    pub(super) summary_problem: Option<String>,
    /// Channels found by scanning a file without a summary (scanned once),
    /// and the error that stopped the scan, if one did.
    pub(super) scanned: std::sync::OnceLock<(Vec<Channel>, Option<InputError>)>,
}

impl LogFile {
    pub(super) fn open(path: PathBuf) -> Result<Self, InputError> {
        let file = crate::open_input(&path).map_err(|source| InputError::Io {
            path: path.clone(),
            source,
        })?;
        // SAFETY: the map is read-only; if another process truncates the
        // file while it is mapped, reads fault (SIGBUS) rather than return
        // wrong data. Logs being read are not expected to be rewritten.
        let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|source| InputError::Io {
            path: path.clone(),
            source,
        })?;
        let _ = map.advise(memmap2::Advice::Sequential);
        if map.len() < 8 || &map[..8] != mcap::MAGIC {
            return Err(InputError::Log {
                path,
                reason: "not an MCAP file (no MCAP magic at its start)".into(),
            });
        }
        let (summary, summary_problem) = match mcap::Summary::read(&map) {
            Ok(Some(s)) if !s.chunk_indexes.is_empty() || s.stats.is_some() => (Some(s), None),
            Ok(Some(_)) => (None, Some("the summary has no chunk index".to_string())),
            Ok(None) => (None, Some("the file has no summary section".to_string())),
            Err(e) => (
                None,
                Some(format!(
                    "the summary cannot be read ({e}); the file may be truncated"
                )),
            ),
        };
        if let Some(p) = &summary_problem {
            log::warn!("{}: {p}; reading it linearly", path.display());
        }
        let plain = summary.as_ref().map(PlainChunks::new);
        Ok(LogFile {
            path,
            map,
            summary,
            plain,
            summary_problem,
            scanned: std::sync::OnceLock::new(),
        })
    }

    pub(super) fn error(&self, e: impl std::fmt::Display) -> InputError {
        InputError::Log {
            path: self.path.clone(),
            reason: e.to_string(),
        }
    }
}

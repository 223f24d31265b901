//! Foxglove files: the topics of a map written by the foxglove crate's
//! MCAP sink, whole or not at all.

use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::Path;
use std::sync::{Arc, Mutex};

use foxglove::{McapCompression, McapWriteOptions};

use latentam_base::{Error, Result};

use crate::topics::Topics;

/// Writes a Foxglove file (MCAP, zstd chunks, Foxglove's protobuf
/// messages with their schemas) at `path` whole or not at all: `body` publishes the messages
/// on the topics it is given, whose messages are in `frame_id`.
///
/// ```no_run
/// use latentam_view::{write_foxglove_file, Cloud};
///
/// write_foxglove_file("map.mcap".as_ref(), "map", |topics| {
///     let cloud = Cloud { positions: &[[0.0, 0.0, 1.0]], colours: &[[255, 0, 0, 255]], value: ("opacity", &[1.0]) };
///     topics.cloud("/latentam/map", 1_000, &cloud)?;
///     Ok(())
/// })?;
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub fn write_foxglove_file(
    path: &Path,
    frame_id: &str,
    body: impl FnOnce(&Topics) -> Result<()>,
) -> Result<()> {
    let mut failure = None;
    let written = latentam_base::files::write_atomically(path, |w| {
        let run = (|| {
            // The sink owns its writer: a second handle on the same file,
            // whose buffered bytes are flushed before the file is committed.
            let file = w.get_ref().try_clone().map_err(|e| write_error(path, &e))?;
            let latch = Latched::new(BufWriter::new(file));
            let topics = Topics::new(frame_id);
            let options = McapWriteOptions::new()
                .compression(Some(McapCompression::Zstd))
                .library(concat!("latentam ", env!("CARGO_PKG_VERSION")));
            let sink = topics
                .context()
                .mcap_writer_with_options(options)
                .create(latch.clone())
                .map_err(|e| write_error(path, &e))?;
            body(&topics)?;
            let mut out = sink.close().map_err(|e| write_error(path, &e))?;
            out.flush().map_err(|e| write_error(path, &e))?;
            latch.result(path)
        })();
        run.map_err(|e: Error| {
            let message = e.to_string();
            failure = Some(e);
            std::io::Error::other(message)
        })
    });
    match (written, failure) {
        (Err(_), Some(e)) => Err(e),
        (r, _) => r,
    }
}

/// A failure writing the Foxglove file at `path`, as [`Error::Io`]: the
/// foxglove sink's errors (and a failed write it only logged) name no file.
fn write_error(path: &Path, e: &dyn std::fmt::Display) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(format!("writing the Foxglove file: {e}")),
    }
}

/// A writer that keeps its first error: the foxglove sink reports a
/// failed write only in its log, so the file's writer remembers it for
/// the caller.
pub(crate) struct Latched<W> {
    inner: Arc<Mutex<(W, Option<std::io::Error>)>>,
}

impl<W> Clone for Latched<W> {
    fn clone(&self) -> Self {
        Latched {
            inner: self.inner.clone(),
        }
    }
}

impl<W> Latched<W> {
    pub(crate) fn new(w: W) -> Self {
        Latched {
            inner: Arc::new(Mutex::new((w, None))),
        }
    }

    fn with<R>(&self, f: impl FnOnce(&mut W) -> std::io::Result<R>) -> std::io::Result<R> {
        let mut guard = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (w, first) = &mut *guard;
        if let Some(e) = first {
            return Err(std::io::Error::new(e.kind(), e.to_string()));
        }
        let r = f(w);
        if let Err(e) = &r {
            *first = Some(std::io::Error::new(e.kind(), e.to_string()));
        }
        r
    }

    /// The first error of a write to the file at `path`, if any.
    pub(crate) fn result(&self, path: &Path) -> Result<()> {
        match &self.inner.lock().unwrap_or_else(|e| e.into_inner()).1 {
            Some(e) => Err(write_error(path, e)),
            None => Ok(()),
        }
    }
}

impl<W: Write> Write for Latched<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.with(|w| w.write(buf))
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.with(|w| w.flush())
    }
}

impl<W: Seek> Seek for Latched<W> {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.with(|w| w.seek(pos))
    }
}

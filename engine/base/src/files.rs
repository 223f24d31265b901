//! Files that appear whole or not at all: written to a partial file of
//! the writer's own beside the target (`<name>.<pid>-<n>.partial`, so two
//! processes writing the same output never share one), synced, then
//! renamed over it (and the directory synced), so a crash or a full disk
//! leaves the previous file intact. Partial files of the same target left
//! by processes that are gone are removed the next time it is written
//! (regular files of this user only). The
//! partial file is always created anew, never opened through a link: a
//! symbolic link planted under its name is removed (the link, not what
//! it points to), and the file is created exclusively, so a write never
//! lands outside the target's folder.
//!
//! [`write_atomically`] when the content is written through a `Write`;
//! [`PartialFile`] when a library writes to a path of its own (an MCAP
//! writer, say).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// `<path>.partial`: every partial file of `path` is named after it
/// (`<path>.<pid>-<n>.partial`, see [`write_atomically`]).
pub fn partial_path(path: &Path) -> Option<PathBuf> {
    let mut name = path.file_name()?.to_os_string();
    name.push(".partial");
    Some(path.with_file_name(name))
}

/// A partial file of this writer's own for `path`:
/// `<path>.<pid>-<n>.partial`. Partial files of `path` left by processes
/// that are gone are removed first.
fn own_partial_path(path: &Path) -> Option<PathBuf> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let shared = partial_path(path)?;
    remove_stale_partials(path);
    Some(shared.with_extension(format!(
        "{}-{}.partial",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )))
}

/// Removes `<path>.<pid>-<n>.partial` files whose process is gone: regular
/// files of this user only, never links or others' files.
fn remove_stale_partials(path: &Path) {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let (Some(dir), Some(name)) = (path.parent(), path.file_name()) else {
            return;
        };
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let prefix = format!("{}.", name.to_string_lossy());
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        // SAFETY: getuid has no preconditions.
        let me = unsafe { libc::getuid() };
        for entry in entries.flatten() {
            let file = entry.file_name().to_string_lossy().into_owned();
            let Some(pid) = file
                .strip_prefix(&prefix)
                .and_then(|rest| rest.strip_suffix(".partial"))
                .and_then(|rest| rest.split_once('-'))
                .and_then(|(pid, n)| n.parse::<u64>().ok().and(pid.parse::<i32>().ok()))
            else {
                continue;
            };
            let ours =
                std::fs::symlink_metadata(entry.path()).is_ok_and(|m| m.is_file() && m.uid() == me);
            // SAFETY: signal 0 only asks whether the process exists.
            let gone = pid > 0
                && unsafe { libc::kill(pid, 0) } != 0
                && std::io::Error::last_os_error().raw_os_error() == Some(libc::ESRCH);
            if ours && gone {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
    #[cfg(not(unix))]
    let _ = path;
}

/// Writes `path` through a partial file of this writer's own with `body`;
/// on any error the partial file is removed and `path` is left as it was.
///
/// ```no_run
/// use std::io::Write;
/// latentam_base::files::write_atomically("out/notes.txt".as_ref(), |w| w.write_all(b"mapped\n"))?;
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub fn write_atomically(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    let Some(partial) = own_partial_path(path) else {
        return Err(Error::bad_input(
            path.display().to_string(),
            "not a file path",
        ));
    };
    write_through(&partial, path, body)
}

/// [`write_atomically`] with a body whose errors are the engine's own (a
/// source read while the file is written, a check on the way): the first
/// such error is returned as it was, the partial file removed and `path`
/// left as it was.
///
/// ```no_run
/// use std::io::Write;
/// latentam_base::files::write_atomically_with("out/notes.txt".as_ref(), |w| {
///     w.write_all(b"mapped\n").map_err(|source| latentam_base::Error::Io {
///         path: "out/notes.txt".into(),
///         source,
///     })
/// })?;
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub fn write_atomically_with(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let mut failed = None;
    let written = write_atomically(path, |out| {
        body(out).map_err(|e| {
            let io = std::io::Error::other(e.to_string());
            failed = Some(e);
            io
        })
    });
    match failed {
        Some(e) => Err(e),
        None => written,
    }
}

/// [`write_atomically`], for files that several processes or threads
/// may write at once (a cache): every writer has a partial file of its
/// own and renames it whole into place, and the last one wins.
///
/// ```no_run
/// use std::io::Write;
/// latentam_base::files::write_atomically_shared("cache/table.bin".as_ref(), |w| w.write_all(b"..."))?;
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub fn write_atomically_shared(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    write_atomically(path, body)
}

/// Writes `partial` with `body`, syncs it and renames it to `path`.
fn write_through(
    partial: &Path,
    path: &Path,
    body: impl FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
) -> Result<()> {
    let io_err = |path: &Path, source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let written = (|| {
        let file = create_fresh(partial)?;
        let mut out = BufWriter::with_capacity(1 << 20, file);
        body(&mut out)?;
        if let Some(e) = crate::faults::write_error() {
            return Err(e);
        }
        let file = out.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(partial);
        return Err(io_err(partial, e));
    }
    crate::faults::delay_save();
    if let Err(e) = std::fs::rename(partial, path) {
        let _ = std::fs::remove_file(partial);
        return Err(io_err(path, e));
    }
    // The rename is durable only once the directory entry is; failing to
    // sync it (some file systems refuse) leaves a complete file anyway.
    #[cfg(unix)]
    if let Some(dir) = path.parent() {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        if let Ok(d) = File::open(dir) {
            let _ = d.sync_all();
        }
    }
    Ok(())
}

/// Creates `path` as a new regular file of this process's own: whatever
/// is there (a stale partial file, or a link planted to redirect the
/// write) is removed first, and the file is created exclusively, so a
/// link planted in between makes the creation fail instead of being
/// followed. A directory in the way is an error.
pub fn create_fresh(path: &Path) -> std::io::Result<File> {
    match std::fs::symlink_metadata(path) {
        Ok(m) if m.is_dir() => {
            return Err(std::io::Error::new(
                std::io::ErrorKind::AlreadyExists,
                "a directory has the partial file's name",
            ))
        }
        Ok(_) => std::fs::remove_file(path)?,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e),
    }
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
}

/// [`write_atomically`] for bytes already in memory.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| w.write_all(bytes))
}

/// A file written under a partial name of its own beside `path`
/// (`<path>.<pid>-<n>.partial`) by whatever writes to a path:
/// [`PartialFile::commit`] renames it to its final name, and dropping it
/// uncommitted (an error on the way) removes it, so a failed write leaves
/// no half-written output behind.
///
/// ```no_run
/// use latentam_base::files::PartialFile;
///
/// let out = PartialFile::new("out/log.mcap".as_ref())?;
/// std::fs::write(out.path(), b"...")?; // any writer that takes a path
/// out.commit()?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct PartialFile {
    partial: PathBuf,
    target: PathBuf,
    committed: bool,
}

impl PartialFile {
    /// Reserves `path`: creates [`PartialFile::path`] anew as an empty
    /// regular file of its own (see [`create_fresh`]), to be written
    /// (errors when `path` names no file, or the partial file cannot be
    /// created).
    pub fn new(path: &Path) -> Result<Self> {
        let partial = own_partial_path(path)
            .ok_or_else(|| Error::bad_input(path.display().to_string(), "not a file path"))?;
        create_fresh(&partial).map_err(|source| Error::Io {
            path: partial.clone(),
            source,
        })?;
        Ok(PartialFile {
            partial,
            target: path.to_path_buf(),
            committed: false,
        })
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        &self.partial
    }

    /// Moves the finished file to its final name.
    pub fn commit(mut self) -> Result<()> {
        std::fs::rename(&self.partial, &self.target).map_err(|source| Error::Io {
            path: self.target.clone(),
            source,
        })?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for PartialFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.partial);
        }
    }
}

#[cfg(any(test, feature = "testing"))]
#[doc(hidden)]
pub mod testing {
    use std::path::{Path, PathBuf};

    /// A directory removed on drop.
    pub struct TempDir(PathBuf);

    impl TempDir {
        pub fn new(tag: &str) -> Self {
            use std::sync::atomic::{AtomicUsize, Ordering};
            static N: AtomicUsize = AtomicUsize::new(0);
            let p = std::env::temp_dir().join(format!(
                "latentam-{tag}-{}-{}",
                std::process::id(),
                N.fetch_add(1, Ordering::Relaxed)
            ));
            std::fs::create_dir_all(&p).unwrap();
            TempDir(p)
        }
        pub fn path(&self) -> &Path {
            &self.0
        }
    }

    impl Drop for TempDir {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

#[cfg(all(test, unix))]
mod link_tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("latentam-files-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    /// Links planted under every partial name a writer of `path` could
    /// take (the shared one and this process's next 64) are removed, not
    /// followed; the victim keeps its content.
    fn plant_links(path: &Path, victim: &Path) -> Vec<PathBuf> {
        let mut names = vec![partial_path(path).unwrap()];
        for n in 0..64 {
            names.push(
                partial_path(path)
                    .unwrap()
                    .with_extension(format!("{}-{n}.partial", std::process::id())),
            );
        }
        for name in &names {
            let _ = std::fs::remove_file(name);
            std::os::unix::fs::symlink(victim, name).unwrap();
        }
        names
    }

    #[test]
    fn a_link_planted_as_the_partial_file_is_not_written_through() {
        let dir = scratch("link");
        let victim = dir.join("victim.txt");
        std::fs::write(&victim, "keep me").unwrap();
        let out = dir.join("out.txt");
        plant_links(&out, &victim);
        write_bytes_atomically(&out, b"written").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "written");

        // The same for a file a library writes by path.
        let ply = dir.join("map.ply");
        plant_links(&ply, &victim);
        let p = PartialFile::new(&ply).unwrap();
        std::fs::write(p.path(), "ply").unwrap();
        p.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
        assert_eq!(std::fs::read_to_string(&ply).unwrap(), "ply");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

#[cfg(all(test, unix))]
mod partial_tests {
    use super::*;

    /// Two writers of one output never share a partial file, and partial
    /// files left by processes that are gone are removed (this user's
    /// regular files only).
    #[test]
    fn each_writer_has_its_partial_file_and_the_dead_ones_are_cleared() {
        let dir = std::env::temp_dir().join(format!("latentam-partials-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("heatmap.ply");
        let a = PartialFile::new(&out).unwrap();
        let b = PartialFile::new(&out).unwrap();
        assert_ne!(a.path(), b.path());
        std::fs::write(a.path(), "a").unwrap();
        std::fs::write(b.path(), "b").unwrap();
        b.commit().unwrap();
        a.commit().unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "a");
        // A dead process's partial file (pid beyond any the kernel gives)
        // goes; a live one's, a link and a directory stay.
        let stale = dir.join("heatmap.ply.2147483646-3.partial");
        std::fs::write(&stale, "stale").unwrap();
        let live = dir.join(format!("heatmap.ply.{}-999.partial", std::process::id()));
        std::fs::write(&live, "live").unwrap();
        let dead_link = dir.join("heatmap.ply.2147483645-1.partial");
        std::os::unix::fs::symlink(&out, &dead_link).unwrap();
        write_bytes_atomically(&out, b"new").unwrap();
        assert!(!stale.exists());
        assert!(live.exists() && std::fs::symlink_metadata(&dead_link).is_ok());
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "new");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

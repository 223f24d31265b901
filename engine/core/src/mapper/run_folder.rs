//! A run folder holds one consistent run: the resumable state, the decoder
//! and whatever else the caller writes beside them (the CLI adds the PLY
//! map, the report, the trace...). It is never edited in place. A new
//! version is written into a fresh hidden sibling directory and swapped in
//! whole, so a crash, a full disk or a failed run leaves the previous run
//! intact. One writer at a time holds a lock file beside the folder.
//!
//! Every file of one version carries the same run id (the state's and the
//! decoder's metadata, the CLI's report), so files copied together from
//! different runs are refused when loaded.
//!
//! ```no_run
//! use latentam_core::mapper::RunFolder;
//!
//! let folder = RunFolder::lock("out/run")?; // refuses a second writer
//! let staging = folder.stage()?;
//! std::fs::write(staging.path().join("report.json"), b"{}").unwrap();
//! staging.commit()?; // out/run now holds exactly what was staged
//! # Ok::<(), latentam_core::Error>(())
//! ```

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use super::export::DECODER_FILE;
use latentam_base::{Error, Result};

mod swap;
use swap::exchange;

/// File name of the resumable state inside a run folder.
pub const STATE_FILE: &str = "state.latentam";

/// Every file a latentam run folder may hold. A folder holding anything
/// else is not replaced (its other files would be lost with it).
pub const RUN_FOLDER_FILES: &[&str] = &[
    STATE_FILE,
    DECODER_FILE,
    "map.ply",
    "config.toml",
    "report.json",
    "report.html",
    "trace.json",
    "trajectory.txt",
    // Written into the folder by `latentam query` by default.
    "heatmap.ply",
];

fn io_error(path: &Path, e: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source: e,
    }
}

/// The file every version of a run folder holds from the moment it is
/// staged: the run id of that version. Hidden siblings of a run folder
/// (`.NAME.staging-ID`, `.NAME.old-ID`) are removed or moved back only when
/// they hold it, so a user's folder that merely has such a name is never
/// touched.
pub const RUN_MARKER: &str = ".latentam-run";

/// A fresh id for one version of a run folder: the time in nanoseconds and
/// the process id, in hexadecimal.
pub fn new_run_id() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    format!("{nanos:016x}{:08x}", std::process::id())
}

/// A run folder locked for writing: no other process (or other
/// `RunFolder` of this one) can write it until this value is dropped.
///
/// ```no_run
/// use latentam_core::mapper::RunFolder;
/// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
/// let folder = RunFolder::lock("runs/kitchen")?; // one writer at a time
/// let staging = folder.stage()?;
/// let map = mapper.snapshot()?;
/// map.export_ply(&staging.path().join("map.ply"))?;
/// latentam_io::write_tum(&staging.path().join("trajectory.txt"), &map.trajectory)?;
/// staging.commit()?; // the folder now holds exactly this version
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub struct RunFolder {
    dir: PathBuf,
    lock_path: PathBuf,
    _lock: File,
}

impl RunFolder {
    /// Locks `dir` for writing (its parent is created when missing). Fails
    /// with [`Error::Locked`] when another writer holds it, and with
    /// [`Error::BadInput`] when `dir` is not a directory, is a
    /// folder with something in it but no [`RUN_MARKER`], or holds entries
    /// that are not a run's files (see [`RUN_FOLDER_FILES`]).
    ///
    /// A swap cut short by a crash is finished here: a run moved aside and
    /// not replaced is moved back, and stale staging folders are removed.
    pub fn lock(dir: impl AsRef<Path>) -> Result<Self> {
        let given = dir.as_ref();
        let dir = match std::fs::canonicalize(given) {
            // A symbolic link to a folder: the folder it points to is the
            // run folder (swapping the link itself away would lose it).
            Ok(d) => d,
            // A link to nothing: the first save could not replace it, after
            // all the mapping before it.
            Err(_) if std::fs::symlink_metadata(given).is_ok_and(|m| m.is_symlink()) => {
                let target = std::fs::read_link(given).unwrap_or_default();
                return Err(Error::bad_input(
                    given.display().to_string(),
                    format!(
                        "a link to {}, which does not exist: create that folder or write the \
                         run elsewhere",
                        target.display()
                    ),
                ));
            }
            Err(_) => std::path::absolute(given).map_err(|e| io_error(given, e))?,
        };
        let (Some(parent), Some(name)) = (dir.parent(), dir.file_name()) else {
            return Err(Error::bad_input(
                given.display().to_string(),
                "a run folder needs a name and a parent directory",
            ));
        };
        check_committable(&dir, parent, name)?;
        std::fs::create_dir_all(parent).map_err(|e| io_error(parent, e))?;
        let lock_path = parent.join(hidden_sibling(name, ".lock"));
        let lock = acquire(&lock_path, &dir)?;
        let folder = RunFolder {
            dir,
            lock_path,
            _lock: lock,
        };
        folder.recover()?;
        folder.check_replaceable()?;
        // A destination that cannot take a version fails now, not after
        // hours of mapping: a staging folder is made and removed.
        drop(folder.stage()?);
        Ok(folder)
    }

    /// The folder (absolute).
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// A hidden sibling of the folder: `.NAME` + `suffix`, NAME byte for
    /// byte (names that differ only in bytes that are not UTF-8 must not
    /// share a lock or a staging folder).
    fn sibling(&self, suffix: &str) -> PathBuf {
        self.parent().join(hidden_sibling(
            self.dir.file_name().expect("checked in lock"),
            suffix,
        ))
    }

    fn parent(&self) -> &Path {
        self.dir.parent().expect("checked in lock")
    }

    /// Hidden siblings of the folder with `kind` (`staging`, `old`).
    fn siblings(&self, kind: &str) -> Result<Vec<PathBuf>> {
        let prefix = self.sibling(&format!(".{kind}-"));
        let prefix = prefix.file_name().expect("a sibling has a name");
        let parent = self.parent();
        let mut found = Vec::new();
        for entry in std::fs::read_dir(parent).map_err(|e| io_error(parent, e))? {
            let entry = entry.map_err(|e| io_error(parent, e))?;
            let name = entry.file_name();
            if name
                .as_encoded_bytes()
                .starts_with(prefix.as_encoded_bytes())
            {
                found.push(entry.path());
            }
        }
        found.sort();
        Ok(found)
    }

    fn recover(&self) -> Result<()> {
        for stale in self.ours("staging")? {
            remove_tree(&stale)?;
        }
        let mut old = self.ours("old")?;
        if !self.dir.exists() {
            // Cut between moving the run aside and moving its successor in:
            // the run moved aside is the last complete one.
            if let Some(last) = old.pop() {
                std::fs::rename(&last, &self.dir).map_err(|e| io_error(&last, e))?;
                log::warn!("{}: restored after an interrupted save", self.dir.display());
            }
        }
        for stale in old {
            remove_tree(&stale)?;
        }
        Ok(())
    }

    /// The siblings of `kind` this tool made (see [`RUN_MARKER`]); the
    /// others are left alone, with a warning.
    fn ours(&self, kind: &str) -> Result<Vec<PathBuf>> {
        let mut found = Vec::new();
        for path in self.siblings(kind)? {
            let name = path.file_name().map(|n| n.to_string_lossy().into_owned());
            let id = name.as_deref().and_then(|n| {
                n.rsplit_once(&format!(".{kind}-"))
                    .map(|(_, id)| id.to_string())
            });
            // A staging folder holds its own id; a folder moved aside holds
            // the id of the version it was.
            let expected = (kind == "staging").then_some(id).flatten();
            if holds_marker(&path, expected.as_deref()) {
                found.push(path);
            } else {
                log::warn!(
                    "{}: not a folder this tool made (no {RUN_MARKER}); left alone",
                    path.display()
                );
            }
        }
        Ok(found)
    }

    /// A folder is replaced only when it is missing, empty, or holds the
    /// [`RUN_MARKER`] this tool wrote and nothing but a run's files: the
    /// marker, not the names of its files, says it is a run (a user's own
    /// `config.toml` or a folder named `trace.json` looks like one).
    fn check_replaceable(&self) -> Result<()> {
        let meta = match std::fs::metadata(&self.dir) {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
            Err(e) => return Err(io_error(&self.dir, e)),
        };
        if !meta.is_dir() {
            return Err(Error::bad_input(
                self.dir.display().to_string(),
                "exists and is not a directory",
            ));
        }
        let mut entries = Vec::new();
        for entry in std::fs::read_dir(&self.dir).map_err(|e| io_error(&self.dir, e))? {
            let entry = entry.map_err(|e| io_error(&self.dir, e))?;
            let is_dir = entry.file_type().is_ok_and(|t| t.is_dir());
            entries.push((entry.file_name().to_string_lossy().into_owned(), is_dir));
        }
        if entries.is_empty() {
            return Ok(());
        }
        let dir = self.dir.display();
        if !holds_marker(&self.dir, None) {
            return Err(Error::bad_input(
                dir.to_string(),
                format!(
                    "not empty and not a latentam run folder (it has no {RUN_MARKER}): a run \
                     folder is replaced whole, so what it holds would be lost; write the run to \
                     a new or empty folder"
                ),
            ));
        }
        // A file of a run, or a partial one of a writer (`X.<pid>-<n>.partial`);
        // never a folder, whatever its name.
        let ours = |name: &str| {
            name == RUN_MARKER
                || RUN_FOLDER_FILES.iter().any(|f| {
                    name == *f || (name.starts_with(&format!("{f}.")) && name.ends_with(".partial"))
                })
        };
        let mut foreign: Vec<_> = entries
            .into_iter()
            .filter(|(name, is_dir)| *is_dir || !ours(name))
            .map(|(name, _)| name)
            .collect();
        if foreign.is_empty() {
            return Ok(());
        }
        foreign.sort();
        let shown: Vec<_> = foreign.iter().take(5).map(String::as_str).collect();
        let (entry, are) = match foreign.len() {
            1 => ("an entry", "is"),
            _ => ("entries", "are"),
        };
        let more = if foreign.len() > 5 { ", ..." } else { "" };
        Err(Error::bad_input(
            dir.to_string(),
            format!(
                "holds {entry} that {are} not part of a latentam run ({}{more}): a run folder is \
                 replaced whole, so move them out or write the run to a new or empty folder",
                shown.join(", ")
            ),
        ))
    }

    /// A fresh, empty staging folder beside the run folder, with a new
    /// run id. Write the run's files into [`RunStaging::path`], then
    /// [`RunStaging::commit`]; dropping it uncommitted removes it.
    pub fn stage(&self) -> Result<RunStaging<'_>> {
        let id = new_run_id();
        let path = self.sibling(&format!(".staging-{id}"));
        std::fs::create_dir(&path).map_err(|e| io_error(&path, e))?;
        let staging = RunStaging {
            folder: self,
            path,
            id,
            done: false,
        };
        let marker = staging.path.join(RUN_MARKER);
        let mut file = OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&marker)
            .map_err(|e| io_error(&marker, e))?;
        file.write_all(staging.id.as_bytes())
            .map_err(|e| io_error(&marker, e))?;
        Ok(staging)
    }
}

impl Drop for RunFolder {
    fn drop(&mut self) {
        // Unlinked while still locked: a process that opened the old file
        // and locks it afterwards notices (see `acquire`) and starts over.
        let _ = std::fs::remove_file(&self.lock_path);
    }
}

/// Takes the lock file's exclusive lock (released by the OS if the process
/// dies), retrying when the file was unlinked by its previous holder
/// between our open and our lock.
fn acquire(lock_path: &Path, dir: &Path) -> Result<File> {
    for _ in 0..100 {
        let mut options = OpenOptions::new();
        options.read(true).write(true).create(true).truncate(false);
        // A link planted under the lock's name would have the pid written
        // through it: refused instead.
        #[cfg(unix)]
        std::os::unix::fs::OpenOptionsExt::custom_flags(&mut options, libc::O_NOFOLLOW);
        let mut file = options.open(lock_path).map_err(|e| {
            #[cfg(unix)]
            if e.raw_os_error() == Some(libc::ELOOP) {
                return Error::bad_input(
                    lock_path.display().to_string(),
                    "it is a symbolic link; the run folder's lock is not taken through one \
                     (remove it if it is not yours)",
                );
            }
            io_error(lock_path, e)
        })?;
        match try_lock(&file) {
            Ok(true) => {}
            Ok(false) => {
                let mut text = String::new();
                let _ = file.read_to_string(&mut text);
                return Err(Error::Locked {
                    path: dir.to_path_buf(),
                    pid: text.trim().parse().ok(),
                });
            }
            Err(e) => return Err(io_error(lock_path, e)),
        }
        if !same_file(&file, lock_path) {
            continue;
        }
        file.set_len(0).map_err(|e| io_error(lock_path, e))?;
        write!(file, "{}", std::process::id()).map_err(|e| io_error(lock_path, e))?;
        return Ok(file);
    }
    Err(Error::Locked {
        path: dir.to_path_buf(),
        pid: None,
    })
}

/// An exclusive, non-blocking `flock`: `Ok(false)` when another open file
/// holds it.
#[cfg(unix)]
fn try_lock(file: &File) -> std::io::Result<bool> {
    use std::os::fd::AsRawFd;
    // SAFETY: a valid open descriptor; flock only takes integers.
    if unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EWOULDBLOCK) => Ok(false),
        _ => Err(e),
    }
}

#[cfg(not(unix))]
fn try_lock(_: &File) -> std::io::Result<bool> {
    // No advisory locks here: a second writer is not detected.
    Ok(true)
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_: &File, path: &Path) -> bool {
    path.exists()
}

/// The version a run folder holds now (its [`RUN_MARKER`]), if it has one.
pub fn folder_version(dir: &Path) -> Option<String> {
    let marker = dir.join(RUN_MARKER);
    std::fs::symlink_metadata(&marker)
        .is_ok_and(|m| m.is_file() && m.len() <= 64)
        .then(|| std::fs::read_to_string(&marker).ok())
        .flatten()
}

/// Reads one version of the run folder `dir` with `read`: when a writer
/// swapped the folder while `read` ran (its version changed), what it read
/// may mix two versions or miss a file, so it reads again (up to 50
/// times). Readers need no lock: a swap replaces the whole folder at once.
///
/// ```no_run
/// use latentam_core::mapper::read_one_version;
/// let dir = std::path::Path::new("runs/kitchen");
/// let report = read_one_version(dir, || {
///     let path = dir.join("report.json");
///     std::fs::read_to_string(&path).map_err(|source| latentam_core::Error::Io { path, source })
/// })?;
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub fn read_one_version<T>(dir: &Path, mut read: impl FnMut() -> Result<T>) -> Result<T> {
    for _ in 0..50 {
        let before = folder_version(dir);
        let result = read();
        if before.is_none() || folder_version(dir) == before {
            return result;
        }
    }
    read()
}

/// Bytes a folder name may have: the staging folder beside it adds
/// `.`, `.staging-` and a 24-digit id to it, within the usual 255-byte
/// limit of a file name.
const MAX_NAME_BYTES: usize = 255 - 34;

/// Errors unless a run folder `name` in `parent` can be replaced by
/// renames: a name that leaves room for the staging folder's, and a folder
/// that is not a mount point (renaming one fails with "busy").
/// `.` + `name` + `suffix`, byte for byte.
fn hidden_sibling(name: &std::ffi::OsStr, suffix: &str) -> std::ffi::OsString {
    let mut s = std::ffi::OsString::from(".");
    s.push(name);
    s.push(suffix);
    s
}

fn check_committable(dir: &Path, parent: &Path, name: &std::ffi::OsStr) -> Result<()> {
    let bytes = name.as_encoded_bytes().len();
    if bytes > MAX_NAME_BYTES {
        return Err(Error::bad_input(
            dir.display().to_string(),
            format!(
                "a run folder's name may have at most {MAX_NAME_BYTES} bytes (this one has \
                 {bytes}): the staging folder beside it adds 34"
            ),
        ));
    }
    #[cfg(unix)]
    let mount = {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(dir), std::fs::metadata(parent)) {
            (Ok(d), Ok(p)) => d.dev() != p.dev(),
            _ => false,
        }
    };
    #[cfg(not(unix))]
    let mount = false;
    if dir.exists() && (mount || latentam_base::faults::mount_point()) {
        return Err(Error::bad_input(
            dir.display().to_string(),
            "it is a mount point: a run folder is replaced whole by renaming, which a mount \
             point does not allow; write the run to a folder inside it",
        ));
    }
    Ok(())
}

/// Whether `dir` is a directory (not a link to one) holding a regular
/// [`RUN_MARKER`] with a run id (`expected`, when given).
fn holds_marker(dir: &Path, expected: Option<&str>) -> bool {
    let is_dir = std::fs::symlink_metadata(dir).is_ok_and(|m| m.is_dir());
    let Some(id) = folder_version(dir).filter(|_| is_dir) else {
        return false;
    };
    let well_formed = !id.is_empty() && id.bytes().all(|b| b.is_ascii_hexdigit());
    well_formed && expected.is_none_or(|e| e == id)
}

fn remove_tree(path: &Path) -> Result<()> {
    match std::fs::remove_dir_all(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_error(path, e)),
    }
}

fn sync_dir(dir: &Path) {
    // Some file systems refuse to sync a directory; the entries are then
    // as durable as that file system makes them.
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// The next version of a run folder, being written. See [`RunFolder`].
///
/// ```no_run
/// # fn f(folder: &latentam_core::mapper::RunFolder, report_json: &str) -> Result<(), Box<dyn std::error::Error>> {
/// let staging = folder.stage()?;
/// println!("writing run {} into {}", staging.run_id(), staging.path().display());
/// std::fs::write(staging.path().join("report.json"), report_json)?;
/// staging.commit()?; // dropped instead, the staged files are removed
/// # Ok(())
/// # }
/// ```
#[derive(Debug)]
pub struct RunStaging<'a> {
    folder: &'a RunFolder,
    path: PathBuf,
    id: String,
    done: bool,
}

impl RunStaging<'_> {
    /// The folder to write the files into.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The id every file of this version records.
    pub fn run_id(&self) -> &str {
        &self.id
    }

    /// Replaces the run folder with the staged one, atomically where the
    /// file system can exchange two directories (Linux), otherwise by two
    /// renames whose gap [`RunFolder::lock`] repairs after a crash.
    pub fn commit(mut self) -> Result<()> {
        sync_dir(&self.path);
        let dir = &self.folder.dir;
        if !dir.exists() {
            std::fs::rename(&self.path, dir).map_err(|e| io_error(dir, e))?;
        } else if exchange(&self.path, dir).is_ok() {
            // The staging path now holds the previous run.
            remove_tree(&self.path)?;
        } else {
            let old = self.folder.sibling(&format!(".old-{}", self.id));
            replace_by_renames(&self.path, dir, &old)?;
        }
        self.done = true;
        sync_dir(self.folder.parent());
        Ok(())
    }
}

impl Drop for RunStaging<'_> {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_dir_all(&self.path);
        }
    }
}

/// Moves `dir` aside to `old`, `staged` into its place, then removes
/// `old`; a crash between the renames is repaired by [`RunFolder::lock`].
fn replace_by_renames(staged: &Path, dir: &Path, old: &Path) -> Result<()> {
    std::fs::rename(dir, old).map_err(|e| io_error(dir, e))?;
    if let Err(e) = std::fs::rename(staged, dir) {
        let _ = std::fs::rename(old, dir);
        return Err(io_error(dir, e));
    }
    remove_tree(old)
}

#[cfg(test)]
#[path = "run_folder_tests.rs"]
mod tests;

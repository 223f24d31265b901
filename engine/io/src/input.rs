//! Opening the files a user names as inputs.
//!
//! Only regular files are read: opening a FIFO blocks until something
//! writes to it (forever, for a FIFO nobody feeds), and a device such as
//! `/dev/zero` never ends. The type is checked without opening
//! ([`std::fs::metadata`] follows symlinks, so a link to a FIFO is caught
//! too), then again on the opened file, which is opened non-blocking so a
//! FIFO swapped in between the two cannot block either.
//!
//! A file read whole is capped by its kind ([`MAX_TEXT_BYTES`] for text:
//! configurations, reports, trajectories, names and dataset indexes;
//! [`MAX_BINARY_BYTES`] for an array or image read whole): a larger one is
//! refused from its size before a byte is read, so a huge or sparse file
//! costs nothing to refuse.

use std::fs::{File, FileType};
use std::io::{Error, ErrorKind, Read, Result};
use std::path::Path;

/// What a file type is, for an error message.
fn describe(t: FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO";
        }
        if t.is_socket() {
            return "a socket";
        }
        if t.is_char_device() {
            return "a character device";
        }
        if t.is_block_device() {
            return "a block device";
        }
    }
    if t.is_dir() {
        "a directory"
    } else {
        "not a regular file"
    }
}

fn refuse(t: FileType) -> Error {
    let what = describe(t);
    let why = if what.starts_with("not") {
        what.to_string()
    } else {
        format!("{what}, not a regular file")
    };
    Error::new(ErrorKind::InvalidInput, why)
}

/// Checks that `path` (after following symlinks) is a regular file,
/// without opening it. The error reads e.g. "a FIFO, not a regular file"
/// (callers put the path in front).
pub fn check_input_file(path: &Path) -> Result<()> {
    let t = std::fs::metadata(path)?.file_type();
    if t.is_file() {
        Ok(())
    } else {
        Err(refuse(t))
    }
}

/// Opens `path` for reading if it is a regular file (see
/// [`check_input_file`]).
pub fn open_input(path: &Path) -> Result<File> {
    check_input_file(path)?;
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        // No effect on a regular file's reads.
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path)?;
    let t = file.metadata()?.file_type();
    if !t.is_file() {
        return Err(refuse(t));
    }
    Ok(file)
}

/// Most bytes of a text file read whole: a configuration, a run's
/// `report.json` (about 4 kB a keyframe: some 60 000 keyframes), a
/// trajectory, class names, a dataset's index.
pub const MAX_TEXT_BYTES: u64 = 256 << 20;

/// Most bytes of a binary file read whole: one frame's embedding array or
/// features, an image of a dataset, a query vector. (Logs and saved maps
/// are not read whole: logs are mapped, maps read by their header.)
pub const MAX_BINARY_BYTES: u64 = 1 << 30;

/// The whole of `file`, refused when its size says it holds more than
/// `cap` bytes, and read at most `cap` bytes far (a file that grows while
/// it is read is refused too).
fn read_capped(mut file: File, cap: u64, kind: &str) -> Result<Vec<u8>> {
    let too_big = |n: u64| {
        Error::new(
            ErrorKind::InvalidData,
            format!("{n} bytes, more than a {kind} file may have ({cap} bytes)"),
        )
    };
    let len = file.metadata()?.len();
    if len > cap {
        return Err(too_big(len));
    }
    let mut bytes = Vec::with_capacity(len as usize);
    (&mut file).take(cap + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        return Err(too_big(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The bytes of the regular file `path` (see [`check_input_file`]), at
/// most [`MAX_BINARY_BYTES`].
pub fn read_input(path: &Path) -> Result<Vec<u8>> {
    read_capped(open_input(path)?, MAX_BINARY_BYTES, "binary input")
}

/// The text of the regular file `path` (see [`check_input_file`]), at
/// most [`MAX_TEXT_BYTES`].
pub fn read_input_to_string(path: &Path) -> Result<String> {
    let bytes = read_capped(open_input(path)?, MAX_TEXT_BYTES, "text")?;
    String::from_utf8(bytes)
        .map_err(|_| Error::new(ErrorKind::InvalidData, "stream did not contain valid UTF-8"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_base::files::testing::TempDir;

    /// Makes a FIFO at `path`.
    fn mkfifo(path: &Path) {
        use std::os::unix::ffi::OsStrExt;
        let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
        // SAFETY: `c` is a NUL-terminated path that outlives the call.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    }

    /// Runs `f` on another thread and fails if it takes over 20 s (a
    /// blocked open would otherwise hang the test run).
    fn within_20s<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> T {
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let _ = tx.send(f());
        });
        rx.recv_timeout(std::time::Duration::from_secs(20))
            .expect("blocked for 20 s")
    }

    /// A 3 GiB file (sparse: it takes no disk) of any kind is refused from
    /// its size, before a byte is read; one at the cap is read whole.
    #[test]
    fn files_over_their_kind_s_cap_are_refused_unread() {
        let dir = TempDir::new("input-cap");
        let huge = dir.path().join("report.json");
        File::create(&huge).unwrap().set_len(3 << 30).unwrap();
        for e in [
            read_input_to_string(&huge).unwrap_err(),
            read_input(&huge).unwrap_err(),
        ] {
            assert_eq!(e.kind(), ErrorKind::InvalidData, "{e}");
            assert!(e.to_string().contains("3221225472 bytes, more than"), "{e}");
        }
        let small = dir.path().join("small");
        std::fs::write(&small, b"12345678").unwrap();
        let read = |cap| read_capped(File::open(&small).unwrap(), cap, "test");
        assert_eq!(read(8).unwrap(), b"12345678");
        assert!(read(7).is_err());
        assert_eq!(read_input_to_string(&small).unwrap(), "12345678");
        std::fs::write(&small, [0xff, 0xfe]).unwrap();
        assert_eq!(
            read_input_to_string(&small).unwrap_err().kind(),
            ErrorKind::InvalidData
        );
    }

    #[test]
    fn only_regular_files_are_opened() {
        let dir = TempDir::new("input");
        let fifo = dir.path().join("x.mcap");
        mkfifo(&fifo);
        let link = dir.path().join("link.toml");
        std::os::unix::fs::symlink(&fifo, &link).unwrap();
        let file = dir.path().join("ok.toml");
        std::fs::write(&file, "a = 1\n").unwrap();

        for (path, what) in [
            (fifo.clone(), "a FIFO, not a regular file"),
            (link, "a FIFO, not a regular file"),
            (dir.path().to_path_buf(), "a directory, not a regular file"),
            ("/dev/zero".into(), "a character device, not a regular file"),
        ] {
            let e = within_20s(move || read_input(&path).unwrap_err());
            assert_eq!(e.kind(), ErrorKind::InvalidInput);
            assert_eq!(e.to_string(), what);
        }
        assert_eq!(read_input_to_string(&file).unwrap(), "a = 1\n");
        assert_eq!(
            read_input(&dir.path().join("missing")).unwrap_err().kind(),
            ErrorKind::NotFound
        );
    }

    #[test]
    fn a_fifo_log_is_refused_not_waited_on() {
        let dir = TempDir::new("fifo-log");
        let fifo = dir.path().join("x.mcap");
        mkfifo(&fifo);
        let path = fifo.clone();
        let e = within_20s(move || crate::McapLog::open(&path).err().unwrap());
        assert!(matches!(e, crate::InputError::Io { .. }), "{e:?}");
        assert_eq!(
            e.to_string(),
            format!("{}: a FIFO, not a regular file", fifo.display())
        );

        // A rosbag2 folder whose split file is a link to a FIFO.
        let bag = dir.path().join("bag");
        std::fs::create_dir(&bag).unwrap();
        std::os::unix::fs::symlink(&fifo, bag.join("bag_0.mcap")).unwrap();
        let path = bag.clone();
        let e = within_20s(move || crate::McapLog::open(&path).err().unwrap());
        assert!(e.to_string().contains("a FIFO, not a regular file"), "{e}");

        let path = fifo.clone();
        let e = within_20s(move || crate::read_vocabulary(&path, "/vocabulary").unwrap_err());
        assert!(e.to_string().contains("a FIFO"), "{e}");
        let path = fifo.clone();
        let e = within_20s(move || crate::read_tum(&path).unwrap_err());
        assert!(e.to_string().contains("a FIFO"), "{e}");
    }
}

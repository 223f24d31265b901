//! Reading PLY files.

use super::*;

/// A PLY named on the command line may be a FIFO (a typo, a shell process
/// substitution): reading it is refused at once instead of blocking.
#[test]
fn a_fifo_ply_is_refused_not_waited_on() {
    use std::os::unix::ffi::OsStrExt;
    let dir = latentam_base::files::testing::TempDir::new("fifo-ply");
    let fifo = dir.path().join("map.ply");
    let c = std::ffi::CString::new(fifo.as_os_str().as_bytes()).unwrap();
    // SAFETY: `c` is a NUL-terminated path that outlives the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(read_ply(&fifo).err().map(|e| e.to_string()));
    });
    let e = rx
        .recv_timeout(std::time::Duration::from_secs(20))
        .expect("blocked for 20 s")
        .expect("a FIFO was read as a PLY");
    assert!(e.contains("a FIFO"), "{e}");
}

//! Ctrl-C during mapping: the first SIGINT (or SIGTERM) asks the run to
//! stop after the frame in progress (which skips its remaining
//! optimisation steps), so the run folder is still written with
//! everything mapped so far; a second one exits at once, leaving the
//! run folder as its last save (it is only ever replaced whole).

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    // Only async-signal-safe calls here: an atomic swap, write and _exit.
    if REQUESTED.swap(true, Ordering::SeqCst) {
        unsafe { libc::_exit(130) };
    }
    // Said at once: the frame in progress may take a while on a slow
    // device.
    const SAY: &[u8] =
        b"\nstopping after the frame in progress (its remaining optimisation steps are \
skipped), then saving; press Ctrl-C again to quit at once (the run folder then keeps its last save)\n";
    unsafe { libc::write(2, SAY.as_ptr().cast(), SAY.len()) };
}

/// Installs the handler for SIGINT and SIGTERM.
pub fn install() {
    // SAFETY: `on_signal` only touches an atomic and calls `_exit`, both
    // async-signal-safe; the sigaction struct is fully initialised.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as usize;
        libc::sigemptyset(&mut action.sa_mask);
        action.sa_flags = libc::SA_RESTART;
        libc::sigaction(libc::SIGINT, &action, std::ptr::null_mut());
        libc::sigaction(libc::SIGTERM, &action, std::ptr::null_mut());
    }
}

/// The flag a stop request sets, for the mapper to cut the keyframe in
/// progress short ([`latentam::LogRunOptions::hurry`]).
pub fn flag() -> &'static AtomicBool {
    &REQUESTED
}

/// Whether a stop was asked for.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// Makes a write past the process's file-size limit (`ulimit -f`,
/// RLIMIT_FSIZE) fail with an error naming the file ("File too large"),
/// which the command reports and cleans up after, instead of the default
/// SIGXFSZ that ends the process mid-write with nothing said. Only the
/// tool's own processes call this: a library does not change its host's
/// signal handling.
pub fn file_size_limit_is_an_error() {
    // SAFETY: setting a signal's disposition to "ignore" has no handler
    // to be unsafe in; SIGXFSZ is a valid signal number.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
}

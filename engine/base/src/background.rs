//! Work that must not slow the mapping: threads that take only the CPU
//! time it leaves.

/// Puts the calling thread (and the threads it starts, which inherit it)
/// at the lowest CPU priority: indexing or publishing a view then takes
/// the time mapping leaves, which on a CPU driver is the same cores.
/// Best effort: elsewhere than Linux, or refused, the thread keeps its
/// priority.
pub fn lowest_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain system calls on this thread's id; failure is ignored.
        unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, 19);
        }
    }
}

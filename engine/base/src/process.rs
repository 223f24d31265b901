//! What the operating system measures of this process.

/// The most memory this process has held resident so far (its peak RSS,
/// as the kernel counts it: `getrusage`'s `ru_maxrss`), in bytes; `None`
/// where the platform does not say.
///
/// ```
/// let peak = latentam_base::process::peak_rss_bytes();
/// if let Some(bytes) = peak {
///     assert!(bytes > 0);
/// }
/// ```
pub fn peak_rss_bytes() -> Option<u64> {
    #[cfg(any(target_os = "linux", target_os = "macos"))]
    {
        // SAFETY: getrusage fills the struct it is given.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: a valid pointer to our own struct.
        if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
            return None;
        }
        let max = u64::try_from(usage.ru_maxrss).ok()?;
        // Linux counts kibibytes, macOS bytes.
        #[cfg(target_os = "linux")]
        let max = max * 1024;
        Some(max)
    }
    #[cfg(not(any(target_os = "linux", target_os = "macos")))]
    {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Touching 96 MiB raises the peak by about that much: the unit is
    /// bytes (a kibibyte count read as bytes would be 1024 times short).
    #[test]
    fn the_peak_follows_memory_touched() {
        let before = peak_rss_bytes().expect("Linux reports the peak RSS");
        let size = 96usize << 20;
        let mut block = vec![0u8; size];
        for page in block.chunks_mut(4096) {
            page[0] = 1;
        }
        std::hint::black_box(&block);
        let after = peak_rss_bytes().unwrap();
        assert!(
            after >= size as u64,
            "a peak of {after} bytes after touching {size}"
        );
        assert!(after >= before);
        assert!(
            after < 1 << 40,
            "{after} bytes: more than the machine holds"
        );
        drop(block);
    }
}

//! Fault injection for tests of what the engine does when things go wrong:
//! set `LATENTAM_FAULTS` to a comma-separated list (read once per process).
//!
//! | entry | effect |
//! |---|---|
//! | `alloc_fail_after=N` | the buffer allocations after the first N fail as if GPU memory ran out |
//! | `device_lost_after=N` | the queue submissions after the first N fail with `VK_ERROR_DEVICE_LOST` |
//! | `disk_full` | every file the engine writes fails with "no space left on device" |
//! | `save_delay_ms=N` | a file write waits N ms before it is renamed into place (widens the window a crash can hit) |
//! | `mount_point` | every existing run folder is taken for a mount point (which renames cannot replace) |
//!
//! Without the variable nothing is injected and each hook is one atomic
//! load.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::OnceLock;

#[derive(Debug, Default)]
struct Faults {
    alloc_fail_after: Option<u64>,
    device_lost_after: Option<u64>,
    disk_full: bool,
    save_delay_ms: u64,
    mount_point: bool,
}

static FAULTS: OnceLock<Faults> = OnceLock::new();
static ALLOCATIONS: AtomicU64 = AtomicU64::new(0);
static SUBMISSIONS: AtomicU64 = AtomicU64::new(0);

fn faults() -> &'static Faults {
    FAULTS.get_or_init(|| {
        let mut f = Faults::default();
        let Ok(spec) = std::env::var("LATENTAM_FAULTS") else {
            return f;
        };
        for entry in spec.split(',').map(str::trim).filter(|e| !e.is_empty()) {
            let (key, value) = entry.split_once('=').unwrap_or((entry, ""));
            let n = value.parse::<u64>().ok();
            match (key, n) {
                ("alloc_fail_after", Some(n)) => f.alloc_fail_after = Some(n),
                ("device_lost_after", Some(n)) => f.device_lost_after = Some(n),
                ("disk_full", _) => f.disk_full = true,
                ("save_delay_ms", Some(n)) => f.save_delay_ms = n,
                ("mount_point", _) => f.mount_point = true,
                _ => log::warn!("LATENTAM_FAULTS: ignoring `{entry}`"),
            }
        }
        log::warn!("fault injection on: {f:?}");
        f
    })
}

/// Whether an existing run folder is to be taken for a mount point.
pub fn mount_point() -> bool {
    faults().mount_point
}

/// Whether the next buffer allocation is to fail.
pub fn allocation_fails() -> bool {
    let Some(n) = faults().alloc_fail_after else {
        return false;
    };
    ALLOCATIONS.fetch_add(1, Ordering::Relaxed) >= n
}

/// Whether the next submission is to fail with a lost device.
pub fn device_lost() -> bool {
    let Some(n) = faults().device_lost_after else {
        return false;
    };
    SUBMISSIONS.fetch_add(1, Ordering::Relaxed) >= n
}

/// The error a write is to fail with, if any.
pub fn write_error() -> Option<std::io::Error> {
    faults().disk_full.then(|| {
        std::io::Error::new(
            std::io::ErrorKind::StorageFull,
            "no space left on device (injected by LATENTAM_FAULTS)",
        )
    })
}

/// Waits before a written file is renamed into place, when asked to.
pub fn delay_save() {
    let ms = faults().save_delay_ms;
    if ms > 0 {
        std::thread::sleep(std::time::Duration::from_millis(ms));
    }
}

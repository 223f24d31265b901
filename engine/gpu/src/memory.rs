//! Byte accounting of GPU allocations by category, with an optional budget.

use std::collections::BTreeMap;
use std::sync::Mutex;

use latentam_base::{Error, Result};

/// Bytes in use and the peak, for one category or for the whole context.
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context) {
/// let total = ctx.memory_report().total;
/// println!("{} MiB in use, peak {} MiB", total.current >> 20, total.peak >> 20);
/// assert!(total.peak >= total.current);
/// # }
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ByteCount {
    /// Bytes currently allocated.
    pub current: u64,
    /// Highest `current` seen.
    pub peak: u64,
}

/// A snapshot of the device's `MemoryAccounting`.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let _pixels = Buffer::device(&ctx, "features/pixels", 1 << 20)?;
/// let report = ctx.memory_report();
/// assert!(report.by_category["features"].current >= 1 << 20);
/// assert_eq!(report.budget, None);
/// # Ok::<(), latentam_gpu::Error>(())
/// ```
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct MemoryReport {
    /// All device-memory allocations of the context (staging included).
    pub total: ByteCount,
    /// Per category (the name given when the buffer was created).
    pub by_category: BTreeMap<String, ByteCount>,
    /// The budget, if one is set.
    pub budget: Option<u64>,
}

/// The category of the warm-up's buffers (`Context::warm_up_only`: 64 KiB,
/// alive only while it runs), counted but not held to the budget. A budget
/// is the map's, and one too small for the map is reported as such at the
/// first keyframe, not as a warm-up that could not start.
pub(crate) const OUTSIDE_BUDGET: &str = "warm-up";

/// Running totals of allocated bytes. Allocation requests that would exceed the
/// budget are refused before they reach the driver.
#[derive(Debug)]
pub(crate) struct MemoryAccounting {
    inner: Mutex<MemoryReport>,
}

impl MemoryAccounting {
    pub fn new(budget: Option<u64>) -> Self {
        Self {
            inner: Mutex::new(MemoryReport {
                budget,
                ..Default::default()
            }),
        }
    }

    /// Reserves `bytes` for `category`, or fails when over budget (except
    /// for [`OUTSIDE_BUDGET`]).
    pub fn reserve(&self, category: &str, name: &str, bytes: u64) -> Result<()> {
        let mut m = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(b) = m.budget.filter(|_| category != OUTSIDE_BUDGET) {
            if m.total.current + bytes > b {
                return Err(Error::OutOfMemory(format!(
                    "allocating {bytes} bytes for `{name}` ({category}) would exceed the GPU \
                     memory budget of {b} bytes ({} in use)",
                    m.total.current
                )));
            }
        }
        m.total.current += bytes;
        m.total.peak = m.total.peak.max(m.total.current);
        let c = m.by_category.entry(category.to_string()).or_default();
        c.current += bytes;
        c.peak = c.peak.max(c.current);
        Ok(())
    }

    pub fn release(&self, category: &str, bytes: u64) {
        let mut m = self.inner.lock().unwrap_or_else(|p| p.into_inner());
        m.total.current = m.total.current.saturating_sub(bytes);
        if let Some(c) = m.by_category.get_mut(category) {
            c.current = c.current.saturating_sub(bytes);
        }
    }

    pub fn report(&self) -> MemoryReport {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    pub fn set_budget(&self, budget: Option<u64>) {
        self.inner.lock().unwrap_or_else(|p| p.into_inner()).budget = budget;
    }
}

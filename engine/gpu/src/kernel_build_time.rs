//! What building one kernel cost: kept apart from the warm-up that
//! measures it, so the device that stores the log needs nothing else of it.

/// What building one kernel cost (`Context::kernel_build_times`).
#[derive(Clone, Debug, PartialEq)]
pub struct KernelBuildTime {
    /// The kernel's name.
    pub kernel: &'static str,
    /// Creating its pipeline (`vkCreateComputePipelines` and the module and
    /// layouts), ms, on one of the threads that create them.
    pub create_ms: f64,
    /// Its first, empty dispatch, submitted and waited for, ms: where a
    /// driver compiles lazily, this is the compilation.
    pub first_dispatch_ms: f64,
}

impl KernelBuildTime {
    /// Both parts, ms.
    pub fn total_ms(&self) -> f64 {
        self.create_ms + self.first_dispatch_ms
    }
}

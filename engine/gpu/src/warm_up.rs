//! Building kernels before they are needed: every pipeline a caller will
//! dispatch is created, and then run once, before the caller reports ready.
//!
//! Creating a pipeline is not always the whole build. Drivers may compile
//! lazily: lavapipe turns a pipeline into machine code at its first
//! dispatch, on its queue's thread, and on a machine whose driver cache is
//! cold that took minutes inside the first keyframe. So each pipeline is
//! also dispatched once with zero workgroups (an indirect dispatch whose
//! counts are 0, which Vulkan defines as doing nothing): a driver that
//! compiles at first dispatch compiles then, and one that compiled at
//! creation does nothing.
//!
//! Pipelines are created on every core at once (`vkCreateComputePipelines`
//! may be called from several threads, and the pipeline cache is internally
//! synchronised). The dispatches go to the compute queue from the calling
//! thread as each pipeline comes out, one submission each, so that a
//! driver's compilation at first dispatch can overlap the creation of the
//! next ones (where the driver does not serialise the two), and each
//! kernel's cost is measured on its own. A kernel counts as built once its
//! empty dispatch ran: one whose pipeline was only created (by
//! `Context::kernel_builds`) is dispatched by the next warm-up.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;
use std::time::Instant;

use latentam_shaders::Kernel;

use crate::{Buffer, Context, Error, KernelBuildTime, Result};

/// Makes the warm-up's workers take no further kernel when dropped.
struct StopWorkers<'a> {
    next: &'a AtomicUsize,
    end: usize,
}

impl Drop for StopWorkers<'_> {
    fn drop(&mut self) {
        self.next.store(self.end, Ordering::Relaxed);
    }
}

/// Bytes of the buffer bound at every binding of the empty dispatches: no
/// invocation reads it, but a validation layer checks that each binding
/// holds a live buffer of some size.
const STAND_IN_BYTES: u64 = 64 * 1024;

impl Context {
    /// Builds every kernel this device can run ([`crate::DeviceInfo::can_run`]:
    /// not those needing features it lacks); see
    /// [`Context::warm_up_only`]. Call this before timing anything.
    /// Returns the number of kernels ready.
    pub fn warm_up(&self) -> Result<usize> {
        self.warm_up_only(|_| true)
    }

    /// [`Context::warm_up`] for the kernels `keep` accepts: a client that
    /// knows which variants it dispatches on this device (see
    /// `latentam_core::mapper::Mapper::warm_up`) spares the time of the
    /// others.
    /// Each kernel's pipeline is created (on all cores) and dispatched once
    /// with zero workgroups, so that a driver that compiles at first
    /// dispatch does it now rather than inside the caller's first piece of
    /// work. Kernels built before cost nothing. A kernel the driver
    /// rejects is left out (and remembered: see [`Context::kernel_builds`]);
    /// other errors are returned. Returns the number of kernels ready.
    pub fn warm_up_only(&self, keep: impl Fn(&Kernel) -> bool) -> Result<usize> {
        self.warm_up_reporting(keep, |_, _| {})
    }

    /// [`Context::warm_up_only`], calling `progress(built, of)` on this
    /// thread after each kernel is ready (for a progress line: on a
    /// machine whose driver cache is cold this takes seconds to minutes).
    pub fn warm_up_reporting(
        &self,
        keep: impl Fn(&Kernel) -> bool,
        mut progress: impl FnMut(usize, usize),
    ) -> Result<usize> {
        let built: Vec<&str> = self.kernel_build_times().iter().map(|t| t.kernel).collect();
        let wanted: Vec<&'static Kernel> = latentam_shaders::ALL
            .iter()
            .copied()
            .filter(|k| keep(k) && self.info().can_run(k))
            .collect();
        let todo: Vec<&'static Kernel> = wanted
            .iter()
            .copied()
            .filter(|k| !built.contains(&k.name))
            .collect();
        let mut ready = wanted.len() - todo.len();
        if !todo.is_empty() {
            ready += self.build(&todo, &mut progress)?;
        }
        *self
            .dev
            .ready_after
            .lock()
            .unwrap_or_else(|e| e.into_inner()) = Some(self.dev.opened.elapsed());
        Ok(ready)
    }

    /// Creates `todo`'s pipelines on worker threads and dispatches each as
    /// it comes out; returns how many built.
    fn build(
        &self,
        todo: &[&'static Kernel],
        progress: &mut impl FnMut(usize, usize),
    ) -> Result<usize> {
        let category = crate::memory::OUTSIDE_BUDGET;
        let stand_in = Buffer::device(self, &format!("{category}/stand-in"), STAND_IN_BYTES)?;
        let counts = Buffer::device(self, &format!("{category}/zero workgroups"), 16)?;
        let workers = std::thread::available_parallelism()
            .map_or(1, |n| n.get())
            .min(todo.len());
        let next = AtomicUsize::new(0);
        let (tx, rx) = mpsc::channel::<(usize, f64, Result<()>)>();
        let mut ready = 0;
        std::thread::scope(|s| -> Result<()> {
            // However this thread leaves the scope (an error, a panic in
            // `progress`), the workers take no further kernel, so the
            // scope's wait is for the kernels they hold, not for all.
            let _stop = StopWorkers {
                next: &next,
                end: todo.len(),
            };
            for _ in 0..workers {
                let tx = tx.clone();
                let next = &next;
                s.spawn(move || loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    let Some(&k) = todo.get(i) else { break };
                    let start = Instant::now();
                    let made = self
                        .dev
                        .pipelines
                        .get(&self.dev.raw, self.dev.pipeline_cache, k)
                        .map(|_| ());
                    let ms = start.elapsed().as_secs_f64() * 1e3;
                    if tx.send((i, ms, made)).is_err() {
                        break;
                    }
                });
            }
            drop(tx);
            for (done, (i, create_ms, made)) in rx.iter().enumerate() {
                let k = todo[i];
                let outcome = made.and_then(|()| self.first_dispatch(k, &stand_in, &counts));
                match outcome {
                    Ok(first_dispatch_ms) => {
                        ready += 1;
                        self.dev
                            .build_times
                            .lock()
                            .unwrap_or_else(|e| e.into_inner())
                            .push(KernelBuildTime {
                                kernel: k.name,
                                create_ms,
                                first_dispatch_ms,
                            });
                    }
                    // Logged and remembered by the pipeline cache; a caller
                    // with another variant falls back on it.
                    Err(Error::KernelBuild { .. }) => {}
                    // A lost device or exhausted memory: the rest would fail
                    // too.
                    Err(e) => return Err(e),
                }
                progress(done + 1, todo.len());
            }
            Ok(())
        })?;
        Ok(ready)
    }

    /// One dispatch of `k` with zero workgroups, waited for; its time, ms.
    fn first_dispatch(
        &self,
        k: &'static Kernel,
        stand_in: &Buffer,
        counts: &Buffer,
    ) -> Result<f64> {
        let start = Instant::now();
        let mut rec = self.recorder()?;
        rec.fill_u32(counts, 0);
        rec.dispatch_untyped_indirect(k, counts, &vec![stand_in; k.bindings.len()])?;
        rec.submit()?.wait()?;
        Ok(start.elapsed().as_secs_f64() * 1e3)
    }

    /// What building each kernel cost in this process, in the order they
    /// became ready (kernels built by a warm-up; one built on first use by
    /// a dispatch is not listed).
    pub fn kernel_build_times(&self) -> Vec<KernelBuildTime> {
        self.dev
            .build_times
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// The kernels whose pipelines exist in this context, sorted: built by
    /// a warm-up or on first use.
    pub fn built_kernels(&self) -> Vec<&'static str> {
        let mut built = self.dev.pipelines.built();
        built.sort_unstable();
        built
    }

    /// How long after the device was opened the last warm-up
    /// ([`Context::warm_up_only`]) had every kernel ready, ms; `None`
    /// before one. With warm driver caches this is mostly the driver's
    /// start.
    pub fn time_to_ready_ms(&self) -> Option<f64> {
        self.dev
            .ready_after
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .map(|d| d.as_secs_f64() * 1e3)
    }
}

//! latentam's compute kernels, compiled to SPIR-V 1.3 at build time.
//!
//! Every kernel is a [`KernelDef`] static named after it (`SCAN_BLOCKS`,
//! `GEMM_NN`, ...); its push-constant block is mirrored by a `#[repr(C)]`
//! struct in [`push`], so dispatching with the wrong parameters does not
//! compile. Sources live in the workspace's `glsl/` (GLSL, the default) and in
//! `shaders/wgsl/` (kernels that need atomics or subgroup operations); each
//! entry's doc names its file.
//!
//! ```
//! use latentam_shaders::{ALL, SCAN_BLOCKS};
//! assert_eq!(SCAN_BLOCKS.kernel.name, "scan_blocks");
//! assert!(ALL.iter().any(|k| k.source.ends_with("scan.comp")));
//! ```

#![deny(missing_docs)]

use std::marker::PhantomData;

/// One storage buffer of a kernel (set 0, binding = its index in
/// [`Kernel::bindings`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Binding {
    /// Name of the buffer variable in the kernel source.
    pub name: &'static str,
    /// Whether the kernel may write the buffer (not declared `readonly`).
    pub writable: bool,
}

/// A compiled kernel, independent of its push-constant type.
#[derive(Debug)]
pub struct Kernel {
    /// Unique kernel name (the profiler reports by it).
    pub name: &'static str,
    /// Source file, relative to the workspace root.
    pub source: &'static str,
    /// SPIR-V 1.3 words; the entry point is named `main` for GLSL kernels and
    /// after the kernel for WGSL ones (see [`Kernel::entry_point`]).
    pub spirv: &'static [u32],
    /// Workgroup size declared in the source.
    pub workgroup: [u32; 3],
    /// Bytes of workgroup (shared) memory it uses: at most the device's
    /// `maxComputeSharedMemorySize` (16 KiB is all Vulkan guarantees).
    pub shared_bytes: u32,
    /// Storage buffers, binding 0..n of set 0.
    pub bindings: &'static [Binding],
    /// Size in bytes of the push-constant block (0 when it has none).
    pub push_constant_size: u32,
    /// What the kernel needs of the device beyond Vulkan 1.2 compute.
    pub requires: Requires,
    /// How one dispatch's work is counted (the kernel's `// @cost` line).
    pub work: WorkCount,
}

/// The work of one dispatch: arithmetic operations and bytes of global
/// memory (storage buffers) read and written, each element counted once.
/// A floor, not a measurement: an add, multiply or compare is one
/// operation, a fused multiply-add two, a division or square root four,
/// an exponential or logarithm ten; index arithmetic and loop control are
/// not counted, and caches are taken as perfect.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Work {
    /// Arithmetic operations.
    pub flops: f64,
    /// Bytes of global memory read plus written.
    pub bytes: f64,
}

impl std::ops::Add for Work {
    type Output = Work;

    fn add(self, o: Work) -> Work {
        Work {
            flops: self.flops + o.flops,
            bytes: self.bytes + o.bytes,
        }
    }
}

/// How a kernel's work per dispatch is known.
#[derive(Clone, Copy, Debug)]
pub enum WorkCount {
    /// From the dispatch's push-constant bytes and its workgroup counts
    /// (`None` for an indirect dispatch; the count is then unknown if the
    /// kernel's expression needs them).
    Launch(fn(&[u8], Option<[u32; 3]>) -> Option<Work>),
    /// The work depends on data the launch does not show (the lengths of
    /// per-tile lists, say): the code that dispatches it states it.
    Caller,
}

/// Device features a kernel uses, read by the build from the kernel's own
/// code (so each variant of a file states only what it uses).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Requires {
    /// 32-bit float atomic add on storage buffers
    /// (`VK_EXT_shader_atomic_float`).
    pub float_atomics: bool,
    /// Subgroup reductions, scans, ballots or votes in compute.
    pub subgroup_arithmetic: bool,
    /// Subgroup shuffles in compute.
    pub subgroup_shuffle: bool,
}

/// Whether the kernel named `name` is a column-layout blending variant
/// (`raster_*_columns*`, see `BlendLayout::Columns`): the variants a GPU's
/// compiler may reject, for which the rasterizer has pixel-layout ones to
/// fall back on.
pub fn is_column_layout(name: &str) -> bool {
    name.starts_with("raster_") && name.contains("_columns")
}

impl Kernel {
    /// Whether this is a column-layout blending variant ([`is_column_layout`]).
    pub fn is_column_layout(&self) -> bool {
        is_column_layout(self.name)
    }

    /// Name of the SPIR-V entry point.
    pub fn entry_point(&self) -> &'static str {
        if self.source.ends_with(".wgsl") {
            self.name
        } else {
            "main"
        }
    }

    /// The work of one dispatch with these push constants (the bytes of
    /// the kernel's push struct) and workgroup counts (`None` when
    /// indirect), if its `@cost` line can count it from them.
    ///
    /// ```
    /// use latentam_shaders::{push, GEMM_NN};
    /// let p = push::Gemm { m: 4, n: 5, k: 6, ..Default::default() };
    /// let w = GEMM_NN.kernel.work_of(bytemuck::bytes_of(&p), Some([1, 1, 1])).unwrap();
    /// assert_eq!(w.flops, 2.0 * 4.0 * 5.0 * 6.0);
    /// ```
    pub fn work_of(&self, push: &[u8], groups: Option<[u32; 3]>) -> Option<Work> {
        match self.work {
            WorkCount::Launch(count) => count(push, groups),
            WorkCount::Caller => None,
        }
    }

    /// Invocations per workgroup.
    pub fn workgroup_invocations(&self) -> u32 {
        self.workgroup[0] * self.workgroup[1] * self.workgroup[2]
    }
}

/// A kernel together with the Rust types of its push constants (`P`) and
/// of the buffers it binds (`S`, a [`BindingSet`] of [`bind`]): a dispatch
/// through it cannot pass the wrong push constants or the wrong buffers.
#[derive(Debug)]
pub struct KernelDef<P, S> {
    /// The untyped kernel.
    pub kernel: Kernel,
    _types: PhantomData<fn(P, S)>,
}

impl<P, S> KernelDef<P, S> {
    /// Wraps a kernel; used by the generated table.
    pub const fn new(kernel: Kernel) -> Self {
        Self {
            kernel,
            _types: PhantomData,
        }
    }
}

/// The storage buffers a set of kernels binds, as a struct with one named
/// field per binding (`Buffers`), generated for each set in [`bind`].
///
/// ```
/// use latentam_shaders::{bind, BindingSet};
///
/// // Any buffer type works; the engine uses its own.
/// let (x, y) = ("x", "y");
/// let buffers = bind::SoftmaxBuffers { x: &x, y: &y };
/// assert_eq!(bind::Softmax::in_order(&buffers), vec![&"x", &"y"]);
/// assert_eq!(bind::Softmax::COUNT, 2);
/// ```
pub trait BindingSet {
    /// The named buffers, borrowed for `'a`.
    type Buffers<'a, B: 'a>;
    /// How many buffers the kernels bind.
    const COUNT: usize;
    /// The buffers in binding order (binding 0 first).
    fn in_order<'a, B: 'a>(buffers: &Self::Buffers<'a, B>) -> Vec<&'a B>;
}

include!(concat!(env!("OUT_DIR"), "/kernels.rs"));

/// Constants and buffer structs shared by the host and the kernels,
/// generated from `shaders/layouts.rs` (kernels get the same declarations
/// from `#include "shared.glsl"` or `#include "shared.wgsl"`).
///
/// ```
/// use latentam_shaders::shared::{View, TILE_SIZE};
/// assert_eq!(std::mem::size_of::<View>(), 128);
/// assert_eq!(TILE_SIZE, 16);
/// ```
pub mod shared {
    include!(concat!(env!("OUT_DIR"), "/shared.rs"));
}

#[cfg(test)]
mod tests;

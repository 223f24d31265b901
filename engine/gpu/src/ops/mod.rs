//! GPU primitives. Each type records its kernels into a [`crate::Recorder`];
//! its CPU reference is the same-named module in `latentam_reference`.

mod atomic;
mod gemm;
mod normalize;
mod reduce;
mod rows;
mod scan;
mod softmax;
mod sort;

pub use atomic::{scatter_add_f32, SCATTER_THREADS};
pub use gemm::{Gemm, GemmKernel, Transpose, GEMM_TILE};
pub use normalize::{normalize_rows, normalize_rows_backward};
pub use reduce::{ReduceOp, Reducer, REDUCE_BLOCK};
pub use rows::{gather_rows, move_rows, scatter_rows, Packed, RowList};
pub use scan::{PrefixScan, SCAN_BLOCK};
pub use softmax::{row_softmax, row_softmax_backward};
pub use sort::{RadixSorter, RADIX_BITS, SORT_BLOCK};

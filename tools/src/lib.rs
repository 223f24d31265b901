//! Library side of the `latentam` command-line tool: the dataset
//! converters and progress reporting, shared by the binary, the
//! integration tests and the benchmarks. The demo scene is its own crate,
//! `latentam-scene` (`tools/scene/`).

pub mod convert;
pub mod progress;
pub mod soak;

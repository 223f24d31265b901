//! Library side of the `latentam` command-line tool: the demo-scene
//! generator and the dataset converters, shared by the binary, the
//! integration tests and the benchmarks.

pub mod convert;
pub mod progress;
pub mod scene;
pub mod soak;

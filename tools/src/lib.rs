//! Library side of the `latentam` command-line tool: the dataset
//! converters, progress reporting, Ctrl-C, and the option groups every
//! mapping command shares, used by the binary, the ROS 2 node
//! (`latentam-ros`), the integration tests and the benchmarks. The demo scene is its own crate,
//! `latentam-scene` (`tools/scene/`).

pub mod config_args;
pub mod convert;
pub mod input_args;
pub mod interrupt;
pub mod live_args;
pub mod progress;
pub mod soak;

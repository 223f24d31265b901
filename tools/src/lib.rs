//! Library side of the `latentam` command-line tool: the dataset
//! converters and progress reporting, used by the binary, the integration
//! tests and the benchmarks. The option groups every mapping front shares
//! (also the ROS 2 node's) and Ctrl-C are the crate `latentam-args`
//! (`tools/args/`), re-exported here; the demo scene is its own crate,
//! `latentam-scene` (`tools/scene/`).

pub use latentam_args::{config_args, input_args, interrupt, live_args};
pub mod convert;
pub mod progress;
pub mod soak;

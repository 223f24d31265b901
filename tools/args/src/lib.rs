//! The option groups the fronts that map share, defined once on the
//! `latentam` façade: where the configuration comes from (`--config`,
//! `--preset`, `--set`), how a log's or a robot's topics become frames,
//! the live view's flags, and what Ctrl-C does. The command-line tool
//! (`latentam`) and the ROS 2 node (`latentam-ros`) both flatten them into
//! their arguments, so a flag means the same in both.

pub mod config_args;
pub mod input_args;
pub mod interrupt;
pub mod live_args;

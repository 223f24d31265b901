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

/// A library error about the value given to `flag`, as a front reports
/// it: `FLAG: reason` for a value the library refused (bad input or a
/// setting out of range: the flag says where the value came from, the
/// reason what is wrong with it), `FLAG: message` for anything else.
///
/// ```
/// let refuse = latentam_args::flag_error("--temperature");
/// let e = refuse(latentam::Error::bad_input("temperature", "0 is outside 0.001..=10"));
/// assert_eq!(e.to_string(), "--temperature: 0 is outside 0.001..=10");
/// ```
pub fn flag_error(flag: &'static str) -> impl Fn(latentam::Error) -> anyhow::Error {
    move |e| match e {
        latentam::Error::BadInput { reason, .. } | latentam::Error::Config { reason, .. } => {
            anyhow::anyhow!("{flag}: {reason}")
        }
        e => anyhow::anyhow!("{flag}: {e}"),
    }
}

//! `latentam-ros`: latentam as a ROS 2 node. It subscribes to a camera's
//! colour, depth and calibration, the camera pose (a pose topic or TF)
//! and, when published, region embeddings and a vocabulary, choosing the
//! topics from the ROS graph by the rules `latentam map` applies to a bag;
//! maps them live; and publishes the map, the keyframe trajectory and its
//! status, answers relevance queries and saves on request. Ctrl-C saves
//! the map into `--out` and exits.
//!
//! It speaks DDS through RustDDS (no ROS 2 installation is needed) and
//! interoperates with ROS 2 nodes on the same domain (`ROS_DOMAIN_ID`).

mod args;
mod dds;
mod graph;
mod inputs;
mod node;
mod outputs;
mod param_services;
mod params;
mod services;

use std::process::ExitCode;

use clap::Parser;

use args::Args;

fn main() -> ExitCode {
    let args = Args::parse();
    let level = match args.verbose {
        0 => "warn",
        1 => "info",
        _ => "debug",
    };
    // RustDDS warns of every datagram over 1500 bytes, which loopback
    // and large messages make routine: only its errors are shown unless
    // RUST_LOG says otherwise.
    let filter = format!("{level},rustdds=error");
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(filter))
        .format_timestamp(None)
        .init();
    latentam_args::interrupt::file_size_limit_is_an_error();
    match node::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

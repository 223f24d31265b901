//! The node's command line.

use std::path::PathBuf;

use clap::Parser;
use latentam_args::config_args::ConfigArgs;
use latentam_args::input_args::InputArgs;
use latentam_args::live_args::LiveViewArgs;

/// latentam as a ROS 2 node: maps from a robot's topics, publishes the map
/// and answers queries.
#[derive(Parser)]
#[command(name = "latentam-ros", version)]
pub struct Args {
    /// Run folder the map is saved into on Ctrl-C (and by default on a
    /// save request without a folder); without it, Ctrl-C only stops.
    #[arg(short, long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// DDS domain; default `ROS_DOMAIN_ID`, else 0.
    #[arg(long, value_name = "ID")]
    pub domain: Option<u16>,
    /// Namespace of the node's own topics.
    #[arg(long, default_value = "/latentam", value_name = "NS")]
    pub namespace: String,
    /// Frame id of the map, trajectory and relevance clouds: the world
    /// frame of the input poses.
    #[arg(long, default_value = "map", value_name = "FRAME")]
    pub frame_id: String,
    /// Least seconds between two publications of the map cloud and the
    /// trajectory (each published after a new keyframe only).
    #[arg(long, default_value_t = 1.0, value_name = "SECONDS")]
    pub map_every: f64,
    /// Most points in a published cloud (an even subset of a larger map).
    #[arg(long, default_value_t = 100_000, value_name = "N")]
    pub map_points: usize,
    /// Vocabulary words (of the vocabulary topic) whose relevance rides
    /// on the map cloud as `relevance_<word>` fields, comma-separated.
    #[arg(long, value_delimiter = ',', value_name = "WORD,...")]
    pub words: Vec<String>,
    /// Softmax temperature of relevance over several words.
    #[arg(long, default_value_t = 0.1)]
    pub temperature: f32,
    #[command(flatten)]
    pub config: ConfigArgs,
    #[command(flatten)]
    pub input: InputArgs,
    #[command(flatten)]
    pub live: LiveViewArgs,
    /// More of what the engine reports: -v notes, -vv debug detail.
    #[arg(short, long, action = clap::ArgAction::Count)]
    pub verbose: u8,
}

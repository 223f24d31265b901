//! `latentam`: the command-line front end of the engine.

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use latentam_cli::{config_args, input_args, interrupt, live_args};

mod bench;
mod config_cmd;
mod convert_cmd;
mod demo_cmd;
mod eval_cmd;
mod export_cmd;
mod gen_scene;
mod inspect;
mod loaded_map;
mod logging;
mod map_cmd;
mod mapping;
mod own_inputs;
mod pictures;
mod png_out;
mod profile_cmd;
mod query_args;
mod query_cmd;
mod render_cmd;
mod selfcheck;

#[derive(Parser)]
#[command(
    name = "latentam",
    version,
    about = "Online latent 3D Gaussian mapping on Vulkan"
)]
struct Cli {
    /// Show more of what the engine reports: -v notes, -vv debug detail
    /// (warnings are always shown; RUST_LOG overrides, e.g.
    /// RUST_LOG=latentam_io=debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the Vulkan devices and the one the engine would pick.
    Devices,
    /// Run every GPU primitive once against its CPU reference and report.
    Selfcheck {
        /// Load the Vulkan validation layer and fail on any message.
        #[arg(long)]
        validation: bool,
        /// Print every kernel's build time (pipeline creation and first
        /// dispatch, where a driver may compile lazily), slowest first, and
        /// write them as JSON to this file. Run with a fresh
        /// MESA_SHADER_CACHE_DIR (or your driver's cache emptied) to see
        /// what a new machine pays.
        #[arg(long, value_name = "FILE.json")]
        kernel_times: Option<std::path::PathBuf>,
        /// Build only the kernels whose names contain one of these
        /// (comma-separated), e.g. `--kernels raster_pool_columns`, and
        /// skip the primitives' checks: to time or diagnose a few kernels
        /// without building all of them.
        #[arg(long, value_name = "NAMES", value_delimiter = ',')]
        kernels: Vec<String>,
    },
    /// The built-in scene end to end: generate it, map it, evaluate the
    /// map on held-out views, query it, and print a summary.
    Demo(demo_cmd::Args),
    /// Map a log into a run folder: map.ply, decoder.safetensors,
    /// config.toml, report.json, trace.json, trajectory.txt and the
    /// resumable state. Ctrl-C stops cleanly and still writes the folder.
    Map(map_cmd::Args),
    /// Relevance of every Gaussian of a mapped run to a text embedding or
    /// a vocabulary entry: heat-map PLY, top-k summary, relevance image.
    Query(query_cmd::Args),
    /// Pictures of a mapped run from one camera (a pose, or a frame of a
    /// log): rendered colour, depth and, for a query, relevance as PNGs.
    Render(render_cmd::Args),
    /// A mapped run for other tools: `--foxglove OUT.mcap` writes the map,
    /// one relevance cloud per vocabulary word and the trajectory for
    /// Foxglove.
    Export(export_cmd::Args),
    /// Re-render a log's frames from a mapped run and report PSNR, depth
    /// L1, embedding cosine loss and L2, and mIoU.
    Eval(eval_cmd::Args),
    /// Map a log with every kernel timed: per-kernel table and trace.json.
    Profile(profile_cmd::Args),
    /// Print the configuration: documented defaults, or the effective one
    /// of --config/--set.
    Config(config_cmd::Args),
    /// Write the built-in demo scene (two rooms and a corridor, a dozen
    /// labelled objects, synthetic region embeddings) as an MCAP log, or
    /// with --rooms N a building of N rooms for long walks.
    GenScene(gen_scene::Args),
    /// Convert a TUM RGB-D, 7-Scenes or Replica (NICE-SLAM layout) folder
    /// to an MCAP log, optionally with per-frame embeddings.
    Convert(convert_cmd::Args),
    /// List a log's topics and assemble its frames, reporting every message
    /// the engine would not use, by reason.
    Inspect(inspect::Args),
    /// Benchmarks that print a table and write JSON.
    Bench {
        #[command(subcommand)]
        which: bench::Which,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    logging::install(cli.verbose);
    interrupt::file_size_limit_is_an_error();
    let result = match cli.command {
        Command::Devices => selfcheck::devices(),
        Command::Selfcheck {
            validation,
            kernel_times,
            kernels,
        } => selfcheck::run(validation, kernel_times.as_deref(), &kernels),
        Command::Demo(args) => demo_cmd::run(args),
        Command::Map(args) => match map_cmd::run(args) {
            Ok(true) => return ExitCode::from(map_cmd::INTERRUPTED),
            Ok(false) => Ok(()),
            Err(e) => Err(e),
        },
        Command::Query(args) => query_cmd::run(args),
        Command::Render(args) => render_cmd::run(args),
        Command::Export(args) => export_cmd::run(args),
        Command::Eval(args) => eval_cmd::run(args),
        Command::Profile(args) => profile_cmd::run(args),
        Command::Config(args) => config_cmd::run(args),
        Command::GenScene(args) => gen_scene::run(args),
        Command::Convert(args) => convert_cmd::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Bench { which } => bench::run(which),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Errors quote file contents and arguments: shown defused.
            eprintln!("error: {}", latentam::text::shown(&mapping::describe(&e)));
            ExitCode::FAILURE
        }
    }
}

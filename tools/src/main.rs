//! `latentam`: the command-line front end of the engine.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod bench;
mod bench_ingest;
mod bench_latent;
mod bench_map;
mod bench_raster;
mod convert_cmd;
mod gen_scene;
mod inspect;
mod selfcheck;

#[derive(Parser)]
#[command(
    name = "latentam",
    version,
    about = "Online latent 3D Gaussian mapping on Vulkan"
)]
struct Cli {
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
    },
    /// The end-to-end demo. The built-in demo scene and mapper are not part
    /// of the engine yet, so this currently runs the GPU self-check.
    Demo {
        /// Output folder for the demo's results.
        #[arg(long, default_value = "latentam-demo")]
        out: PathBuf,
    },
    /// Write the built-in demo scene (two rooms and a corridor, a dozen
    /// labelled objects, synthetic region embeddings) as an MCAP log.
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
    let result = match cli.command {
        Command::Devices => selfcheck::devices(),
        Command::Selfcheck { validation } => selfcheck::run(validation),
        Command::Demo { out } => {
            eprintln!(
                "note: the demo scene and the mapper are not implemented yet; running the GPU \
                 self-check instead (results would go to {}).",
                out.display()
            );
            selfcheck::run(false)
        }
        Command::GenScene(args) => gen_scene::run(args),
        Command::Convert(args) => convert_cmd::run(args),
        Command::Inspect(args) => inspect::run(args),
        Command::Bench { which } => bench::run(which),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

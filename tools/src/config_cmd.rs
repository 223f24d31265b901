//! `latentam config`: the documented defaults, or an effective
//! configuration.

use anyhow::Result;
use latentam::config::documented_defaults;
use latentam_cli::config_args::ConfigArgs;

#[derive(clap::Args)]
pub struct Args {
    /// Print the default configuration with every key documented, as a
    /// TOML file to start from.
    #[arg(long)]
    print_defaults: bool,
    #[command(flatten)]
    config: ConfigArgs,
}

/// Prints the documented defaults, or the effective configuration of
/// `--config`/`--set` (checking it).
pub fn run(args: Args) -> Result<()> {
    if args.print_defaults {
        print!("{}", documented_defaults());
    } else {
        print!("{}", args.config.load()?.to_toml());
    }
    Ok(())
}

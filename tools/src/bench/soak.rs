//! `latentam bench soak`: hours of operation compressed — the demo scene
//! walked lap after lap, checking that GPU memory stays flat, CPU memory
//! follows the explored space, no Vulkan object leaks and the validation
//! layer stays silent.

use std::path::PathBuf;

use anyhow::Result;
use latentam_cli::progress::Progress;
use latentam_cli::soak::{lap_table, run, SoakOptions};
use latentam_gpu::{Context, ContextOptions, Validation};
use latentam_scene::SceneConfig;

use crate::config_args::ConfigArgs;

/// Settings of the soak's mapper unless --config is given: small enough
/// for thousands of frames on a CPU driver.
const SOAK_DEFAULTS: &[&str] = &["keyframes.policy.interval=8", "replay=2", "atoms=64"];

#[derive(clap::Args)]
pub struct Args {
    /// Frames, spread over all laps.
    #[arg(long, default_value_t = 5000, value_parser = clap::value_parser!(u64).range(2..))]
    frames: u64,
    /// Traversals of the scene's path (forwards, backwards, ...); at least 2.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(2..))]
    laps: u64,
    /// Image width.
    #[arg(long, default_value_t = 64, value_parser = clap::value_parser!(u32).range(16..=4096))]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 48, value_parser = clap::value_parser!(u32).range(16..=4096))]
    height: u32,
    /// Walk a building of this many rooms along corridors instead of the
    /// demo room (2 to 1000): a map that grows through the first lap.
    #[arg(long, value_parser = clap::value_parser!(u64).range(2..=1000))]
    rooms: Option<u64>,
    /// Embedding dimension of the scene.
    #[arg(long, default_value_t = 32, value_parser = clap::value_parser!(u64).range(1..=8192))]
    dim: u64,
    /// Mapper configuration; without --config the soak uses keyframe
    /// interval 8, replay 2 and 64 atoms, then applies --set.
    #[command(flatten)]
    config: ConfigArgs,
    /// Run with the Vulkan validation layer (required, and every message
    /// counted).
    #[arg(long)]
    validation: bool,
    /// Write the report with the per-keyframe curves here.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn run_bench(args: Args) -> Result<()> {
    let mut config = args.config.clone();
    if config.config.is_none() {
        let mut sets: Vec<String> = SOAK_DEFAULTS.iter().map(|s| s.to_string()).collect();
        sets.extend(config.sets);
        config.sets = sets;
    }
    let config = config.load()?;
    let ctx = Context::new(ContextOptions {
        validation: if args.validation {
            Validation::Required
        } else {
            ContextOptions::default().validation
        },
        ..ContextOptions::default()
    })?;
    let scene = SceneConfig {
        frames: args.frames as usize,
        laps: args.laps as usize,
        width: args.width,
        height: args.height,
        dim: args.dim as usize,
        rooms: args.rooms.map(|n| n as usize),
        ..SceneConfig::default()
    };
    let scratch = std::env::temp_dir().join(format!("latentam-soak-{}", std::process::id()));
    let mut progress = Progress::new("soak", scene.frames);
    let result = run(&ctx, &SoakOptions { scene, config }, &scratch, |d| {
        progress.set(d)
    });
    let _ = std::fs::remove_dir_all(&scratch);
    let r = result?;
    println!(
        "{} frames in {} laps ({}×{}) on {}: {:.0} s",
        r.frames, r.laps, r.width, r.height, r.device, r.wall_s
    );
    print!("{}", lap_table(&r));
    println!(
        "after the first lap: GPU peak ×{:.3}, CPU ×{:.3}, Gaussians ×{:.3}; live objects steady: \
         {}; validation messages: {}",
        r.gpu_growth_after_first_lap,
        r.cpu_growth_after_first_lap,
        r.gaussian_growth_after_first_lap,
        r.objects_steady,
        r.validation_messages
    );
    if let Some(p) = &args.json {
        crate::mapping::write_text(p, &serde_json::to_string_pretty(&r)?)?;
    }
    Ok(())
}

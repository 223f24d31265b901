//! Opening a run folder for the commands that read a mapped run.

use std::path::Path;

use anyhow::{bail, Context as _, Result};
use latentam_cli::progress::Stages;
use latentam_core::mapper::Mapper;
use latentam_gpu::{Context, ContextOptions};

/// The map in `dir` on a new context; a map without Gaussians is refused,
/// as there is nothing to `verb`.
pub fn load_nonempty_map(stages: &Stages, dir: &Path, verb: &str) -> Result<(Context, Mapper)> {
    stages.start(format_args!("loading the map in {}", dir.display()));
    let ctx = Context::new(ContextOptions::default())?;
    let mapper =
        Mapper::load(&ctx, dir).with_context(|| format!("loading the map in {}", dir.display()))?;
    if mapper.global().is_empty() {
        bail!(
            "the map in {} holds no Gaussians: there is nothing to {verb}",
            dir.display()
        );
    }
    Ok((ctx, mapper))
}

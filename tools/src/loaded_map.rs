//! Opening a run folder for the commands that read a mapped run.

use std::path::Path;

use anyhow::{bail, Context as _, Result};
use latentam::{Context, ContextOptions, Mapper};
use latentam_cli::progress::Stages;

/// The run folder `dir`'s `report.json`: `None` when it has none. One
/// that cannot be read (a FIFO or a device in its place, larger than a
/// report may be, not UTF-8) or is not JSON is an error, not a missing
/// report: the checks that rely on it (the run it belongs to) would
/// silently be skipped.
pub fn read_run_report(dir: &Path) -> Result<Option<serde_json::Value>> {
    let path = dir.join("report.json");
    if std::fs::symlink_metadata(&path).is_err_and(|e| e.kind() == std::io::ErrorKind::NotFound) {
        return Ok(None);
    }
    let text = latentam::files::read_input_to_string(&path)
        .with_context(|| format!("reading {}", path.display()))?;
    let report = latentam::files::parse_json(&text)
        .map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    Ok(Some(report))
}

/// The map in `dir` on a new context; a map without Gaussians is refused,
/// as there is nothing to `verb`.
pub fn load_nonempty_map(stages: &Stages, dir: &Path, verb: &str) -> Result<(Context, Mapper)> {
    stages.start(format_args!("loading the map in {}", dir.display()));
    let ctx = Context::new(ContextOptions::default())?;
    let mapper =
        Mapper::load(&ctx, dir).with_context(|| format!("loading the map in {}", dir.display()))?;
    if mapper.stats().gaussians == 0 {
        bail!(
            "the map in {} holds no Gaussians: there is nothing to {verb}",
            dir.display()
        );
    }
    Ok((ctx, mapper))
}

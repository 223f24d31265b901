//! The `--config FILE` / `--preset` / `--set KEY=VALUE` options every
//! mapping command (and the ROS node) shares.

use std::path::PathBuf;

use anyhow::{Context as _, Result};
use latentam::config::{apply_overrides, Preset};
use latentam::Config as MapperConfig;

/// Where the mapper's configuration comes from.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ConfigArgs {
    /// Configuration file (TOML; unknown keys are errors). Every key is
    /// listed and documented by `latentam config --print-defaults`.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Sets one configuration key, after --config; repeatable. Dotted keys
    /// reach into sections: `--set keyframes.policy.interval=4 --set
    /// gpu_budget=500000000`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub sets: Vec<String>,
    /// A named set of settings applied after --config and before --set:
    /// `realtime` (the defaults) or `quality`, for mapping a recorded log
    /// offline (3 Stage I steps per keyframe instead of 1, about 3× the
    /// Stage I time, and every keyframe kept for replay).
    #[arg(long, value_name = "NAME")]
    pub preset: Option<String>,
}

impl ConfigArgs {
    /// The effective configuration.
    pub fn load(&self) -> Result<MapperConfig> {
        self.load_over(MapperConfig::default())
    }

    /// The effective configuration starting from `base` (a resumed run's
    /// settings) instead of the defaults: --config replaces it, then the
    /// preset and --set apply.
    pub fn load_over(&self, base: MapperConfig) -> Result<MapperConfig> {
        let base = match &self.config {
            Some(p) => {
                let text = latentam::config::read_input_to_string(p)
                    .with_context(|| format!("reading {}", p.display()))?;
                MapperConfig::from_toml(&text).with_context(|| format!("in {}", p.display()))?
            }
            None => base,
        };
        let base = match &self.preset {
            Some(name) => name.parse::<Preset>()?.apply(&base)?,
            None => base,
        };
        Ok(apply_overrides(&base, &self.sets)?)
    }
}

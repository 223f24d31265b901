//! Named sets of settings for a kind of use, applied on top of a
//! configuration like `--set` overrides.

use super::{apply_overrides, MapperConfig};
use latentam_base::{Error, Result};

/// A named set of settings.
///
/// ```
/// use latentam_core::mapper::{MapperConfig, Preset};
/// let offline = Preset::Quality.apply(&MapperConfig::default())?;
/// assert!(offline.stage_one_iterations > MapperConfig::default().stage_one_iterations);
/// assert_eq!("quality".parse::<Preset>()?, Preset::Quality);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// The defaults: the paper's one Stage I step per keyframe, for a robot
    /// mapping as it moves.
    Realtime,
    /// For mapping a recorded log offline: more Stage I steps per keyframe
    /// (Stage I's time grows in proportion; see docs/quality.md's ablation),
    /// and every keyframe kept for replay.
    Quality,
}

impl Preset {
    /// All presets, by name.
    pub const ALL: [(&'static str, Preset); 2] =
        [("realtime", Preset::Realtime), ("quality", Preset::Quality)];

    /// The settings it changes, as `key=value` overrides.
    pub fn overrides(self) -> &'static [&'static str] {
        match self {
            Preset::Realtime => &[],
            Preset::Quality => &["stage_one_iterations=3", "history_cell=0"],
        }
    }

    /// `config` with this preset's settings.
    pub fn apply(self, config: &MapperConfig) -> Result<MapperConfig> {
        let sets: Vec<String> = self.overrides().iter().map(|s| s.to_string()).collect();
        apply_overrides(config, &sets)
    }
}

impl std::str::FromStr for Preset {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        Preset::ALL
            .iter()
            .find(|(name, _)| *name == s)
            .map(|&(_, p)| p)
            .ok_or_else(|| {
                Error::config(
                    "preset",
                    format!(
                        "no preset `{s}`; the presets are {}",
                        Preset::ALL.map(|(n, _)| n).join(", ")
                    ),
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_change_only_their_keys_and_unknown_names_are_errors() {
        let base = MapperConfig::default();
        assert_eq!(Preset::Realtime.apply(&base).unwrap(), base);
        let q = Preset::Quality.apply(&base).unwrap();
        assert_eq!(q.stage_one_iterations, 3);
        assert_eq!(q.history_cell, 0.0);
        let reset = MapperConfig {
            stage_one_iterations: base.stage_one_iterations,
            history_cell: base.history_cell,
            ..q.clone()
        };
        assert_eq!(reset, base);
        let e = "fast".parse::<Preset>().unwrap_err().to_string();
        assert!(e.contains("realtime, quality"), "{e}");
    }
}

//! Settings as users give them: `--set key=value` lists and whole
//! configuration files (`MapperConfig::from_toml`), from arbitrary text and
//! from structured picks of real keys with hostile values. They may refuse
//! anything but must not panic; what they accept validates and reads back
//! the same from the TOML it writes.

use arbitrary::{Arbitrary, Unstructured};
use latentam_core::mapper::{apply_overrides, documented_defaults, MapperConfig};

const KEYS: &[&str] = &[
    "voxel_size",
    "window_radius",
    "sync_distance",
    "history_cell",
    "replay",
    "atoms",
    "max_regions",
    "window_capacity",
    "gpu_budget",
    "temperature",
    "stage_one_iterations",
    "stage_two_iterations",
    "latent_lr",
    "prune_interval",
    "prune_min_opacity",
    "prune_max_scale",
    "seed",
    "keyframes.policy",
    "keyframes.policy.interval",
    "keyframes.policy.overlap.min_overlap",
    "keyframes.min_rotation_deg",
    "seeding.stride",
    "seeding.max_depth",
    "seeding.opacity",
    "seeding.hole_fill_radius",
    "seeding.query_init",
    "weights.feature",
    "weights.trust_radius",
    "learning_rates.means",
    "learning_rates.queries",
];

const VALUES: &[&str] = &[
    "0",
    "-0",
    "1",
    "-1",
    "nan",
    "inf",
    "-inf",
    "1e-30",
    "1e308",
    "4294967295",
    "18446744073709551615",
    "true",
    "\"x\"",
    "[]",
    "{}",
    "{ interval = 0 }",
    "overlap",
    "embedding",
    "",
];

#[derive(Arbitrary, Debug)]
enum Value {
    Pick(u8),
    Float(f64),
    Int(i64),
    Text(String),
}

#[derive(Arbitrary, Debug)]
enum Input {
    Sets(Vec<(u8, Value)>),
    Raw(Vec<String>),
    /// The documented defaults with one line replaced.
    File {
        line: u16,
        text: String,
    },
}

fn check(cfg: MapperConfig) {
    cfg.validate().expect("an accepted configuration validates");
    let back = MapperConfig::from_toml(&cfg.to_toml()).expect("written settings read back");
    assert_eq!(format!("{back:?}"), format!("{cfg:?}"));
}

/// One input.
pub fn run(data: &[u8]) {
    let Ok(input) = Input::arbitrary(&mut Unstructured::new(data)) else {
        return;
    };
    match input {
        Input::Sets(sets) => {
            let sets: Vec<String> = sets
                .iter()
                .map(|(k, v)| {
                    let v = match v {
                        Value::Pick(i) => VALUES[*i as usize % VALUES.len()].to_string(),
                        Value::Float(x) => x.to_string(),
                        Value::Int(x) => x.to_string(),
                        Value::Text(t) => t.clone(),
                    };
                    format!("{}={v}", KEYS[*k as usize % KEYS.len()])
                })
                .collect();
            if let Ok(cfg) = apply_overrides(&MapperConfig::default(), &sets) {
                check(cfg);
            }
        }
        Input::Raw(sets) => {
            if let Ok(cfg) = apply_overrides(&MapperConfig::default(), &sets) {
                check(cfg);
            }
        }
        Input::File { line, text } => {
            let doc = documented_defaults();
            let mut lines: Vec<&str> = doc.lines().collect();
            let i = line as usize % lines.len().max(1);
            if let Some(l) = lines.get_mut(i) {
                *l = &text;
            }
            if let Ok(cfg) = MapperConfig::from_toml(&lines.join("\n")) {
                check(cfg);
            }
        }
    }
}

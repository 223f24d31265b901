//! Tests of the documented defaults and `--set` overrides.

use super::*;
use crate::map::KeyframePolicy;
use Kind::VariantField;

fn sets(items: &[&str]) -> Vec<String> {
    items.iter().map(|s| s.to_string()).collect()
}

fn apply(items: &[&str]) -> Result<MapperConfig> {
    apply_overrides(&MapperConfig::default(), &sets(items))
}

fn error(items: &[&str]) -> String {
    match apply(items) {
        Ok(cfg) => panic!("{items:?} was accepted: {cfg:?}"),
        Err(e) => {
            assert!(matches!(e, Error::Config { .. }), "{e:?}");
            e.to_string()
        }
    }
}

/// Checks that every key of `table` (at `path`) is documented, with
/// the right kind.
fn check_documented(table: &Table, path: &str) {
    for (k, v) in table {
        let key = if path.is_empty() {
            k.clone()
        } else {
            format!("{path}.{k}")
        };
        let d = lookup(&key).unwrap_or_else(|| panic!("`{key}` has no documentation"));
        match d.kind {
            Section => check_documented(v.as_table().expect("a section is a table"), &key),
            Kind::Value | Kind::Optional { .. } => {
                assert!(
                    !v.is_table(),
                    "`{key}` is a table, document it as a section"
                )
            }
            Choice => {
                let t = v.as_table().expect("a choice is a one-key table");
                assert_eq!(t.len(), 1, "`{key}`");
                check_documented(t, &key);
            }
            Kind::Variant { .. } => {
                if let Some(t) = v.as_table() {
                    check_documented(t, &key);
                }
            }
            VariantField => {}
        }
    }
}

fn get<'v>(table: &'v Table, key: &str) -> Option<&'v Value> {
    let mut segments = key.split('.');
    let mut v = table.get(segments.next()?)?;
    for s in segments {
        v = v.as_table()?.get(s)?;
    }
    Some(v)
}

#[test]
fn every_field_is_documented_and_every_entry_exists() {
    let defaults = to_table(&MapperConfig::default()).unwrap();
    check_documented(&defaults, "");
    for (i, d) in docs().iter().enumerate() {
        assert!(
            docs()[..i].iter().all(|e| e.key != d.key),
            "`{}` documented twice",
            d.key
        );
        assert!(!d.text.trim().is_empty(), "`{}` has an empty text", &d.key);
        let up = parent(&d.key);
        let up_kind = lookup(up).map(|p| p.kind);
        match d.kind {
            Section | Kind::Value | Kind::Optional { .. } | Choice => assert!(
                up.is_empty() || up_kind == Some(Section),
                "`{}` must sit in a section",
                d.key
            ),
            Kind::Variant { .. } => {
                assert_eq!(up_kind, Some(Choice), "`{}` must sit in a choice", &d.key)
            }
            VariantField => assert!(
                matches!(up_kind, Some(Kind::Variant { .. })),
                "`{}` must sit in a variant",
                d.key
            ),
        }
        match d.kind {
            Section => assert!(
                get(&defaults, &d.key).is_some_and(Value::is_table),
                "`{}` is not a section of the configuration",
                d.key
            ),
            Kind::Value | Choice => assert!(
                get(&defaults, &d.key).is_some(),
                "`{}` is not in the configuration",
                d.key
            ),
            Kind::Optional { example } => {
                // Setting it must work (deny_unknown_fields rejects a
                // key the configuration lacks) and show in the result.
                let cfg = apply(&[&format!("{}={example}", &d.key)])
                    .unwrap_or_else(|e| panic!("`{}`: {e}", &d.key));
                let set = to_table(&cfg).unwrap();
                assert_eq!(
                    get(&set, &d.key).map(format_value),
                    Some(example.to_string()),
                    "`{}`",
                    d.key
                );
            }
            Kind::Variant { payload } => {
                // Selecting it by name gives its payload, whose fields
                // are exactly the documented ones.
                let (choice, variant) = (parent(&d.key), name(&d.key));
                let cfg = apply(&[&format!("{choice}={variant}")])
                    .unwrap_or_else(|e| panic!("`{}`: {e}", &d.key));
                let set = to_table(&cfg).unwrap();
                let payload: Value = payload.parse().unwrap();
                // (Compared as written: f32 fields widen 0.9 to
                // 0.8999999761581421.)
                assert_eq!(
                    get(&set, &d.key).map(format_value),
                    Some(format_value(&payload)),
                    "`{}`",
                    d.key
                );
                let mut fields: Vec<&str> = children(&d.key).map(|f| name(&f.key)).collect();
                let expected: Vec<&str> = payload
                    .as_table()
                    .map(|t| t.keys().map(String::as_str).collect())
                    .unwrap_or_default();
                fields.sort_unstable();
                assert_eq!(fields, expected, "fields of `{}`", &d.key);
            }
            VariantField => {}
        }
    }
}

#[test]
fn documented_defaults_parse_back_to_the_defaults() {
    let text = documented_defaults();
    let cfg = MapperConfig::from_toml(&text).unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(cfg.to_toml(), MapperConfig::default().to_toml());
    assert_eq!(cfg, MapperConfig::default());
    // Every line is a comment, a section header, a key or blank, and
    // every key comes after a comment.
    let lines: Vec<&str> = text.lines().collect();
    for (i, line) in lines.iter().enumerate() {
        if line.is_empty() || line.starts_with('#') || line.starts_with('[') {
            continue;
        }
        assert!(line.contains(" = "), "{line}");
        assert!(lines[i - 1].starts_with('#'), "`{line}` is undocumented");
    }
    for d in docs() {
        let shown = match d.kind {
            Section => format!("[{}]", &d.key),
            Kind::Optional { example } => format!("# {} = {example}", name(&d.key)),
            Kind::Value | Choice => format!("{} = ", name(&d.key)),
            Kind::Variant { .. } | VariantField => name(&d.key).to_string(),
        };
        assert!(text.contains(&shown), "`{}` is not shown\n{text}", &d.key);
    }
    assert!(text.contains("\nvoxel_size = 0.01\n"), "{text}");
    // The documented range is the checked one (both come from the
    // declaration).
    for (key, range) in [
        ("voxel_size", "From 0.0001 to 1 metres."),
        ("window_radius", "From voxel_size to 5000 metres."),
        ("replay", "Integer from 0 to 65536."),
        ("gpu_budget", "Integer at least 1."),
        ("seeding.opacity", "From 0 to 1."),
        ("temperature", "From 0.0009765625 to 10."),
    ] {
        let d = lookup(key).unwrap();
        assert!(d.text.ends_with(range), "`{key}`: {}", d.text);
    }
    assert!(text.contains("\ntemperature = 0.05\n"), "{text}");
    assert!(text.contains("\npolicy = { interval = 4 }\n"), "{text}");
    assert!(text.contains("\nmeans = 4e-6\n"), "{text}");
    assert!(text.contains("{ overlap = { min_overlap = 0.9, stride = 8 } }"));
    assert!(text.lines().all(|l| l.chars().count() <= 80), "{text}");
}

#[test]
fn overrides_set_values() {
    let cfg = apply(&[
        "replay=3",
        "window_radius = 2.5",
        "seeding.stride=4",
        "gpu_budget=200000000",
        "window_capacity=1000",
        "sync_distance=1",
        "seed=7",
    ])
    .unwrap();
    let d = MapperConfig::default();
    assert_eq!(cfg.replay, 3);
    assert_eq!(cfg.window_radius, 2.5);
    assert_eq!(cfg.seeding.stride, 4);
    assert_eq!(cfg.seeding.max_depth, d.seeding.max_depth);
    assert_eq!(cfg.gpu_budget, Some(200_000_000));
    assert_eq!(cfg.window_capacity, Some(1000));
    assert_eq!(cfg.sync_distance, 1.0);
    assert_eq!(cfg.seed, 7);
    assert_eq!(cfg.atoms, d.atoms);
    // Later settings win; a section's table merges.
    let cfg = apply(&[
        "replay=3",
        "replay=4",
        "seeding={ stride = 3, opacity = 0.25 }",
    ])
    .unwrap();
    assert_eq!(cfg.replay, 4);
    assert_eq!(cfg.seeding.stride, 3);
    assert_eq!(cfg.seeding.opacity, 0.25);
    assert_eq!(cfg.seeding.max_depth, d.seeding.max_depth);
    // No settings: the same configuration.
    assert_eq!(apply(&[]).unwrap(), d);
    let custom = MapperConfig {
        gpu_budget: Some(5),
        ..d.clone()
    };
    let kept = apply_overrides(&custom, &sets(&["atoms=10"])).unwrap();
    assert_eq!((kept.gpu_budget, kept.atoms), (Some(5), 10));
}

#[test]
fn overrides_select_variants() {
    let policy = |items: &[&str]| apply(items).unwrap().keyframes.policy;
    let overlap = |min_overlap, stride| KeyframePolicy::Overlap {
        min_overlap,
        stride,
    };
    assert_eq!(policy(&["keyframes.policy=overlap"]), overlap(0.9, 8));
    assert_eq!(policy(&["keyframes.policy=\"overlap\""]), overlap(0.9, 8));
    assert_eq!(
        policy(&["keyframes.policy.overlap.min_overlap=0.5"]),
        overlap(0.5, 8)
    );
    assert_eq!(
        policy(&[
            "keyframes.policy.overlap.stride=2",
            "keyframes.policy.overlap.min_overlap=0.7",
        ]),
        overlap(0.7, 2)
    );
    assert_eq!(
        policy(&["keyframes.policy={ overlap = { min_overlap = 0.6, stride = 3 } }"]),
        overlap(0.6, 3)
    );
    assert_eq!(
        policy(&["keyframes.policy.overlap={ stride = 3 }"]),
        overlap(0.9, 3)
    );
    assert_eq!(
        policy(&["keyframes.policy.interval=8"]),
        KeyframePolicy::Interval(8)
    );
    assert_eq!(
        policy(&[
            "keyframes.policy=overlap",
            "keyframes.policy={ interval = 6 }"
        ]),
        KeyframePolicy::Interval(6)
    );
    assert_eq!(
        policy(&["keyframes.policy=interval"]),
        KeyframePolicy::Interval(4)
    );
    let cfg = apply(&["keyframes.min_rotation_deg=5"]).unwrap();
    assert_eq!(cfg.keyframes.min_rotation_deg, 5.0);
    assert_eq!(cfg.keyframes.policy, KeyframePolicy::Interval(4));
}

#[test]
fn unknown_keys_are_named() {
    let e = error(&["replya=3"]);
    assert!(e.contains("`replya`") && e.contains("voxel_size"), "{e}");
    let e = error(&["seeding.strid=4"]);
    assert!(
        e.contains("`seeding.strid`") && e.contains("stride, max_depth"),
        "{e}"
    );
    let e = error(&["keyframes.interval=4"]);
    assert!(
        e.contains("`keyframes.interval`") && e.contains("policy"),
        "{e}"
    );
    let e = error(&["keyframes.policy.sometimes=1"]);
    assert!(
        e.contains("`keyframes.policy.sometimes`") && e.contains("interval, overlap"),
        "{e}"
    );
    let e = error(&["keyframes.policy.overlap.strides=1"]);
    assert!(
        e.contains("`keyframes.policy.overlap.strides`") && e.contains("min_overlap"),
        "{e}"
    );
    let e = error(&["replay.x=1"]);
    assert!(e.contains("`replay.x`"), "{e}");
    let e = error(&["keyframes.policy.interval.n=1"]);
    assert!(e.contains("`keyframes.policy.interval.n`"), "{e}");
    let e = error(&["seeding={ stride = 3, strid = 4 }"]);
    assert!(e.contains("`seeding.strid`"), "{e}");
    let e = error(&["=3"]);
    assert!(e.contains("empty"), "{e}");
}

#[test]
fn malformed_and_wrong_values_are_errors() {
    let e = error(&["replay"]);
    assert!(e.contains("`replay`") && e.contains("key=value"), "{e}");
    let e = error(&["replay=abc"]);
    assert!(e.contains("replay=abc"), "{e}");
    let e = error(&["replay=2.5"]);
    assert!(e.contains("replay"), "{e}");
    let e = error(&["replay=-1"]);
    assert!(e.contains("replay"), "{e}");
    let e = error(&["window_radius=true"]);
    assert!(e.contains("window_radius"), "{e}");
    let e = error(&["keyframes.policy=sometimes"]);
    assert!(e.contains("keyframes.policy"), "{e}");
    let e = error(&["seeding=4"]);
    assert!(e.contains("section") && e.contains("stride"), "{e}");
    // Range errors come from validate(), which names the field.
    let e = error(&["voxel_size=-1"]);
    assert!(e.contains("voxel_size"), "{e}");
    let e = error(&["seeding.stride=65"]);
    assert!(e.contains("seeding.stride"), "{e}");
    let e = error(&["gpu_budget=0"]);
    assert!(e.contains("gpu_budget"), "{e}");
    let e = error(&["keyframes.policy.interval=0"]);
    assert!(e.contains("interval"), "{e}");
    // A program reads the setting from the error's kind, not its words.
    for (set, key) in [
        ("seeding.stride=65", "seeding.stride"),
        ("keyframes.policy.interval=0", "keyframes.policy.interval"),
        ("replay=abc", "replay"),
        ("replya=3", "replya"),
    ] {
        match apply(&[set]) {
            Err(Error::Config { setting, .. }) => assert_eq!(setting, key, "{set}"),
            other => panic!("{set}: {other:?}"),
        }
    }
    for set in ["stage_one_iterations=0", "stage_one_iterations=1001"] {
        let e = error(&[set]);
        assert!(
            e.contains("stage_one_iterations") && e.contains("from 1 to 1000"),
            "{e}"
        );
    }
    // Settings that used to pass and then hang or run without end.
    for (set, want) in [
        ("voxel_size=1e-30", "voxel_size"),
        ("voxel_size=2", "voxel_size"),
        ("window_radius=1e308", "window_radius"),
        ("window_radius=0.001", "window_radius"),
        ("sync_distance=100", "sync_distance"),
        ("history_cell=1e9", "history_cell"),
        ("stage_two_iterations=4294967295", "stage_two_iterations"),
        ("stage_two_iterations=1001", "stage_two_iterations"),
        ("micro_clusters=0", "micro_clusters"),
        ("micro_clusters=65537", "micro_clusters"),
        // NaN weights and rates turn the map into NaN.
        ("weights.feature=nan", "weights.feature"),
        ("learning_rates.means=-1", "learning_rates.means"),
        ("latent_lr=inf", "latent_lr"),
        ("seeding.max_depth=inf", "seeding.max_depth"),
        ("prune_min_opacity=2", "prune_min_opacity"),
        ("keyframes.min_rotation_deg=nan", "min_rotation_deg"),
        // Finite but overflowing f32 in the first step.
        (
            "weights.rgb=1e30",
            "setting `weights.rgb`: 1e30 must be from 0 to 10000",
        ),
        (
            "learning_rates.means=1e30",
            "setting `learning_rates.means`: 1e30 must be from 0 to 10",
        ),
    ] {
        let e = error(&[set]);
        assert!(e.contains(want), "{set}: {e}");
    }
    for ok in [
        "stage_two_iterations=0",
        "stage_two_iterations=1000",
        "sync_distance=6",
        "micro_clusters=2000",
    ] {
        assert!(apply(&[ok]).is_ok(), "{ok}");
    }
    assert_eq!(
        apply(&["stage_one_iterations=1000"])
            .unwrap()
            .stage_one_iterations,
        1000
    );
    // Upper bounds keep the sizes computed from these in range (the
    // largest values used to overflow when the first keyframe sized
    // its buffers).
    for (set, key, bound) in [
        ("replay=4294967295", "replay", "65536"),
        ("atoms=4294967295", "atoms", "65536"),
        ("max_regions=4294967295", "max_regions", "16777216"),
        (
            "window_capacity=2147483649",
            "window_capacity",
            "2147483648",
        ),
    ] {
        let e = error(&[set]);
        assert!(e.contains(key) && e.contains(&format!("to {bound}")), "{e}");
    }
    // The bounds themselves are accepted.
    let cfg = apply(&[
        "replay=65536",
        "atoms=65536",
        "max_regions=16777216",
        "window_capacity=2147483648",
    ])
    .unwrap();
    assert_eq!(cfg.window_capacity, Some(1 << 31));
}

/// Every leaf key of the defaults, dotted.
fn leaf_keys(table: &Table, prefix: &str, out: &mut Vec<String>) {
    for (k, v) in table {
        let key = if prefix.is_empty() {
            k.clone()
        } else {
            format!("{prefix}.{k}")
        };
        match v {
            Value::Table(t) => leaf_keys(t, &key, out),
            _ => out.push(key),
        }
    }
}

/// Random `--set` lists over every key, with hostile values: never a
/// panic, and what is accepted is within range (validates again) and
/// reads back the same from its TOML.
#[test]
fn random_settings_are_refused_or_valid_never_a_panic() {
    use rand::Rng;
    let mut keys = Vec::new();
    leaf_keys(&to_table(&MapperConfig::default()).unwrap(), "", &mut keys);
    keys.extend(["keyframes.policy", "seeding", "nope", "", "a.b.c.d"].map(String::from));
    let values = [
        "0",
        "-0",
        "1",
        "-1",
        "2",
        "0.5",
        "1e-30",
        "1e30",
        "1e308",
        "-1e308",
        "nan",
        "inf",
        "-inf",
        "4294967295",
        "4294967296",
        "18446744073709551615",
        "9223372036854775808",
        "true",
        "\"\"",
        "\"x\"",
        "[]",
        "[1, 2]",
        "{}",
        "{ interval = 3 }",
        "interval",
        "overlap",
        "embedding",
        "zeros",
        "=",
        "0x10",
        "1_000",
        "",
    ];
    let mut rng = latentam_gpu::testing::rng("random_settings");
    let (mut accepted, mut refused) = (0, 0);
    for _ in 0..4000 {
        let sets: Vec<String> = (0..rng.random_range(1..4))
            .map(|_| {
                let key = &keys[rng.random_range(0..keys.len())];
                let value = match rng.random_range(0..3) {
                    0 => values[rng.random_range(0..values.len())].to_string(),
                    1 => rng.random_range(-1e6f64..1e6).to_string(),
                    _ => (rng.random::<f64>() * 10f64.powi(rng.random_range(-40..40))).to_string(),
                };
                format!("{key}={value}")
            })
            .collect();
        match apply_overrides(&MapperConfig::default(), &sets) {
            Ok(cfg) => {
                accepted += 1;
                cfg.validate().unwrap_or_else(|e| panic!("{sets:?}: {e}"));
                let back = MapperConfig::from_toml(&cfg.to_toml())
                    .unwrap_or_else(|e| panic!("{sets:?}: {e}"));
                assert_eq!(back, cfg, "{sets:?}");
                assert!(cfg.stage_one_iterations <= 1000 && cfg.stage_two_iterations <= 1000);
                assert!(cfg.window_radius / cfg.voxel_size <= 5e7, "{sets:?}");
            }
            Err(e) => {
                refused += 1;
                assert!(!e.to_string().is_empty());
            }
        }
    }
    // Both outcomes are exercised.
    assert!(
        accepted > 100 && refused > 100,
        "{accepted} accepted, {refused} refused"
    );
}

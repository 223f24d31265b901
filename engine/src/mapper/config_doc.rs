//! The mapper configuration for users: every setting written out with its
//! documentation ([`documented_defaults`], what `latentam config
//! --print-defaults` prints), and `--set key=value` overrides on top of a
//! configuration ([`apply_overrides`]).
//!
//! Both rest on one table of documentation, keyed by dotted path
//! (`seeding.stride`). It is the source of truth for which keys exist,
//! so an optional setting that is unset (absent from the serialized
//! configuration) can still be set, and an unknown key is reported with
//! the keys that do exist. Values are never written here: they come from
//! serializing [`MapperConfig::default`], so the printed defaults cannot
//! drift from the code. The tests fail when a field of [`MapperConfig`]
//! has no entry in the table, or an entry names no field.

use toml::{Table, Value};

use super::MapperConfig;
use crate::error::{Error, Result};
use Kind::{Choice, Section, Value as Val, VariantField};

/// What a documented key is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    /// A `[section]`: a nested structure with keys of its own.
    Section,
    /// A value that is always present.
    Value,
    /// A value that may be unset (an `Option`); `example` is shown,
    /// commented out, when it is unset by default.
    Optional { example: &'static str },
    /// One of several variants (an enum), written as a one-key inline
    /// table `{ variant = payload }`; the variants are the entries below it.
    Choice,
    /// A variant of the `Choice` above it. `payload` (TOML) is what it
    /// starts from when selected by name or by one of its fields.
    Variant { payload: &'static str },
    /// A field of a `Variant` whose payload is a table.
    VariantField,
}

/// Documentation of one key.
struct Doc {
    /// Dotted path from the top of the configuration.
    key: &'static str,
    kind: Kind,
    /// For users: meaning, unit and valid range.
    text: &'static str,
}

const fn doc(key: &'static str, kind: Kind, text: &'static str) -> Doc {
    Doc { key, kind, text }
}

/// Every key of [`MapperConfig`], in the order it is printed: top-level
/// keys, then each section with its keys.
static DOCS: &[Doc] = &[
    doc(
        "voxel_size",
        Val,
        "Edge length of the global map's voxels, in metres (s_v); the map \
         keeps at most one Gaussian per voxel. From 0.0001 to 1.",
    ),
    doc(
        "gpu_budget",
        Kind::Optional {
            example: "2000000000",
        },
        "GPU memory budget in bytes for everything the mapper allocates; \
         allocations past it are refused. Integer >= 1. Unset: half of the \
         device's largest device-local memory heap.",
    ),
    doc(
        "window_capacity",
        Kind::Optional { example: "1000000" },
        "Number of Gaussians the GPU window holds. Integer from 1 to \
         2147483648. Unset: as many as the GPU memory budget allows.",
    ),
    doc(
        "window_radius",
        Val,
        "Radius of the local window around the camera, in metres: the \
         Gaussians within it are kept on the GPU and trained. From \
         voxel_size to 5000.",
    ),
    doc(
        "sync_distance",
        Val,
        "The window is re-synchronised with the global map once the camera \
         has moved this far (metres) since the last synchronisation; new \
         Gaussians are always brought in. From 0 to window_radius.",
    ),
    doc(
        "replay",
        Val,
        "Past keyframes replayed in each Stage I batch (B), drawn uniformly \
         among those whose camera lies within window_radius of the current \
         one. Integer from 0 to 65536.",
    ),
    doc(
        "history_cell",
        Val,
        "Keyframes kept for replay are thinned in space: a keyframe taken \
         within the same cell of this size (metres) and looking the same way \
         (45-degree bins) as a kept one replaces it, so memory grows with the \
         space explored rather than with time. 0 keeps every keyframe (the \
         paper's setting). From 0 to 5000.",
    ),
    doc(
        "stage_one_iterations",
        Val,
        "Stage I iterations per keyframe (R1): joint steps on the Gaussians, \
         W and D over the keyframe and its replayed ones; the paper uses 1. \
         Each costs one Stage I (render, backward, Adam step), so more suit \
         offline mapping. Integer from 1 to 1000.",
    ),
    doc(
        "stage_two_iterations",
        Val,
        "Stage II iterations per keyframe (R2). From 0 to 1000.",
    ),
    doc(
        "attach_feature_gradients",
        Val,
        "Let the feature loss move the Gaussians' opacity, position and \
         shape too, not only their queries (true/false). Stage I then \
         renders a 32-channel query image per view: 128 more bytes of GPU \
         memory per pixel of a chunk, and slower backward passes.",
    ),
    doc(
        "atoms",
        Val,
        "Dictionary size (K): number of latent atoms. Integer from 1 to \
         65536.",
    ),
    doc(
        "micro_clusters",
        Val,
        "Micro-clusters each keyframe's region embeddings are summarised \
         into before they join the dictionary (m; the paper uses 5). The \
         dictionary grows by up to this many atoms a keyframe until it \
         holds `atoms`, then re-clusters. Integer from 1 to 65536 (values \
         above `atoms` act as `atoms`).",
    ),
    doc(
        "temperature",
        Val,
        "Softmax temperature (tau) of the latent decoder, over the cosine \
         similarities between a query and the dictionary atoms (M3 uses \
         0.05). Must be > 0.",
    ),
    doc(
        "latent_lr",
        Val,
        "Learning rate of the latent weights W and the dictionary D. \
         Must be >= 0.",
    ),
    doc(
        "max_regions",
        Val,
        "Most regions in one training batch, over all its views. \
         Integer from 1 to 16777216.",
    ),
    doc(
        "min_region_pixels",
        Val,
        "Regions smaller than this many pixels are ignored. Integer >= 0.",
    ),
    doc(
        "prune_interval",
        Val,
        "Prune the map every this many keyframes; 0 = never. Integer >= 0.",
    ),
    doc(
        "prune_min_opacity",
        Val,
        "Gaussians less opaque than this are pruned (GS-ICP uses 0.005). \
         Range 0 to 1.",
    ),
    doc(
        "prune_max_scale",
        Val,
        "Gaussians with a standard deviation above this many metres are \
         pruned (GS-ICP's 0.1 x scene extent, for a 5 m indoor scene). \
         Must be > 0.",
    ),
    doc(
        "seed",
        Val,
        "Seed of every random choice (initial W, queries, replay sampling); \
         the same seed and input give the same map. Integer >= 0.",
    ),
    doc(
        "keyframes",
        Section,
        "Keyframe selection: which frames of the stream the mapper trains \
         on. The first frame always is a keyframe.",
    ),
    doc(
        "keyframes.policy",
        Choice,
        "The rule that proposes keyframes; a proposal is then kept only if \
         the camera moved enough (min_translation, min_rotation_deg).",
    ),
    doc(
        "keyframes.policy.interval",
        Kind::Variant { payload: "4" },
        "Every N-th frame, N an integer >= 1 (for ORB-SLAM3-style \
         trackers; the paper reports N from 4 to 10).",
    ),
    doc(
        "keyframes.policy.overlap",
        Kind::Variant {
            payload: "{ min_overlap = 0.9, stride = 8 }",
        },
        "When the share of the frame's back-projected depth points that lie \
         on already mapped surface drops below min_overlap (GS-ICP-style). \
         The values shown are a starting point, not defaults.",
    ),
    doc(
        "keyframes.policy.overlap.min_overlap",
        VariantField,
        "a keyframe when the overlap is below this; range 0 to 1.",
    ),
    doc(
        "keyframes.policy.overlap.stride",
        VariantField,
        "the check uses every stride-th pixel along rows and columns; \
         integer >= 1.",
    ),
    doc(
        "keyframes.min_translation",
        Val,
        "A proposed keyframe is dropped unless the camera moved at least \
         this far (metres) or turned at least min_rotation_deg since the \
         last keyframe. Must be >= 0; with both at 0 every proposal is kept.",
    ),
    doc(
        "keyframes.min_rotation_deg",
        Val,
        "See min_translation: the rotation (degrees) since the last \
         keyframe that is enough on its own. Must be >= 0.",
    ),
    doc(
        "seeding",
        Section,
        "Seeding of new Gaussians from each keyframe: back-projected depth \
         where the map does not yet explain the view, at most one Gaussian \
         per free voxel; isotropic, with a scale from depth over focal \
         length.",
    ),
    doc(
        "seeding.stride",
        Val,
        "Every stride-th pixel along rows and columns is a candidate. \
         Integer >= 1.",
    ),
    doc(
        "seeding.max_depth",
        Val,
        "Depths beyond this (metres) are not seeded. Must be > 0.",
    ),
    doc(
        "seeding.alpha_threshold",
        Val,
        "A pixel is unexplained, and may be seeded, where the rendered \
         (accumulated) alpha is below this. Range 0 to 1.",
    ),
    doc(
        "seeding.depth_error",
        Val,
        "... or where the rendered depth is off by more than this fraction \
         of the measured depth (0.05 = 5 %). Must be >= 0.",
    ),
    doc(
        "seeding.opacity",
        Val,
        "Initial opacity of new Gaussians. Between 0 and 1, exclusive.",
    ),
    doc(
        "seeding.refill_alpha",
        Val,
        "Where the map already has a Gaussian within the seed spacing \
         (stride x depth / focal), a pixel is seeded only if the rendered \
         alpha is below this (a hole); partial alpha or depth disagreements \
         there add nothing, so revisits do not grow the map while closer \
         views still add detail. Set it to alpha_threshold to seed every \
         unexplained pixel. Range 0 to 1.",
    ),
    doc(
        "seeding.hole_fill_radius",
        Val,
        "A pixel without a valid depth (RGB-D sensors leave 5-15 % of \
         pixels empty: shadows beside edges, dark, shiny or distant \
         surfaces) is seeded at the median depth of the nearest ring of \
         pixels around it that has valid ones, up to this many pixels \
         away. 0 seeds measured depth only, and empty pixels stay holes \
         in the map. At most 64.",
    ),
    doc(
        "seeding.query_init",
        Val,
        "Where a new Gaussian's query starts: \"embedding\" (its pixel's \
         region embedding projected through the decoder's W, so it decodes \
         to about that embedding before any step; pixels without one copy \
         a neighbour's query or start at random) or \"random\" (a \
         neighbouring Gaussian's query, else N(0, 1)).",
    ),
    doc(
        "seeding.scale_factor",
        Val,
        "Initial standard deviation of new Gaussians as a multiple of the \
         spacing between seeds (stride x depth / focal length); at least \
         half a voxel in any case. Must be > 0.",
    ),
    doc(
        "weights",
        Section,
        "Weights of the loss terms (the paper's values). The total is \
         rgb * (rgb_l1 * L1 + ssim * (1 - SSIM)) + depth * L_depth + \
         feature * (cosine * L_cos + l2 * L_l2 + trust_region * L_trust). \
         The paper's 0.2/0.8 split between L1 and SSIM is the reverse of \
         the reference 3DGS systems (0.8/0.2); swap rgb_l1 and ssim for \
         theirs. Every weight must be >= 0 (0 turns the term off).",
    ),
    doc(
        "weights.rgb",
        Val,
        "lambda_rgb, weight of the photometric term (not given by the paper).",
    ),
    doc(
        "weights.rgb_l1",
        Val,
        "lambda_I1, share of L1 in the photometric term.",
    ),
    doc(
        "weights.ssim",
        Val,
        "lambda_I2, share of 1 - SSIM in the photometric term.",
    ),
    doc(
        "weights.depth",
        Val,
        "lambda_d, weight of the depth L1 term, on pixels with a valid \
         measured depth.",
    ),
    doc(
        "weights.feature",
        Val,
        "lambda_f, weight of the whole feature loss.",
    ),
    doc(
        "weights.cosine",
        Val,
        "lambda_cos, weight of the cosine term inside the feature loss.",
    ),
    doc(
        "weights.l2",
        Val,
        "lambda_2, weight of the mean-squared-error term inside the feature \
         loss.",
    ),
    doc(
        "weights.trust_region",
        Val,
        "lambda_D, weight of the trust-region term inside the feature loss, \
         which keeps the dictionary near its k-means anchor.",
    ),
    doc(
        "weights.trust_radius",
        Val,
        "delta, the trust-region radius: how far (L2 norm, per atom) the \
         dictionary may move from its anchor before the term applies.",
    ),
    doc(
        "learning_rates",
        Section,
        "Adam learning rates per Gaussian parameter (GS-ICP's values, the \
         colour rate converted from SH DC to RGB, the query rate of OLS). \
         Every rate must be >= 0; 0 freezes the parameter.",
    ),
    doc(
        "learning_rates.means",
        Val,
        "Means (positions). Effectively frozen: the poses come from the \
         tracker.",
    ),
    doc("learning_rates.log_scales", Val, "Log-scales."),
    doc("learning_rates.quats", Val, "Rotation quaternions."),
    doc("learning_rates.colors", Val, "RGB colours."),
    doc("learning_rates.opacity", Val, "Opacity logits."),
    doc("learning_rates.queries", Val, "Latent queries."),
];

const HEADER: &str = "\
# latentam mapper configuration: every setting, with its default value.
#
# Any key may be left out (it then keeps the default shown here); unknown
# keys are errors. On the command line, `--set key=value` overrides one
# key, with dotted keys for the sections (`--set seeding.stride=4`).
";

/// Width of the comment lines.
const WIDTH: usize = 76;

/// The documentation entry of a dotted key.
fn lookup(key: &str) -> Option<&'static Doc> {
    DOCS.iter().find(|d| d.key == key)
}

/// `a.b` of `a.b.c`; empty at the top.
fn parent(key: &str) -> &str {
    key.rsplit_once('.').map_or("", |(p, _)| p)
}

/// `c` of `a.b.c`.
fn name(key: &str) -> &str {
    key.rsplit_once('.').map_or(key, |(_, n)| n)
}

/// The documented keys directly below `key` (empty: the top level).
fn children(key: &str) -> impl Iterator<Item = &'static Doc> + '_ {
    DOCS.iter().filter(move |d| parent(d.key) == key)
}

fn invalid(message: String) -> Error {
    Error::InvalidArgument(message)
}

/// The configuration as a TOML table (unset optional keys are absent).
fn to_table(config: &MapperConfig) -> Result<Table> {
    match Value::try_from(config) {
        Ok(Value::Table(t)) => Ok(t),
        Ok(other) => Err(invalid(format!(
            "mapper configuration serialized to a {}, not a table",
            other.type_str()
        ))),
        Err(e) => Err(invalid(format!("mapper configuration: {e}"))),
    }
}

/// The default configuration as a TOML document in which every key is
/// preceded by comments saying what it means, its unit and valid range:
/// top-level keys first, then each `[section]`. Unset optional keys
/// (`gpu_budget`, `window_capacity`) are shown commented out with an
/// example value. Parsed back with [`MapperConfig::from_toml`] it gives
/// [`MapperConfig::default`].
pub fn documented_defaults() -> String {
    let mut out = String::from(HEADER);
    match to_table(&MapperConfig::default()) {
        Ok(root) => write_table(&mut out, &root, ""),
        // Not reached: the configuration is plain data.
        Err(e) => comment(&mut out, "", &format!("unavailable: {e}")),
    }
    out
}

/// Writes the keys of the table at `path`, then its sections.
fn write_table(out: &mut String, table: &Table, path: &str) {
    for d in children(path).filter(|d| d.kind != Section) {
        out.push('\n');
        write_key(out, table, d);
    }
    for d in children(path).filter(|d| d.kind == Section) {
        out.push('\n');
        comment(out, "", d.text);
        out.push_str(&format!("[{}]\n", d.key));
        let empty = Table::new();
        let sub = table.get(name(d.key)).and_then(Value::as_table);
        write_table(out, sub.unwrap_or(&empty), d.key);
    }
}

fn write_key(out: &mut String, table: &Table, d: &Doc) {
    let key = name(d.key);
    comment(out, "", d.text);
    match (d.kind, table.get(key)) {
        (Kind::Optional { example }, None) => {
            out.push_str(&format!("# {key} = {example}\n"));
        }
        (Choice, value) => {
            comment(out, "", "One of:");
            for v in children(d.key) {
                let Kind::Variant { payload } = v.kind else {
                    continue;
                };
                let variant = format_key(name(v.key));
                comment(out, "  ", &format!("{{ {variant} = {payload} }}"));
                comment(out, "      ", v.text);
                for f in children(v.key) {
                    comment(out, "      ", &format!("{}: {}", name(f.key), f.text));
                }
            }
            // The --set hint shows a variant other than the current one.
            let current = value
                .and_then(Value::as_table)
                .and_then(|t| t.keys().next());
            let variants = || children(d.key).filter(|v| matches!(v.kind, Kind::Variant { .. }));
            let shown = variants()
                .find(|v| Some(name(v.key)) != current.map(String::as_str))
                .or_else(|| variants().next());
            if let Some(v) = shown {
                let mut hint = format!(
                    "With --set, `{}={}` selects a variant with the values shown",
                    d.key,
                    name(v.key)
                );
                if let Some(f) = children(v.key).next() {
                    hint.push_str(&format!("; `{}=...` changes one of them", f.key));
                }
                hint.push('.');
                comment(out, "", &hint);
            }
            if let Some(value) = value {
                out.push_str(&format!("{key} = {}\n", format_value(value)));
            }
        }
        (_, Some(value)) => out.push_str(&format!("{key} = {}\n", format_value(value))),
        // A documented key the configuration lacks (the tests rule it out).
        (_, None) => {}
    }
}

/// Writes `text` as `# ` comment lines, wrapped, each starting with
/// `indent`.
fn comment(out: &mut String, indent: &str, text: &str) {
    let mut line = String::new();
    for word in text.split_whitespace() {
        if !line.is_empty() && 2 + indent.len() + line.len() + 1 + word.len() > WIDTH {
            out.push_str(&format!("# {indent}{line}\n"));
            line.clear();
        }
        if !line.is_empty() {
            line.push(' ');
        }
        line.push_str(word);
    }
    if !line.is_empty() {
        out.push_str(&format!("# {indent}{line}\n"));
    }
}

/// A TOML key, quoted unless it is bare.
fn format_key(key: &str) -> String {
    let bare = !key.is_empty()
        && key
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if bare {
        key.to_string()
    } else {
        Value::String(key.to_string()).to_string()
    }
}

/// A TOML value on one line. Floats widened from `f32` are written in
/// their shortest `f32` form (`0.05`, not `0.05000000074505806`); they
/// read back to the same `f32`.
fn format_value(value: &Value) -> String {
    match value {
        Value::Float(f) if f.is_nan() => "nan".to_string(),
        Value::Float(f) if f.is_infinite() => if *f > 0.0 { "inf" } else { "-inf" }.to_string(),
        Value::Float(f) => {
            let narrow = *f as f32;
            if narrow as f64 == *f {
                format!("{narrow:?}")
            } else {
                format!("{f:?}")
            }
        }
        Value::Array(items) => {
            let items: Vec<String> = items.iter().map(format_value).collect();
            format!("[{}]", items.join(", "))
        }
        Value::Table(t) if t.is_empty() => "{}".to_string(),
        Value::Table(t) => {
            let items: Vec<String> = t
                .iter()
                .map(|(k, v)| format!("{} = {}", format_key(k), format_value(v)))
                .collect();
            format!("{{ {} }}", items.join(", "))
        }
        other => other.to_string(),
    }
}

/// `config` with each `key=value` of `sets` applied in order.
///
/// Keys are dotted paths (`replay`, `seeding.stride`,
/// `keyframes.policy.overlap.min_overlap`); optional keys that are unset
/// can be set (`gpu_budget=200000000`). A value is read as TOML (`4`,
/// `0.5`, `true`, `"text"`, `[1, 2]`, `{ stride = 4 }`) and, when it is
/// not valid TOML, as a bare string. A variant is selected by name
/// (`keyframes.policy=overlap`), starting from the values its
/// documentation shows, or by setting one of its fields. A table given
/// for a section is merged key by key.
///
/// Errors ([`Error::InvalidArgument`]) name the key: an unknown key (with
/// the valid keys beside it), a missing `=`, a value of the wrong type;
/// the result is then checked with [`MapperConfig::validate`].
pub fn apply_overrides(config: &MapperConfig, sets: &[String]) -> Result<MapperConfig> {
    let mut root = to_table(config)?;
    for set in sets {
        let Some((key, raw)) = set.split_once('=') else {
            return Err(invalid(format!(
                "--set `{set}`: expected key=value, e.g. seeding.stride=4"
            )));
        };
        let (key, raw) = (key.trim(), raw.trim());
        if key.is_empty() {
            return Err(invalid(format!(
                "--set `{set}`: the key before `=` is empty"
            )));
        }
        set_key(&mut root, key, parse_value(raw))?;
        // Check the types now, so the error names this key.
        from_table(&root).map_err(|e| invalid(format!("--set {key}={raw}: {}", one_line(&e))))?;
    }
    let cfg = from_table(&root)
        .map_err(|e| invalid(format!("mapper configuration: {}", one_line(&e))))?;
    cfg.validate()?;
    Ok(cfg)
}

/// A parse error on one line (toml ends its messages with "\nin `key`").
fn one_line(e: &toml::de::Error) -> String {
    e.to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// Reads the configuration back (types and unknown fields; no ranges).
fn from_table(table: &Table) -> std::result::Result<MapperConfig, toml::de::Error> {
    Value::Table(table.clone()).try_into()
}

/// A command-line value: TOML, else the text as a string.
fn parse_value(raw: &str) -> Value {
    raw.parse::<Value>()
        .unwrap_or_else(|_| Value::String(raw.to_string()))
}

/// Sets `key` to `value`, merging tables given for sections and
/// expanding variants given by name.
fn set_key(root: &mut Table, key: &str, value: Value) -> Result<()> {
    let kind = lookup(key).map(|d| d.kind);
    match (kind, value) {
        (Some(Section), Value::Table(t)) => {
            for (k, v) in t {
                set_key(root, &format!("{key}.{k}"), v)?;
            }
            Ok(())
        }
        (Some(Section), other) => Err(invalid(format!(
            "--set {key}: `{key}` is a section, not a value ({} given); set its keys: {}",
            other.type_str(),
            keys_below(key)
        ))),
        (Some(Kind::Variant { payload }), Value::Table(t))
            if payload.trim_start().starts_with('{') =>
        {
            // Select the variant first, so that a partial table keeps its
            // other fields.
            set_path(root, key, None)?;
            for (k, v) in t {
                set_key(root, &format!("{key}.{k}"), v)?;
            }
            Ok(())
        }
        (Some(Choice), Value::Table(t)) if t.len() == 1 => {
            // The guard says the table has exactly one entry.
            let (k, v) = t.into_iter().next().expect("one entry");
            set_key(root, &format!("{key}.{k}"), v)
        }
        (Some(Choice), Value::String(s)) if matches!(lookup(&format!("{key}.{s}")), Some(d) if matches!(d.kind, Kind::Variant { .. })) => {
            set_path(root, &format!("{key}.{s}"), None)
        }
        (_, value) => set_path(root, key, Some(value)),
    }
}

/// The valid keys below `key`, for error messages.
fn keys_below(key: &str) -> String {
    let keys: Vec<&str> = children(key).map(|d| name(d.key)).collect();
    keys.join(", ")
}

fn unknown_key(key: &str, parent: &str) -> Error {
    let place = if parent.is_empty() {
        "top-level keys".to_string()
    } else {
        match lookup(parent).map(|d| d.kind) {
            Some(Choice) => format!("variants of `{parent}`"),
            _ => format!("keys of `{parent}`"),
        }
    };
    invalid(format!(
        "unknown configuration key `{key}`; valid {place}: {}",
        keys_below(parent)
    ))
}

/// Walks the dotted `key` through `root`, creating absent sections and
/// switching a choice to the variant named in the path (starting from the
/// variant's documented payload), then stores `value` at the end; `None`
/// only selects the variant `key` names.
fn set_path(root: &mut Table, key: &str, value: Option<Value>) -> Result<()> {
    let segments: Vec<&str> = key.split('.').map(str::trim).collect();
    let mut table = root;
    let mut path = String::new();
    for (i, &segment) in segments.iter().enumerate() {
        let above = path.clone();
        if !path.is_empty() {
            path.push('.');
        }
        path.push_str(segment);
        let Some(d) = lookup(&path) else {
            return Err(unknown_key(key, &above));
        };
        if i + 1 == segments.len() {
            if let Some(value) = value {
                table.insert(segment.to_string(), value);
            }
            return Ok(());
        }
        let here = table;
        table = match d.kind {
            Section => here
                .entry(segment)
                .or_insert_with(|| Value::Table(Table::new()))
                .as_table_mut()
                .ok_or_else(|| invalid(format!("--set {key}: `{path}` is not a table")))?,
            Choice => {
                // Not the last segment: the last one returned above.
                let variant = segments[i + 1];
                let Some(Doc {
                    kind: Kind::Variant { payload },
                    ..
                }) = lookup(&format!("{path}.{variant}"))
                else {
                    return Err(unknown_key(key, &path));
                };
                select_variant(here, segment, variant, payload)?
            }
            Kind::Variant { .. } => match here.get_mut(segment) {
                Some(Value::Table(t)) => t,
                _ => {
                    return Err(invalid(format!(
                        "unknown configuration key `{key}`; `{path}` is a value, \
                         not a table"
                    )))
                }
            },
            _ => {
                return Err(invalid(format!(
                    "unknown configuration key `{key}`; `{path}` is a value, not a \
                     section"
                )))
            }
        };
    }
    Ok(())
}

/// Makes `table[choice]` the one-key table `{ variant = ... }`, keeping it
/// when it already is that variant, else starting from `payload`; returns
/// that one-key table.
fn select_variant<'t>(
    table: &'t mut Table,
    choice: &str,
    variant: &str,
    payload: &str,
) -> Result<&'t mut Table> {
    let current = match table.get(choice) {
        Some(Value::Table(t)) if t.len() == 1 => t.keys().next().cloned(),
        _ => None,
    };
    if current.as_deref() != Some(variant) {
        let start = payload
            .parse::<Value>()
            .map_err(|e| invalid(format!("documented value of `{variant}`: {e}")))?;
        let mut one = Table::new();
        one.insert(variant.to_string(), start);
        table.insert(choice.to_string(), Value::Table(one));
    }
    match table.get_mut(choice) {
        Some(Value::Table(t)) => Ok(t),
        _ => Err(invalid(format!("`{choice}` is not a table"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::KeyframePolicy;

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
                assert!(matches!(e, Error::InvalidArgument(_)), "{e:?}");
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
        for (i, d) in DOCS.iter().enumerate() {
            assert!(
                DOCS[..i].iter().all(|e| e.key != d.key),
                "`{}` documented twice",
                d.key
            );
            assert!(!d.text.trim().is_empty(), "`{}` has an empty text", d.key);
            let up = parent(d.key);
            let up_kind = lookup(up).map(|p| p.kind);
            match d.kind {
                Section | Kind::Value | Kind::Optional { .. } | Choice => assert!(
                    up.is_empty() || up_kind == Some(Section),
                    "`{}` must sit in a section",
                    d.key
                ),
                Kind::Variant { .. } => {
                    assert_eq!(up_kind, Some(Choice), "`{}` must sit in a choice", d.key)
                }
                VariantField => assert!(
                    matches!(up_kind, Some(Kind::Variant { .. })),
                    "`{}` must sit in a variant",
                    d.key
                ),
            }
            match d.kind {
                Section => assert!(
                    get(&defaults, d.key).is_some_and(Value::is_table),
                    "`{}` is not a section of the configuration",
                    d.key
                ),
                Kind::Value | Choice => assert!(
                    get(&defaults, d.key).is_some(),
                    "`{}` is not in the configuration",
                    d.key
                ),
                Kind::Optional { example } => {
                    // Setting it must work (deny_unknown_fields rejects a
                    // key the configuration lacks) and show in the result.
                    let cfg = apply(&[&format!("{}={example}", d.key)])
                        .unwrap_or_else(|e| panic!("`{}`: {e}", d.key));
                    let set = to_table(&cfg).unwrap();
                    assert_eq!(
                        get(&set, d.key).map(format_value),
                        Some(example.to_string()),
                        "`{}`",
                        d.key
                    );
                }
                Kind::Variant { payload } => {
                    // Selecting it by name gives its payload, whose fields
                    // are exactly the documented ones.
                    let (choice, variant) = (parent(d.key), name(d.key));
                    let cfg = apply(&[&format!("{choice}={variant}")])
                        .unwrap_or_else(|e| panic!("`{}`: {e}", d.key));
                    let set = to_table(&cfg).unwrap();
                    let payload: Value = payload.parse().unwrap();
                    // (Compared as written: f32 fields widen 0.9 to
                    // 0.8999999761581421.)
                    assert_eq!(
                        get(&set, d.key).map(format_value),
                        Some(format_value(&payload)),
                        "`{}`",
                        d.key
                    );
                    let mut fields: Vec<&str> = children(d.key).map(|f| name(f.key)).collect();
                    let expected: Vec<&str> = payload
                        .as_table()
                        .map(|t| t.keys().map(String::as_str).collect())
                        .unwrap_or_default();
                    fields.sort_unstable();
                    assert_eq!(fields, expected, "fields of `{}`", d.key);
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
        for d in DOCS {
            let shown = match d.kind {
                Section => format!("[{}]", d.key),
                Kind::Optional { example } => format!("# {} = {example}", name(d.key)),
                Kind::Value | Choice => format!("{} = ", name(d.key)),
                Kind::Variant { .. } | VariantField => name(d.key).to_string(),
            };
            assert!(text.contains(&shown), "`{}` is not shown\n{text}", d.key);
        }
        assert!(text.contains("\nvoxel_size = 0.01\n"), "{text}");
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
        let e = error(&["seeding.stride=0"]);
        assert!(e.contains("seeding.stride"), "{e}");
        let e = error(&["gpu_budget=0"]);
        assert!(e.contains("gpu_budget"), "{e}");
        let e = error(&["keyframes.policy.interval=0"]);
        assert!(e.contains("interval"), "{e}");
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
            ("weights.rgb=1e30", "weights"),
            ("learning_rates.means=1e30", "learning_rates"),
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
        for (set, key) in [
            ("replay=4294967295", "replay"),
            ("atoms=4294967295", "atoms"),
            ("max_regions=4294967295", "max_regions"),
            ("window_capacity=2147483649", "window_capacity"),
        ] {
            let e = error(&[set]);
            assert!(e.contains(key) && e.contains("at most"), "{e}");
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
        let mut rng = crate::gpu::testing::rng("random_settings");
        let (mut accepted, mut refused) = (0, 0);
        for _ in 0..4000 {
            let sets: Vec<String> = (0..rng.random_range(1..4))
                .map(|_| {
                    let key = &keys[rng.random_range(0..keys.len())];
                    let value = match rng.random_range(0..3) {
                        0 => values[rng.random_range(0..values.len())].to_string(),
                        1 => rng.random_range(-1e6f64..1e6).to_string(),
                        _ => (rng.random::<f64>() * 10f64.powi(rng.random_range(-40..40)))
                            .to_string(),
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
}

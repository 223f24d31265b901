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

use std::sync::OnceLock;

use toml::{Table, Value};

use super::config::WHOLE_CONFIGURATION;
use super::MapperConfig;
use latentam_base::settings::{KeyDoc, Kind, Setting};
use latentam_base::{Error, Result};
use Kind::{Choice, Section};

/// Every key of [`MapperConfig`], from its declaration: top-level keys,
/// then each section with its keys, in the order they are declared.
fn docs() -> &'static [KeyDoc] {
    static DOCS: OnceLock<Vec<KeyDoc>> = OnceLock::new();
    DOCS.get_or_init(|| {
        let mut out = Vec::new();
        MapperConfig::nested_docs("", &mut out);
        out
    })
}

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
fn lookup(key: &str) -> Option<&'static KeyDoc> {
    docs().iter().find(|d| d.key == key)
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
fn children(key: &str) -> impl Iterator<Item = &'static KeyDoc> + '_ {
    docs().iter().filter(move |d| parent(&d.key) == key)
}

/// The configuration as a TOML table (unset optional keys are absent).
fn to_table(config: &MapperConfig) -> Result<Table> {
    match Value::try_from(config) {
        Ok(Value::Table(t)) => Ok(t),
        Ok(other) => Err(Error::config(
            WHOLE_CONFIGURATION,
            format!("serialized to a {}, not a table", other.type_str()),
        )),
        Err(e) => Err(Error::config(WHOLE_CONFIGURATION, e.to_string())),
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
        comment(out, "", &d.text);
        out.push_str(&format!("[{}]\n", d.key));
        let empty = Table::new();
        let sub = table.get(name(&d.key)).and_then(Value::as_table);
        write_table(out, sub.unwrap_or(&empty), &d.key);
    }
}

fn write_key(out: &mut String, table: &Table, d: &KeyDoc) {
    let key = name(&d.key);
    comment(out, "", &d.text);
    match (d.kind, table.get(key)) {
        (Kind::Optional { example }, None) => {
            out.push_str(&format!("# {key} = {example}\n"));
        }
        (Choice, value) => {
            comment(out, "", "One of:");
            for v in children(&d.key) {
                let Kind::Variant { payload } = v.kind else {
                    continue;
                };
                let variant = format_key(name(&v.key));
                comment(out, "  ", &format!("{{ {variant} = {payload} }}"));
                comment(out, "      ", &v.text);
                for f in children(&v.key) {
                    comment(out, "      ", &format!("{}: {}", name(&f.key), f.text));
                }
            }
            // The --set hint shows a variant other than the current one.
            let current = value
                .and_then(Value::as_table)
                .and_then(|t| t.keys().next());
            let variants = || children(&d.key).filter(|v| matches!(v.kind, Kind::Variant { .. }));
            let shown = variants()
                .find(|v| Some(name(&v.key)) != current.map(String::as_str))
                .or_else(|| variants().next());
            if let Some(v) = shown {
                let mut hint = format!(
                    "With --set, `{}={}` selects a variant with the values shown",
                    d.key,
                    name(&v.key)
                );
                if let Some(f) = children(&v.key).next() {
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
/// Errors ([`Error::Config`]) name the key: an unknown key (with
/// the valid keys beside it), a missing `=`, a value of the wrong type;
/// the result is then checked with [`MapperConfig::validate`].
pub fn apply_overrides(config: &MapperConfig, sets: &[String]) -> Result<MapperConfig> {
    let mut root = to_table(config)?;
    for set in sets {
        let Some((key, raw)) = set.split_once('=') else {
            return Err(Error::config(
                set,
                "expected key=value, e.g. seeding.stride=4",
            ));
        };
        let (key, raw) = (key.trim(), raw.trim());
        if key.is_empty() {
            return Err(Error::config(set, "the key before `=` is empty"));
        }
        set_key(&mut root, key, parse_value(raw))?;
        // Check the types now, so the error names this key.
        from_table(&root)
            .map_err(|e| Error::config(key, format!("{key}={raw}: {}", one_line(&e))))?;
    }
    let cfg = from_table(&root).map_err(|e| Error::config(WHOLE_CONFIGURATION, one_line(&e)))?;
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
        (Some(Section), other) => Err(Error::config(
            key,
            format!(
                "a section, not a value ({} given); set its keys: {}",
                other.type_str(),
                keys_below(key)
            ),
        )),
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
    let keys: Vec<&str> = children(key).map(|d| name(&d.key)).collect();
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
    Error::config(
        key,
        format!(
            "unknown configuration key; valid {place}: {}",
            keys_below(parent)
        ),
    )
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
                .ok_or_else(|| Error::config(key, format!("`{path}` is not a table")))?,
            Choice => {
                // Not the last segment: the last one returned above.
                let variant = segments[i + 1];
                let Some(KeyDoc {
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
                    return Err(Error::config(
                        key,
                        format!("unknown configuration key; `{path}` is a value, not a table"),
                    ))
                }
            },
            _ => {
                return Err(Error::config(
                    key,
                    format!("unknown configuration key; `{path}` is a value, not a section"),
                ))
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
            .map_err(|e| Error::config(variant, format!("its documented value: {e}")))?;
        let mut one = Table::new();
        one.insert(variant.to_string(), start);
        table.insert(choice.to_string(), Value::Table(one));
    }
    match table.get_mut(choice) {
        Some(Value::Table(t)) => Ok(t),
        _ => Err(Error::config(choice, "not a table")),
    }
}

#[cfg(test)]
#[path = "config_doc_tests.rs"]
mod tests;

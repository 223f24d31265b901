//! Text before naga: directives, `#include`s, GLSL variants' `#define`s,
//! WGSL's `#if` lines and `#unroll` blocks.

use super::*;

/// `// @word rest...` directives in a file.
pub(crate) fn directives<'a>(text: &'a str, word: &str) -> Vec<&'a str> {
    let tag = format!("@{word}");
    text.lines()
        .filter_map(|l| {
            let l = l.trim_start();
            let l = l.strip_prefix("//")?.trim_start();
            let rest = l.strip_prefix(tag.as_str())?;
            if rest.is_empty() || rest.starts_with(char::is_whitespace) {
                Some(rest.trim())
            } else {
                None
            }
        })
        .collect()
}

pub(crate) fn capabilities(text: &str, file: &str) -> Result<Capabilities, String> {
    let mut caps = Capabilities::IMMEDIATES;
    for d in directives(text, "capabilities") {
        for name in d.split_whitespace() {
            match Capabilities::from_name(name) {
                Some(c) => caps |= c,
                None => return Err(format!("{file}: unknown naga capability `{name}`")),
            }
        }
    }
    Ok(caps)
}

pub(crate) fn expand_includes(
    path: &Path,
    include_dir: &Path,
    out: &mut String,
    map: &mut LineMap,
    depth: u32,
) -> Result<(), String> {
    if depth > 16 {
        return Err(format!("{}: #include nested too deeply", rel(path)));
    }
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", rel(path)))?;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        if let Some(rest) = trimmed.strip_prefix("#include") {
            let name = rest
                .trim()
                .trim_matches(|c| c == '"' || c == '<' || c == '>');
            let inc = if name == SHARED_GLSL || name == SHARED_WGSL {
                PathBuf::from(std::env::var("OUT_DIR").unwrap()).join(name)
            } else {
                include_dir.join(name)
            };
            println!("cargo:rerun-if-changed={}", inc.display());
            if !inc.is_file() {
                return Err(format!(
                    "{}:{}: cannot find include file `{name}` in {}/",
                    rel(path),
                    i + 1,
                    rel(include_dir)
                ));
            }
            // Each file once, as if it had `#pragma once`: shared.glsl
            // reaches a kernel directly and through splat.glsl.
            let inc_rel = PathBuf::from(rel(&inc));
            if !map.lines.iter().any(|(f, _)| *f == inc_rel) {
                expand_includes(&inc, include_dir, out, map, depth + 1)?;
            }
        } else {
            out.push_str(line);
            out.push('\n');
            map.lines.push((PathBuf::from(rel(path)), i as u32 + 1));
        }
    }
    Ok(())
}

/// `@kernel` directives of a file: (variant name, definitions).
pub(crate) fn variants(raw: &str, file: &str) -> Result<Vec<(String, Defines)>, String> {
    let mut out = Vec::new();
    for d in directives(raw, "kernel") {
        let mut parts = d.split_whitespace();
        let name = parts
            .next()
            .ok_or_else(|| format!("{file}: `@kernel` needs a name"))?
            .to_string();
        let mut defs = Vec::new();
        for p in parts {
            let (k, v) = p
                .split_once('=')
                .ok_or_else(|| format!("{file}: `@kernel {name}`: `{p}` is not KEY=VALUE"))?;
            defs.push((k.to_string(), v.to_string()));
        }
        out.push((name, defs));
    }
    Ok(out)
}

/// Expands `#unroll NAME COUNT` / `#endunroll` blocks (which may nest) of
/// `text`, whose line `i` comes from `map.lines[i]`; returns the new text
/// and its line map.
pub(crate) fn expand_unroll(
    text: &str,
    map: &LineMap,
    defs: &[(String, String)],
    file: &str,
) -> Result<(String, LineMap), String> {
    let mut out = String::with_capacity(text.len());
    let mut lines = Vec::new();
    let origin = |i: usize| {
        map.lines
            .get(i)
            .cloned()
            .unwrap_or((PathBuf::from(file), i as u32 + 1))
    };
    // Open blocks, innermost last.
    let mut blocks: Vec<UnrollBlock> = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        if let Some(rest) = t.strip_prefix("#unroll ") {
            let mut parts = rest.split_whitespace();
            let (Some(name), Some(count), None) = (parts.next(), parts.next(), parts.next()) else {
                return Err(format!(
                    "{}: expected `#unroll NAME COUNT`",
                    map.describe(i as u32 + 1)
                ));
            };
            let value = defs
                .iter()
                .find(|(k, _)| k == count)
                .map_or(count, |(_, v)| v.as_str());
            let count: u32 = value.parse().map_err(|_| {
                format!(
                    "{}: `#unroll` count `{count}` is neither a number nor a variant key",
                    map.describe(i as u32 + 1)
                )
            })?;
            blocks.push((name.to_string(), count, Vec::new()));
        } else if t == "#endunroll" {
            let (name, count, body) = blocks.pop().ok_or_else(|| {
                format!(
                    "{}: `#endunroll` without `#unroll`",
                    map.describe(i as u32 + 1)
                )
            })?;
            for k in 0..count {
                for (l, at) in &body {
                    let l = replace_word(l, &name, &format!("{k}u"));
                    match blocks.last_mut() {
                        Some((_, _, outer)) => outer.push((l, *at)),
                        None => {
                            out.push_str(&l);
                            out.push('\n');
                            lines.push(origin(*at));
                        }
                    }
                }
            }
        } else if let Some((_, _, body)) = blocks.last_mut() {
            body.push((line.to_string(), i));
        } else {
            out.push_str(line);
            out.push('\n');
            lines.push(origin(i));
        }
    }
    if !blocks.is_empty() {
        return Err(format!("{file}: `#unroll` without `#endunroll`"));
    }
    Ok((out, LineMap { lines }))
}

/// `line` with every whole-word (identifier) occurrence of `name` replaced.
pub(crate) fn replace_word(line: &str, name: &str, with: &str) -> String {
    let is_ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    let mut out = String::with_capacity(line.len());
    let mut rest = line;
    while let Some(at) = rest.find(name) {
        let before = rest[..at].chars().next_back();
        let after = rest[at + name.len()..].chars().next();
        out.push_str(&rest[..at]);
        if before.is_some_and(is_ident) || after.is_some_and(is_ident) {
            out.push_str(name);
        } else {
            out.push_str(with);
        }
        rest = &rest[at + name.len()..];
    }
    out.push_str(rest);
    out
}

/// WGSL has no preprocessor; variants select code with whole-line
/// `#if KEY` / `#else` / `#endif` (KEY is true when defined and not `0`).
/// Removed lines become empty so error positions stay those of the file.
pub(crate) fn preprocess_wgsl(
    text: &str,
    defs: &[(String, String)],
    file: &str,
) -> Result<String, String> {
    let truthy = |key: &str| defs.iter().any(|(k, v)| k == key && v != "0");
    // Stack of (this branch active, some branch of this #if was taken).
    let mut stack: Vec<(bool, bool)> = Vec::new();
    let mut out = String::with_capacity(text.len());
    for (i, line) in text.lines().enumerate() {
        let t = line.trim();
        let outer = stack.iter().all(|(a, _)| *a);
        if let Some(key) = t.strip_prefix("#if ") {
            let on = truthy(key.trim());
            stack.push((on, on));
        } else if t == "#else" {
            let top = stack
                .last_mut()
                .ok_or_else(|| format!("{file}:{}: `#else` without `#if`", i + 1))?;
            *top = (!top.1, true);
        } else if t == "#endif" {
            stack
                .pop()
                .ok_or_else(|| format!("{file}:{}: `#endif` without `#if`", i + 1))?;
        } else if t.starts_with('#') && !t.starts_with("#unroll ") && t != "#endunroll" {
            return Err(format!(
                "{file}:{}: unknown directive `{t}` (WGSL kernels support #if/#else/#endif \
                 and #unroll/#endunroll)",
                i + 1
            ));
        } else if outer {
            out.push_str(line);
        }
        out.push('\n');
    }
    if !stack.is_empty() {
        return Err(format!("{file}: `#if` without `#endif`"));
    }
    Ok(out)
}

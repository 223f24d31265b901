//! Compiles every compute kernel to SPIR-V 1.3 with naga and generates the
//! typed kernel table (`$OUT_DIR/kernels.rs`, included by `src/lib.rs`).
//!
//! * `glsl/*.comp` (workspace top level) go through naga's GLSL front end.
//!   Text before that is expanded here: `#include "x.glsl"` (relative to
//!   `glsl/`) and per-variant `#define`s.
//! * `shaders/wgsl/*.wgsl` go through the WGSL front end; every compute entry
//!   point becomes one kernel, named after the entry point. They may
//!   `#include "x.wgsl"` from `shaders/wgsl/include/` (code shared by
//!   kernels, compiled only where included).
//!
//! Directives, written as comments anywhere in a kernel file:
//! * `// @kernel NAME KEY=VALUE ...` declares one variant of a file: GLSL
//!   gets those `#define`s (a file without the directive is one kernel named
//!   after its stem); WGSL, which has no preprocessor, selects lines with
//!   `#if KEY` / `#else` / `#endif` handled here (a WGSL file with variants
//!   has one entry point, renamed after each variant);
//! * `// @capabilities NAME ...` lists the naga validator capabilities the
//!   kernel needs beyond push constants (e.g. `SHADER_FLOAT32_ATOMIC`,
//!   `SUBGROUP`); nothing else is enabled.
//! * `#unroll NAME COUNT` ... `#endunroll` (GLSL and WGSL, per variant):
//!   the lines between are written COUNT times (a number or a variant's
//!   KEY) with every whole-word NAME replaced by `0u`, `1u`, ... Array
//!   indices then are constants, so per-invocation arrays stay in registers:
//!   drivers do not unroll large loop bodies themselves, and some (CPU ones)
//!   turn dynamically indexed local arrays into memory accessed lane by lane.
//!
//! IR fix-up: naga 30's GLSL front end lowers `barrier()` to a control barrier
//! with *every* flag set, and its SPIR-V writer then picks Subgroup execution
//! scope. That synchronises only one subgroup, so shared-memory algorithms
//! race on any device whose workgroup spans several subgroups (all real
//! GPUs). We rewrite such barriers to workgroup execution scope with
//! workgroup-memory semantics, which is what `barrier()` means in Vulkan GLSL.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use naga::valid::{Capabilities, ValidationFlags, Validator};

/// A kernel-source location, for error messages that point at the user's file.
struct LineMap {
    /// For each line of the expanded text: (file, 1-based line).
    lines: Vec<(PathBuf, u32)>,
}

impl LineMap {
    fn describe(&self, expanded_line: u32) -> String {
        match self.lines.get(expanded_line.saturating_sub(1) as usize) {
            Some((file, line)) => format!("{}:{}", file.display(), line),
            None => format!("<expanded>:{expanded_line}"),
        }
    }
}

struct KernelOut {
    name: String,
    source: String,
    spirv: Vec<u32>,
    workgroup: [u32; 3],
    bindings: Vec<(String, bool)>,
    push: Option<PushStruct>,
}

struct PushStruct {
    size: u32,
    /// (field name, rust type, byte offset, byte size)
    fields: Vec<(String, String, u32, u32)>,
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let glsl_dir = manifest.join("../glsl");
    let wgsl_dir = manifest.join("wgsl");
    println!("cargo:rerun-if-changed={}", glsl_dir.display());
    println!("cargo:rerun-if-changed={}", wgsl_dir.display());

    let mut kernels = Vec::new();
    let mut errors = Vec::new();

    for path in sorted_files(&glsl_dir, "comp") {
        println!("cargo:rerun-if-changed={}", path.display());
        match compile_glsl_file(&path, &glsl_dir) {
            Ok(mut ks) => kernels.append(&mut ks),
            Err(e) => errors.push(e),
        }
    }
    for path in sorted_files(&glsl_dir, "glsl") {
        println!("cargo:rerun-if-changed={}", path.display());
    }
    println!(
        "cargo:rerun-if-changed={}",
        wgsl_dir.join("include").display()
    );
    for path in sorted_files(&wgsl_dir, "wgsl") {
        println!("cargo:rerun-if-changed={}", path.display());
        match compile_wgsl_file(&path, &wgsl_dir.join("include")) {
            Ok(mut ks) => kernels.append(&mut ks),
            Err(e) => errors.push(e),
        }
    }

    let mut seen = BTreeMap::new();
    for k in &kernels {
        if let Some(prev) = seen.insert(k.name.clone(), k.source.clone()) {
            errors.push(format!(
                "kernel name `{}` is declared twice ({} and {})",
                k.name, prev, k.source
            ));
        }
    }

    if !errors.is_empty() {
        for e in &errors {
            // cargo shows build-script stderr when the script fails.
            eprintln!("error: {e}\n");
        }
        panic!(
            "{} kernel(s) failed to compile; see the messages above",
            errors.len()
        );
    }

    let out = PathBuf::from(std::env::var("OUT_DIR").unwrap()).join("kernels.rs");
    std::fs::write(&out, generate_table(&kernels)).expect("write kernels.rs");
}

fn sorted_files(dir: &Path, ext: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = match std::fs::read_dir(dir) {
        Ok(rd) => rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().and_then(|e| e.to_str()) == Some(ext))
            .collect(),
        Err(_) => Vec::new(),
    };
    v.sort();
    v
}

fn rel(path: &Path) -> String {
    // Paths relative to the workspace root read best in errors and tables.
    let s = path.to_string_lossy().replace('\\', "/");
    match s.find("/shaders/../") {
        Some(i) => s[i + "/shaders/../".len()..].to_string(),
        None => match s.rfind("/shaders/") {
            Some(i) => s[i + 1..].to_string(),
            None => s,
        },
    }
}

/// `// @word rest...` directives in a file.
fn directives<'a>(text: &'a str, word: &str) -> Vec<&'a str> {
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

fn capabilities(text: &str, file: &str) -> Result<Capabilities, String> {
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

fn expand_includes(
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
            let inc = include_dir.join(name);
            println!("cargo:rerun-if-changed={}", inc.display());
            if !inc.is_file() {
                return Err(format!(
                    "{}:{}: cannot find include file `{name}` in {}/",
                    rel(path),
                    i + 1,
                    rel(include_dir)
                ));
            }
            expand_includes(&inc, include_dir, out, map, depth + 1)?;
        } else {
            out.push_str(line);
            out.push('\n');
            map.lines.push((PathBuf::from(rel(path)), i as u32 + 1));
        }
    }
    Ok(())
}

fn compile_glsl_file(path: &Path, include_dir: &Path) -> Result<Vec<KernelOut>, String> {
    let file = rel(path);
    let raw = std::fs::read_to_string(path).map_err(|e| format!("{file}: {e}"))?;
    let caps = capabilities(&raw, &file)?;
    let mut variants = variants(&raw, &file)?;
    if variants.is_empty() {
        let stem = path.file_stem().unwrap().to_string_lossy().to_string();
        variants.push((stem, Vec::new()));
    }

    let mut expanded = String::new();
    let mut map = LineMap { lines: Vec::new() };
    // The version line must come first for naga; keep the user's, or add one.
    if !raw.lines().any(|l| l.trim_start().starts_with("#version")) {
        expanded.push_str("#version 450\n");
        map.lines.push((PathBuf::from(&file), 0));
    }
    expand_includes(path, include_dir, &mut expanded, &mut map, 0)?;

    let mut out = Vec::new();
    for (name, defs) in variants {
        let mut options = naga::front::glsl::Options::from(naga::ShaderStage::Compute);
        for (k, v) in &defs {
            options.defines.insert(k.clone(), v.clone());
        }
        let (expanded, map) = expand_unroll(&expanded, &map, &defs, &file)?;
        let mut frontend = naga::front::glsl::Frontend::default();
        let mut module = frontend.parse(&options, &expanded).map_err(|errs| {
            let mut s = String::new();
            for e in &errs.errors {
                let loc = e.meta.location(&expanded);
                let _ = writeln!(
                    s,
                    "{} (kernel `{name}`): {}",
                    map.describe(loc.line_number),
                    e.kind
                );
            }
            s
        })?;
        fix_glsl_barriers(&mut module);
        let what = format!("{file} (kernel `{name}`)");
        out.push(finish(
            module,
            &expanded,
            &map,
            caps,
            "main",
            name,
            &what,
            file.clone(),
        )?);
    }
    Ok(out)
}

/// `KEY=VALUE` definitions of one variant.
type Defines = Vec<(String, String)>;

/// `@kernel` directives of a file: (variant name, definitions).
fn variants(raw: &str, file: &str) -> Result<Vec<(String, Defines)>, String> {
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

/// An open `#unroll` block: the name, the count, and the body lines with
/// the index of the input line each came from.
type UnrollBlock = (String, u32, Vec<(String, usize)>);

/// Expands `#unroll NAME COUNT` / `#endunroll` blocks (which may nest) of
/// `text`, whose line `i` comes from `map.lines[i]`; returns the new text
/// and its line map.
fn expand_unroll(
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
fn replace_word(line: &str, name: &str, with: &str) -> String {
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
fn preprocess_wgsl(text: &str, defs: &[(String, String)], file: &str) -> Result<String, String> {
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

fn compile_wgsl_file(path: &Path, include_dir: &Path) -> Result<Vec<KernelOut>, String> {
    let file = rel(path);
    let raw = std::fs::read_to_string(path).map_err(|e| format!("{file}: {e}"))?;
    let caps = capabilities(&raw, &file)?;
    // `#include "x.wgsl"` pulls in shaders/wgsl/include/x.wgsl, as GLSL
    // includes do from glsl/; errors point at the file and line written.
    let mut expanded = String::new();
    let mut map = LineMap { lines: Vec::new() };
    expand_includes(path, include_dir, &mut expanded, &mut map, 0)?;
    let declared = variants(&raw, &file)?;
    let runs: Vec<(Option<String>, Defines)> = if declared.is_empty() {
        vec![(None, Vec::new())]
    } else {
        declared.into_iter().map(|(n, d)| (Some(n), d)).collect()
    };
    let mut out = Vec::new();
    for (variant, defs) in runs {
        let text = preprocess_wgsl(&expanded, &defs, &file)?;
        let (text, map) = expand_unroll(&text, &map, &defs, &file)?;
        let mut module = naga::front::wgsl::parse_str(&text).map_err(|e| {
            let at = e
                .location(&text)
                .map(|l| map.describe(l.line_number))
                .unwrap_or_else(|| file.clone());
            let v = variant.as_deref().unwrap_or("");
            format!("{at} {v}: {}", e.emit_to_string(&text))
        })?;
        let entry_names: Vec<String> = module
            .entry_points
            .iter()
            .filter(|e| e.stage == naga::ShaderStage::Compute)
            .map(|e| e.name.clone())
            .collect();
        if entry_names.is_empty() {
            return Err(format!("{file}: no @compute entry point"));
        }
        if let Some(v) = &variant {
            // A variant is one kernel: its entry point takes the variant's
            // name, which is also what the SPIR-V exports.
            if entry_names.len() != 1 {
                return Err(format!(
                    "{file}: `@kernel` variants need exactly one entry point, found {}",
                    entry_names.len()
                ));
            }
            module.entry_points[0].name = v.clone();
            let what = format!("{file} (kernel `{v}`)");
            out.push(finish(
                module,
                &text,
                &map,
                caps,
                v,
                v.clone(),
                &what,
                file.clone(),
            )?);
            continue;
        }
        for ep in entry_names {
            let what = format!("{file} (entry point `{ep}`)");
            out.push(finish(
                module.clone(),
                &text,
                &map,
                caps,
                &ep.clone(),
                ep,
                &what,
                file.clone(),
            )?);
        }
    }
    Ok(out)
}

/// See the module comment: `barrier()` must synchronise the whole workgroup.
fn fix_glsl_barriers(module: &mut naga::Module) {
    fn fix_block(block: &mut naga::Block) {
        for (stmt, _) in block.span_iter_mut() {
            match stmt {
                naga::Statement::ControlBarrier(flags)
                    if flags.contains(naga::Barrier::SUB_GROUP) =>
                {
                    *flags = naga::Barrier::WORK_GROUP;
                }
                naga::Statement::Block(b) => fix_block(b),
                naga::Statement::If { accept, reject, .. } => {
                    fix_block(accept);
                    fix_block(reject);
                }
                naga::Statement::Switch { cases, .. } => {
                    for c in cases.iter_mut() {
                        fix_block(&mut c.body);
                    }
                }
                naga::Statement::Loop {
                    body, continuing, ..
                } => {
                    fix_block(body);
                    fix_block(continuing);
                }
                _ => {}
            }
        }
    }
    for (_, f) in module.functions.iter_mut() {
        fix_block(&mut f.body);
    }
    for ep in module.entry_points.iter_mut() {
        fix_block(&mut ep.function.body);
    }
}

#[allow(clippy::too_many_arguments)]
fn finish(
    module: naga::Module,
    text: &str,
    map: &LineMap,
    caps: Capabilities,
    entry: &str,
    name: String,
    what: &str,
    source: String,
) -> Result<KernelOut, String> {
    let info = Validator::new(ValidationFlags::all(), caps)
        .validate(&module)
        .map_err(|e| {
            let at = e
                .location(text)
                .map(|l| map.describe(l.line_number))
                .unwrap_or_else(|| what.to_string());
            format!(
                "{at}: {what} failed validation: {}\n{}",
                e.as_inner(),
                e.emit_to_string(text)
            )
        })?;

    let ep = module
        .entry_points
        .iter()
        .find(|e| e.name == entry)
        .ok_or_else(|| format!("{what}: entry point `{entry}` missing"))?;

    // One binding convention: set 0, binding i = storage buffer i.
    let mut bindings: BTreeMap<u32, (String, bool)> = BTreeMap::new();
    let mut push = None;
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .map_err(|e| format!("{what}: layout: {e}"))?;
    let used = &info.get_entry_point(
        module
            .entry_points
            .iter()
            .position(|e| e.name == entry)
            .unwrap(),
    );
    for (handle, var) in module.global_variables.iter() {
        if used[handle].is_empty() {
            continue;
        }
        match var.space {
            naga::AddressSpace::Storage { access } => {
                let rb = var
                    .binding
                    .as_ref()
                    .ok_or_else(|| format!("{what}: storage buffer without a binding"))?;
                if rb.group != 0 {
                    return Err(format!(
                        "{what}: buffer `{}` uses set {}; every kernel binds its buffers in set 0",
                        var.name.as_deref().unwrap_or("?"),
                        rb.group
                    ));
                }
                let bname = var
                    .name
                    .clone()
                    .or_else(|| type_name(&module, var.ty))
                    .unwrap_or_else(|| format!("binding{}", rb.binding));
                if bindings
                    .insert(
                        rb.binding,
                        (bname, access.contains(naga::StorageAccess::STORE)),
                    )
                    .is_some()
                {
                    return Err(format!("{what}: binding {} declared twice", rb.binding));
                }
            }
            naga::AddressSpace::Immediate => {
                push = Some(push_struct(&module, &layouter, var.ty, what)?);
            }
            naga::AddressSpace::WorkGroup
            | naga::AddressSpace::Private
            | naga::AddressSpace::Function => {}
            other => {
                return Err(format!(
                    "{what}: resource in address space {other:?}; kernels use storage buffers \
                     (set 0) and push constants only"
                ))
            }
        }
    }
    for (i, (b, _)) in bindings.iter().enumerate() {
        if *b != i as u32 {
            return Err(format!(
                "{what}: bindings must be numbered 0..n without gaps (found {b} at position {i})"
            ));
        }
    }

    let mut options = naga::back::spv::Options {
        lang_version: (1, 3),
        ..Default::default()
    };
    options.flags = naga::back::spv::WriterFlags::empty();
    // Kernels size their own loops and shared memory; the polyfills cost time
    // in every inner loop and zero-fill shared memory nobody reads unwritten.
    options.force_loop_bounding = false;
    options.zero_initialize_workgroup_memory =
        naga::back::spv::ZeroInitializeWorkgroupMemoryMode::None;
    options.emit_int_div_checks = false;
    let pipeline = naga::back::spv::PipelineOptions {
        shader_stage: naga::ShaderStage::Compute,
        entry_point: entry.to_string(),
    };
    let spirv = naga::back::spv::write_vec(&module, &info, &options, Some(&pipeline))
        .map_err(|e| format!("{what}: SPIR-V output failed: {e}"))?;

    Ok(KernelOut {
        name,
        source,
        spirv,
        workgroup: ep.workgroup_size,
        bindings: bindings.into_values().collect(),
        push,
    })
}

fn type_name(module: &naga::Module, ty: naga::Handle<naga::Type>) -> Option<String> {
    module.types[ty].name.clone()
}

fn push_struct(
    module: &naga::Module,
    layouter: &naga::proc::Layouter,
    ty: naga::Handle<naga::Type>,
    what: &str,
) -> Result<PushStruct, String> {
    let naga::TypeInner::Struct { members, span } = &module.types[ty].inner else {
        return Err(format!("{what}: push constants must be a struct/block"));
    };
    let mut fields = Vec::new();
    for m in members {
        let mname = m
            .name
            .clone()
            .unwrap_or_else(|| format!("field{}", fields.len()));
        let size = layouter[m.ty].size;
        let rust = rust_type(&module.types[m.ty].inner, size).ok_or_else(|| {
            format!("{what}: push-constant member `{mname}` has an unsupported type")
        })?;
        fields.push((mname, rust, m.offset, size));
    }
    Ok(PushStruct {
        size: *span,
        fields,
    })
}

fn scalar_rust(s: naga::Scalar) -> Option<&'static str> {
    match (s.kind, s.width) {
        (naga::ScalarKind::Uint, 4) => Some("u32"),
        (naga::ScalarKind::Sint, 4) => Some("i32"),
        (naga::ScalarKind::Float, 4) => Some("f32"),
        _ => None,
    }
}

fn rust_type(inner: &naga::TypeInner, size: u32) -> Option<String> {
    match *inner {
        naga::TypeInner::Scalar(s) => scalar_rust(s).map(str::to_string),
        naga::TypeInner::Vector { size: n, scalar } => {
            Some(format!("[{}; {}]", scalar_rust(scalar)?, n as u32))
        }
        naga::TypeInner::Matrix { scalar, .. } => {
            // Column-major with padded columns, exactly as laid out.
            Some(format!("[{}; {}]", scalar_rust(scalar)?, size / 4))
        }
        naga::TypeInner::Array {
            base: _,
            size: naga::ArraySize::Constant(n),
            stride: 4,
        } => Some(format!("[u32; {n}]")),
        _ => None,
    }
}

fn camel(name: &str) -> String {
    name.split('_')
        .filter(|s| !s.is_empty())
        .map(|s| {
            let mut c = s.chars();
            match c.next() {
                Some(f) => f.to_ascii_uppercase().to_string() + c.as_str(),
                None => String::new(),
            }
        })
        .collect()
}

fn generate_table(kernels: &[KernelOut]) -> String {
    let mut s = String::new();
    s.push_str("// @generated by shaders/build.rs. Do not edit.\n\n");
    s.push_str("/// Push-constant blocks of the kernels, mirrored as `#[repr(C)]` structs.\n");
    s.push_str("pub mod push {\n");
    for k in kernels {
        let Some(p) = &k.push else { continue };
        let _ = writeln!(
            s,
            "    /// Push constants of kernel `{}` ({}).\n    #[repr(C)]\n    #[derive(Clone, Copy, Debug, Default, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]\n    pub struct {} {{",
            k.name,
            k.source,
            camel(&k.name)
        );
        let mut at = 0u32;
        let mut pad = 0;
        for (name, ty, off, size) in &p.fields {
            if *off > at {
                let _ = writeln!(
                    s,
                    "        /// Layout padding.\n        pub _pad{pad}: [u32; {}],",
                    (off - at) / 4
                );
                pad += 1;
            }
            let _ = writeln!(s, "        /// `{name}` in the kernel's push-constant block.\n        pub {name}: {ty},");
            at = off + size;
        }
        if p.size > at {
            let _ = writeln!(
                s,
                "        /// Layout padding.\n        pub _pad{pad}: [u32; {}],",
                (p.size - at) / 4
            );
        }
        s.push_str("    }\n");
    }
    s.push_str("}\n\n");

    for k in kernels {
        let upper = k.name.to_ascii_uppercase();
        let _ = write!(s, "static {upper}_SPIRV: [u32; {}] = [", k.spirv.len());
        for (i, w) in k.spirv.iter().enumerate() {
            if i % 12 == 0 {
                s.push_str("\n    ");
            }
            let _ = write!(s, "{w:#010x}, ");
        }
        s.push_str("\n];\n");
        let push_ty = match &k.push {
            Some(_) => format!("push::{}", camel(&k.name)),
            None => "()".to_string(),
        };
        let push_size = k.push.as_ref().map(|p| p.size).unwrap_or(0);
        let mut binds = String::new();
        for (n, w) in &k.bindings {
            let _ = write!(binds, "Binding {{ name: {n:?}, writable: {w} }}, ");
        }
        let _ = writeln!(
            s,
            "/// Kernel `{}` from `{}`.\npub static {upper}: KernelDef<{push_ty}> = KernelDef::new(Kernel {{\n    name: {:?},\n    source: {:?},\n    spirv: &{upper}_SPIRV,\n    workgroup: [{}, {}, {}],\n    bindings: &[{binds}],\n    push_constant_size: {push_size},\n}});\n",
            k.name, k.source, k.name, k.source, k.workgroup[0], k.workgroup[1], k.workgroup[2]
        );
    }
    s.push_str("/// Every kernel, in source order.\npub static ALL: &[&Kernel] = &[\n");
    for k in kernels {
        let _ = writeln!(s, "    &{}.kernel,", k.name.to_ascii_uppercase());
    }
    s.push_str("];\n");
    s
}

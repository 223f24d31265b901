//! Compiles every compute kernel to SPIR-V 1.3 with naga and generates the
//! typed kernel table (`$OUT_DIR/kernels.rs`, included by `src/lib.rs`):
//! each kernel's push-constant struct (`push`), its buffers by name
//! (`bind`, see `build/bindings.rs`) and its variant selector.
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
//! * `// @select KEY ...` (a file with variants): generate a selector,
//!   `FileVariant { key: bool, ... }.kernel()`, over those keys' 0/1
//!   values; a variant that leaves a key out serves both values, and the
//!   build fails unless every combination names exactly one variant;
//! * `// @capabilities NAME ...` lists the naga validator capabilities the
//!   kernel needs beyond push constants (e.g. `SHADER_FLOAT32_ATOMIC`,
//!   `SUBGROUP`); nothing else is enabled. What each variant actually uses
//!   of the device (float atomics, subgroup arithmetic or shuffles) is read
//!   from its IR into `Kernel::requires`, which the engine checks before
//!   creating a pipeline.
//! * `// @push NAME` (in a kernel or an include) names the Rust type of the
//!   push constants, shared by kernels of several files with one layout.
//!   Without it the variants of one file share a type named after the file
//!   when their layouts agree; kernels that end up with one type must agree.
//! * `// @cost flops=EXPR bytes=EXPR` (or `// @cost NAME: ...` for one
//!   kernel of the file, or `caller`) states the arithmetic and the bytes of
//!   global memory one dispatch needs, from its push constants and launch
//!   size: `Kernel::work`. Every kernel has one; see `build/cost.rs`.
//!
//! Constants and structs the host shares with kernels are declared once in
//! `shaders/layouts.rs`; kernels `#include "shared.glsl"` or
//! `#include "shared.wgsl"` (generated), Rust uses `latentam_shaders::shared`.
//! Every file is included once per kernel, however many includes name it.
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

// Scalar field types are part of the declaration language even while no
// struct uses them.
#[allow(dead_code)]
#[path = "layouts.rs"]
mod layouts;

#[path = "build/backend.rs"]
mod backend;
#[path = "build/bindings.rs"]
mod bindings;
#[path = "build/codegen.rs"]
mod codegen;
#[path = "build/cost.rs"]
mod cost;
#[path = "build/ir.rs"]
mod ir;
#[path = "build/preprocess.rs"]
mod preprocess;
#[path = "build/shared.rs"]
mod shared;

use backend::*;
use bindings::*;
use codegen::*;
use cost::*;
use ir::*;
use preprocess::*;
use shared::*;

/// Include names that resolve to the text generated from `layouts.rs`.
const SHARED_GLSL: &str = "shared.glsl";
const SHARED_WGSL: &str = "shared.wgsl";

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
    /// Bytes of workgroup (shared) memory the entry point uses.
    shared_bytes: u32,
    bindings: Vec<(String, bool)>,
    push: Option<PushStruct>,
    /// The push-constant type named by a `// @push NAME` directive.
    push_group: Option<String>,
    requires: Requires,
    /// The variant's `KEY=VALUE` definitions (`@kernel` line).
    defines: Defines,
    /// The keys of the file's `// @select` directive, if it has one.
    select: Option<Vec<String>>,
    /// How a dispatch's work is counted (`// @cost`).
    cost: Option<CostDecl>,
}

#[derive(PartialEq)]
struct PushStruct {
    size: u32,
    /// (field name, rust type, byte offset, byte size)
    fields: Vec<(String, String, u32, u32)>,
}

/// Writes `contents` to `path` unless it holds them already: the crate
/// depends on these files, so a rewrite with a new time would rebuild it
/// and every crate above it although nothing changed.
fn write_if_changed(path: &Path, contents: &str) {
    if std::fs::read_to_string(path).is_ok_and(|old| old == contents) {
        return;
    }
    std::fs::write(path, contents).unwrap_or_else(|e| panic!("writing {}: {e}", path.display()));
}

fn main() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let glsl_dir = manifest.join("../glsl");
    let wgsl_dir = manifest.join("wgsl");
    println!("cargo:rerun-if-changed={}", glsl_dir.display());
    println!("cargo:rerun-if-changed={}", wgsl_dir.display());

    println!(
        "cargo:rerun-if-changed={}",
        manifest.join("layouts.rs").display()
    );
    let out_dir = PathBuf::from(std::env::var("OUT_DIR").unwrap());
    let shared = match shared_sources() {
        Ok(s) => s,
        Err(e) => panic!("shaders/layouts.rs: {e}"),
    };
    write_if_changed(&out_dir.join(SHARED_GLSL), &shared.glsl);
    write_if_changed(&out_dir.join(SHARED_WGSL), &shared.wgsl);
    write_if_changed(&out_dir.join("shared.rs"), &shared.rust);

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

    let table = match generate_table(&kernels) {
        Ok(t) => t,
        Err(e) => panic!("{e}"),
    };
    write_if_changed(&out_dir.join("kernels.rs"), &table);
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
    let name = path.file_name().and_then(|n| n.to_str());
    if matches!(name, Some(SHARED_GLSL | SHARED_WGSL))
        && path.starts_with(std::env::var("OUT_DIR").unwrap())
    {
        return format!("{} (generated from shaders/layouts.rs)", name.unwrap());
    }
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
    let push_group = push_group(&expanded, &file)?;
    let select = select_keys(&raw, &file)?;

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
        let mut k = finish(
            module,
            &expanded,
            &map,
            caps,
            "main",
            name,
            &what,
            file.clone(),
        )?;
        k.defines = defs;
        out.push(k);
    }
    for k in &mut out {
        k.push_group = push_group.clone();
        k.select = select.clone();
    }
    assign_costs(&raw, &file, &mut out)?;
    Ok(out)
}

/// `KEY=VALUE` definitions of one variant.
type Defines = Vec<(String, String)>;

/// An open `#unroll` block: the name, the count, and the body lines with
/// the index of the input line each came from.
type UnrollBlock = (String, u32, Vec<(String, usize)>);

fn compile_wgsl_file(path: &Path, include_dir: &Path) -> Result<Vec<KernelOut>, String> {
    let file = rel(path);
    let raw = std::fs::read_to_string(path).map_err(|e| format!("{file}: {e}"))?;
    let caps = capabilities(&raw, &file)?;
    // `#include "x.wgsl"` pulls in shaders/wgsl/include/x.wgsl, as GLSL
    // includes do from glsl/; errors point at the file and line written.
    let mut expanded = String::new();
    let mut map = LineMap { lines: Vec::new() };
    expand_includes(path, include_dir, &mut expanded, &mut map, 0)?;
    let push_group = push_group(&expanded, &file)?;
    let select = select_keys(&raw, &file)?;
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
            let mut k = finish(module, &text, &map, caps, v, v.clone(), &what, file.clone())?;
            k.defines = defs.clone();
            out.push(k);
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
    for k in &mut out {
        k.push_group = push_group.clone();
        k.select = select.clone();
    }
    assign_costs(&raw, &file, &mut out)?;
    Ok(out)
}

/// The keys of a file's `// @select KEY ...` directive: the flags a
/// generated selector picks its variant by.
fn select_keys(raw: &str, file: &str) -> Result<Option<Vec<String>>, String> {
    let found = directives(raw, "select");
    match found.as_slice() {
        [] => Ok(None),
        [one] => {
            let keys: Vec<String> = one.split_whitespace().map(str::to_string).collect();
            if keys.is_empty() {
                return Err(format!("{file}: `@select` needs at least one key"));
            }
            if variants(raw, file)?.is_empty() {
                return Err(format!("{file}: `@select` without `@kernel` variants"));
            }
            Ok(Some(keys))
        }
        _ => Err(format!("{file}: more than one `@select` line")),
    }
}

/// The `// @push NAME` directive of a kernel file or its includes: kernels
/// of different files whose push constants are one layout share that type.
fn push_group(expanded: &str, file: &str) -> Result<Option<String>, String> {
    let mut names: Vec<&str> = directives(expanded, "push");
    names.dedup();
    match names.as_slice() {
        [] => Ok(None),
        [one] if !one.is_empty() && !one.contains(char::is_whitespace) => Ok(Some(one.to_string())),
        _ => Err(format!(
            "{file}: `@push` takes one type name, found {names:?}"
        )),
    }
}

/// The Rust type name of each kernel's push constants: the `@push` name;
/// else the file's name when all its variants share one layout; else the
/// kernel's own. Kernels that end up with one name must agree on the
/// layout.
fn push_type_names(kernels: &[KernelOut]) -> Result<Vec<Option<String>>, String> {
    let stem = |source: &str| {
        let file = source.rsplit('/').next().unwrap_or(source);
        camel(file.split('.').next().unwrap_or(file))
    };
    let names: Vec<Option<String>> = kernels
        .iter()
        .map(|k| {
            k.push.as_ref()?;
            if let Some(g) = &k.push_group {
                return Some(g.clone());
            }
            let same_file_agrees = kernels
                .iter()
                .filter(|o| o.source == k.source)
                .all(|o| o.push == k.push);
            Some(if same_file_agrees {
                stem(&k.source)
            } else {
                camel(&k.name)
            })
        })
        .collect();
    for (i, a) in kernels.iter().enumerate() {
        for (j, b) in kernels.iter().enumerate().skip(i + 1) {
            if names[i].is_some() && names[i] == names[j] && a.push != b.push {
                return Err(format!(
                    "kernels `{}` ({}) and `{}` ({}) share push-constant type `{}` but \
                     their layouts differ",
                    a.name,
                    a.source,
                    b.name,
                    b.source,
                    names[i].as_deref().unwrap()
                ));
            }
        }
    }
    Ok(names)
}

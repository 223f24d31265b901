//! The engine's layers inside this crate (written in `src/lib.rs`): a
//! module uses only modules of lower layers. Between crates cargo enforces
//! the order (`latentam-base` → `latentam-gpu`, `latentam-io` → this crate
//! → `latentam`), and the CPU reference is only a dev-dependency, so
//! production code cannot call it. Checked on the parsed sources, so a
//! `use` that reaches up fails here rather than in review.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use syn::visit::Visit;

/// Layer of each top-level module; a module may use those of lower layers.
const LAYERS: &[(&str, u32)] = &[
    ("splat", 0),
    ("loss", 1),
    ("optim", 2),
    ("latent", 3),
    ("map", 4),
    ("mapper", 5),
    ("live", 6),
];

/// Names at the crate root that are no module of it: the error type,
/// re-exported from `latentam-base`, which every layer may name.
const ROOT_NAMES: &[&str] = &["Error", "Result"];

fn layer(module: &str) -> Option<u32> {
    LAYERS.iter().find(|(m, _)| *m == module).map(|&(_, l)| l)
}

fn is_cfg_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("cfg")
            && a.parse_args::<syn::Expr>()
                .map(|e| matches!(&e, syn::Expr::Path(p) if p.path.is_ident("test")))
                .unwrap_or(false)
    })
}

/// The top-level modules a file's non-test code names as `crate::m`, and
/// the files of its test-only submodules (`#[cfg(test)] mod tests;`).
#[derive(Default)]
struct Uses {
    modules: BTreeSet<String>,
    test_modules: Vec<String>,
}

impl<'ast> Visit<'ast> for Uses {
    fn visit_item(&mut self, item: &'ast syn::Item) {
        let attrs = match item {
            syn::Item::Mod(m) => &m.attrs,
            syn::Item::Fn(f) => &f.attrs,
            syn::Item::Use(u) => &u.attrs,
            syn::Item::Impl(i) => &i.attrs,
            syn::Item::Struct(s) => &s.attrs,
            syn::Item::Const(c) => &c.attrs,
            _ => return syn::visit::visit_item(self, item),
        };
        if is_cfg_test(attrs) {
            if let syn::Item::Mod(m) = item {
                if m.content.is_none() {
                    self.test_modules.push(m.ident.to_string());
                }
            }
            return;
        }
        syn::visit::visit_item(self, item);
    }

    fn visit_impl_item_fn(&mut self, f: &'ast syn::ImplItemFn) {
        if !is_cfg_test(&f.attrs) {
            syn::visit::visit_impl_item_fn(self, f);
        }
    }

    fn visit_path(&mut self, p: &'ast syn::Path) {
        let mut segs = p.segments.iter();
        if let (Some(first), Some(second)) = (segs.next(), segs.next()) {
            if first.ident == "crate" {
                self.modules.insert(second.ident.to_string());
            }
        }
        syn::visit::visit_path(self, p);
    }

    fn visit_use_tree(&mut self, t: &'ast syn::UseTree) {
        if let syn::UseTree::Path(p) = t {
            if p.ident == "crate" {
                let mut names = Vec::new();
                collect_first(&p.tree, &mut names);
                self.modules.extend(names);
                return;
            }
        }
        syn::visit::visit_use_tree(self, t);
    }
}

fn collect_first(t: &syn::UseTree, out: &mut Vec<String>) {
    match t {
        syn::UseTree::Path(p) => out.push(p.ident.to_string()),
        syn::UseTree::Name(n) => out.push(n.ident.to_string()),
        syn::UseTree::Rename(r) => out.push(r.ident.to_string()),
        syn::UseTree::Group(g) => g.items.iter().for_each(|t| collect_first(t, out)),
        syn::UseTree::Glob(_) => out.push("*".into()),
    }
}

/// Every production source file under `dir`, skipping test-only modules.
fn production_files(file: &Path, dir: &Path, out: &mut Vec<(PathBuf, Uses)>) {
    let text = std::fs::read_to_string(file).unwrap();
    let parsed = syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
    let mut uses = Uses::default();
    uses.visit_file(&parsed);
    let tests = std::mem::take(&mut uses.test_modules);
    for item in &parsed.items {
        let syn::Item::Mod(m) = item else { continue };
        let name = m.ident.to_string();
        if m.content.is_some() || tests.contains(&name) {
            continue;
        }
        let flat = dir.join(format!("{name}.rs"));
        let child = if flat.exists() {
            flat
        } else {
            dir.join(&name).join("mod.rs")
        };
        production_files(&child, &dir.join(&name), out);
    }
    out.push((file.to_path_buf(), uses));
}

#[test]
fn modules_use_only_lower_layers() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    production_files(&src.join("lib.rs"), &src, &mut files);
    assert!(files.len() > 40, "found only {} source files", files.len());
    let mut wrong = Vec::new();
    for (file, uses) in &files {
        let rel = file.strip_prefix(&src).unwrap();
        let Some(own) = rel.iter().next().and_then(|c| c.to_str()) else {
            continue;
        };
        let own = own.trim_end_matches(".rs");
        let Some(own_layer) = layer(own) else {
            assert!(
                own == "lib",
                "{}: module `{own}` has no layer",
                rel.display()
            );
            continue;
        };
        for used in &uses.modules {
            if used == own || used == "self" {
                continue;
            }
            if ROOT_NAMES.contains(&used.as_str()) {
                continue;
            }
            let Some(l) = layer(used) else {
                wrong.push(format!(
                    "{}: uses crate::{used}, which has no layer",
                    rel.display()
                ));
                continue;
            };
            if l >= own_layer {
                wrong.push(format!(
                    "{}: `{own}` (layer {own_layer}) uses `{used}` (layer {l})",
                    rel.display()
                ));
            }
        }
    }
    assert!(wrong.is_empty(), "layering broken:\n{}", wrong.join("\n"));
}

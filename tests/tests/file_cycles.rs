//! No two source files of one crate depend on each other, directly or
//! through others: cargo keeps the crates in layers, this keeps the files
//! inside each crate in layers too, so any file can be read (and moved)
//! knowing only what lies below it.
//!
//! A file depends on the file that defines each item it names through a
//! `crate::`, `super::` or `self::` path or a `use`. Re-exports are
//! followed to the defining file (a `mod.rs` that only re-exports is no
//! hub), and a glob import counts only for the names the file uses. Test
//! modules (`#[cfg(test)]`) are left out: a test may use anything.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use syn::visit::Visit;

/// The crate roots checked, relative to the workspace.
const ROOTS: &[&str] = &[
    "engine/src/lib.rs",
    "engine/base/src/lib.rs",
    "engine/gpu/src/lib.rs",
    "engine/io/src/lib.rs",
    "engine/core/src/lib.rs",
    "engine/reference/src/lib.rs",
    "engine/view/src/lib.rs",
    "engine/python/src/lib.rs",
    "engine/capi/src/lib.rs",
    "shaders/src/lib.rs",
    "tools/src/lib.rs",
    "tools/src/main.rs",
    "tools/args/src/lib.rs",
    "tools/report/src/lib.rs",
    "tools/scene/src/lib.rs",
    "tools/ros/src/main.rs",
    "fuzz/targets/src/lib.rs",
];

fn is_cfg_test(attrs: &[syn::Attribute]) -> bool {
    attrs.iter().any(|a| {
        a.path().is_ident("cfg")
            && a.parse_args::<syn::Expr>()
                .map(|e| matches!(&e, syn::Expr::Path(p) if p.path.is_ident("test")))
                .unwrap_or(false)
    })
}

/// One source file: a module, with the inline modules it contains
/// flattened into it (they are the same file).
#[derive(Default)]
struct Module {
    file: PathBuf,
    /// Names of the items defined here. Items a macro generates are not
    /// seen: a name found nowhere counts as this module's.
    defs: BTreeSet<String>,
    /// `use` imports: the name they bind → the path they name.
    uses: BTreeMap<String, Vec<String>>,
    /// Glob imports (`use x::*`).
    globs: Vec<Vec<String>>,
    /// Child modules declared here (`mod x;`), by name.
    children: BTreeSet<String>,
    /// Paths starting at `crate`, `super` or `self` named in code.
    paths: Vec<Vec<String>>,
    /// Single identifiers named in code (for glob imports).
    idents: BTreeSet<String>,
}

struct Collect<'m> {
    module: &'m mut Module,
}

impl Collect<'_> {
    fn use_tree(&mut self, prefix: &mut Vec<String>, tree: &syn::UseTree) {
        match tree {
            syn::UseTree::Path(p) => {
                prefix.push(p.ident.to_string());
                self.use_tree(prefix, &p.tree);
                prefix.pop();
            }
            syn::UseTree::Name(n) => {
                let mut path = prefix.clone();
                let name = n.ident.to_string();
                if name == "self" {
                    let bound = prefix.last().cloned().unwrap_or_default();
                    self.module.uses.insert(bound, path);
                } else {
                    path.push(name.clone());
                    self.module.uses.insert(name, path);
                }
            }
            syn::UseTree::Rename(r) => {
                let mut path = prefix.clone();
                if r.ident != "self" {
                    path.push(r.ident.to_string());
                }
                self.module.uses.insert(r.rename.to_string(), path);
            }
            syn::UseTree::Glob(_) => self.module.globs.push(prefix.clone()),
            syn::UseTree::Group(g) => {
                for t in &g.items {
                    self.use_tree(prefix, t);
                }
            }
        }
    }
}

impl<'ast> Visit<'ast> for Collect<'_> {
    fn visit_item(&mut self, item: &'ast syn::Item) {
        let (attrs, name): (&[syn::Attribute], Option<String>) = match item {
            syn::Item::Const(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Enum(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Fn(i) => (&i.attrs, Some(i.sig.ident.to_string())),
            syn::Item::Macro(i) => (&i.attrs, i.ident.as_ref().map(|i| i.to_string())),
            syn::Item::Mod(i) => (&i.attrs, None),
            syn::Item::Static(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Struct(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Trait(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Type(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Union(i) => (&i.attrs, Some(i.ident.to_string())),
            syn::Item::Impl(i) => (&i.attrs, None),
            syn::Item::Use(i) => (&i.attrs, None),
            _ => (&[], None),
        };
        if is_cfg_test(attrs) {
            return;
        }
        if let Some(name) = name {
            self.module.defs.insert(name);
        }
        match item {
            syn::Item::Use(u) => self.use_tree(&mut Vec::new(), &u.tree),
            syn::Item::Mod(m) if m.content.is_none() => {
                self.module.children.insert(m.ident.to_string());
            }
            _ => syn::visit::visit_item(self, item),
        }
    }

    fn visit_impl_item_fn(&mut self, f: &'ast syn::ImplItemFn) {
        if !is_cfg_test(&f.attrs) {
            syn::visit::visit_impl_item_fn(self, f);
        }
    }

    fn visit_path(&mut self, p: &'ast syn::Path) {
        let segs: Vec<String> = p.segments.iter().map(|s| s.ident.to_string()).collect();
        match segs.first().map(String::as_str) {
            Some("crate" | "super" | "self") if segs.len() > 1 => self.module.paths.push(segs),
            Some(first) => {
                self.module.idents.insert(first.to_string());
            }
            None => {}
        }
        syn::visit::visit_path(self, p);
    }

    fn visit_macro(&mut self, m: &'ast syn::Macro) {
        // Paths inside macro calls (format arguments, `matches!`) are plain
        // tokens; their identifiers still name things a glob may bring.
        for t in m.tokens.clone() {
            if let proc_macro2::TokenTree::Ident(i) = t {
                self.module.idents.insert(i.to_string());
            }
        }
        syn::visit::visit_macro(self, m);
    }
}

/// Every module file of the crate whose root is `root`, by module path.
fn modules(root: &Path) -> BTreeMap<Vec<String>, Module> {
    fn walk(file: &Path, dir: &Path, path: Vec<String>, out: &mut BTreeMap<Vec<String>, Module>) {
        let text = std::fs::read_to_string(file).unwrap();
        let parsed = syn::parse_file(&text).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let mut module = Module {
            file: file.to_path_buf(),
            ..Module::default()
        };
        Collect {
            module: &mut module,
        }
        .visit_file(&parsed);
        let children = module.children.clone();
        out.insert(path.clone(), module);
        for name in children {
            let flat = dir.join(format!("{name}.rs"));
            let child = if flat.exists() {
                flat
            } else {
                dir.join(&name).join("mod.rs")
            };
            let mut p = path.clone();
            p.push(name.clone());
            walk(&child, &dir.join(&name), p, out);
        }
    }
    let mut out = BTreeMap::new();
    walk(root, root.parent().unwrap(), Vec::new(), &mut out);
    out
}

struct Resolver<'a> {
    modules: &'a BTreeMap<Vec<String>, Module>,
}

impl Resolver<'_> {
    /// `path` as seen from module `at`, made absolute (from the crate
    /// root); `None` for another crate's.
    fn absolute(&self, at: &[String], path: &[String]) -> Option<Vec<String>> {
        let mut base: Vec<String> = at.to_vec();
        let mut rest = path;
        match rest.first().map(String::as_str) {
            Some("crate") => {
                base.clear();
                rest = &rest[1..];
            }
            Some("super") | Some("self") => {
                while let Some(s) = rest.first() {
                    match s.as_str() {
                        "super" => {
                            base.pop()?;
                        }
                        "self" => {}
                        _ => break,
                    }
                    rest = &rest[1..];
                }
            }
            Some(first) => {
                // A child module of `at` (2018 paths); anything else is
                // another crate or a prelude name.
                if !self.modules[at].children.contains(first) {
                    return None;
                }
            }
            None => return None,
        }
        base.extend(rest.iter().cloned());
        Some(base)
    }

    /// The file that defines the item at absolute `path`.
    fn file_of(&self, path: &[String], depth: usize) -> Option<&Path> {
        if depth > 32 {
            return None;
        }
        // The longest prefix that is a module.
        let mut split = path.len();
        while !self.modules.contains_key(&path[..split]) {
            split -= 1;
        }
        let module = &self.modules[&path[..split]];
        let Some(name) = path.get(split) else {
            return Some(&module.file);
        };
        if module.defs.contains(name) {
            return Some(&module.file);
        }
        if let Some(target) = module.uses.get(name) {
            let at = &path[..split];
            return match self.absolute(at, target) {
                Some(mut abs) => {
                    abs.extend(path[split + 1..].iter().cloned());
                    self.file_of(&abs, depth + 1)
                }
                None => None, // re-exported from another crate
            };
        }
        for glob in &module.globs {
            if let Some(mut abs) = self.absolute(&path[..split], glob) {
                abs.extend(path[split..].iter().cloned());
                if let Some(f) = self.defining_file(&abs, depth + 1) {
                    return Some(f);
                }
            }
        }
        Some(&module.file)
    }

    /// Like [`Resolver::file_of`], but only where a definition is found.
    fn defining_file(&self, path: &[String], depth: usize) -> Option<&Path> {
        let mut split = path.len();
        while !self.modules.contains_key(&path[..split]) {
            split -= 1;
        }
        let name = path.get(split)?;
        let module = &self.modules[&path[..split]];
        if module.defs.contains(name) || module.uses.contains_key(name) {
            self.file_of(path, depth)
        } else {
            None
        }
    }
}

/// File → files it depends on, within one crate, with the names that make
/// each dependency.
type Dependencies = BTreeMap<PathBuf, BTreeMap<PathBuf, BTreeSet<String>>>;

/// The dependencies of the files of the crate whose root is `root`.
fn dependencies(root: &Path) -> Dependencies {
    let modules = modules(root);
    let r = Resolver { modules: &modules };
    let mut deps = Dependencies::new();
    for (at, module) in &modules {
        let mut targets: BTreeMap<PathBuf, BTreeSet<String>> = BTreeMap::new();
        let mut named: Vec<Vec<String>> = module.uses.values().cloned().collect();
        named.extend(module.paths.iter().cloned());
        for path in &named {
            if let Some(abs) = r.absolute(at, path) {
                if let Some(f) = r.file_of(&abs, 0) {
                    let name = path.last().cloned().unwrap_or_default();
                    targets.entry(f.to_path_buf()).or_default().insert(name);
                }
            }
        }
        for glob in &module.globs {
            let Some(abs) = r.absolute(at, glob) else {
                continue;
            };
            for name in &module.idents {
                if module.defs.contains(name) || module.uses.contains_key(name) {
                    continue;
                }
                let mut p = abs.clone();
                p.push(name.clone());
                if let Some(f) = r.defining_file(&p, 0) {
                    targets
                        .entry(f.to_path_buf())
                        .or_default()
                        .insert(name.clone());
                }
            }
        }
        // Declaring a child module is no dependency on it.
        targets.remove(&module.file);
        deps.insert(module.file.clone(), targets);
    }
    deps
}

/// The cycles of a graph: its strongly connected components of more than
/// one file (Tarjan's algorithm).
fn cycles(deps: &Dependencies) -> Vec<Vec<PathBuf>> {
    struct State<'g> {
        deps: &'g Dependencies,
        index: BTreeMap<&'g Path, usize>,
        low: BTreeMap<&'g Path, usize>,
        stack: Vec<&'g Path>,
        on_stack: BTreeSet<&'g Path>,
        out: Vec<Vec<PathBuf>>,
    }
    fn visit<'g>(s: &mut State<'g>, v: &'g Path) {
        let i = s.index.len();
        s.index.insert(v, i);
        s.low.insert(v, i);
        s.stack.push(v);
        s.on_stack.insert(v);
        for w in s.deps.get(v).into_iter().flat_map(|t| t.keys()) {
            let w = w.as_path();
            if !s.deps.contains_key(w) {
                continue;
            }
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.push(w.to_path_buf());
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                component.sort();
                s.out.push(component);
            }
        }
    }
    let mut s = State {
        deps,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in deps.keys() {
        if !s.index.contains_key(v.as_path()) {
            visit(&mut s, v);
        }
    }
    s.out
}

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn no_two_files_of_a_crate_depend_on_each_other() {
    let ws = workspace();
    let mut found = Vec::new();
    for root in ROOTS {
        let deps = dependencies(&ws.join(root));
        assert!(!deps.is_empty(), "{root}: no source files found");
        let rel = |p: &Path| p.strip_prefix(&ws).unwrap_or(p).display().to_string();
        for cycle in cycles(&deps) {
            let mut text = cycle.iter().map(|p| rel(p)).collect::<Vec<_>>().join(" ↔ ");
            for a in &cycle {
                for (b, names) in &deps[a] {
                    if cycle.contains(b) {
                        let names: Vec<&str> = names.iter().map(String::as_str).collect();
                        text += &format!("\n    {} uses {}: {}", rel(a), rel(b), names.join(", "));
                    }
                }
            }
            found.push(text);
        }
    }
    assert!(
        found.is_empty(),
        "files that depend on each other (move what both need into a file below them):\n{}",
        found.join("\n")
    );
}

/// The check finds a cycle through a re-export and a glob import, and
/// none where a file only declares the other as its child module.
#[test]
fn the_check_sees_cycles_through_re_exports_and_globs() {
    let dir = std::env::temp_dir().join(format!("latentam-file-cycles-{}", std::process::id()));
    let src = dir.join("src");
    std::fs::create_dir_all(src.join("frames")).unwrap();
    let write = |p: &str, text: &str| std::fs::write(src.join(p), text).unwrap();
    write("lib.rs", "mod frames;\nmod plan;\npub use plan::Choice;\n");
    write(
        "frames/mod.rs",
        "mod config;\npub use config::Config;\n#[cfg(test)]\nmod tests { use crate::plan::*; }\n",
    );
    write(
        "frames/config.rs",
        "use super::*;\npub struct Config { pub choose: crate::Choice }\n",
    );
    write(
        "plan.rs",
        "use super::frames::Config;\npub struct Choice;\npub fn plan(_: &Config) {}\n",
    );
    let deps = dependencies(&src.join("lib.rs"));
    let found = cycles(&deps);
    let names: Vec<Vec<String>> = found
        .iter()
        .map(|c| {
            c.iter()
                .map(|p| p.strip_prefix(&src).unwrap().display().to_string())
                .collect()
        })
        .collect();
    assert_eq!(
        names,
        vec![vec!["frames/config.rs".to_string(), "plan.rs".to_string()]]
    );

    // The same files with the shared type moved below both: no cycle.
    write(
        "lib.rs",
        "mod choice;\nmod frames;\nmod plan;\npub use choice::Choice;\n",
    );
    write("choice.rs", "pub struct Choice;\n");
    write(
        "plan.rs",
        "use super::frames::Config;\npub fn plan(_: &Config) {}\n",
    );
    assert!(cycles(&dependencies(&src.join("lib.rs"))).is_empty());
    std::fs::remove_dir_all(&dir).ok();
}

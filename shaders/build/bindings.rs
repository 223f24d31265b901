//! Typed kernel bindings: for every set of storage buffers some kernels
//! bind (the same names, in the same order, with the same push-constant
//! type), a struct with one named field per buffer, so a dispatch names
//! each buffer it binds and a swapped, missing or extra buffer does not
//! compile; and for a file that declares `// @select KEY ...`, a variant
//! selector from those keys' flags that always names a declared variant.

use super::*;

/// Rust keywords a binding name could collide with.
const KEYWORDS: &[&str] = &[
    "as", "break", "const", "continue", "crate", "else", "enum", "extern", "false", "fn", "for",
    "if", "impl", "in", "let", "loop", "match", "mod", "move", "mut", "pub", "ref", "return",
    "self", "static", "struct", "super", "trait", "true", "type", "unsafe", "use", "where",
    "while", "async", "await", "dyn", "abstract", "become", "box", "do", "final", "macro",
    "override", "priv", "typeof", "unsized", "virtual", "yield", "try", "gen",
];

/// `BestValue` → `best_value`, `L1Partial` → `l1_partial`, `keys_in`
/// stays: the binding's name as a Rust field.
pub(crate) fn snake(name: &str) -> String {
    let mut out = String::new();
    let chars: Vec<char> = name.chars().collect();
    for (i, &c) in chars.iter().enumerate() {
        if c.is_ascii_uppercase() {
            let prev = i.checked_sub(1).map(|j| chars[j]);
            let next = chars.get(i + 1).copied();
            let boundary = match prev {
                Some(p) if p.is_ascii_lowercase() || p.is_ascii_digit() => true,
                Some(p) if p.is_ascii_uppercase() => next.is_some_and(|n| n.is_ascii_lowercase()),
                _ => false,
            };
            if boundary && !out.ends_with('_') {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
        } else {
            out.push(c);
        }
    }
    if KEYWORDS.contains(&out.as_str()) {
        format!("r#{out}")
    } else {
        out
    }
}

/// The binding set of each kernel: its type name in `bind`, shared by the
/// kernels with the same push-constant type and buffers.
pub(crate) fn binding_set_names(
    kernels: &[KernelOut],
    push_names: &[Option<String>],
) -> Vec<String> {
    let same = |i: usize, j: usize| {
        push_names[i] == push_names[j] && kernels[i].bindings == kernels[j].bindings
    };
    (0..kernels.len())
        .map(|i| {
            // One layout per push type: the set takes its name; else the
            // first kernel of the set names it.
            let push_shared = (0..kernels.len())
                .filter(|&j| push_names[j].is_some() && push_names[j] == push_names[i])
                .all(|j| same(i, j));
            match &push_names[i] {
                Some(p) if push_shared => p.clone(),
                _ => {
                    let first = (0..kernels.len()).find(|&j| same(i, j)).unwrap_or(i);
                    camel(&kernels[first].name)
                }
            }
        })
        .collect()
}

/// `pub mod bind`: the binding sets.
pub(crate) fn generate_bind(kernels: &[KernelOut], set_names: &[String]) -> String {
    let mut s = String::new();
    s.push_str(
        "/// The storage buffers each kernel binds, by name: a dispatch fills one\n\
         /// of the `…Buffers` structs, so a buffer cannot be swapped, left out or\n\
         /// added. `B` is the engine's buffer type.\npub mod bind {\n",
    );
    let mut written = std::collections::BTreeSet::new();
    for (i, k) in kernels.iter().enumerate() {
        let name = &set_names[i];
        if !written.insert(name.clone()) {
            continue;
        }
        let users: Vec<String> = kernels
            .iter()
            .zip(set_names)
            .filter(|(_, n)| *n == name)
            .map(|(o, _)| format!("`{}`", o.name))
            .collect();
        let _ = writeln!(
            s,
            "    /// The buffers of {} ({}).\n    #[derive(Clone, Copy, Debug)]\n    pub struct {name};\n",
            users.join(", "),
            k.source
        );
        let _ = writeln!(
            s,
            "    /// The buffers [`{name}`]'s kernels bind, in binding order.\n    #[derive(Clone, Copy, Debug)]\n    pub struct {name}Buffers<'a, B> {{"
        );
        for (b, writable) in &k.bindings {
            let access = if *writable {
                "read and written"
            } else {
                "read"
            };
            let _ = writeln!(
                s,
                "        /// `{b}` ({access}).\n        pub {}: &'a B,",
                snake(b)
            );
        }
        s.push_str("    }\n\n");
        let fields: Vec<String> = k
            .bindings
            .iter()
            .map(|(b, _)| format!("b.{}", snake(b)))
            .collect();
        let _ = writeln!(
            s,
            "    impl super::BindingSet for {name} {{\n        type Buffers<'a, B: 'a> = {name}Buffers<'a, B>;\n        const COUNT: usize = {};\n        fn in_order<'a, B: 'a>(b: &{name}Buffers<'a, B>) -> Vec<&'a B> {{\n            vec![{}]\n        }}\n    }}\n",
            k.bindings.len(),
            fields.join(", ")
        );
    }
    s.push_str("}\n\n");
    s
}

/// One variant selector per file with a `// @select KEY ...` directive.
pub(crate) fn generate_selectors(
    kernels: &[KernelOut],
    push_names: &[Option<String>],
    set_names: &[String],
) -> Result<String, String> {
    let mut s = String::new();
    let mut done = std::collections::BTreeSet::new();
    for k in kernels {
        let Some(keys) = &k.select else { continue };
        if !done.insert(k.source.clone()) {
            continue;
        }
        let members: Vec<usize> = (0..kernels.len())
            .filter(|&i| kernels[i].source == k.source)
            .collect();
        let first = members[0];
        for &i in &members {
            if push_names[i] != push_names[first] || set_names[i] != set_names[first] {
                return Err(format!(
                    "{}: `@select` needs every variant to share its push constants and buffers \
                     (`{}` and `{}` differ)",
                    k.source, kernels[first].name, kernels[i].name
                ));
            }
        }
        let arms = selector_arms(kernels, &members, keys, &k.source)?;
        let stem = k.source.rsplit('/').next().unwrap_or(&k.source);
        let ty = format!("{}Variant", camel(stem.split('.').next().unwrap_or(stem)));
        let push_ty = match &push_names[first] {
            Some(p) => format!("push::{p}"),
            None => "()".to_string(),
        };
        let set = &set_names[first];
        let _ = writeln!(
            s,
            "/// Picks the variant of `{}` for a device and a job: every\n/// combination of the flags names one declared kernel.\n#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]\npub struct {ty} {{",
            k.source
        );
        for key in keys {
            let _ = writeln!(
                s,
                "    /// The `{key}` key of the `@kernel` lines.\n    pub {}: bool,",
                snake(&key.to_ascii_lowercase())
            );
        }
        let fields: Vec<String> = keys
            .iter()
            .map(|key| format!("self.{}", snake(&key.to_ascii_lowercase())))
            .collect();
        let _ = writeln!(
            s,
            "}}\n\nimpl {ty} {{\n    /// The kernel these flags select.\n    pub fn kernel(self) -> &'static KernelDef<{push_ty}, bind::{set}> {{\n        match ({}) {{\n{arms}        }}\n    }}\n}}\n",
            fields.join(", ")
        );
    }
    Ok(s)
}

/// The match arms of a selector: for every combination of the keys'
/// flags, the one variant it names (a variant matches when every key it
/// defines has that value; a key it leaves out matches both), or an error
/// when a combination names none or several.
fn selector_arms(
    kernels: &[KernelOut],
    members: &[usize],
    keys: &[String],
    source: &str,
) -> Result<String, String> {
    // Each variant matches a combination of the keys' flags when every
    // key it defines has that value; a key it leaves out matches both.
    let value = |i: usize, key: &str| -> Result<Option<bool>, String> {
        match kernels[i].defines.iter().find(|(k, _)| k == key) {
            None => Ok(None),
            Some((_, v)) if v == "0" => Ok(Some(false)),
            Some((_, v)) if v == "1" => Ok(Some(true)),
            Some((_, v)) => Err(format!(
                "{}: `@select` key {key} of `{}` is {v}, not 0 or 1",
                source, kernels[i].name
            )),
        }
    };
    let mut arms = String::new();
    for combo in 0..(1u32 << keys.len()) {
        let flags: Vec<bool> = (0..keys.len()).map(|b| combo >> b & 1 == 1).collect();
        let mut matching = Vec::new();
        for &i in members {
            let mut all = true;
            for (key, &f) in keys.iter().zip(&flags) {
                if value(i, key)?.is_some_and(|v| v != f) {
                    all = false;
                }
            }
            if all {
                matching.push(i);
            }
        }
        let described: Vec<String> = keys
            .iter()
            .zip(&flags)
            .map(|(k, f)| format!("{k}={}", *f as u8))
            .collect();
        let i = match matching.as_slice() {
            [i] => *i,
            [] => {
                return Err(format!(
                    "{}: `@select` has no variant for {}",
                    source,
                    described.join(" ")
                ))
            }
            many => {
                let names: Vec<&str> = many.iter().map(|&i| kernels[i].name.as_str()).collect();
                return Err(format!(
                    "{}: `@select` {} matches several variants: {}",
                    source,
                    described.join(" "),
                    names.join(", ")
                ));
            }
        };
        let pattern: Vec<String> = flags.iter().map(|f| f.to_string()).collect();
        let _ = writeln!(
            arms,
            "            ({}) => &{},",
            pattern.join(", "),
            kernels[i].name.to_ascii_uppercase()
        );
    }
    Ok(arms)
}

//! `// @cost` directives: the work one dispatch of a kernel does, as
//! arithmetic operations and bytes of global memory, counted from its
//! launch (push constants and workgroup counts). The build turns each
//! expression into a Rust function of the push-constant bytes, so a
//! profile can state how far a measured time is from what a GPU's peak
//! rate and bandwidth allow (`latentam_gpu::GpuModel`).
//!
//! ```text
//! // @cost flops=EXPR bytes=EXPR          every kernel of the file
//! // @cost NAME: flops=EXPR bytes=EXPR    one kernel (a variant or entry point)
//! // @cost caller                         the dispatching code states the work
//! // @cost NAME: caller
//! ```
//!
//! EXPR is arithmetic in f64 over numbers, the kernel's scalar
//! push-constant fields by name, `groups` (workgroups launched) and
//! `invocations` (groups × workgroup size), with `+ - * / ( )`, `min(a, b)`
//! and `max(a, b)`. Anything else fails the build, as does a kernel
//! without a cost: every kernel declares how its work is counted.

use super::*;

/// How a kernel's work is counted.
#[derive(Clone, Debug)]
pub(crate) enum CostDecl {
    /// Rust expressions (already translated) for the flops and the bytes,
    /// and whether they read the workgroup counts.
    Launch {
        flops: String,
        bytes: String,
        fields: Vec<String>,
        uses_groups: bool,
    },
    /// The work depends on data the launch does not show; the dispatching
    /// code states it.
    Caller,
}

/// Gives each kernel of one file its cost from the file's `@cost` lines.
pub(crate) fn assign_costs(raw: &str, file: &str, kernels: &mut [KernelOut]) -> Result<(), String> {
    let mut general: Option<&str> = None;
    let mut named: BTreeMap<&str, &str> = BTreeMap::new();
    for d in directives(raw, "cost") {
        let (name, rest) = match d.split_once(':') {
            Some((n, r)) if !n.contains('=') => (Some(n.trim()), r.trim()),
            _ => (None, d),
        };
        match name {
            None if general.replace(rest).is_some() => {
                return Err(format!(
                    "{file}: more than one `@cost` line for the whole file"
                ));
            }
            None => {}
            Some(n) => {
                if !kernels.iter().any(|k| k.name == n) {
                    return Err(format!("{file}: `@cost {n}:` names no kernel of the file"));
                }
                if named.insert(n, rest).is_some() {
                    return Err(format!("{file}: two `@cost` lines for kernel `{n}`"));
                }
            }
        }
    }
    for k in kernels.iter_mut() {
        let Some(text) = named.get(k.name.as_str()).copied().or(general) else {
            return Err(format!(
                "{file}: kernel `{}` has no `// @cost` line (flops=EXPR bytes=EXPR, or caller)",
                k.name
            ));
        };
        k.cost = Some(
            parse_cost(text, k.push.as_ref())
                .map_err(|e| format!("{file}: `@cost` of kernel `{}`: {e}", k.name))?,
        );
    }
    Ok(())
}

fn parse_cost(text: &str, push: Option<&PushStruct>) -> Result<CostDecl, String> {
    if text == "caller" {
        return Ok(CostDecl::Caller);
    }
    let rest = text
        .strip_prefix("flops=")
        .ok_or("expected `flops=EXPR bytes=EXPR` or `caller`")?;
    let (flops, bytes) = rest
        .split_once("bytes=")
        .ok_or("expected `bytes=EXPR` after the flops")?;
    let scalars: Vec<&str> = push
        .map(|p| {
            p.fields
                .iter()
                .filter(|(_, ty, _, _)| matches!(ty.as_str(), "u32" | "i32" | "f32"))
                .map(|(n, _, _, _)| n.as_str())
                .collect()
        })
        .unwrap_or_default();
    let mut fields = Vec::new();
    let mut uses_groups = false;
    let mut translate = |e: &str| -> Result<String, String> {
        let tokens = tokens(e)?;
        check_syntax(&tokens)?;
        let mut out = String::new();
        for t in &tokens {
            match t {
                Token::Number(n) => {
                    let v: f64 = n.parse().map_err(|_| format!("`{n}` is not a number"))?;
                    let _ = write!(out, "{v:?}_f64");
                }
                Token::Ident(i) if i == "min" || i == "max" => {
                    let _ = write!(out, "f64::{i}");
                }
                Token::Ident(i) if i == "groups" || i == "invocations" => {
                    uses_groups = true;
                    out.push_str(i);
                }
                Token::Ident(i) if scalars.contains(&i.as_str()) => {
                    if !fields.contains(i) {
                        fields.push(i.clone());
                    }
                    let _ = write!(out, "f_{i}");
                }
                Token::Ident(i) => {
                    return Err(format!(
                        "`{i}` is not a scalar push-constant field ({}), `groups`, \
                         `invocations`, `min` or `max`",
                        scalars.join(", ")
                    ))
                }
                Token::Op(c) => {
                    out.push(*c);
                    if *c == ',' {
                        out.push(' ');
                    }
                }
            }
        }
        Ok(out)
    };
    let flops = translate(flops.trim())?;
    let bytes = translate(bytes.trim())?;
    Ok(CostDecl::Launch {
        flops,
        bytes,
        fields,
        uses_groups,
    })
}

#[derive(Debug, PartialEq)]
enum Token {
    Number(String),
    Ident(String),
    Op(char),
}

fn tokens(e: &str) -> Result<Vec<Token>, String> {
    let mut out = Vec::new();
    let mut chars = e.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_whitespace() {
            chars.next();
        } else if c.is_ascii_digit() || c == '.' {
            let mut s = String::new();
            while let Some(&d) = chars.peek().filter(|d| d.is_ascii_digit() || **d == '.') {
                s.push(d);
                chars.next();
            }
            out.push(Token::Number(s));
        } else if c.is_ascii_alphabetic() || c == '_' {
            let mut s = String::new();
            while let Some(&d) = chars
                .peek()
                .filter(|d| d.is_ascii_alphanumeric() || **d == '_')
            {
                s.push(d);
                chars.next();
            }
            out.push(Token::Ident(s));
        } else if "+-*/(),".contains(c) {
            out.push(Token::Op(c));
            chars.next();
        } else {
            return Err(format!("unexpected `{c}` in `{e}`"));
        }
    }
    if out.is_empty() {
        return Err("empty expression".into());
    }
    Ok(out)
}

/// Refuses what is not an expression of the grammar (the Rust compiler
/// would too, but with an error far from the kernel's line): operands and
/// operators alternate, parentheses balance, and `min`/`max` are calls.
fn check_syntax(tokens: &[Token]) -> Result<(), String> {
    let mut depth = 0i32;
    let mut want_operand = true;
    for (i, t) in tokens.iter().enumerate() {
        match t {
            Token::Number(_) | Token::Ident(_) if want_operand => {
                if let Token::Ident(f) = t {
                    let call = matches!(f.as_str(), "min" | "max");
                    let next_is_paren = tokens.get(i + 1) == Some(&Token::Op('('));
                    if call != next_is_paren {
                        return Err(format!(
                            "`{f}` must be `min(a, b)` or `max(a, b)`, or a name"
                        ));
                    }
                    if call {
                        continue;
                    }
                }
                want_operand = false;
            }
            Token::Op('(') if want_operand => depth += 1,
            Token::Op('-') if want_operand => {}
            Token::Op(')') if !want_operand && depth > 0 => depth -= 1,
            Token::Op('+' | '-' | '*' | '/' | ',') if !want_operand => want_operand = true,
            _ => return Err(format!("unexpected {t:?}")),
        }
    }
    if want_operand || depth != 0 {
        return Err("incomplete expression".into());
    }
    Ok(())
}

/// The function that counts one dispatch's work of kernel `k`, and the
/// `WorkCount` expression the kernel table stores.
pub(crate) fn work_count(k: &KernelOut, push_ty: &str) -> (String, String) {
    let Some(CostDecl::Launch {
        flops,
        bytes,
        fields,
        uses_groups,
    }) = &k.cost
    else {
        return (String::new(), "WorkCount::Caller".to_string());
    };
    let fname = format!("{}_work", k.name);
    let mut f = String::new();
    let _ = writeln!(
        f,
        "/// Work of one dispatch of `{}` (its `@cost` line).\n#[allow(clippy::all)]\nfn {fname}(push: &[u8], groups: Option<[u32; 3]>) -> Option<Work> {{",
        k.name
    );
    if k.push.is_some() {
        let _ = writeln!(
            f,
            "    if push.len() != std::mem::size_of::<{push_ty}>() {{\n        return None;\n    }}"
        );
    } else {
        f.push_str("    let _ = push;\n");
    }
    if !fields.is_empty() {
        let _ = writeln!(
            f,
            "    let p: {push_ty} = bytemuck::pod_read_unaligned(push);"
        );
        for field in fields {
            let _ = writeln!(f, "    let f_{field} = p.{field} as f64;");
        }
    }
    if *uses_groups {
        let wg = k.workgroup[0] as u64 * k.workgroup[1] as u64 * k.workgroup[2] as u64;
        let _ = writeln!(
            f,
            "    let groups = groups.map(|[x, y, z]| x as f64 * y as f64 * z as f64)?;\n    #[allow(unused_variables)]\n    let invocations = groups * {wg}_f64;"
        );
    } else {
        f.push_str("    let _ = groups;\n");
    }
    let _ = writeln!(
        f,
        "    Some(Work {{ flops: {flops}, bytes: {bytes} }})\n}}\n"
    );
    (f, format!("WorkCount::Launch({fname})"))
}

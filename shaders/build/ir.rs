//! What is read from and fixed in naga's IR: the device features a kernel
//! uses, the `barrier()` scope fix-up, and the shared structs' layouts
//! checked against the kernels'.

use super::*;

/// What a kernel needs of the device, read from its IR (not from the
/// file's `@capabilities`, which covers all its variants).
#[derive(Clone, Copy, Default)]
pub(crate) struct Requires {
    pub(crate) float_atomics: bool,
    pub(crate) subgroup_arithmetic: bool,
    pub(crate) subgroup_shuffle: bool,
}

pub(crate) fn requires(module: &naga::Module, entry: &str) -> Requires {
    // Only code the entry point reaches: a file's helpers for other
    // variants are compiled into every module.
    fn walk(
        module: &naga::Module,
        block: &naga::Block,
        r: &mut Requires,
        seen: &mut Vec<naga::Handle<naga::Function>>,
    ) {
        for stmt in block.iter() {
            match stmt {
                naga::Statement::SubgroupCollectiveOperation { .. }
                | naga::Statement::SubgroupBallot { .. } => r.subgroup_arithmetic = true,
                naga::Statement::SubgroupGather { .. } => r.subgroup_shuffle = true,
                naga::Statement::Call { function, .. } if !seen.contains(function) => {
                    seen.push(*function);
                    walk(module, &module.functions[*function].body, r, seen);
                }
                naga::Statement::Block(b) => walk(module, b, r, seen),
                naga::Statement::If { accept, reject, .. } => {
                    walk(module, accept, r, seen);
                    walk(module, reject, r, seen);
                }
                naga::Statement::Switch { cases, .. } => {
                    cases.iter().for_each(|c| walk(module, &c.body, r, seen))
                }
                naga::Statement::Loop {
                    body, continuing, ..
                } => {
                    walk(module, body, r, seen);
                    walk(module, continuing, r, seen);
                }
                _ => {}
            }
        }
    }
    let mut r = Requires {
        float_atomics: module.types.iter().any(|(_, t)| {
            matches!(t.inner, naga::TypeInner::Atomic(s) if s.kind == naga::ScalarKind::Float)
        }),
        ..Requires::default()
    };
    if let Some(ep) = module.entry_points.iter().find(|e| e.name == entry) {
        walk(module, &ep.function.body, &mut r, &mut Vec::new());
    }
    r
}

/// Byte offsets of a shared struct's fields and its size, as `layouts.rs`
/// lays them out.
pub(crate) fn shared_layout(st: &layouts::Struct) -> (Vec<u32>, u32) {
    let mut offsets = Vec::new();
    let mut at = 0;
    for f in st.fields {
        offsets.push(at);
        at += match f.ty {
            layouts::FieldType::Vec4 | layouts::FieldType::UVec4 => 16,
            layouts::FieldType::F32 | layouts::FieldType::U32 => 4,
        };
    }
    (offsets, at)
}

/// See the module comment: `barrier()` must synchronise the whole workgroup.
pub(crate) fn fix_glsl_barriers(module: &mut naga::Module) {
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

/// Every struct named like one of `layouts.rs` must be laid out as it is
/// there (a kernel declaring its own `View`, say, would silently disagree
/// with the host).
pub(crate) fn check_shared_structs(
    module: &naga::Module,
    layouter: &naga::proc::Layouter,
    what: &str,
) -> Result<(), String> {
    for (handle, ty) in module.types.iter() {
        let Some(st) = layouts::STRUCTS
            .iter()
            .find(|st| ty.name.as_deref() == Some(st.name))
        else {
            continue;
        };
        let naga::TypeInner::Struct { members, .. } = &ty.inner else {
            continue;
        };
        let (offsets, size) = shared_layout(st);
        let got: Vec<u32> = members.iter().map(|m| m.offset).collect();
        let names_agree = members
            .iter()
            .zip(st.fields)
            .all(|(m, f)| m.name.as_deref() == Some(f.name));
        if got != offsets || layouter[handle].size != size || !names_agree {
            return Err(format!(
                "{what}: struct `{}` is laid out as offsets {got:?}, size {}, but \
                 shaders/layouts.rs has offsets {offsets:?}, size {size}: include \
                 \"shared.glsl\" / \"shared.wgsl\" instead of declaring it",
                st.name, layouter[handle].size
            ));
        }
    }
    Ok(())
}

pub(crate) fn type_name(module: &naga::Module, ty: naga::Handle<naga::Type>) -> Option<String> {
    module.types[ty].name.clone()
}

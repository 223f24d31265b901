//! Validation and the SPIR-V back end: an entry point's storage buffers,
//! push constants and shared memory, its SPIR-V, and the kernel record.

use super::*;

/// The storage buffers (name, written) the entry point `entry` uses, in
/// binding order, its push-constant struct and its shared memory in
/// bytes. One binding convention: set 0, binding i = storage buffer i,
/// numbered without gaps.
#[allow(clippy::type_complexity)]
fn resources(
    module: &naga::Module,
    info: &naga::valid::ModuleInfo,
    entry: &str,
    what: &str,
) -> Result<(Vec<(String, bool)>, Option<PushStruct>, u32), String> {
    let mut bindings: BTreeMap<u32, (String, bool)> = BTreeMap::new();
    let mut push = None;
    let mut shared_bytes = 0u32;
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .map_err(|e| format!("{what}: layout: {e}"))?;
    check_shared_structs(module, &layouter, what)?;
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
                    .or_else(|| type_name(module, var.ty))
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
                push = Some(push_struct(module, &layouter, var.ty, what)?);
            }
            naga::AddressSpace::WorkGroup => shared_bytes += layouter[var.ty].size,
            naga::AddressSpace::Private | naga::AddressSpace::Function => {}
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

    Ok((bindings.into_values().collect(), push, shared_bytes))
}

/// The SPIR-V of entry point `entry`.
fn spirv(
    module: &naga::Module,
    info: &naga::valid::ModuleInfo,
    entry: &str,
    what: &str,
) -> Result<Vec<u32>, String> {
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
    naga::back::spv::write_vec(module, info, &options, Some(&pipeline))
        .map_err(|e| format!("{what}: SPIR-V output failed: {e}"))
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn finish(
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

    let (bindings, push, shared_bytes) = resources(&module, &info, entry, what)?;
    let requires = requires(&module, entry);
    let spirv = spirv(&module, &info, entry, what)?;

    Ok(KernelOut {
        name,
        source,
        spirv,
        workgroup: ep.workgroup_size,
        shared_bytes,
        bindings,
        push,
        push_group: None,
        requires,
        defines: Vec::new(),
        select: None,
        cost: None,
    })
}

//! Checks on the emitted SPIR-V itself.

use super::*;

const OP_CONSTANT: u32 = 43;
const OP_CONTROL_BARRIER: u32 = 224;
const SCOPE_WORKGROUP: u32 = 2;

/// (execution scope) of every OpControlBarrier in a module.
fn control_barrier_scopes(words: &[u32]) -> Vec<u32> {
    let mut constants = std::collections::HashMap::new();
    let mut barrier_ids = Vec::new();
    let mut i = 5; // header
    while i < words.len() {
        let op = words[i] & 0xffff;
        let len = (words[i] >> 16) as usize;
        assert!(len > 0, "malformed SPIR-V");
        if op == OP_CONSTANT && len == 4 {
            constants.insert(words[i + 2], words[i + 3]);
        }
        if op == OP_CONTROL_BARRIER {
            barrier_ids.push(words[i + 1]);
        }
        i += len;
    }
    barrier_ids
        .iter()
        .map(|id| *constants.get(id).expect("barrier scope is not a constant"))
        .collect()
}

#[test]
fn every_barrier_synchronises_the_whole_workgroup() {
    let mut checked = 0;
    for k in ALL {
        for scope in control_barrier_scopes(k.spirv) {
            assert_eq!(
                scope, SCOPE_WORKGROUP,
                "kernel {} has a narrower barrier",
                k.name
            );
            checked += 1;
        }
    }
    assert!(
        checked > 0,
        "no kernel has a barrier, so the fix-up was not exercised"
    );
}

#[test]
fn spirv_is_version_1_3() {
    for k in ALL {
        assert_eq!(k.spirv[0], 0x0723_0203, "{}: not SPIR-V", k.name);
        assert_eq!(k.spirv[1], 0x0001_0300, "{}: not SPIR-V 1.3", k.name);
    }
}

#[test]
fn table_describes_bindings_and_push_constants() {
    assert_eq!(GEMM_NN.kernel.bindings.len(), 3);
    assert!(!GEMM_NN.kernel.bindings[0].writable);
    assert!(GEMM_NN.kernel.bindings[2].writable);
    assert_eq!(
        GEMM_NN.kernel.push_constant_size as usize,
        std::mem::size_of::<push::Gemm>()
    );
    assert_eq!(GEMM_NN.kernel.workgroup, [16, 16, 1]);
    assert_eq!(RADIX_SCATTER.kernel.entry_point(), "radix_scatter");
    for k in ALL {
        assert_eq!(k.push_constant_size % 4, 0, "{}", k.name);
    }
}

#[test]
fn each_variant_requires_only_what_its_code_uses() {
    let none = Requires::default();
    assert_eq!(
        RASTER_BACKWARD.kernel.requires,
        Requires {
            float_atomics: true,
            subgroup_arithmetic: true,
            subgroup_shuffle: false
        }
    );
    assert_eq!(RASTER_BACKWARD_PLAIN_CAS.kernel.requires, none);
    assert!(ATOMIC_ADD_F32.kernel.requires.float_atomics);
    assert_eq!(ATOMIC_ADD_F32_CAS.kernel.requires, none);
    assert!(RASTER_BACKWARD_COLUMNS_CAS.kernel.requires.subgroup_shuffle);
    assert!(!RASTER_BACKWARD_COLUMNS_CAS.kernel.requires.float_atomics);
    assert_eq!(GEMM_NN.kernel.requires, none);
}

#[test]
fn variants_with_one_push_layout_share_one_type() {
    // Typed dispatch of every GEMM variant with one `push::Gemm` value:
    // this compiles only if the build gave them one type.
    let defs: [&KernelDef<push::Gemm>; 4] = [
        &GEMM_NN,
        &GEMM_TN,
        &GEMM_BLOCKED_NT,
        &GEMM_BLOCKED_NN_SCALAR,
    ];
    assert!(defs
        .iter()
        .all(|d| d.kernel.push_constant_size as usize == std::mem::size_of::<push::Gemm>()));
    let _: [&KernelDef<push::RasterBackward>; 2] = [
        &RASTER_BACKWARD,
        &RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN_CAS,
    ];
}

#[test]
fn shared_structs_have_the_std430_size() {
    assert_eq!(std::mem::size_of::<shared::View>(), 128);
    assert_eq!(std::mem::align_of::<shared::View>(), 4);
}

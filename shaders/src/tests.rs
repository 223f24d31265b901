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
    let defs: [&KernelDef<push::Gemm, bind::Gemm>; 4] = [
        &GEMM_NN,
        &GEMM_TN,
        &GEMM_BLOCKED_NT,
        &GEMM_BLOCKED_NN_SCALAR,
    ];
    assert!(defs
        .iter()
        .all(|d| d.kernel.push_constant_size as usize == std::mem::size_of::<push::Gemm>()));
    let _: [&KernelDef<push::RasterBackward, bind::RasterBackward>; 2] = [
        &RASTER_BACKWARD,
        &RASTER_BACKWARD_COLUMNS_ATTACHED_PLAIN_CAS,
    ];
}

/// The named buffers go to the bindings of those names, in binding order,
/// for WGSL kernels (snake_case names) and GLSL ones (block names).
#[test]
fn named_buffers_are_bound_in_binding_order() {
    let names = |k: &Kernel| -> Vec<&'static str> { k.bindings.iter().map(|b| b.name).collect() };
    let b = bind::RasterPoolBuffers {
        views: &"views",
        queries: &"queries",
        splats: &"splats",
        pairs: &"pairs",
        ranges: &"ranges",
        state: &"state",
        labels: &"labels",
        pooled: &"pooled",
    };
    let got: Vec<&str> = bind::RasterPool::in_order(&b)
        .into_iter()
        .copied()
        .collect();
    assert_eq!(got, names(&RASTER_POOL_CAS.kernel));

    let b = bind::KmeansFirstAssignBuffers {
        unit: &"Unit",
        centre_unit: &"CentreUnit",
        sims: &"Sims",
        replaced: &"Replaced",
        gate: &"Gate",
        best_value: &"BestValue",
        best_index: &"BestIndex",
        row_complete: &"RowComplete",
    };
    let got: Vec<&str> = bind::KmeansFirstAssign::in_order(&b)
        .into_iter()
        .copied()
        .collect();
    assert_eq!(got, names(&KMEANS_FIRST_ASSIGN.kernel));
    assert_eq!(bind::KmeansFirstAssign::COUNT, got.len());
}

/// Every combination of a selector's flags names the variant the kernel
/// file's naming says it should (stated here independently of the
/// generated match).
#[test]
fn selectors_name_the_declared_variant_for_every_combination() {
    for bits in 0..16u32 {
        let [columns, attached, subgroup, cas] = [0, 1, 2, 3].map(|i| bits >> i & 1 == 1);
        let v = RasterBackwardVariant {
            columns,
            attached,
            subgroup,
            cas,
        };
        let mut want = String::from("raster_backward");
        if columns {
            want += "_columns";
            if attached {
                want += "_attached";
            }
        }
        if !subgroup {
            want += "_plain";
        }
        if cas {
            want += "_cas";
        }
        assert_eq!(v.kernel().kernel.name, want, "{v:?}");
    }
    for bits in 0..8u32 {
        let [columns, subgroup, cas] = [0, 1, 2].map(|i| bits >> i & 1 == 1);
        let v = RasterPoolVariant {
            columns,
            subgroup,
            cas,
        };
        let mut want = String::from("raster_pool");
        if columns {
            // The column kernel sums without subgroup operations.
            want += "_columns";
        } else if !subgroup {
            want += "_plain";
        }
        if cas {
            want += "_cas";
        }
        assert_eq!(v.kernel().kernel.name, want, "{v:?}");
    }
    for bits in 0..4u32 {
        let [columns, query] = [0, 1].map(|i| bits >> i & 1 == 1);
        let v = RasterForwardVariant { columns, query };
        let want = format!(
            "raster_forward{}{}",
            if columns { "_columns" } else { "" },
            if query { "" } else { "_colour" }
        );
        assert_eq!(v.kernel().kernel.name, want, "{v:?}");
    }
}

#[test]
fn shared_structs_have_the_std430_size() {
    assert_eq!(std::mem::size_of::<shared::View>(), 128);
    assert_eq!(std::mem::align_of::<shared::View>(), 4);
}

/// naga's GLSL front end evaluates both operands of `&&` and `||` (it
/// lowers them to SPIR-V's OpLogicalAnd/Or, not to branches), so a guard
/// such as `i > 0u && keys[i - 1u] != k` still reads `keys[-1]`: an
/// out-of-bounds access a GPU without robust buffer access may fault on.
/// GPU-assisted validation found one; this keeps new ones out of the
/// GLSL kernels. An index after a logical operator is allowed only where
/// it is in bounds whatever the left operand says (listed here).
#[test]
fn no_glsl_condition_guards_an_index_with_a_logical_operator() {
    const IN_BOUNDS_ANYWAY: &[&str] = &[
        // j < micro_count: in bounds on every iteration.
        "novel = novel || best_value[pc.atoms + j] < pc.threshold",
        "own = own && replaced[j] != r",
        // A constant index into a 9-word buffer.
        "row_complete[r] = (r >= pc.atoms || gate[8] != 0u) ? 1u : 0u",
    ];
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../glsl");
    let mut found = Vec::new();
    for entry in std::fs::read_dir(&root).unwrap() {
        let path = entry.unwrap().path();
        let text = std::fs::read_to_string(&path).unwrap();
        let code: String = text
            .lines()
            .map(|l| l.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join(" ");
        for statement in code.split([';', '{', '}']) {
            let statement = statement.split_whitespace().collect::<Vec<_>>().join(" ");
            let Some(at) = statement.find("&&").or_else(|| statement.find("||")) else {
                continue;
            };
            if statement[at..].contains('[')
                && !IN_BOUNDS_ANYWAY.iter().any(|ok| statement.contains(ok))
            {
                found.push(format!("{}: {statement}", path.display()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "split these into nested ifs (naga evaluates both operands):\n{}",
        found.join("\n")
    );
}

/// Every kernel counted from its launch gives a finite, non-negative work
/// for push constants of zeros and of ones (flags off and on, sizes of 1),
/// and nothing for push bytes of the wrong size.
#[test]
fn every_launch_counted_kernel_gives_a_sane_work() {
    let mut counted = 0;
    for k in ALL {
        if matches!(k.work, WorkCount::Caller) {
            continue;
        }
        let words = k.push_constant_size as usize / 4;
        for fill in [0u32, 1] {
            let push: Vec<u8> = std::iter::repeat_n(fill.to_le_bytes(), words)
                .flatten()
                .collect();
            let w = k
                .work_of(&push, Some([1, 1, 1]))
                .unwrap_or_else(|| panic!("kernel {}: no work for its own push size", k.name));
            assert!(
                w.flops.is_finite() && w.bytes.is_finite() && w.flops >= 0.0 && w.bytes >= 0.0,
                "kernel {} with push words of {fill}: {w:?}",
                k.name
            );
        }
        if words > 0 {
            assert_eq!(k.work_of(&[0u8; 3], Some([1, 1, 1])), None, "{}", k.name);
        }
        counted += 1;
    }
    assert!(
        counted > 40,
        "only {counted} kernels counted from their launch"
    );
}

/// The GEMM's count is the product's flops, and its bytes read A and B
/// once and write C (reading C too when beta is not 0).
#[test]
fn gemm_work_is_the_products() {
    for k in [&GEMM_NN.kernel, &GEMM_BLOCKED_TN.kernel] {
        let (m, n, kk) = (48u32, 40u32, 64u32);
        let p = push::Gemm {
            m,
            n,
            k: kk,
            beta: 0.0,
            ..Default::default()
        };
        let w = k.work_of(bytemuck::bytes_of(&p), None).unwrap();
        let (m, n, kk) = (m as f64, n as f64, kk as f64);
        assert_eq!(w.flops, 2.0 * m * n * kk);
        assert_eq!(w.bytes, 4.0 * (m * kk + kk * n + m * n));
        let p = push::Gemm { beta: 1.0, ..p };
        let w = k.work_of(bytemuck::bytes_of(&p), None).unwrap();
        assert_eq!(w.bytes, 4.0 * (m * kk + kk * n + 2.0 * m * n));
    }
}

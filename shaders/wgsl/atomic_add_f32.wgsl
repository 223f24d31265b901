// Scatter-add of f32 values into bins with native float atomics
// (VK_EXT_shader_atomic_float, shaderBufferFloat32AtomicAdd). WGSL because
// naga's GLSL front end has no atomics. The engine picks this kernel or
// atomic_add_f32_cas.wgsl at start-up (engine/gpu/src/features.rs); both are
// tested against engine/reference/src/atomic.rs.
// @capabilities SHADER_FLOAT32_ATOMIC

// @push ScatterAdd
// @cost flops=n bytes=16 * n
// One add per element; value 4 + target 4 read, 8 for the atomic add.
struct Params {
    n: u32,
}

var<immediate> pc: Params;

@group(0) @binding(0) var<storage, read> values: array<f32>;
@group(0) @binding(1) var<storage, read> targets: array<u32>;
@group(0) @binding(2) var<storage, read_write> acc: array<atomic<f32>>;

@compute @workgroup_size(256)
fn atomic_add_f32(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let i = (wid.y * nwg.x + wid.x) * 256u + t;
    if (i < pc.n) {
        atomicAdd(&acc[targets[i]], values[i]);
    }
}

// Scatter-add of f32 values into bins for devices without float atomics: a
// compare-and-swap loop on the bits of the value. WGSL because naga's GLSL
// front end has no atomics. Same interface as atomic_add_f32.wgsl.

// @push ScatterAdd
// @cost flops=n bytes=16 * n
// One add per element; value 4 + target 4 read, 8 for the successful
// compare-and-swap (its first atomicLoad reads the same word; retries
// under contention are not counted: a floor).
struct Params {
    n: u32,
}

var<immediate> pc: Params;

@group(0) @binding(0) var<storage, read> values: array<f32>;
@group(0) @binding(1) var<storage, read> targets: array<u32>;
@group(0) @binding(2) var<storage, read_write> acc: array<atomic<u32>>;

fn add_f32(slot: u32, v: f32) {
    var old = atomicLoad(&acc[slot]);
    loop {
        let new_bits = bitcast<u32>(bitcast<f32>(old) + v);
        let r = atomicCompareExchangeWeak(&acc[slot], old, new_bits);
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

@compute @workgroup_size(256)
fn atomic_add_f32_cas(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let i = (wid.y * nwg.x + wid.x) * 256u + t;
    if (i < pc.n) {
        add_f32(targets[i], values[i]);
    }
}

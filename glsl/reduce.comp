// One level of a tree reduction of f32 (sum or max): each workgroup folds
// REDUCE_BLOCK elements of `src` into dst[group]; the host repeats until one
// value is left (engine/gpu/src/ops/reduce.rs). CPU reference:
// engine/reference/src/reduce.rs. The shared-memory tree is also the test of
// the build's barrier() fix-up: with subgroup scope it races on any device
// whose subgroups are smaller than the workgroup.
// @kernel reduce_sum_f32 OP=0
// @kernel reduce_max_f32 OP=1
// @cost flops=n bytes=4 * n + 4 * max(1, n / 2048)
// one add (max) per element; reads src[..n], writes one value per block.
#version 450
#include "common.glsl"

#define THREADS 256
#define ITEMS 8
#define REDUCE_BLOCK (THREADS * ITEMS)

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Src { float src[]; };
layout(std430, set = 0, binding = 1) buffer Dst { float dst[]; };

layout(push_constant) uniform Params {
    uint n;
} pc;

shared float partial[THREADS];

float identity() {
#if OP == 0
    return 0.0;
#else
    return uintBitsToFloat(0xff800000u); // -inf
#endif
}

float combine(float a, float b) {
#if OP == 0
    return a + b;
#else
    return max(a, b);
#endif
}

void main() {
    uint block = linear_group();
    // One group even for n = 0, so the identity is written.
    uint blocks = max(1u, (pc.n + REDUCE_BLOCK - 1u) / REDUCE_BLOCK);
    if (block >= blocks) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    float acc = identity();
    // Strided so neighbouring threads read neighbouring addresses.
    for (uint i = 0u; i < ITEMS; i++) {
        uint idx = block * REDUCE_BLOCK + i * THREADS + t;
        if (idx < pc.n) {
            acc = combine(acc, src[idx]);
        }
    }
    partial[t] = acc;
    barrier();
    for (uint s = THREADS / 2u; s > 0u; s /= 2u) {
        if (t < s) {
            partial[t] = combine(partial[t], partial[t + s]);
        }
        barrier();
    }
    if (t == 0u) {
        dst[block] = partial[0];
    }
}

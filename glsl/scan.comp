// Exclusive prefix sum of u32, any length, in two kernels driven by the host
// recursively (engine/gpu/src/ops/scan.rs):
//   scan_blocks: each workgroup scans SCAN_BLOCK elements in place and writes
//                the block total to `sums`;
//   scan_add:    adds the (already scanned) block totals back.
// CPU reference: engine/reference/src/scan.rs.
// @kernel scan_blocks PASS=0
// @kernel scan_add PASS=1
// @cost scan_blocks: flops=2 * n bytes=8 * n + 4 * max(1, n / 1024)
// @cost scan_add: flops=n bytes=8 * n + 4 * n / 1024
// scan_blocks: the running sum and the block offset add per element, data
// read and written, one total per SCAN_BLOCK (1024) block written;
// scan_add: one add per element, data read and written, block totals read.
#version 450
#include "common.glsl"
#include "shared.glsl"

// Few threads with long serial runs: each barrier costs a context switch per
// SIMD chunk on CPU drivers; 64x16 scanned twice as fast as 256x4 on lavapipe.
#define THREADS 64
#define ITEMS (SCAN_BLOCK / THREADS)

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) buffer Sums { uint sums[]; };

layout(push_constant) uniform Params {
    uint n;
} pc;

shared uint partial[THREADS];

void main() {
    uint block = linear_group();
    // Workgroup-uniform, so no barrier is skipped by part of a group.
    if (block * SCAN_BLOCK >= pc.n) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint base = block * SCAN_BLOCK + t * ITEMS;
#if PASS == 0
    uint v[ITEMS];
    uint run = 0u;
    for (uint i = 0u; i < ITEMS; i++) {
        uint idx = base + i;
        uint x = idx < pc.n ? data[idx] : 0u;
        v[i] = run;
        run += x;
    }
    partial[t] = run;
    barrier();
    // Hillis-Steele inclusive scan of the per-thread totals.
    for (uint off = 1u; off < THREADS; off *= 2u) {
        uint add = t >= off ? partial[t - off] : 0u;
        barrier();
        partial[t] += add;
        barrier();
    }
    uint before = t > 0u ? partial[t - 1u] : 0u;
    for (uint i = 0u; i < ITEMS; i++) {
        uint idx = base + i;
        if (idx < pc.n) {
            data[idx] = v[i] + before;
        }
    }
    if (t == THREADS - 1u) {
        sums[block] = partial[THREADS - 1u];
    }
#else
    uint add = sums[block];
    for (uint i = 0u; i < ITEMS; i++) {
        uint idx = base + i;
        if (idx < pc.n) {
            data[idx] += add;
        }
    }
#endif
}

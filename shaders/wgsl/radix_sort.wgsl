// Stable key-value radix sort, one 4-bit digit per pass (engine/gpu/src/ops/sort.rs
// drives it: histogram -> exclusive scan of the histogram -> scatter).
// WGSL because the histogram counts with workgroup atomics, which naga's GLSL
// front end does not have. CPU reference: engine/reference/src/sort.rs.
//
// A block is THREADS * ITEMS consecutive elements. The histogram is stored
// digit-major, hist[digit * num_blocks + block], so one exclusive scan over it
// yields every block's first output slot for every digit. The scatter ranks
// elements inside a block by (digit, position), which keeps the sort stable
// without atomics.
//
// @cost radix_histogram: flops=0 bytes=4 * n + 64 * num_blocks
// @cost radix_scatter: flops=0 bytes=16 * n + 64 * num_blocks
// Integer digit extraction and counting only (no arithmetic counted).
// Histogram: each key read once, 16 counts written per block. Scatter:
// keys and values read and written once each, 16 counts read per block.

const THREADS: u32 = 128u;
const ITEMS: u32 = 16u;
const BLOCK: u32 = 2048u; // THREADS * ITEMS
const RADIX: u32 = 16u;

struct Params {
    n: u32,
    shift: u32,
    num_blocks: u32,
    // Key bits this pass sorts by (RADIX_BITS, or fewer on the last pass).
    bits: u32,
}

var<immediate> pc: Params;

@group(0) @binding(0) var<storage, read> keys_in: array<u32>;
@group(0) @binding(1) var<storage, read_write> hist: array<u32>;
@group(0) @binding(2) var<storage, read> vals_in: array<u32>;
@group(0) @binding(3) var<storage, read_write> keys_out: array<u32>;
@group(0) @binding(4) var<storage, read_write> vals_out: array<u32>;

var<workgroup> counts: array<atomic<u32>, 16>;
var<workgroup> table: array<u32, 2048>; // RADIX * THREADS
var<workgroup> totals: array<u32, 128>;

fn block_index(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

@compute @workgroup_size(128)
fn radix_histogram(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let block = block_index(wid, nwg);
    if (t < RADIX) {
        atomicStore(&counts[t], 0u);
    }
    workgroupBarrier();
    if (block < pc.num_blocks) {
        for (var i = 0u; i < ITEMS; i++) {
            let idx = block * BLOCK + i * THREADS + t;
            if (idx < pc.n) {
                let d = (keys_in[idx] >> pc.shift) & ((1u << pc.bits) - 1u);
                atomicAdd(&counts[d], 1u);
            }
        }
    }
    workgroupBarrier();
    if (t < RADIX && block < pc.num_blocks) {
        hist[t * pc.num_blocks + block] = atomicLoad(&counts[t]);
    }
}

@compute @workgroup_size(128)
fn radix_scatter(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
) {
    let block = block_index(wid, nwg);
    let valid_block = block < pc.num_blocks;
    let base = block * BLOCK + t * ITEMS;

    var cnt: array<u32, 16>;
    for (var d = 0u; d < RADIX; d++) {
        cnt[d] = 0u;
    }
    if (valid_block) {
        for (var i = 0u; i < ITEMS; i++) {
            let idx = base + i;
            if (idx < pc.n) {
                let d = (keys_in[idx] >> pc.shift) & ((1u << pc.bits) - 1u);
                cnt[d] += 1u;
            }
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        table[d * THREADS + t] = cnt[d];
    }
    workgroupBarrier();

    // Exclusive scan of the table in (digit, thread) order: each thread takes
    // RADIX consecutive entries, then the per-thread totals are scanned.
    var run = 0u;
    for (var e = 0u; e < RADIX; e++) {
        let v = table[t * RADIX + e];
        table[t * RADIX + e] = run;
        run += v;
    }
    totals[t] = run;
    workgroupBarrier();
    for (var off = 1u; off < THREADS; off *= 2u) {
        var add = 0u;
        if (t >= off) {
            add = totals[t - off];
        }
        workgroupBarrier();
        totals[t] += add;
        workgroupBarrier();
    }
    var before = 0u;
    if (t > 0u) {
        before = totals[t - 1u];
    }
    for (var e = 0u; e < RADIX; e++) {
        table[t * RADIX + e] += before;
    }
    workgroupBarrier();

    if (!valid_block) {
        return;
    }
    // Output slot of this thread's first element of each digit.
    var next: array<u32, 16>;
    for (var d = 0u; d < RADIX; d++) {
        next[d] = hist[d * pc.num_blocks + block] + table[d * THREADS + t] - table[d * THREADS];
    }
    for (var i = 0u; i < ITEMS; i++) {
        let idx = base + i;
        if (idx < pc.n) {
            let k = keys_in[idx];
            let d = (k >> pc.shift) & ((1u << pc.bits) - 1u);
            let pos = next[d];
            next[d] = pos + 1u;
            keys_out[pos] = k;
            vals_out[pos] = vals_in[idx];
        }
    }
}

// Region pooling inside the rasterizer: the mean rendered query of every
// region, without a per-pixel query image,
//     pooled[first_row + r, c] += sum_{p in r} query[p, c] / |r|
// (rows zero-filled by the host first). Runs after a forward pass of the
// same batch (any channels): walks each tile's depth-sorted list as
// glsl/raster_forward.comp does, up to each pixel's last contributor (its
// state), blending only the 32 query channels, and adds each pixel's share
// into its region's row. Pixels in no region are not walked. CPU reference:
// engine/reference/src/raster.rs (`render`) followed by
// engine/reference/src/pooling.rs (`pool`).
//
// WGSL because the sums need float atomics (or a compare-and-swap loop
// where the device lacks them), and subgroup operations where available;
// naga's GLSL front end has neither.
//
// One pixel per invocation (GPUs): where a subgroup's pixels all lie in one
// region (most of an image), they are summed with subgroupAdd and one
// invocation adds the row; elsewhere each pixel adds its own. COLUMNS
// variants (CPU drivers, see glsl/raster_forward.comp): each of 16
// invocations blends one 16-pixel tile column, and a column whose pixels
// share a region adds one row for the column.
//
// The region of pixel p is labels[p] (0xffffffff: none); from offsets_at,
// labels holds the regions' CSR offsets, so |r| = labels[offsets_at + r + 1]
// - labels[offsets_at + r]. The same layout feeds raster_backward.
//
// @capabilities SHADER_FLOAT32_ATOMIC SUBGROUP
// @select COLUMNS SUBGROUP CAS
// @kernel raster_pool SUBGROUP=1 CAS=0 COLUMNS=0
// @kernel raster_pool_cas SUBGROUP=1 CAS=1 COLUMNS=0
// @kernel raster_pool_plain SUBGROUP=0 CAS=0 COLUMNS=0
// @kernel raster_pool_plain_cas SUBGROUP=0 CAS=1 COLUMNS=0
// @kernel raster_pool_columns CAS=0 COLUMNS=1
// @kernel raster_pool_columns_cas CAS=1 COLUMNS=1
// @cost caller
// Per-tile list lengths, per-pixel walks and regions are data. Host, with
// I, P, V, U as for glsl/raster_forward.comp (I tile-list entries, P
// pixels, V visible pairs, U = min(n_gaussians, V)), 256 * I pairs tested
// (every entry by every pixel of its tile: an upper bound; pixels in no
// region test none), R regions, S the device's subgroup size:
// flops
//   pixel variants (raster_pool, _cas, _plain, _plain_cas):
//     25 * 256 * I + 70 * P  (CostModel TEST per tested pair; per pixel
//     the 1/|r| share and 32-channel scale, and its subgroup sum or row
//     add. Blending the 32 query channels of a contributor, 67, is not
//     host-known at dispatch: add it times contributors where known)
//   raster_pool_columns, _columns_cas:
//     125 * 256 * I + 70 * P  (branchless: every tested (entry, pixel)
//     also blends the 32 channels with selects)
// bytes = 4 * I + 32 * V + 128 * U + 4 * n_tiles + 8 * P + 4 * R + A
//   (pair index per entry; splat per visible pair; query per Gaussian,
//   distinct once; tile start; label and walked count per pixel; region
//   offsets), A = 32 atomic adds of 8 bytes per row add (CAS the same,
//   retries not counted): 256 * P for the _plain ones (one per pixel in a
//   region: an upper bound), 256 * P / S for raster_pool, _cas (one per
//   subgroup in one region, a floor) and 256 * P / 16 for the column ones
//   (one per 16-pixel column in one region, a floor).

#include "raster.wgsl"

#if COLUMNS
// Pixels per invocation (one tile column), and invocations per workgroup.
const ROWS: u32 = 16u;
const INVOCATIONS: u32 = 16u;
#else
const INVOCATIONS: u32 = 256u;
#endif

struct Params {
    n_gaussians: u32,
    n_views: u32,
    n_tiles: u32,
    first_row: u32,
    offsets_at: u32,
}

var<immediate> pc: Params;

@group(0) @binding(0) var<storage, read> views: array<View>;
@group(0) @binding(1) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> splats: array<Splat>;
@group(0) @binding(3) var<storage, read> pairs: array<u32>;
@group(0) @binding(4) var<storage, read> ranges: array<TileRange>;
// Per pixel: (list entries walked, final transmittance bits).
@group(0) @binding(5) var<storage, read> state: array<PixelState>;
@group(0) @binding(6) var<storage, read> labels: array<u32>;
#if CAS
@group(0) @binding(7) var<storage, read_write> pooled: array<atomic<u32>>;

fn add_pooled(i: u32, v: f32) {
    var old = atomicLoad(&pooled[i]);
    loop {
        let r = atomicCompareExchangeWeak(&pooled[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) { break; }
        old = r.old_value;
    }
}
#else
@group(0) @binding(7) var<storage, read_write> pooled: array<atomic<f32>>;

fn add_pooled(i: u32, v: f32) { atomicAdd(&pooled[i], v); }
#endif

// Adds 32 channels to region r's row.
fn add_row(r: u32, q: array<vec4<f32>, 8>) {
    let row = 32u * (pc.first_row + r);
    for (var c = 0u; c < 8u; c++) {
        add_pooled(row + 4u * c, q[c].x);
        add_pooled(row + 4u * c + 1u, q[c].y);
        add_pooled(row + 4u * c + 2u, q[c].z);
        add_pooled(row + 4u * c + 3u, q[c].w);
    }
}

// A pixel's region and its share 1/|r| (0 for none).
struct Region {
    index: u32,
    share: f32,
}

fn region_of(p: u32) -> Region {
    let r = labels[p];
    if (r == NO_REGION) {
        return Region(NO_REGION, 0.0);
    }
    let size = labels[pc.offsets_at + r + 1u] - labels[pc.offsets_at + r];
    return Region(r, 1.0 / f32(max(size, 1u)));
}

var<workgroup> sh_gaussian: array<u32, BLEND_BATCH>;
var<workgroup> sh_splat: array<vec4<f32>, BLEND_BATCH>;
var<workgroup> sh_conic: array<vec4<f32>, BLEND_BATCH>;

#if COLUMNS
@compute @workgroup_size(16)
#else
@compute @workgroup_size(256)
#endif
fn raster_pool(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
#if SUBGROUP
    @builtin(subgroup_invocation_id) lane: u32,
#endif
) {
    let tile = wid.y * nwg.x + wid.x;
    if (tile >= pc.n_tiles) {
        return;
    }
    var vi = 0u;
    for (var k = 1u; k < pc.n_views; k++) {
        if (views[k].offsets.x <= tile) {
            vi = k;
        }
    }
    let v = views[vi];
    let local_tile = tile - v.offsets.x;
    let start = ranges[tile].start;
#if COLUMNS
    let px = (local_tile % v.size.z) * TILE_SIZE + t;
    let py0 = (local_tile / v.size.z) * TILE_SIZE;
    // Per pixel K (row py0 + K of column px), indexed by constants only
    // (unrolled below).
    var walked: array<u32, ROWS>;
    var region: array<u32, ROWS>;
    var share: array<f32, ROWS>;
    var trans: array<f32, ROWS>;
    var q: array<vec4<f32>, 128>;
    var my_walk = 0u;
#unroll K 16
    {
        let py = py0 + K;
        walked[K] = 0u;
        region[K] = NO_REGION;
        share[K] = 0.0;
        trans[K] = 1.0;
#unroll C 8
        q[8u * K + C] = vec4<f32>(0.0);
#endunroll
        if (px < v.size.x && py < v.size.y) {
            let p = v.offsets.y + py * v.size.x + px;
            let reg = region_of(p);
            region[K] = reg.index;
            share[K] = reg.share;
            walked[K] = select(0u, state[p].walked, reg.index != NO_REGION);
        }
        my_walk = max(my_walk, walked[K]);
    }
#endunroll

    let tile_walk = tile_max(t, my_walk);
    for (var base = 0u; base < tile_walk; base += BLEND_BATCH) {
        workgroupBarrier();
        for (var e = t; e < BLEND_BATCH; e += INVOCATIONS) {
            if (base + e < tile_walk) {
                let pair = pairs[start + base + e];
                sh_gaussian[e] = pair % pc.n_gaussians;
                sh_splat[e] = splats[pair].mean_depth_opacity;
                sh_conic[e] = splats[pair].conic;
            }
        }
        workgroupBarrier();
        let count = min(BLEND_BATCH, tile_walk - base);
        for (var j = 0u; j < count; j++) {
            let s = sh_splat[j];
            let conic = sh_conic[j].xyz;
            let g = sh_gaussian[j];
            // Loaded once for the column.
            var f: array<vec4<f32>, 8>;
#unroll C 8
            f[C] = queries[8u * g + C];
#endunroll
#unroll K 16
            {
                let d = s.xy - vec2<f32>(f32(px), f32(py0 + K));
                let sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
                let alpha = min(MAX_ALPHA, s.w * exp(-sigma));
                let hit = base + j < walked[K] && sigma >= 0.0 && alpha >= MIN_ALPHA;
                let w = alpha * trans[K];
                // Selected, not multiplied by a zero weight: a non-finite
                // query must not reach pixels the Gaussian does not cover.
#unroll C 8
                q[8u * K + C] = select(q[8u * K + C], q[8u * K + C] + w * f[C], hit);
#endunroll
                trans[K] = select(trans[K], trans[K] * (1.0 - alpha), hit);
            }
#endunroll
        }
    }

    // One row update for a column in one region, else one per pixel.
    var same = true;
    var sum: array<vec4<f32>, 8>;
#unroll K 16
    {
        same = same && region[K] == region[0u];
#unroll C 8
        sum[C] += q[8u * K + C] * share[K];
#endunroll
    }
#endunroll
    if (same && region[0u] != NO_REGION) {
        add_row(region[0u], sum);
    }
    // A column across regions adds pixel by pixel, from one call site in
    // a loop: the pixel's values are picked by selects, since indexing the
    // per-pixel arrays by the loop counter would take them out of
    // registers, and 16 inlined row updates cost the driver's compiler far
    // more than these selects cost at run time. A column in one region
    // skips the loop.
    for (var k = 0u; k < select(ROWS, 0u, same); k++) {
        var r = NO_REGION;
        var mine: array<vec4<f32>, 8>;
#unroll K 16
        {
            let pick = k == K;
            r = select(r, region[K], pick);
#unroll C 8
            mine[C] = select(mine[C], q[8u * K + C] * share[K], pick);
#endunroll
        }
#endunroll
        if (r != NO_REGION) {
            add_row(r, mine);
        }
    }
#else
    let px = (local_tile % v.size.z) * TILE_SIZE + t % TILE_SIZE;
    let py = (local_tile / v.size.z) * TILE_SIZE + t / TILE_SIZE;
    let pix = vec2<f32>(f32(px), f32(py));
    var walked = 0u;
    var reg = Region(NO_REGION, 0.0);
    if (px < v.size.x && py < v.size.y) {
        let p = v.offsets.y + py * v.size.x + px;
        reg = region_of(p);
        walked = select(0u, state[p].walked, reg.index != NO_REGION);
    }
    let tile_walk = tile_max(t, walked);
    var trans = 1.0;
    var q: array<vec4<f32>, 8>;
    for (var base = 0u; base < tile_walk; base += BLEND_BATCH) {
        workgroupBarrier();
        if (base + t < tile_walk) {
            let pair = pairs[start + base + t];
            sh_gaussian[t] = pair % pc.n_gaussians;
            sh_splat[t] = splats[pair].mean_depth_opacity;
            sh_conic[t] = splats[pair].conic;
        }
        workgroupBarrier();
        let count = min(BLEND_BATCH, tile_walk - base);
        for (var j = 0u; j < count && base + j < walked; j++) {
            let s = sh_splat[j];
            let conic = sh_conic[j].xyz;
            let d = s.xy - pix;
            let sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
            let alpha = min(MAX_ALPHA, s.w * exp(-sigma));
            if (sigma >= 0.0 && alpha >= MIN_ALPHA) {
                let w = alpha * trans;
                let g = sh_gaussian[j];
                for (var c = 0u; c < 8u; c++) {
                    q[c] += w * queries[8u * g + c];
                }
                trans *= 1.0 - alpha;
            }
        }
    }
    for (var c = 0u; c < 8u; c++) {
        q[c] *= reg.share;
    }
#if SUBGROUP
    // Every invocation reaches this point: subgroup operations are safe.
    let lo = subgroupMin(reg.index);
    let hi = subgroupMax(reg.index);
    if (lo == hi) {
        if (lo != NO_REGION) {
            var sum: array<vec4<f32>, 8>;
            for (var c = 0u; c < 8u; c++) {
                sum[c] = subgroupAdd(q[c]);
            }
            if (lane == 0u) {
                add_row(lo, sum);
            }
        }
    } else if (reg.index != NO_REGION) {
        add_row(reg.index, q);
    }
#else
    if (reg.index != NO_REGION) {
        add_row(reg.index, q);
    }
#endif
#endif
}

// Front-to-back blending of depth-sorted Gaussians: one workgroup per 16x16
// tile of every view. Writes colour (with background), depth (sum of weight
// x camera z, not normalised), alpha, the 32 query channels, and per pixel
// the state the backward pass replays: how many of the tile's list it walked
// up to its last contributor, and the final transmittance. CPU reference:
// engine/reference/src/raster.rs (`render`).
//
// raster_forward gives each invocation one pixel, the usual layout for
// GPUs. CPU drivers run a subgroup as SIMD lanes, emulate every buffer or
// shared-memory load lane by lane, and execute both sides of every branch;
// there (raster_forward_columns) each of 16 invocations blends one 16-pixel
// column of the tile, so a Gaussian's data is loaded once for 16 pixels,
// and branches become selects. (Two columns per invocation load it once for
// 32, but took lavapipe's compiler 3.7x as long for no measurable gain at
// run time: 6.9 s against 1.9 s on a cold driver cache.)
//
// The _colour variants (QUERY=0) skip the 32 query channels: for renders
// whose queries nobody reads (coverage before seeding, logs without
// embeddings, Stage I with detached query gradients, which pools queries in
// raster_pool). Their query image is left as it was. A batch whose query
// image would not fit one buffer is blended once per band of pixels
// (query_first, query_count), each band written to the start of the image.
//
// @select COLUMNS QUERY
// @kernel raster_forward COLUMNS=0 ROWS=1 QUERY=1
// @kernel raster_forward_columns COLUMNS=1 ROWS=16 QUERY=1
// @kernel raster_forward_colour COLUMNS=0 ROWS=1 QUERY=0
// @kernel raster_forward_columns_colour COLUMNS=1 ROWS=16 QUERY=0
// @cost caller
// Per-tile list lengths and per-pixel stops are data. Host, with I = the
// intersections (tile-list entries) read back after binning, P = batch
// pixels (sum of width * height), Pq = the pixels in the query band
// [query_first, query_first + query_count), V = visible pairs, U =
// min(n_gaussians, V) (Gaussians in some list, an upper bound), and
// 256 * I pairs tested (every entry by every pixel of its tile: an upper
// bound, pixels stop at their last contributor); constants as
// tools/src/bench/raster.rs CostModel:
//   raster_forward:                flops = 25 * 256 * I + 7 * P
//   raster_forward_colour:         flops = 25 * 256 * I + 7 * P
//     (TEST 25 per tested pair; background 7 per pixel. Blending a
//     contributor, BLEND 76 (12 for _colour), is not host-known at dispatch:
//     add 76 * contributors where a count exists)
//   raster_forward_columns:        flops = 140 * 256 * I + 7 * P
//   raster_forward_columns_colour: flops = 44 * 256 * I + 7 * P
//     (branchless: every tested (entry, pixel) also does the blend and its
//     selects: 25 + 19 + 96 for the 32 query FMAs and selects; 25 + 19
//     for _colour)
//   bytes = 4 * I + 28 * V + 140 * U + 8 * n_tiles + 28 * P + 128 * Pq,
//     the _colour variants 4 * I + 28 * V + 12 * U + 8 * n_tiles + 28 * P
//     (pair index per entry; splat per visible pair; colour + query per
//     Gaussian, each distinct element once (CostModel's ENTRY_BYTES
//     instead re-reads them per entry); tile range; rgbd, alpha and
//     state per pixel; the 32 query channels per band pixel)
#version 450
#include "common.glsl"
#include "splat.glsl"

#define QUERY_VEC4 8u
#define INVOCATIONS (256u / ROWS)

#if ROWS == 1
layout(local_size_x = 16, local_size_y = 16) in;
#else
layout(local_size_x = 16, local_size_y = 1) in;
#endif

layout(std430, set = 0, binding = 0) readonly buffer Views { View views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Colors { float colors[]; };
layout(std430, set = 0, binding = 2) readonly buffer Queries { vec4 queries[]; };
layout(std430, set = 0, binding = 3) readonly buffer Splats { Splat splats[]; };
layout(std430, set = 0, binding = 4) readonly buffer Pairs { uint pairs[]; };
layout(std430, set = 0, binding = 5) readonly buffer Ranges { TileRange ranges[]; };
layout(std430, set = 0, binding = 6) buffer Rgbd { vec4 out_rgbd[]; };
layout(std430, set = 0, binding = 7) buffer Alpha { float out_alpha[]; };
layout(std430, set = 0, binding = 8) buffer Query { vec4 out_query[]; };
// Per pixel: (list entries walked, final transmittance bits).
layout(std430, set = 0, binding = 9) buffer State { PixelState out_state[]; };

layout(push_constant) uniform Params {
    uint n_gaussians;
    uint n_views;
    uint n_tiles;
    float bg_r;
    float bg_g;
    float bg_b;
    // The query image holds batch pixels query_first .. query_first +
    // query_count (a band of a batch too large for one buffer).
    uint query_first;
    uint query_count;
} pc;

shared uint sh_gaussian[BLEND_BATCH];
shared vec4 sh_splat[BLEND_BATCH];
shared vec3 sh_conic[BLEND_BATCH];

void main() {
    uint tile = linear_group();
    if (tile >= pc.n_tiles) {
        return;
    }
    uint vi = 0u;
    for (uint k = 1u; k < pc.n_views; k++) {
        if (views[k].offsets.x <= tile) {
            vi = k;
        }
    }
    View v = views[vi];
#if QUERY == 0
    // Keeps the query bindings in the interface every variant shares.
    if (pc.n_tiles == 0xffffffffu) {
        out_query[0] = queries[0];
    }
#endif
    uint local_tile = tile - v.offsets.x;
    uint t = gl_LocalInvocationIndex;
    TileRange range = ranges[tile];
    uint n = range.end - range.start;

#if ROWS == 1
    uint px = (local_tile % v.size.z) * TILE_SIZE + gl_LocalInvocationID.x;
    uint py = (local_tile / v.size.z) * TILE_SIZE + gl_LocalInvocationID.y;
    bool inside = px < v.size.x && py < v.size.y;
    bool done = !inside;
    float trans = 1.0;
    vec4 rgbd = vec4(0.0);
#if QUERY
    vec4 q[QUERY_VEC4];
    for (uint c = 0u; c < QUERY_VEC4; c++) {
        q[c] = vec4(0.0);
    }
#endif
    uint walked = 0u;
#else
    uint px0 = (local_tile % v.size.z) * TILE_SIZE + t;
    uint py0 = (local_tile / v.size.z) * TILE_SIZE;
    // Per pixel K (column x0 + t, row y0 + K); indexed by constants only,
    // so they stay in registers.
    float trans[ROWS];
    vec4 rgbd[ROWS];
#if QUERY
    vec4 q[ROWS * QUERY_VEC4];
#endif
    uint walked[ROWS];
    bool done[ROWS];
    uint active = 0u;
#unroll K ROWS
    trans[K] = 1.0;
    rgbd[K] = vec4(0.0);
#if QUERY
#unroll C 8
    q[K * QUERY_VEC4 + C] = vec4(0.0);
#endunroll
#endif
    walked[K] = 0u;
    done[K] = !(px0 < v.size.x && py0 + K < v.size.y);
    active += done[K] ? 0u : 1u;
#endunroll
#endif

    for (uint base = 0u; base < n; base += BLEND_BATCH) {
        barrier();
        for (uint e = t; e < BLEND_BATCH; e += INVOCATIONS) {
            if (base + e < n) {
                uint pair = pairs[range.start + base + e];
                sh_gaussian[e] = pair % pc.n_gaussians;
                sh_splat[e] = splats[pair].mean_depth_opacity;
                sh_conic[e] = splats[pair].conic.xyz;
            }
        }
        barrier();
        uint count = min(BLEND_BATCH, n - base);
#if ROWS == 1
        for (uint j = 0u; j < count && !done; j++) {
            vec4 s = sh_splat[j];
            vec3 conic = sh_conic[j];
            vec2 d = s.xy - vec2(float(px), float(py));
            float sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
            if (sigma < 0.0) {
                continue;
            }
            float alpha = min(MAX_ALPHA, s.w * exp(-sigma));
            if (alpha < MIN_ALPHA) {
                continue;
            }
            float next = trans * (1.0 - alpha);
            if (next < MIN_TRANSMITTANCE) {
                done = true;
                break;
            }
            float w = alpha * trans;
            uint g = sh_gaussian[j];
            rgbd += w * vec4(colors[3u * g], colors[3u * g + 1u], colors[3u * g + 2u], s.z);
#if QUERY
            for (uint c = 0u; c < QUERY_VEC4; c++) {
                q[c] += w * queries[QUERY_VEC4 * g + c];
            }
#endif
            trans = next;
            walked = base + j + 1u;
        }
#else
        for (uint j = 0u; j < count && active > 0u; j++) {
            vec4 s = sh_splat[j];
            vec3 conic = sh_conic[j];
            uint g = sh_gaussian[j];
            vec4 f = vec4(colors[3u * g], colors[3u * g + 1u], colors[3u * g + 2u], s.z);
#if QUERY
            vec4 fq[QUERY_VEC4];
#unroll C 8
            fq[C] = queries[QUERY_VEC4 * g + C];
#endunroll
#endif
#unroll K ROWS
            {
                vec2 d = s.xy - vec2(float(px0), float(py0 + K));
                float sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
                float alpha = min(MAX_ALPHA, s.w * exp(-sigma));
                float next = trans[K] * (1.0 - alpha);
                bool hit = !done[K] && sigma >= 0.0 && alpha >= MIN_ALPHA;
                bool stop = hit && next < MIN_TRANSMITTANCE;
                done[K] = done[K] || stop;
                active -= stop ? 1u : 0u;
                hit = hit && !stop;
                float w = alpha * trans[K];
                // Selected, not multiplied by a zero weight: a Gaussian with
                // a non-finite colour must not reach pixels it does not cover.
                rgbd[K] = hit ? rgbd[K] + w * f : rgbd[K];
#if QUERY
#unroll C 8
                q[K * QUERY_VEC4 + C] = hit ? q[K * QUERY_VEC4 + C] + w * fq[C] : q[K * QUERY_VEC4 + C];
#endunroll
#endif
                walked[K] = hit ? base + j + 1u : walked[K];
                trans[K] = hit ? next : trans[K];
            }
#endunroll
        }
#endif
    }

    vec3 bg = vec3(pc.bg_r, pc.bg_g, pc.bg_b);
#if ROWS == 1
    if (inside) {
        uint p = v.offsets.y + py * v.size.x + px;
        out_rgbd[p] = vec4(rgbd.xyz + trans * bg, rgbd.w);
        out_alpha[p] = 1.0 - trans;
#if QUERY
        uint band = p - pc.query_first;
        if (band < pc.query_count) {
            for (uint c = 0u; c < QUERY_VEC4; c++) {
                out_query[QUERY_VEC4 * band + c] = q[c];
            }
        }
#endif
        out_state[p] = PixelState(walked, trans);
    }
#else
#unroll K ROWS
    {
        uint px = px0;
        uint py = py0 + K;
        if (px < v.size.x && py < v.size.y) {
            uint p = v.offsets.y + py * v.size.x + px;
            out_rgbd[p] = vec4(rgbd[K].xyz + trans[K] * bg, rgbd[K].w);
            out_alpha[p] = 1.0 - trans[K];
#if QUERY
            uint band = p - pc.query_first;
            if (band < pc.query_count) {
#unroll C 8
                out_query[QUERY_VEC4 * band + C] = q[K * QUERY_VEC4 + C];
#endunroll
            }
#endif
            out_state[p] = PixelState(walked[K], trans[K]);
        }
    }
#endunroll
#endif
}

// Tile binning, between projection and blending (orchestrated by
// engine/core/src/splat/tile_bins.rs):
//   compact_visible:  visible pairs -> (depth key, pair) lists, in pair order
//   gather_counts:    tile counts in depth-sorted order (for the offset scan)
//   emit_tiles:       one (global tile, pair) intersection per covered tile,
//                     written in depth order so a stable sort by tile keeps
//                     every tile's list sorted front to back
//   tile_ranges:      [start, end) of each tile's run in the sorted list
// @kernel compact_visible STEP=0
// @kernel gather_counts STEP=1
// @kernel emit_tiles STEP=2
// @kernel tile_ranges STEP=3
// @cost compact_visible: caller
// Host (n = pairs, V = visible pairs): flops = n (tile-count test);
// bytes = 4 * n + 16 * V (tile count per pair; per visible pair its
// position, depth, and key + value written).
// @cost gather_counts: flops=0 bytes=12 * n
// Reads order[i] and the count it points at, writes the sorted count.
// @cost emit_tiles: caller
// Host (n = V visible pairs, I = intersections read back after binning):
// flops = 0 (tile keys are index arithmetic); bytes = 16 * n + 8 * I
// + 8 * n_views (order, rect 8, offset per pair; key + value per
// intersection; two words of each view).
// @cost tile_ranges: flops=2 * n bytes=4 * n
// Two neighbour-key compares per intersection; each key read once (the
// <= 8 bytes of range written per non-empty tile are left out: the tile
// count is not a push field here).
#version 450
#include "common.glsl"
#include "splat.glsl"

layout(local_size_x = 256) in;

layout(push_constant) uniform Params {
    uint n;          // items this step walks (pairs, visible, or intersections)
    uint n_gaussians;
    uint n_views;
} pc;

#if STEP == 0
layout(std430, set = 0, binding = 0) readonly buffer Splats { Splat splats[]; };
layout(std430, set = 0, binding = 1) readonly buffer Counts { uint tile_counts[]; };
layout(std430, set = 0, binding = 2) readonly buffer Positions { uint positions[]; };
layout(std430, set = 0, binding = 3) buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 4) buffer Vals { uint vals[]; };
#elif STEP == 1
layout(std430, set = 0, binding = 0) readonly buffer Counts { uint tile_counts[]; };
layout(std430, set = 0, binding = 1) readonly buffer Order { uint order[]; };
layout(std430, set = 0, binding = 2) buffer Sorted { uint sorted_counts[]; };
#elif STEP == 2
layout(std430, set = 0, binding = 0) readonly buffer Views { View views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Rects { TileRect rects[]; };
layout(std430, set = 0, binding = 2) readonly buffer Order { uint order[]; };
layout(std430, set = 0, binding = 3) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 4) buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 5) buffer Vals { uint vals[]; };
#else
layout(std430, set = 0, binding = 0) readonly buffer Keys { uint keys[]; };
layout(std430, set = 0, binding = 1) buffer Ranges { TileRange ranges[]; };
#endif

void main() {
    uint i = linear_group() * 256u + gl_LocalInvocationIndex;
    if (i >= pc.n) {
        return;
    }
#if STEP == 0
    if (tile_counts[i] > 0u) {
        // Depth is positive, so its IEEE bits sort like the value.
        keys[positions[i]] = floatBitsToUint(splats[i].mean_depth_opacity.z);
        vals[positions[i]] = i;
    }
#elif STEP == 1
    sorted_counts[i] = tile_counts[order[i]];
#elif STEP == 2
    uint pair = order[i];
    View v = views[pair / pc.n_gaussians];
    TileRect r = rects[pair];
    uint x0 = r.first & 0xffffu, y0 = r.first >> 16, x1 = r.last & 0xffffu, y1 = r.last >> 16;
    uint out_i = offsets[i];
    for (uint y = y0; y <= y1; y++) {
        for (uint x = x0; x <= x1; x++) {
            keys[out_i] = v.offsets.x + y * v.size.z + x;
            vals[out_i] = pair;
            out_i++;
        }
    }
#else
    uint tile = keys[i];
    // Nested ifs, not `||`: naga's GLSL front end evaluates both operands
    // of a logical operator, and keys[i - 1] at i = 0 (or keys[n] at the
    // end) is an out-of-bounds read, which a GPU without robust buffer
    // access may fault on (GPU-assisted validation caught it).
    bool first = i == 0u;
    if (!first) {
        first = keys[i - 1u] != tile;
    }
    if (first) {
        ranges[tile].start = i;
    }
    bool last = i + 1u == pc.n;
    if (!last) {
        last = keys[i + 1u] != tile;
    }
    if (last) {
        ranges[tile].end = i + 1u;
    }
#endif
}

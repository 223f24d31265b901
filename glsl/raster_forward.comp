// Front-to-back blending of depth-sorted Gaussians: one workgroup per 16x16
// tile of every view. Writes colour (with background), depth (sum of weight
// x camera z, not normalised), alpha, the 32 query channels, and per pixel
// the state the backward pass replays: how many of the tile's list it walked
// up to its last contributor, and the final transmittance. CPU reference:
// engine/src/reference/raster.rs (`render`).
//
// Each invocation blends ROWS pixels of one tile column (rows y, y + 16/ROWS,
// ...). ROWS = 1 is the usual one-pixel-per-thread layout for GPUs. CPU
// drivers run a subgroup as SIMD lanes and emulate every buffer or shared
// load lane by lane, and they execute both sides of every branch; there a
// Gaussian's data is better loaded once for a whole column (ROWS = 16),
// which cuts the loads per tested (pixel, Gaussian) pair sixteenfold.
//
// @kernel raster_forward ROWS=1
// @kernel raster_forward_columns ROWS=16
#version 450
#include "common.glsl"
#include "splat.glsl"

#define BATCH 256u
#define QUERY_VEC4 8u
#define STRIDE (16u / ROWS)
#define INVOCATIONS (256u / ROWS)

layout(local_size_x = 16, local_size_y = STRIDE) in;

layout(std430, set = 0, binding = 0) readonly buffer Views { View views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Colors { float colors[]; };
layout(std430, set = 0, binding = 2) readonly buffer Queries { vec4 queries[]; };
layout(std430, set = 0, binding = 3) readonly buffer Splats { vec4 splats[]; };
layout(std430, set = 0, binding = 4) readonly buffer Pairs { uint pairs[]; };
layout(std430, set = 0, binding = 5) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, set = 0, binding = 6) buffer Rgbd { vec4 out_rgbd[]; };
layout(std430, set = 0, binding = 7) buffer Alpha { float out_alpha[]; };
layout(std430, set = 0, binding = 8) buffer Query { vec4 out_query[]; };
// Per pixel: (list entries walked, final transmittance bits).
layout(std430, set = 0, binding = 9) buffer State { uvec2 out_state[]; };

layout(push_constant) uniform Params {
    uint n_gaussians;
    uint n_views;
    uint n_tiles;
    float bg_r;
    float bg_g;
    float bg_b;
} pc;

shared uint sh_gaussian[BATCH];
shared vec4 sh_splat[BATCH];
shared vec3 sh_conic[BATCH];

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
    uint local_tile = tile - v.offsets.x;
    uint px = (local_tile % v.size.z) * TILE_SIZE + gl_LocalInvocationID.x;
    uint py0 = (local_tile / v.size.z) * TILE_SIZE + gl_LocalInvocationID.y;
    uint t = gl_LocalInvocationIndex;

    uvec2 range = ranges[tile];
    uint n = range.y - range.x;
    float trans[ROWS];
    vec4 rgbd[ROWS];
    vec4 q[ROWS * QUERY_VEC4];
    uint walked[ROWS];
    bool done[ROWS];
    uint active = 0u;
    for (uint k = 0u; k < ROWS; k++) {
        trans[k] = 1.0;
        rgbd[k] = vec4(0.0);
        for (uint c = 0u; c < QUERY_VEC4; c++) {
            q[k * QUERY_VEC4 + c] = vec4(0.0);
        }
        walked[k] = 0u;
        done[k] = !(px < v.size.x && py0 + STRIDE * k < v.size.y);
        active += done[k] ? 0u : 1u;
    }

    for (uint base = 0u; base < n; base += BATCH) {
        barrier();
        for (uint e = t; e < BATCH; e += INVOCATIONS) {
            if (base + e < n) {
                uint pair = pairs[range.x + base + e];
                sh_gaussian[e] = pair % pc.n_gaussians;
                sh_splat[e] = splats[2u * pair];
                sh_conic[e] = splats[2u * pair + 1u].xyz;
            }
        }
        barrier();
        uint count = min(BATCH, n - base);
        for (uint j = 0u; j < count && active > 0u; j++) {
            vec4 s = sh_splat[j];
            vec3 conic = sh_conic[j];
            uint g = sh_gaussian[j];
#if ROWS > 1
            // Loaded once for the column (see the top comment).
            vec4 f = vec4(colors[3u * g], colors[3u * g + 1u], colors[3u * g + 2u], s.z);
            vec4 fq[QUERY_VEC4];
            for (uint c = 0u; c < QUERY_VEC4; c++) {
                fq[c] = queries[QUERY_VEC4 * g + c];
            }
#endif
            for (uint k = 0u; k < ROWS; k++) {
                vec2 d = s.xy - vec2(float(px), float(py0 + STRIDE * k));
                float sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
                float alpha = min(MAX_ALPHA, s.w * exp(-sigma));
                float next = trans[k] * (1.0 - alpha);
#if ROWS == 1
                if (done[k] || sigma < 0.0 || alpha < MIN_ALPHA) {
                    continue;
                }
                if (next < 1e-4) {
                    done[k] = true;
                    active -= 1u;
                    continue;
                }
                float w = alpha * trans[k];
                vec4 f = vec4(colors[3u * g], colors[3u * g + 1u], colors[3u * g + 2u], s.z);
                vec4 fq[QUERY_VEC4];
                for (uint c = 0u; c < QUERY_VEC4; c++) {
                    fq[c] = queries[QUERY_VEC4 * g + c];
                }
#else
                // Selects instead of branches: the CPU driver runs both sides.
                bool hit = !done[k] && sigma >= 0.0 && alpha >= MIN_ALPHA;
                bool stop = hit && next < 1e-4;
                done[k] = done[k] || stop;
                active -= stop ? 1u : 0u;
                hit = hit && !stop;
                float w = hit ? alpha * trans[k] : 0.0;
                next = hit ? next : trans[k];
#endif
#if ROWS == 1
                rgbd[k] += w * f;
                for (uint c = 0u; c < QUERY_VEC4; c++) {
                    q[k * QUERY_VEC4 + c] += w * fq[c];
                }
#else
                // Selected, not multiplied by zero: a Gaussian with a NaN
                // colour must not reach pixels it does not cover.
                rgbd[k] = hit ? rgbd[k] + w * f : rgbd[k];
                for (uint c = 0u; c < QUERY_VEC4; c++) {
                    q[k * QUERY_VEC4 + c] = hit ? q[k * QUERY_VEC4 + c] + w * fq[c] : q[k * QUERY_VEC4 + c];
                }
#endif
#if ROWS > 1
                walked[k] = hit ? base + j + 1u : walked[k];
#else
                walked[k] = base + j + 1u;
#endif
                trans[k] = next;
            }
        }
    }

    vec3 bg = vec3(pc.bg_r, pc.bg_g, pc.bg_b);
    for (uint k = 0u; k < ROWS; k++) {
        uint py = py0 + STRIDE * k;
        if (px < v.size.x && py < v.size.y) {
            uint p = v.offsets.y + py * v.size.x + px;
            out_rgbd[p] = vec4(rgbd[k].xyz + trans[k] * bg, rgbd[k].w);
            out_alpha[p] = 1.0 - trans[k];
            for (uint c = 0u; c < QUERY_VEC4; c++) {
                out_query[QUERY_VEC4 * p + c] = q[k * QUERY_VEC4 + c];
            }
            out_state[p] = uvec2(walked[k], floatBitsToUint(trans[k]));
        }
    }
}

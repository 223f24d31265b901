// Front-to-back blending of depth-sorted Gaussians: one 16x16 workgroup per
// tile of every view, one thread per pixel. The tile's Gaussians are staged
// through shared memory 256 at a time. Writes colour (with background),
// depth (sum of weight x camera z, not normalised), alpha, the 32 query
// channels, and per pixel the state the backward pass replays: how many of
// the tile's list it walked up to its last contributor, and the final
// transmittance. CPU reference: engine/src/reference/raster.rs (`render`).
#version 450
#include "common.glsl"
#include "splat.glsl"

#define BATCH 256u
#define QUERY_VEC4 8u

layout(local_size_x = 16, local_size_y = 16) in;

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
    uint py = (local_tile / v.size.z) * TILE_SIZE + gl_LocalInvocationID.y;
    bool inside = px < v.size.x && py < v.size.y;
    vec2 pix = vec2(float(px), float(py));
    uint t = gl_LocalInvocationIndex;

    uvec2 range = ranges[tile];
    uint n = range.y - range.x;
    bool done = !inside;
    float trans = 1.0;
    vec3 rgb = vec3(0.0);
    float depth = 0.0;
    vec4 q[QUERY_VEC4];
    for (uint c = 0u; c < QUERY_VEC4; c++) {
        q[c] = vec4(0.0);
    }
    uint walked = 0u;

    for (uint base = 0u; base < n; base += BATCH) {
        barrier();
        if (base + t < n) {
            uint pair = pairs[range.x + base + t];
            sh_gaussian[t] = pair % pc.n_gaussians;
            sh_splat[t] = splats[2u * pair];
            sh_conic[t] = splats[2u * pair + 1u].xyz;
        }
        barrier();
        uint count = min(BATCH, n - base);
        for (uint j = 0u; j < count && !done; j++) {
            vec4 s = sh_splat[j];
            vec3 conic = sh_conic[j];
            vec2 d = s.xy - pix;
            float sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
            if (sigma < 0.0) {
                continue;
            }
            float alpha = min(MAX_ALPHA, s.w * exp(-sigma));
            if (alpha < MIN_ALPHA) {
                continue;
            }
            float next = trans * (1.0 - alpha);
            if (next < 1e-4) {
                done = true;
                break;
            }
            float w = alpha * trans;
            uint g = sh_gaussian[j];
            rgb += w * vec3(colors[3u * g], colors[3u * g + 1u], colors[3u * g + 2u]);
            depth += w * s.z;
            for (uint c = 0u; c < QUERY_VEC4; c++) {
                q[c] += w * queries[QUERY_VEC4 * g + c];
            }
            trans = next;
            walked = base + j + 1u;
        }
    }

    if (inside) {
        uint p = v.offsets.y + py * v.size.x + px;
        out_rgbd[p] = vec4(rgb + trans * vec3(pc.bg_r, pc.bg_g, pc.bg_b), depth);
        out_alpha[p] = 1.0 - trans;
        for (uint c = 0u; c < QUERY_VEC4; c++) {
            out_query[QUERY_VEC4 * p + c] = q[c];
        }
        out_state[p] = uvec2(walked, floatBitsToUint(trans));
    }
}

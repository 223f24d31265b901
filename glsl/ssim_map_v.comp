// SSIM pass 2 of 4: vertical window sums complete the local statistics; per
// (pixel, channel) this computes the SSIM value m and the derivatives of
// the loss -weight * m with respect to the three window sums it depends on
// through x: S[x], S[x²] and S[xy]. Each workgroup adds weight * (1 - m)
// over its items to the partial sums. CPU reference:
// engine/reference/src/ssim.rs.
// @cost flops=513 * width * height bytes=(96 + 12 / 256) * width * height
// per (pixel, channel): 11 taps x 5 mul-adds, ~60 for the SSIM value and its three derivatives, 1 for the loss sum; reads 5 stats, writes 3 derivatives, and one partial per 256 items.
#version 450
#include "common.glsl"
#include "ssim.glsl"

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Stats { float stats[]; };
layout(std430, set = 0, binding = 1) buffer Dmap { float dmap[]; };
layout(std430, set = 0, binding = 2) buffer Partial { float partial_out[]; };

shared float partial[THREADS];

void main() {
    uint p, c, u, v;
    bool valid = ssim_item(p, c, u, v);
    float loss = 0.0;
    if (valid) {
        float mx = 0.0;
        float my = 0.0;
        float exx = 0.0;
        float eyy = 0.0;
        float exy = 0.0;
        for (int k = -RADIUS; k <= RADIUS; k++) {
            int vv = int(v) + k;
            if (vv < 0 || vv >= int(pc.height)) {
                continue;
            }
            uint o = ((uint(vv) * pc.width + u) * 3u + c) * 5u;
            float w = tap(k);
            mx += w * stats[o];
            my += w * stats[o + 1u];
            exx += w * stats[o + 2u];
            eyy += w * stats[o + 3u];
            exy += w * stats[o + 4u];
        }
        float sx = exx - mx * mx;
        float sy = eyy - my * my;
        float sxy = exy - mx * my;
        float num_m = 2.0 * mx * my + C1;
        float num_s = 2.0 * sxy + C2;
        float den_m = mx * mx + my * my + C1;
        float den_s = sx + sy + C2;
        float m = num_m * num_s / (den_m * den_s);
        float dm_dmx = 2.0 * my * num_s / (den_m * den_s) - m * 2.0 * mx / den_m;
        float dm_dsx = -m / den_s;
        float dm_dsxy = 2.0 * num_m / (den_m * den_s);
        float g = -pc.weight;
        uint o = (p * 3u + c) * 3u;
        dmap[o] = g * (dm_dmx - 2.0 * mx * dm_dsx - my * dm_dsxy);
        dmap[o + 1u] = g * dm_dsx;
        dmap[o + 2u] = g * dm_dsxy;
        loss = pc.weight * (1.0 - m);
    }
    uint t = gl_LocalInvocationID.x;
    partial[t] = loss;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    uint group = linear_group();
    if (t == 0u && group * THREADS < pc.width * pc.height * 3u) {
        partial_out[pc.partial_offset + group] = partial[0];
    }
}

// SSIM pass 3 of 4: the backward pass is the window applied again (the
// zero-padded symmetric window is its own adjoint): horizontal sums of the
// three derivative maps of ssim_map_v.comp. CPU reference:
// engine/reference/src/ssim.rs.
// @cost flops=198 * width * height bytes=72 * width * height
// per (pixel, channel): 11 taps x 3 mul-adds; reads and writes 3 floats.
#version 450
#include "common.glsl"
#include "ssim.glsl"

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Dmap { float dmap[]; };
layout(std430, set = 0, binding = 1) buffer Blurred { float blurred[]; };

void main() {
    uint p, c, u, v;
    if (!ssim_item(p, c, u, v)) {
        return;
    }
    float s0 = 0.0;
    float s1 = 0.0;
    float s2 = 0.0;
    for (int k = -RADIUS; k <= RADIUS; k++) {
        int uu = int(u) + k;
        if (uu < 0 || uu >= int(pc.width)) {
            continue;
        }
        uint o = ((v * pc.width + uint(uu)) * 3u + c) * 3u;
        float w = tap(k);
        s0 += w * dmap[o];
        s1 += w * dmap[o + 1u];
        s2 += w * dmap[o + 2u];
    }
    uint o = (p * 3u + c) * 3u;
    blurred[o] = s0;
    blurred[o + 1u] = s1;
    blurred[o + 2u] = s2;
}

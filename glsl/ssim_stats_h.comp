// SSIM pass 1 of 4: horizontal window sums of x, y, x², y², xy per (pixel,
// channel) of one view, x the rendered and y the target colour. See
// engine/core/src/loss/image.rs for the pass structure; CPU reference:
// engine/reference/src/ssim.rs.
// @cost flops=429 * width * height bytes=84 * width * height
// per (pixel, channel): 11 taps x (2 + 2 + 3 + 3 + 3) for the five weighted sums; reads 3 channels of rendered and target, writes 5 floats.
#version 450
#include "common.glsl"
#include "ssim.glsl"

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Rendered { vec4 rendered[]; };
layout(std430, set = 0, binding = 1) readonly buffer Target { vec4 target[]; };
layout(std430, set = 0, binding = 2) buffer Stats { float stats[]; };

void main() {
    uint p, c, u, v;
    if (!ssim_item(p, c, u, v)) {
        return;
    }
    float s0 = 0.0;
    float s1 = 0.0;
    float s2 = 0.0;
    float s3 = 0.0;
    float s4 = 0.0;
    for (int k = -RADIUS; k <= RADIUS; k++) {
        int uu = int(u) + k;
        if (uu < 0 || uu >= int(pc.width)) {
            continue;
        }
        uint q = pc.first_pixel + v * pc.width + uint(uu);
        float x = rendered[q][c];
        float y = target[q][c];
        float w = tap(k);
        s0 += w * x;
        s1 += w * y;
        s2 += w * x * x;
        s3 += w * y * y;
        s4 += w * x * y;
    }
    uint o = (p * 3u + c) * 5u;
    stats[o] = s0;
    stats[o + 1u] = s1;
    stats[o + 2u] = s2;
    stats[o + 3u] = s3;
    stats[o + 4u] = s4;
}

// SSIM pass 4 of 4: vertical sums finish the window on the derivative maps
// (s0, s1, s2 for S[x], S[x²], S[xy]); the chain rule through x gives
//     dL/dx = s0 + 2 x s1 + y s2
// added to the colour gradient of the batch image. CPU reference:
// engine/reference/src/ssim.rs.
// @cost flops=216 * width * height bytes=84 * width * height
// per (pixel, channel): 11 taps x 3 mul-adds and 6 for the chain rule and accumulation; reads 3 blurred, x, y, reads and writes grad.
#version 450
#include "common.glsl"
#include "ssim.glsl"

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Blurred { float blurred[]; };
layout(std430, set = 0, binding = 1) readonly buffer Rendered { vec4 rendered[]; };
layout(std430, set = 0, binding = 2) readonly buffer Target { vec4 target[]; };
layout(std430, set = 0, binding = 3) buffer Grad { float grad[]; };

void main() {
    uint p, c, u, v;
    if (!ssim_item(p, c, u, v)) {
        return;
    }
    float s0 = 0.0;
    float s1 = 0.0;
    float s2 = 0.0;
    for (int k = -RADIUS; k <= RADIUS; k++) {
        int vv = int(v) + k;
        if (vv < 0 || vv >= int(pc.height)) {
            continue;
        }
        uint o = ((uint(vv) * pc.width + u) * 3u + c) * 3u;
        float w = tap(k);
        s0 += w * blurred[o];
        s1 += w * blurred[o + 1u];
        s2 += w * blurred[o + 2u];
    }
    uint q = pc.first_pixel + p;
    float x = rendered[q][c];
    float y = target[q][c];
    grad[q * 4u + c] += s0 + 2.0 * x * s1 + y * s2;
}

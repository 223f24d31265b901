// Photometric L1 and depth L1 of one view of the batch, with their gradient
// (paper Eqs. 7–8). Per pixel p of the view (rendered r, target t, as R, G, B, depth):
//     grad[p].rgb = w_rgb * sign(r.rgb - t.rgb)
//     grad[p].z   = w_depth * sign(r.z - t.z)   where t.z is valid (> 0, finite), else 0
// The gradient is overwritten (the SSIM pass adds to it afterwards); each
// workgroup writes its share of both weighted losses to the partial sums.
// CPU reference: engine/reference/src/loss.rs (`image_l1_depth`).
// @cost flops=19 * pixels bytes=48 * pixels + pixels / 32
// Floor, per pixel: rgb sub, sign, scale, abs, sum (15), depth validity
// tests (2), partial sums (2); a valid depth adds 5 more (not counted: the
// host's valid_depth_pixels knows how many). Reads rendered and target
// (vec4), writes grad (vec4); two partial floats per 256 pixels.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Rendered { vec4 rendered[]; };
layout(std430, set = 0, binding = 1) readonly buffer Target { vec4 target[]; };
layout(std430, set = 0, binding = 2) buffer Grad { vec4 grad[]; };
layout(std430, set = 0, binding = 3) buffer L1Partial { float l1_partial[]; };
layout(std430, set = 0, binding = 4) buffer DepthPartial { float depth_partial[]; };

layout(push_constant) uniform Params {
    uint pixels;
    uint first_pixel;
    uint partial_offset;
    float w_rgb;
    float w_depth;
} pc;

shared vec2 partial[THREADS];

void main() {
    uint group = linear_group();
    uint t = gl_LocalInvocationID.x;
    uint i = group * THREADS + t;
    vec2 loss = vec2(0.0);
    if (i < pc.pixels) {
        uint q = pc.first_pixel + i;
        vec4 r = rendered[q];
        vec4 g = target[q];
        vec3 e = r.xyz - g.xyz;
        vec4 out_grad = vec4(pc.w_rgb * sign(e), 0.0);
        loss.x = pc.w_rgb * (abs(e.x) + abs(e.y) + abs(e.z));
        if (g.w > 0.0 && !isinf(g.w)) {
            float ez = r.w - g.w;
            out_grad.w = pc.w_depth * sign(ez);
            loss.y = pc.w_depth * abs(ez);
        }
        grad[q] = out_grad;
    }
    partial[t] = loss;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    if (t == 0u && group * THREADS < pc.pixels) {
        l1_partial[pc.partial_offset + group] = partial[0].x;
        depth_partial[pc.partial_offset + group] = partial[0].y;
    }
}

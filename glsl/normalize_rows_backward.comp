// Vector-Jacobian product of normalize_rows.comp. Given y = x/(r + eps), the
// norm r and g = dL/dy:
//     dx = beta * dx + g/(r + eps) - y (y.g)/r
// (the second term tends to 0 with r and is 0 at r = 0). beta = 0 never reads
// dx, so it may start as garbage. One workgroup per row. CPU reference:
// engine/reference/src/decoder.rs (`normalize_rows_vjp`).
// @cost flops=(5 + 2 * min(1, max(beta, 0 - beta) * 1000000)) * rows * cols + 10 * rows bytes=(12 + 4 * min(1, max(beta, 0 - beta) * 1000000)) * rows * cols + 4 * rows
// per element: the y.g dot (fma, 2), g*inv - y*k (3), + beta*dx (fma, 2,
// only when beta != 0: the min/max term is 1 for |beta| >= 1e-6, 0 for
// beta = 0); per row two divisions. Reads y, g, norm (and dx), writes dx.
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Y { float y[]; };
layout(std430, set = 0, binding = 1) readonly buffer Norm { float norm[]; };
layout(std430, set = 0, binding = 2) readonly buffer G { float g[]; };
layout(std430, set = 0, binding = 3) buffer Dx { float dx[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float eps;
    float beta;
} pc;

shared float partial[THREADS];

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint base = row * pc.cols;
    float s = 0.0;
    for (uint j = t; j < pc.cols; j += THREADS) {
        s += y[base + j] * g[base + j];
    }
    partial[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float r = norm[row];
    float k = r > 0.0 ? partial[0] / r : 0.0;
    float inv = 1.0 / (r + pc.eps);
    for (uint j = t; j < pc.cols; j += THREADS) {
        float v = g[base + j] * inv - y[base + j] * k;
        if (pc.beta != 0.0) {
            v += pc.beta * dx[base + j];
        }
        dx[base + j] = v;
    }
}

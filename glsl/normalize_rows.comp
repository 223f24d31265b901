// Row normalisation with an epsilon on the norm, as the attention decoder
// uses it (paper Eq. 5):  y[r, :] = x[r, :] / (‖x[r, :]‖ + eps),  norm[r] = ‖x[r, :]‖.
// One workgroup per row. CPU reference: engine/reference/src/decoder.rs
// (`normalize_rows`).
// @cost flops=3 * rows * cols + 9 * rows bytes=8 * rows * cols + 4 * rows
// per element: the squared norm (fma, 2) and one multiply; per row sqrt,
// add, division. Reads x, writes y and norm.
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer X { float x[]; };
layout(std430, set = 0, binding = 1) buffer Y { float y[]; };
layout(std430, set = 0, binding = 2) buffer Norm { float norm[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float eps;
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
        float v = x[base + j];
        s += v * v;
    }
    partial[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float r = sqrt(partial[0]);
    float inv = 1.0 / (r + pc.eps);
    for (uint j = t; j < pc.cols; j += THREADS) {
        y[base + j] = x[base + j] * inv;
    }
    if (t == 0u) {
        norm[row] = r;
    }
}

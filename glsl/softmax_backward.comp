// Vector-Jacobian product of a row softmax with a logit scale: for
// a = softmax(scale * s) and g = dL/da,
//     ds = scale * a * (g - sum_j a_j g_j)
// written over g (in place: each element is read and written by the same
// thread, after the row's dot product is complete). One workgroup per row.
// CPU reference: engine/reference/src/decoder.rs (`backward`).
// @cost flops=5 * rows * cols bytes=12 * rows * cols
// per element: the a.g dot (fma, 2) and scale * a * (g - dot) (3); reads a
// and g, writes g.
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer A { float a[]; };
layout(std430, set = 0, binding = 1) buffer G { float g[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float scale;
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
        s += a[base + j] * g[base + j];
    }
    partial[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float dot = partial[0];
    for (uint j = t; j < pc.cols; j += THREADS) {
        g[base + j] = pc.scale * a[base + j] * (g[base + j] - dot);
    }
}

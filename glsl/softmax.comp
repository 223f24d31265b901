// Row softmax:  y[r, :] = softmax(scale * x[r, :]) for a rows x cols matrix,
// one workgroup per row. Each thread keeps a running (max, sum of exp) pair
// that is rescaled when the max grows (online softmax), so the row is read
// twice instead of three times. CPU reference: engine/reference/src/softmax.rs.
// @cost flops=27 * rows * cols + 4 * rows bytes=8 * rows * cols
// per element: pass 1 scale, compare, sub, exp, add (14); pass 2 fma, exp,
// mul (13); per row one division. Reads x once, writes y.
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer X { float x[]; };
layout(std430, set = 0, binding = 1) buffer Y { float y[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float scale;
} pc;

shared float smax[THREADS];
shared float ssum[THREADS];

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint base = row * pc.cols;
    float m = uintBitsToFloat(0xff800000u);
    float s = 0.0;
    for (uint j = t; j < pc.cols; j += THREADS) {
        float v = pc.scale * x[base + j];
        if (v > m) {
            s = s * exp(m - v) + 1.0;
            m = v;
        } else {
            s += exp(v - m);
        }
    }
    smax[t] = m;
    ssum[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            float m1 = smax[t];
            float m2 = smax[t + h];
            float mm = max(m1, m2);
            // Threads that saw no element carry (-inf, 0); keep them at 0.
            float s1 = m1 == mm ? ssum[t] : ssum[t] * exp(m1 - mm);
            float s2 = m2 == mm ? ssum[t + h] : ssum[t + h] * exp(m2 - mm);
            smax[t] = mm;
            ssum[t] = s1 + s2;
        }
        barrier();
    }
    float rmax = smax[0];
    float inv = 1.0 / ssum[0];
    for (uint j = t; j < pc.cols; j += THREADS) {
        y[base + j] = exp(pc.scale * x[base + j] - rmax) * inv;
    }
}

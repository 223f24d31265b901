// Trust-region penalty on the dictionary (paper Eq. 6, third term): for each atom k,
//     loss_k = lambda * max(0, |D_k - D0_k| - radius)
//     grad_k += lambda * (D_k - D0_k) / |D_k - D0_k|   when the norm exceeds radius
// The gradient is added to `grad` (the decoder's dL/dD); `atom_loss` is
// overwritten. One workgroup per atom. CPU reference:
// engine/reference/src/loss.rs (`trust_region`).
// @cost flops=3 * rows * cols + 6 * rows bytes=8 * rows * cols + 4 * rows
// Floor: per element sub + fma for the norm; per row sqrt, compare, select.
// Reads atoms and anchor, writes atom_loss. Each atom past the radius also
// adds 3 flops and 8 bytes (grad read-modify-write) per element, not counted
// (how many is known only on the device).
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Atoms { float atoms[]; };
layout(std430, set = 0, binding = 1) readonly buffer Anchor { float anchor[]; };
layout(std430, set = 0, binding = 2) buffer Grad { float grad[]; };
layout(std430, set = 0, binding = 3) buffer AtomLoss { float atom_loss[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float lambda;
    float radius;
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
        float e = atoms[base + j] - anchor[base + j];
        s += e * e;
    }
    partial[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float norm = sqrt(partial[0]);
    bool active = norm > pc.radius;
    if (active) {
        float k = pc.lambda / norm;
        for (uint j = t; j < pc.cols; j += THREADS) {
            grad[base + j] += k * (atoms[base + j] - anchor[base + j]);
        }
    }
    if (t == 0u) {
        atom_loss[row] = active ? pc.lambda * (norm - pc.radius) : 0.0;
    }
}

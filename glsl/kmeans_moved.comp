// Which atoms a k-means update changed, for the optimiser's moment reset:
// flag = 1 for a new row (k >= old_count) or when |D_k - old_k| > tolerance.
// One workgroup per atom. CPU reference: engine/reference/src/kmeans.rs.
// @cost flops=min(old_count, atoms_count) * (3 * dim + 5) bytes=8 * dim * min(old_count, atoms_count) + 4 * atoms_count
// per old atom: dim subtract + mul-adds, a sqrt and a compare, reading its new and old rows; one flag written per atom.
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Atoms { float atoms[]; };
layout(std430, set = 0, binding = 1) readonly buffer Old { float old[]; };
layout(std430, set = 0, binding = 2) buffer Moved { uint moved[]; };

layout(push_constant) uniform Params {
    uint atoms_count;
    uint old_count;
    uint dim;
    float tolerance;
} pc;

shared float partial[THREADS];

void main() {
    uint k = linear_group();
    if (k >= pc.atoms_count) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    if (k >= pc.old_count) {
        if (t == 0u) {
            moved[k] = 1u;
        }
        return;
    }
    float s = 0.0;
    for (uint i = t; i < pc.dim; i += THREADS) {
        float e = atoms[k * pc.dim + i] - old[k * pc.dim + i];
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
    if (t == 0u) {
        moved[k] = sqrt(partial[0]) > pc.tolerance ? 1u : 0u;
    }
}

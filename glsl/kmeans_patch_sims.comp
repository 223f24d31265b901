// After kmeans_novelty.comp replaced some warm-start centres by
// micro-centres, recomputes just those columns of the point-to-centre
// cosine matrix (rows x atoms) instead of the whole (K + m) x K x d_f
// product: sims[r, replaced[j]] = unit[r] . unit[atoms + j], the
// micro-centres being the last rows of the unit points. One thread per
// (point, micro-centre). CPU reference: engine/reference/src/kmeans.rs.
// @cost flops=2 * dim * rows * min(micro_count, atoms / 2) bytes=4 * dim * rows + 4 * rows * min(micro_count, atoms / 2) + 4 * micro_count
// worst case, as kmeans_novelty's: every micro-centre took a slot (at most min(micro_count, atoms / 2)); a dim-long dot per (point, replaced column),
// reading every unit row once (the micro-centres are the last rows) and writing one sims entry each.
#version 450
#include "common.glsl"

#define THREADS 256
#define NONE 0xffffffffu

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Unit { float unit[]; };
layout(std430, set = 0, binding = 1) readonly buffer Replaced { uint replaced[]; };
layout(std430, set = 0, binding = 2) buffer Sims { float sims[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint atoms;
    uint micro_count;
    uint dim;
} pc;

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.rows * pc.micro_count) {
        return;
    }
    uint r = i / pc.micro_count;
    uint j = i % pc.micro_count;
    uint slot = replaced[j];
    if (slot == NONE) {
        return;
    }
    uint c = pc.atoms + j;
    float s = 0.0;
    for (uint k = 0u; k < pc.dim; k++) {
        s += unit[r * pc.dim + k] * unit[c * pc.dim + k];
    }
    sims[r * pc.atoms + slot] = s;
}

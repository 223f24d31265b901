// Advances the per-row Adam step counts after adam_step.comp (a separate
// pass, because every element of a row reads the count during the update).
// CPU reference: engine/reference/src/adam.rs.
// @cost flops=rows bytes=8 * rows + 4 * use_mask * rows
// one increment per row (step count read and written; mask read); with a
// mask, counts every row as advanced (an upper bound).
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer Steps { uint steps[]; };
layout(std430, set = 0, binding = 1) readonly buffer Mask { uint mask[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint use_mask;
} pc;

void main() {
    uint row = linear_group() * THREADS + gl_LocalInvocationID.x;
    // Nested ifs: naga evaluates both operands of `||` and `&&`, and
    // mask[row] is out of bounds past the rows (or without a mask).
    if (row >= pc.rows) {
        return;
    }
    if (pc.use_mask != 0u) {
        if (mask[row] == 0u) {
            return;
        }
    }
    steps[row] += 1u;
}

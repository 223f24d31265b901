// Forgets the Adam history of the rows whose flag is non-zero (e.g.
// dictionary atoms that streaming k-means moved or replaced): both moments
// and the step count go back to zero. CPU reference:
// engine/reference/src/adam.rs.
// @cost flops=elems bytes=4 * elems / max(width, 1)
// Floor: one flag test per element, the flags read once per row. Each flagged
// row also writes 8 * width + 4 bytes (moments and step count), not counted:
// which rows are flagged is known only on the device.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer M { float m1[]; };
layout(std430, set = 0, binding = 1) buffer V { float m2[]; };
layout(std430, set = 0, binding = 2) buffer Steps { uint steps[]; };
layout(std430, set = 0, binding = 3) readonly buffer Flags { uint flags[]; };

layout(push_constant) uniform Params {
    uint elems;
    uint width;
} pc;

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.elems) {
        return;
    }
    uint row = i / pc.width;
    if (flags[row] == 0u) {
        return;
    }
    m1[i] = 0.0;
    m2[i] = 0.0;
    if (i % pc.width == 0u) {
        steps[row] = 0u;
    }
}

// One Adam update of a parameter tensor of `rows` rows x `width` columns,
// with a step count per row (bias correction per row, so rows that sit out
// steps or had their moments reset are corrected for their own history):
//     m = b1 m + (1 - b1) g ;  v = b2 v + (1 - b2) g^2
//     p -= lr * (m / (1 - b1^t)) / (sqrt(v / (1 - b2^t)) + eps),  t = steps[row] + 1
// Rows whose mask is 0 (when use_mask != 0) are left untouched, and so is an
// element whose gradient is not finite (it must not poison the map).
// adam_count.comp advances the step counts afterwards. CPU reference:
// engine/reference/src/adam.rs.
// @cost flops=52 * elems bytes=28 * elems + 4 * (1 + use_mask) * elems / max(width, 1)
// per element: finite test (2), moments (9), two bias corrections with pow
// (30), the update with sqrt and division (11); param, m, v read and written,
// grad read; steps (and mask) once per row. With a mask, counts every row as
// updated (an upper bound).
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer Param { float param[]; };
layout(std430, set = 0, binding = 1) readonly buffer Grad { float grad[]; };
layout(std430, set = 0, binding = 2) buffer M { float m1[]; };
layout(std430, set = 0, binding = 3) buffer V { float m2[]; };
layout(std430, set = 0, binding = 4) readonly buffer Steps { uint steps[]; };
layout(std430, set = 0, binding = 5) readonly buffer Mask { uint mask[]; };

layout(push_constant) uniform Params {
    uint elems;
    uint width;
    uint use_mask;
    float lr;
    float beta1;
    float beta2;
    float eps;
} pc;

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.elems) {
        return;
    }
    uint row = i / pc.width;
    // Nested: naga evaluates both operands of `&&`, and without a mask the
    // bound buffer may be shorter than the rows.
    if (pc.use_mask != 0u) {
        if (mask[row] == 0u) {
            return;
        }
    }
    float g = grad[i];
    if (isnan(g) || isinf(g)) {
        return;
    }
    float t = float(steps[row] + 1u);
    float m = pc.beta1 * m1[i] + (1.0 - pc.beta1) * g;
    float v = pc.beta2 * m2[i] + (1.0 - pc.beta2) * g * g;
    m1[i] = m;
    m2[i] = v;
    float mhat = m / (1.0 - pow(pc.beta1, t));
    float vhat = v / (1.0 - pow(pc.beta2, t));
    param[i] -= pc.lr * mhat / (sqrt(vhat) + pc.eps);
}

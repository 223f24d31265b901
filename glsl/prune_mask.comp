// Marks the window's Gaussians that pruning removes, 32 rows a word: bit
// b of mask[w] is set for row r = 32w + b < rows when
//   !(opacity_logit[r] >= min_logit) or !(s <= max_log_scale),
//   s = the largest of the row's three log scales that are numbers
//       (starting from -FLT_MAX: a NaN scale is passed over),
// so a NaN opacity is pruned and a NaN scale is not (the host's rule
// before this kernel). NaNs are told by their bits, not by comparisons: a
// driver may assume no operand is NaN unless the module says otherwise. Bits past the rows stay clear. The host reads back
// one bit a row instead of 16 bytes (scales and opacity), and within the
// wait that ends Stage II rather than one of its own.
// CPU reference: engine/reference/src/prune.rs (`prune_mask`).
// @kernel prune_mask
// @cost flops=4 * rows bytes=16 * rows + 4 * words
// Per row: three comparisons for the largest scale and two against the
// bounds, reading 16 bytes; one word written per 32 rows.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 1) readonly buffer OpacityLogits { float opacity_logits[]; };
layout(std430, set = 0, binding = 2) buffer Mask { uint mask[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint words;
    float min_logit;
    float max_log_scale;
} pc;

bool is_nan(float x) {
    return (floatBitsToUint(x) & 0x7fffffffu) > 0x7f800000u;
}

void main() {
    uint w = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (w >= pc.words) {
        return;
    }
    uint bits = 0u;
    for (uint b = 0u; b < 32u; b++) {
        uint r = 32u * w + b;
        if (r >= pc.rows) {
            break;
        }
        float s = -3.402823466e38;
        for (uint c = 0u; c < 3u; c++) {
            float x = log_scales[3u * r + c];
            if (!is_nan(x) && x > s) {
                s = x;
            }
        }
        float o = opacity_logits[r];
        bool keep_opacity = !is_nan(o) && o >= pc.min_logit;
        bool keep_scale = s <= pc.max_log_scale;
        if (!keep_opacity || !keep_scale) {
            bits |= 1u << b;
        }
    }
    mask[w] = bits;
}

// Expands one keyframe kept in its compact form on the GPU into Stage I's
// per-pixel inputs, for the pixels i < pixels of one view of a chunk:
//   the image loss's target (when write_target is 1),
//     target[first_pixel + i] = (rgb[3i] / scale, rgb[3i+1] / scale,
//                                rgb[3i+2] / scale, depth_mm[i] * 0.001)
//     with scale = 255 * the keyframe's exposure gain (depth 0, invalid,
//     stays 0);
//   the region each pixel pools into (when write_labels is 1),
//     labels[first_pixel + i] = row_base + local[i], or NO_REGION where
//     local[i] is 0xffff or the view has no regions (has_labels 0),
//     local being the view's own region rows (the chunk's rows of its
//     regions start at row_base).
// `rgb` is the byte string from word rgb_word of `packed`, four bytes a
// word in memory order (little-endian, the byte order of every Vulkan
// host); `depth_mm` and `local` the 16-bit strings from depth_word and
// label_word, two a word. Kept this way a replayed keyframe uploads
// nothing: 7 bytes a pixel stay on the GPU instead of 20 crossing the link
// at every step.
// CPU reference: engine/reference/src/targets.rs (`unpack_target`,
// `unpack_labels`).
// @kernel target_unpack
// @cost flops=5 * write_target * pixels + write_labels * pixels bytes=21 * write_target * pixels + 6 * write_labels * pixels
// Per pixel: three divisions, a multiplication and the byte extraction,
// reading 5 bytes and writing a vec4; per label an addition, reading 2
// bytes and writing 4.
#version 450
#include "common.glsl"
#include "shared.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Packed { uint packed[]; };
layout(std430, set = 0, binding = 1) buffer Target { vec4 target[]; };
layout(std430, set = 0, binding = 2) buffer Labels { uint labels[]; };

layout(push_constant) uniform Params {
    uint pixels;
    uint rgb_word;
    uint depth_word;
    uint label_word;
    uint first_pixel;
    uint row_base;
    uint write_target;
    uint write_labels;
    uint has_labels;
    float scale;
} pc;

uint byte_at(uint k) {
    return (packed[pc.rgb_word + (k >> 2)] >> ((k & 3u) * 8u)) & 0xffu;
}

uint half_at(uint word, uint i) {
    return (packed[word + (i >> 1)] >> ((i & 1u) * 16u)) & 0xffffu;
}

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.pixels) {
        return;
    }
    if (pc.write_target != 0u) {
        uint k = 3u * i;
        vec3 rgb = vec3(float(byte_at(k)), float(byte_at(k + 1u)), float(byte_at(k + 2u)));
        float d = float(half_at(pc.depth_word, i));
        target[pc.first_pixel + i] = vec4(rgb / pc.scale, d * 0.001);
    }
    if (pc.write_labels != 0u) {
        uint row = NO_REGION;
        if (pc.has_labels != 0u) {
            uint local = half_at(pc.label_word, i);
            if (local != 0xffffu) {
                row = pc.row_base + local;
            }
        }
        labels[pc.first_pixel + i] = row;
    }
}

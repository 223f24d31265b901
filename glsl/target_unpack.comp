// Expands one keyframe kept in its compact form (packed RGB bytes and
// millimetre depth, as the host keeps it for replay) into the image loss's
// target: per pixel i < pixels,
//     target[target_pixel + i] = (rgb[3i] / scale, rgb[3i+1] / scale,
//                                 rgb[3i+2] / scale, depth_mm[i] * 0.001)
// where scale = 255 * the keyframe's exposure gain, and depth 0 stays 0
// (invalid). `rgb` is the byte string starting at word rgb_word of
// `packed`, four bytes a word in memory order (little-endian, the byte
// order of every Vulkan host); `depth_mm` the 16-bit string starting at
// word depth_word, two a word. Keeping the compact form on the GPU is what
// lets a replayed keyframe cost no upload: 5 bytes a pixel instead of 16.
// CPU reference: engine/reference/src/targets.rs (`unpack_target`).
// @kernel target_unpack
// @cost flops=5 * pixels bytes=21 * pixels
// Per pixel: three divisions, a multiplication and the byte extraction;
// reads 5 bytes of the compact form, writes a vec4.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Packed { uint packed[]; };
layout(std430, set = 0, binding = 1) buffer Target { vec4 target[]; };

layout(push_constant) uniform Params {
    uint pixels;
    uint rgb_word;
    uint depth_word;
    uint target_pixel;
    float scale;
} pc;

uint byte_at(uint k) {
    return (packed[pc.rgb_word + (k >> 2)] >> ((k & 3u) * 8u)) & 0xffu;
}

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.pixels) {
        return;
    }
    uint k = 3u * i;
    vec3 rgb = vec3(float(byte_at(k)), float(byte_at(k + 1u)), float(byte_at(k + 2u)));
    uint d = (packed[pc.depth_word + (i >> 1)] >> ((i & 1u) * 16u)) & 0xffffu;
    target[pc.target_pixel + i] = vec4(rgb / pc.scale, float(d) * 0.001);
}

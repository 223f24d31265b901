// Gathers a rendered view at the pixels of a grid: every `stride`-th pixel
// across and down from (start_u, start_v), as seeding looks at a keyframe
// (its candidate pixels). For cell k < count, row r = k / cols and column
// c = k % cols (count cells in all),
//   i = first_pixel + (start_v + r * stride) * width + start_u + c * stride
//   cells[4k .. 4k + 4] = rgbd[i]   (colour and unnormalised depth)
//   cells[4 * count + k] = alpha[i]
// Words are copied as bits, so the cells hold exactly what the full images
// hold there. Reading back the grid instead of the images takes 20 bytes a
// cell across the host link instead of 20 a pixel: a quarter at seeding's
// stride of 2 (640x480), a ninth at 3 (1280x720). The host checks that
// every pixel of the grid lies in the view. CPU reference:
// engine/reference/src/grid.rs (`gather_grid`).
// @kernel coverage_grid
// @cost flops=0 bytes=40 * count
// Per cell: a vec4 and a float read, the same written.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

// Four words a pixel: r, g, b and the unnormalised depth.
layout(std430, set = 0, binding = 0) readonly buffer Rgbd { uint rgbd[]; };
layout(std430, set = 0, binding = 1) readonly buffer Alpha { uint alpha[]; };
layout(std430, set = 0, binding = 2) buffer Cells { uint cells[]; };

layout(push_constant) uniform Params {
    uint count;
    uint cols;
    uint stride;
    uint start_u;
    uint start_v;
    uint width;
    uint first_pixel;
} pc;

void main() {
    uint k = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (k >= pc.count) {
        return;
    }
    uint r = k / pc.cols;
    uint c = k - r * pc.cols;
    uint i = pc.first_pixel + (pc.start_v + r * pc.stride) * pc.width + pc.start_u + c * pc.stride;
    for (uint j = 0u; j < 4u; j++) {
        cells[4u * k + j] = rgbd[4u * i + j];
    }
    cells[4u * pc.count + k] = alpha[i];
}

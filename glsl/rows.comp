// Moves whole rows of 32-bit words between a row-major buffer and a packed
// staging buffer, by a list of row indices: what the GPU window's paging
// moves when a block of Gaussians leaves or enters the window.
//   gather:  staging[first + i * width + j] = data[index[list + i] * width + j]
//   scatter: data[index[list + i] * width + j] = staging[first + i * width + j]
// for i < count and j < width. `first` places the rows in a staging buffer
// that packs several fields one after another (the window's outbox);
// `list` is where the row list starts in the index buffer. Words are copied
// as bits (uint), so every value, NaN payloads and signed zeros included,
// moves unchanged. One invocation per word; the host checks that every
// range fits its buffer. CPU reference: engine/reference/src/rows.rs.
// @kernel rows_gather GATHER=1
// @kernel rows_scatter GATHER=0
// @cost flops=0 bytes=8 * count * width + 4 * count
// Per word: one read and one write; per row: its index.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) buffer Staging { uint staging[]; };
layout(std430, set = 0, binding = 2) readonly buffer Index { uint index[]; };

layout(push_constant) uniform Params {
    uint count;
    uint width;
    uint first;
    uint list;
} pc;

void main() {
    uint k = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (k >= pc.count * pc.width) {
        return;
    }
    uint i = k / pc.width;
    uint at = index[pc.list + i] * pc.width + (k - i * pc.width);
#if GATHER
    staging[pc.first + k] = data[at];
#else
    data[at] = staging[pc.first + k];
#endif
}

// Moves whole rows of 32-bit words within one row-major buffer:
//   data[index[list + count + i] * width + j] = data[index[list + i] * width + j]
// for i < count and j < width: row index[list + i] goes to row
// index[list + count + i]. The window's compaction: rows from its tail fill
// the rows its leaving Gaussians freed. No row may be both a source and a
// destination, and no destination may repeat (the host builds the lists
// so: sources lie at or above the rows kept, destinations below), so the
// invocations never race and need no staging copy. Words move as bits.
// CPU reference: engine/reference/src/rows.rs (`move_rows`).
// @kernel rows_move
// @cost flops=0 bytes=8 * count * width + 8 * count
// Per word: one read and one write; per row: its two indices.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) buffer Data { uint data[]; };
layout(std430, set = 0, binding = 1) readonly buffer Index { uint index[]; };

layout(push_constant) uniform Params {
    uint count;
    uint width;
    uint list;
} pc;

void main() {
    uint k = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (k >= pc.count * pc.width) {
        return;
    }
    uint i = k / pc.width;
    uint j = k - i * pc.width;
    uint from = index[pc.list + i] * pc.width + j;
    uint to = index[pc.list + pc.count + i] * pc.width + j;
    data[to] = data[from];
}

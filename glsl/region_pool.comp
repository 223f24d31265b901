// Region pooling: the mean rendered query of each region's pixels,
//     pooled[first_row + r, c] = (1/|r|) sum_{p in r} query[p, c]
// (first_row places a chunk of views' regions among the batch's rows)
// over a CSR list of pixel indices (built on the CPU, so no atomics). One
// workgroup per region: 8 pixel lanes x 32 channels, lanes summed in shared
// memory. Regions are never empty (the builder drops small ones). CPU
// reference: engine/reference/src/pooling.rs.
// @cost caller
// host formula, with P = member pixels of the uploaded regions (regions.pixels.len() = offsets[regions], known to the host at record_upload_at):
//   flops = 32 * P + 128 * regions  (one add per member pixel and channel, one divide per pooled value)
//   bytes = 132 * P + 132 * regions + 4  (pixel indices and 32-float query rows of the members; offsets; pooled rows written).
#version 450
#include "common.glsl"

#define CHANNELS 32
#define LANES 8

layout(local_size_x = LANES * CHANNELS) in;

layout(std430, set = 0, binding = 0) readonly buffer Query { float query[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 2) readonly buffer Pixels { uint pixels[]; };
layout(std430, set = 0, binding = 3) buffer Pooled { float pooled[]; };

layout(push_constant) uniform Params {
    uint regions;
    uint first_row;
} pc;

shared float partial[LANES * CHANNELS];

void main() {
    uint r = linear_group();
    if (r >= pc.regions) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint lane = t / CHANNELS;
    uint c = t % CHANNELS;
    uint begin = offsets[r];
    uint end = offsets[r + 1u];
    float s = 0.0;
    for (uint i = begin + lane; i < end; i += LANES) {
        s += query[pixels[i] * CHANNELS + c];
    }
    partial[t] = s;
    barrier();
    for (uint h = LANES / 2u; h > 0u; h /= 2u) {
        if (lane < h) {
            partial[t] += partial[t + h * CHANNELS];
        }
        barrier();
    }
    if (lane == 0u) {
        pooled[(pc.first_row + r) * CHANNELS + c] = partial[c] / float(end - begin);
    }
}

// Gradient of region pooling with respect to the rendered query image:
//     grad_query[p, c] = grad_pooled[first_row + r(p), c] / |r(p)|,  0 for pixels in no region
// Regions are disjoint (one label per pixel), so each pixel has at most one
// region and the whole image gradient is overwritten without atomics. One
// thread per (pixel, channel). CPU reference: engine/reference/src/pooling.rs.
// @cost caller
// host formula, with P = member pixels of the uploaded regions (regions.pixels.len(), as for region_pool) and R = that upload's region count (self.regions()):
//   flops = 128 * P  (a divide per member (pixel, channel); pixels in no region store 0)
//   bytes = 132 * pixels + 132 * R + 4  (pixel_region read and 32 gradients written per pixel; grad_pooled rows and offsets read).
#version 450
#include "common.glsl"
#include "shared.glsl"

#define CHANNELS 32
#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer GradPooled { float grad_pooled[]; };
layout(std430, set = 0, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, set = 0, binding = 2) readonly buffer PixelRegion { uint pixel_region[]; };
layout(std430, set = 0, binding = 3) buffer GradQuery { float grad_query[]; };

layout(push_constant) uniform Params {
    uint pixels;
    uint first_row;
} pc;

void main() {
    uint i = linear_group() * THREADS + gl_LocalInvocationID.x;
    if (i >= pc.pixels * CHANNELS) {
        return;
    }
    uint p = i / CHANNELS;
    uint c = i % CHANNELS;
    uint r = pixel_region[p];
    float g = 0.0;
    if (r != NO_REGION) {
        g = grad_pooled[(pc.first_row + r) * CHANNELS + c] / float(offsets[r + 1u] - offsets[r]);
    }
    grad_query[i] = g;
}

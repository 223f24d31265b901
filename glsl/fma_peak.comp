// Arithmetic-throughput probe for `latentam bench primitives`: every
// invocation runs `iters` rounds of 8 independent multiply-adds in registers
// and writes one value (so the work cannot be optimised away). It measures
// the device's attainable f32 FLOP rate, the yardstick for compute-bound
// kernels. No CPU reference: its output is only a sink.
// @cost flops=16 * iters * invocations bytes=4 * invocations
// per invocation iters rounds of 8 fmas (as measure_fma_peak counts them),
// one float written; every launched invocation does the work.
#version 450
#include "common.glsl"

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) buffer Sink { float sink[]; };

layout(push_constant) uniform Params {
    uint iters;
    float seed;
} pc;

void main() {
    uint i = linear_group() * 256u + gl_LocalInvocationID.x;
    float x = pc.seed * float(i & 7u);
    float a0 = x, a1 = x + 1.0, a2 = x + 2.0, a3 = x + 3.0;
    float a4 = x + 4.0, a5 = x + 5.0, a6 = x + 6.0, a7 = x + 7.0;
    float m = 0.999;
    float c = 0.001;
    for (uint k = 0u; k < pc.iters; k++) {
        a0 = a0 * m + c; a1 = a1 * m + c; a2 = a2 * m + c; a3 = a3 * m + c;
        a4 = a4 * m + c; a5 = a5 * m + c; a6 = a6 * m + c; a7 = a7 * m + c;
    }
    sink[i] = a0 + a1 + a2 + a3 + a4 + a5 + a6 + a7;
}

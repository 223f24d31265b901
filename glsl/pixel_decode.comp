// Per-pixel decoding of rendered queries (paper Eq. 5) for evaluation and
// relevance images, one workgroup per pixel, around two GEMMs:
// L = Q M (M = W D̂ᵀ, QUERY_DIM x K, computed once per map) before
// pixel_attention, and E = A D between it and pixel_norms.
//
// pixel_attention: the attention a = softmax_k(L_k / (τ (‖qW‖ + ε))), with
//   ‖qW‖² = q G qᵀ (G = W Wᵀ), written over the logits. Rows are `stride`
//   long (K rounded up to 4, so the GEMMs load 16 bytes at a time); the
//   columns past K are set to 0.
// pixel_norms: ‖e‖ and ⟨e, t_r⟩ for the unit target t_r of the pixel's
//   region r (0 for NO_REGION) from the pixel's row e of E.
//
// CPU references: FactorisedDecoder in engine/core/src/latent/pixel_decoder.rs
// (the same quantities, factorised) and the explicit f64 decoder of
// engine/reference/src/decoder.rs.
//
// @kernel pixel_attention STEP=0
// @kernel pixel_norms STEP=1
// @cost pixel_attention: flops=27 * rows * atoms + 2126 * rows bytes=4 * rows * atoms + 4 * rows * stride + 128 * rows + 4096
// per pixel: q G q (32x32 fma + 32 mul + 32 add = 2112), the scale (10),
// one division; per atom the online softmax as softmax.comp (27). Reads the
// row's logits, 32 query floats and G (32x32) once; writes stride floats.
// @cost pixel_norms: flops=2 * rows * dim + 2 * rows * dim * min(regions, 1) + 4 * rows bytes=4 * rows * dim + 12 * rows + 4 * min(regions, rows) * dim
// The norm's mul-add per element, a square root per pixel; with targets
// (regions > 0) each pixel's dot with its region's target, counted for every
// pixel (pixels outside every region skip it). Reads E, region and the
// targets used; writes norm and target_dot.
#version 450
#include "common.glsl"
#include "shared.glsl"

#define THREADS 64
#define QDIM 32

layout(local_size_x = THREADS) in;

#if STEP == 0
layout(std430, set = 0, binding = 0) buffer Weights { float weights[]; };
layout(std430, set = 0, binding = 1) readonly buffer Queries { float queries[]; };
layout(std430, set = 0, binding = 2) readonly buffer QueryGram { float query_gram[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint atoms;
    uint stride;
    float inv_tau;
    float eps;
} pc;

shared float smax[THREADS];
shared float ssum[THREADS];

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint qbase = row * QDIM;
    // ‖qW‖² = Σ_i q_i (G q)_i: thread i < QDIM forms one term.
    float term = 0.0;
    if (t < QDIM) {
        float gq = 0.0;
        for (uint j = 0u; j < QDIM; j++) {
            gq += query_gram[t * QDIM + j] * queries[qbase + j];
        }
        term = queries[qbase + t] * gq;
    }
    ssum[t] = term;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            ssum[t] += ssum[t + h];
        }
        barrier();
    }
    float scale = pc.inv_tau / (sqrt(max(ssum[0], 0.0)) + pc.eps);
    barrier();

    // Online softmax over the row (see softmax.comp).
    uint base = row * pc.stride;
    float m = uintBitsToFloat(0xff800000u);
    float s = 0.0;
    for (uint j = t; j < pc.atoms; j += THREADS) {
        float v = scale * weights[base + j];
        if (v > m) {
            s = s * exp(m - v) + 1.0;
            m = v;
        } else {
            s += exp(v - m);
        }
    }
    smax[t] = m;
    ssum[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            float m1 = smax[t];
            float m2 = smax[t + h];
            float mm = max(m1, m2);
            float s1 = m1 == mm ? ssum[t] : ssum[t] * exp(m1 - mm);
            float s2 = m2 == mm ? ssum[t + h] : ssum[t + h] * exp(m2 - mm);
            smax[t] = mm;
            ssum[t] = s1 + s2;
        }
        barrier();
    }
    float rmax = smax[0];
    float inv = 1.0 / ssum[0];
    for (uint j = t; j < pc.stride; j += THREADS) {
        float a = 0.0;
        if (j < pc.atoms) {
            a = exp(scale * weights[base + j] - rmax) * inv;
        }
        weights[base + j] = a;
    }
}
#else
layout(std430, set = 0, binding = 0) readonly buffer Embeddings { float embeddings[]; };
layout(std430, set = 0, binding = 1) readonly buffer Region { uint region[]; };
layout(std430, set = 0, binding = 2) readonly buffer Targets { float targets[]; };
layout(std430, set = 0, binding = 3) buffer Norm { float norm[]; };
layout(std430, set = 0, binding = 4) buffer TargetDot { float target_dot[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint dim;
    uint regions;
} pc;

shared float snorm[THREADS];
shared float sdot[THREADS];

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint r = region[row];
    bool has_target = r != NO_REGION && r < pc.regions;
    float n2 = 0.0;
    float dot_t = 0.0;
    for (uint d = t; d < pc.dim; d += THREADS) {
        float e = embeddings[row * pc.dim + d];
        n2 += e * e;
        if (has_target) {
            dot_t += e * targets[r * pc.dim + d];
        }
    }
    snorm[t] = n2;
    sdot[t] = dot_t;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            snorm[t] += snorm[t + h];
            sdot[t] += sdot[t + h];
        }
        barrier();
    }
    if (t == 0u) {
        norm[row] = sqrt(snorm[0]);
        target_dot[row] = sdot[0];
    }
}
#endif

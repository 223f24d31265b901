// Per-pixel decoding of rendered queries (paper Eq. 5) for evaluation and
// relevance images, one workgroup per pixel, in two steps around the GEMM
// of the logits L = Q M (M = W D̂ᵀ, QUERY_DIM x K, computed once per map):
//
// pixel_attention: the attention a = softmax_k(L_k / (τ (‖qW‖ + ε))), with
//   ‖qW‖² = q G qᵀ (G = W Wᵀ), written over the logits; and the atoms the
//   pixel's embedding needs, those weighing at least `cutoff` of the
//   largest weight (1/Σ, since the largest exponent is 0), listed with
//   their count. Leaving the others out changes e by less than
//   K x cutoff of its largest term: sharp attention (τ = 0.05) uses few
//   atoms, so the embedding costs |S| d_f instead of K d_f.
// pixel_embed: e = Σ_{k in S} a_k D_k written as the pixel's row of
//   `embeddings`, with ‖e‖ and ⟨e, t_r⟩ for the unit target t_r of the
//   pixel's region r (0 for NO_REGION).
//
// CPU references: FactorisedDecoder in engine/core/src/latent/pixel_decoder.rs
// (the same factorisation) and the explicit f64 decoder of
// engine/reference/src/decoder.rs.
//
// @kernel pixel_attention STEP=0
// @kernel pixel_embed STEP=1
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
layout(std430, set = 0, binding = 3) buffer Used { uint used[]; };
layout(std430, set = 0, binding = 4) buffer UsedCount { uint used_count[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint atoms;
    float inv_tau;
    float eps;
    float cutoff;
} pc;

shared float smax[THREADS];
shared float ssum[THREADS];
shared uint sfirst[THREADS];

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
    uint base = row * pc.atoms;
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
    // The largest weight is exp(0) / Σ.
    float cut = pc.cutoff * inv;

    // Count this thread's kept atoms, then place them after those of the
    // threads before it.
    uint count = 0u;
    for (uint j = t; j < pc.atoms; j += THREADS) {
        if (exp(scale * weights[base + j] - rmax) * inv >= cut) {
            count += 1u;
        }
    }
    sfirst[t] = count;
    barrier();
    if (t == 0u) {
        uint total = 0u;
        for (uint i = 0u; i < THREADS; i++) {
            uint c = sfirst[i];
            sfirst[i] = total;
            total += c;
        }
        used_count[row] = total;
    }
    barrier();
    uint next = base + sfirst[t];
    for (uint j = t; j < pc.atoms; j += THREADS) {
        float a = exp(scale * weights[base + j] - rmax) * inv;
        weights[base + j] = a;
        if (a >= cut) {
            used[next] = j;
            next += 1u;
        }
    }
}
#else
layout(std430, set = 0, binding = 0) readonly buffer Weights { float weights[]; };
layout(std430, set = 0, binding = 1) readonly buffer Used { uint used[]; };
layout(std430, set = 0, binding = 2) readonly buffer UsedCount { uint used_count[]; };
layout(std430, set = 0, binding = 3) readonly buffer Atoms { float atoms_d[]; };
layout(std430, set = 0, binding = 4) readonly buffer Region { uint region[]; };
layout(std430, set = 0, binding = 5) readonly buffer Targets { float targets[]; };
layout(std430, set = 0, binding = 6) buffer Embeddings { float embeddings[]; };
layout(std430, set = 0, binding = 7) buffer Norm { float norm[]; };
layout(std430, set = 0, binding = 8) buffer TargetDot { float target_dot[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint atoms;
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
    uint base = row * pc.atoms;
    uint n = used_count[row];
    uint r = region[row];
    bool has_target = r != NO_REGION && r < pc.regions;
    float n2 = 0.0;
    float dot_t = 0.0;
    for (uint d = t; d < pc.dim; d += THREADS) {
        float e = 0.0;
        for (uint u = 0u; u < n; u++) {
            uint k = used[base + u];
            e += weights[base + k] * atoms_d[k * pc.dim + d];
        }
        embeddings[row * pc.dim + d] = e;
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

// Sparse Lloyd iterations of the full-dictionary k-means update (paper Eq. 10),
// orchestrated by engine/core/src/latent/kmeans.rs. After the first iteration
// only the centres that gained or lost members change, so the
// point-to-centre cosine matrix needs only their columns again:
//   kmeans_stale:      for each centre that may have changed (its members
//                      did, or every centre), its unit vector; when that is
//                      more than `tolerance` (L2) from the one its column of
//                      the matrix was computed with, the column is stale:
//                      the new unit vector is kept and the centre flagged.
//                      The unit vector is computed exactly as
//                      normalize_rows.comp does, so an unchanged centre
//                      compares equal.
//   kmeans_stale_list: the flagged centres as a list (one workgroup), and
//                      the dirty flags cleared for the next reassignment.
// CPU reference: engine/reference/src/kmeans.rs (dense Lloyd iterations;
// the sparse ones reach the same assignments).
// @kernel kmeans_stale STEP=0
// @kernel kmeans_stale_list STEP=1
// @cost kmeans_stale: flops=all_dirty * centres_count * (6 * dim + 14) bytes=4 * centres_count * (2 - all_dirty) + all_dirty * 8 * centres_count * dim
// Exact when every centre is examined (all_dirty, the first iteration); after
// that a floor, since the dirty flags (D centres) are the GPU's: per examined
// centre 6 * dim + 14 flops and 8 * dim bytes, per stale one dim flops and
// 4 * dim bytes more.
// @cost kmeans_stale_list: flops=2 * centres_count bytes=8 * centres_count + 4
// per centre: a flag test and a prefix-sum add; reads stale, clears dirty, writes the count (the 4 bytes per listed stale centre are GPU-data-dependent and left out).
#version 450
#include "common.glsl"

#define THREADS 64

layout(local_size_x = THREADS) in;

#if STEP == 0
layout(std430, set = 0, binding = 0) readonly buffer Centres { float centres[]; };
layout(std430, set = 0, binding = 1) buffer CentreUnit { float centre_unit[]; };
layout(std430, set = 0, binding = 2) readonly buffer Dirty { uint dirty[]; };
layout(std430, set = 0, binding = 3) buffer Stale { uint stale[]; };

layout(push_constant) uniform Params {
    uint centres_count;
    uint dim;
    uint all_dirty;
    float eps;
    float tolerance;
} pc;

shared float partial[THREADS];

float workgroup_sum(float v, uint t) {
    partial[t] = v;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float s = partial[0];
    barrier();
    return s;
}

void main() {
    uint j = linear_group();
    if (j >= pc.centres_count) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    // Spelled out: naga evaluates both operands of `&&`, and with
    // all_dirty the bound `dirty` buffer may be shorter.
    bool clean = false;
    if (pc.all_dirty == 0u) {
        clean = dirty[j] == 0u;
    }
    if (clean) {
        if (t == 0u) {
            stale[j] = 0u;
        }
        return;
    }
    uint base = j * pc.dim;
    float s = 0.0;
    for (uint k = t; k < pc.dim; k += THREADS) {
        float v = centres[base + k];
        s += v * v;
    }
    float inv = 1.0 / (sqrt(workgroup_sum(s, t)) + pc.eps);
    float e = 0.0;
    for (uint k = t; k < pc.dim; k += THREADS) {
        float d = centres[base + k] * inv - centre_unit[base + k];
        e += d * d;
    }
    bool is_stale = sqrt(workgroup_sum(e, t)) > pc.tolerance;
    if (is_stale) {
        for (uint k = t; k < pc.dim; k += THREADS) {
            centre_unit[base + k] = centres[base + k] * inv;
        }
    }
    if (t == 0u) {
        stale[j] = is_stale ? 1u : 0u;
    }
}
#else
layout(std430, set = 0, binding = 0) readonly buffer Stale { uint stale[]; };
layout(std430, set = 0, binding = 1) buffer Dirty { uint dirty[]; };
// [count, then the stale centres in index order].
layout(std430, set = 0, binding = 2) buffer StaleList { uint stale_list[]; };

layout(push_constant) uniform Params {
    uint centres_count;
} pc;

shared uint counts[THREADS];

void main() {
    uint t = gl_LocalInvocationID.x;
    uint listed = 0u;
    for (uint start = 0u; start < pc.centres_count; start += THREADS) {
        uint c = start + t;
        uint flag = 0u;
        if (c < pc.centres_count) {
            flag = stale[c] != 0u ? 1u : 0u;
            dirty[c] = 0u;
        }
        counts[t] = flag;
        barrier();
        // Inclusive scan (Hillis-Steele) of the flags.
        for (uint h = 1u; h < THREADS; h *= 2u) {
            uint add = t >= h ? counts[t - h] : 0u;
            barrier();
            counts[t] += add;
            barrier();
        }
        if (flag != 0u) {
            stale_list[1u + listed + counts[t] - 1u] = c;
        }
        listed += counts[THREADS - 1u];
        barrier();
    }
    if (t == 0u) {
        stale_list[0] = listed;
    }
}
#endif

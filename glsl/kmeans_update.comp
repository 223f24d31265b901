// Weighted Lloyd update of one centre per workgroup (streaming k-means, paper Eq. 10):
//     C_j = sum_{a_i = j} m_i P_i / sum_{a_i = j} m_i,   weight_j = sum m_i
// with m_i = decay * mass_i for the first `decayed` points (the old atoms)
// and mass_i otherwise; re-normalised to unit length when `normalize` != 0.
// A centre that receives no mass keeps its value and gets weight 0. Each
// workgroup scans the assignments once (one u32 per point, split over its
// threads), gathers its members' indices in shared memory (count, scan,
// scatter: no atomics) and then reads only their rows; a centre with more
// members than the list holds reads them by rescanning the assignments.
// kmeans_update_dirty updates only the centres flagged dirty (whose members
// changed since they were last computed; see kmeans_resim.comp): the others
// would come out bit for bit as they are.
// CPU reference: engine/reference/src/kmeans.rs.
// @kernel kmeans_update DIRTY=0
// @kernel kmeans_update_dirty DIRTY=1
// @cost kmeans_update: flops=points_count * centres_count + 2 * points_count * (dim + 1) + centres_count * (6 * dim + 4 + 4 * normalize * dim) bytes=4 * points_count * (dim + 2) + 4 * centres_count * (dim + 1)
// each centre tests every assignment once (the scatter pass repeats it: not counted); each point's mass-weighted row is summed once (mul-add per element);
// per centre a divide and square-sum per element, a sqrt, and with normalize a second divide. Reads assign, mass and points once; writes centres and weights.
// @cost kmeans_update_dirty: flops=0 bytes=4 * centres_count
// A floor: which centres are dirty (D) and their points (P) are the GPU's;
// each adds what kmeans_update counts for it (points_count tests, 2 * P * (dim + 1)
// sums, 6 * dim + 4 per centre).
#version 450
#include "common.glsl"

#define THREADS 64
#define MAX_MEMBERS 2048u

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Points { float points[]; };
layout(std430, set = 0, binding = 1) readonly buffer Mass { float mass[]; };
layout(std430, set = 0, binding = 2) readonly buffer Assign { uint assign[]; };
layout(std430, set = 0, binding = 3) buffer Centres { float centres[]; };
layout(std430, set = 0, binding = 4) buffer Weights { float weights[]; };
#if DIRTY
layout(std430, set = 0, binding = 5) readonly buffer Dirty { uint dirty[]; };
#endif

layout(push_constant) uniform Params {
    uint points_count;
    uint centres_count;
    uint dim;
    uint decayed;
    float decay;
    uint normalize;
} pc;

shared float partial[THREADS];
shared uint offsets[THREADS];
shared uint members[MAX_MEMBERS];

float point_mass(uint i) {
    return i < pc.decayed ? pc.decay * mass[i] : mass[i];
}

void main() {
    uint j = linear_group();
    if (j >= pc.centres_count) {
        return;
    }
#if DIRTY
    if (dirty[j] == 0u) {
        return;
    }
#endif
    uint t = gl_LocalInvocationID.x;
    // Members: per-thread counts and masses over a strided share of points.
    uint count = 0u;
    float m = 0.0;
    for (uint i = t; i < pc.points_count; i += THREADS) {
        if (assign[i] == j) {
            count++;
            m += point_mass(i);
        }
    }
    offsets[t] = count;
    partial[t] = m;
    barrier();
    // Inclusive scan of the counts (Hillis-Steele) and sum of the masses.
    for (uint h = 1u; h < THREADS; h *= 2u) {
        uint add = t >= h ? offsets[t - h] : 0u;
        barrier();
        offsets[t] += add;
        barrier();
    }
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float total = partial[0];
    uint listed = offsets[THREADS - 1u];
    bool in_list = listed <= MAX_MEMBERS;
    if (in_list) {
        uint o = offsets[t] - count;
        for (uint i = t; i < pc.points_count; i += THREADS) {
            if (assign[i] == j) {
                members[o] = i;
                o++;
            }
        }
    }
    barrier();
    if (!(total > 0.0)) {
        if (t == 0u) {
            weights[j] = 0.0;
        }
        return;
    }
    float sq = 0.0;
    for (uint k = t; k < pc.dim; k += THREADS) {
        float acc = 0.0;
        if (in_list) {
            for (uint e = 0u; e < listed; e++) {
                uint i = members[e];
                acc += point_mass(i) * points[i * pc.dim + k];
            }
        } else {
            for (uint i = 0u; i < pc.points_count; i++) {
                if (assign[i] == j) {
                    acc += point_mass(i) * points[i * pc.dim + k];
                }
            }
        }
        float v = acc / total;
        centres[j * pc.dim + k] = v;
        sq += v * v;
    }
    barrier();
    partial[t] = sq;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    float norm = sqrt(partial[0]);
    if (pc.normalize != 0u && norm > 0.0) {
        for (uint k = t; k < pc.dim; k += THREADS) {
            centres[j * pc.dim + k] /= norm;
        }
    }
    if (t == 0u) {
        weights[j] = total;
    }
}

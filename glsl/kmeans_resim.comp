// Sparse Lloyd iterations, continued (see kmeans_stale.comp):
//   kmeans_resim:    the stale columns of the point-to-centre cosine matrix,
//                    sims[r, c] = unit[r] . centre_unit[c] for every listed
//                    centre c; one workgroup per point, one thread per
//                    listed centre. A row the first assignment left
//                    incomplete (an atom's, when the atoms' product did
//                    not run: kmeans_first_assign.comp) is computed whole
//                    once its best centre is stale, since only then is
//                    every column read.
//   kmeans_reassign: each point's best centre again (largest cosine, ties
//                    to the lowest index, as argmax_rows.comp). Unless its
//                    current best is stale, only the stale columns can
//                    beat it (the others did not change), so only they are
//                    read; otherwise the whole row is. When the best
//                    changes, the old and the new centre are flagged dirty
//                    (their members changed) for kmeans_update_dirty.
// CPU reference: engine/reference/src/kmeans.rs.
// @kernel kmeans_resim STEP=0
// @kernel kmeans_reassign STEP=1
// @cost kmeans_resim: flops=0 bytes=8 * rows + 4
// A floor: how many centres went stale (L) and how many rows are recomputed
// whole (W) the GPU decides, and the host never reads either back. With
// S = (rows - W) * L + W * centres_count cosines the work is 2 * dim * S
// flops and 4 * (S + dim * (rows + L) + 2 * rows + L + 1 + W) bytes; the floor
// takes L = W = 0, the worst case is the dense product (L = centres_count).
// @cost kmeans_reassign: flops=0 bytes=20 * rows + 4
// A floor, as above: with Rs rows whose best centre went stale, it reads
// T = (rows - Rs) * L + Rs * centres_count similarities (one compare each).
#version 450
#include "common.glsl"

#define NONE 0xffffffffu

#if STEP == 0
#define THREADS 64
layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Unit { float unit[]; };
layout(std430, set = 0, binding = 1) readonly buffer CentreUnit { float centre_unit[]; };
layout(std430, set = 0, binding = 2) readonly buffer StaleList { uint stale_list[]; };
layout(std430, set = 0, binding = 3) readonly buffer Stale { uint stale[]; };
layout(std430, set = 0, binding = 4) readonly buffer BestIndex { uint best_index[]; };
layout(std430, set = 0, binding = 5) buffer RowComplete { uint row_complete[]; };
layout(std430, set = 0, binding = 6) buffer Sims { float sims[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint centres_count;
    uint dim;
} pc;

float cosine(uint r, uint c) {
    float s = 0.0;
    for (uint k = 0u; k < pc.dim; k++) {
        s += unit[r * pc.dim + k] * centre_unit[c * pc.dim + k];
    }
    return s;
}

void main() {
    uint r = linear_group();
    if (r >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint best = best_index[r];
    // Spelled out: naga evaluates both operands of `&&` and `||`, and
    // stale[NONE] is out of bounds.
    bool whole = false;
    if (row_complete[r] == 0u) {
        whole = best == NONE;
        if (!whole) {
            whole = stale[best] != 0u;
        }
    }
    if (whole) {
        for (uint c = t; c < pc.centres_count; c += THREADS) {
            sims[r * pc.centres_count + c] = cosine(r, c);
        }
        // Every invocation has read the flag before it changes.
        barrier();
        if (t == 0u) {
            row_complete[r] = 1u;
        }
        return;
    }
    uint listed = stale_list[0];
    for (uint e = t; e < listed; e += THREADS) {
        uint c = stale_list[1u + e];
        sims[r * pc.centres_count + c] = cosine(r, c);
    }
}
#else
#define THREADS 64
layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Sims { float sims[]; };
layout(std430, set = 0, binding = 1) readonly buffer Stale { uint stale[]; };
layout(std430, set = 0, binding = 2) readonly buffer StaleList { uint stale_list[]; };
layout(std430, set = 0, binding = 3) buffer BestValue { float best_value[]; };
layout(std430, set = 0, binding = 4) buffer BestIndex { uint best_index[]; };
layout(std430, set = 0, binding = 5) buffer Dirty { uint dirty[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint centres_count;
} pc;

shared float sval[THREADS];
shared uint sidx[THREADS];

// Whether (v, i) beats (w, j): larger value, then lower index.
bool better(float v, uint i, float w, uint j) {
    return i != NONE && (j == NONE || v > w || (v == w && i < j));
}

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint old = best_index[row];
    float bv = uintBitsToFloat(0xff800000u);
    uint bi = NONE;
    uint base = row * pc.centres_count;
    bool rescan = old == NONE;
    if (!rescan) {
        rescan = stale[old] != 0u;
    }
    if (rescan) {
        for (uint c = t; c < pc.centres_count; c += THREADS) {
            float v = sims[base + c];
            if (better(v, c, bv, bi)) {
                bv = v;
                bi = c;
            }
        }
    } else {
        if (t == 0u) {
            bv = best_value[row];
            bi = old;
        }
        uint listed = stale_list[0];
        for (uint e = t; e < listed; e += THREADS) {
            uint c = stale_list[1u + e];
            float v = sims[base + c];
            if (better(v, c, bv, bi)) {
                bv = v;
                bi = c;
            }
        }
    }
    sval[t] = bv;
    sidx[t] = bi;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        // Nested: naga evaluates both operands of `&&`, and sval[t + h]
        // is past the array for t >= h.
        if (t < h) {
            if (better(sval[t + h], sidx[t + h], sval[t], sidx[t])) {
                sval[t] = sval[t + h];
                sidx[t] = sidx[t + h];
            }
        }
        barrier();
    }
    if (t == 0u) {
        uint best = sidx[0];
        best_value[row] = sval[0];
        best_index[row] = best;
        // Several points may flag the same centre: they all write 1.
        if (best != old) {
            if (old != NONE) {
                dirty[old] = 1u;
            }
            if (best != NONE) {
                dirty[best] = 1u;
            }
        }
    }
}
#endif

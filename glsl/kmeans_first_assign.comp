// The first Lloyd assignment of the full-dictionary k-means update
// (paper Eq. 10), orchestrated by engine/core/src/latent/kmeans.rs, without the
// K x K cosine matrix of the atoms unless a new concept needs it:
//   kmeans_micro_rows:   the micro-centres' rows of the point-to-centre
//                        cosine matrix (points `first`.. of `unit` against
//                        every atom) and each row's best atom (largest
//                        cosine, ties to the lowest index). One workgroup
//                        per row.
//   kmeans_gate:         whether any micro-centre is new (best cosine below
//                        the novelty threshold). Only then does the novelty
//                        step need each atom's most similar other atom: the
//                        kernel writes the workgroup counts of the atoms'
//                        cosine product and its row argmax (zero groups
//                        otherwise, so they do not run), and the flag.
//   kmeans_first_assign: each point's first centre. An atom whose centre
//                        was not replaced by a new concept starts in its
//                        own cluster (its cosine to itself is 1, which no
//                        other centre exceeds); every other point, a
//                        micro-centre or an atom whose slot a new concept
//                        took, takes the best column of its row. Also marks
//                        which rows of the matrix are complete: the
//                        micro-centres' always, the atoms' only when their
//                        product ran. Later iterations complete a row when
//                        they need it (kmeans_resim.comp).
// CPU reference: engine/reference/src/kmeans.rs.
// @kernel kmeans_micro_rows STEP=0
// @kernel kmeans_gate STEP=1
// @kernel kmeans_first_assign STEP=2
// @cost kmeans_micro_rows: flops=count * centres_count * (2 * dim + 1) bytes=4 * (count * dim + centres_count * dim + count * centres_count + 2 * count)
// per micro row: a dim-long dot product and an argmax compare against each centre; reads its unit row and every centre once, writes its sims row and best.
// @cost kmeans_gate: flops=micro_count bytes=4 * micro_count + 36
// one threshold compare per micro-centre's best cosine; writes the 9-word gate.
// @cost kmeans_first_assign: flops=2 * dim * (atoms - min(micro_count, atoms / 2)) + atoms * max(rows - atoms + min(micro_count, atoms / 2), 0) bytes=8 * dim * (atoms - min(micro_count, atoms / 2)) + 4 * atoms * max(rows - atoms + min(micro_count, atoms / 2), 0) + 12 * rows + 4 * micro_count + 4
// R = min(micro_count, atoms / 2) atoms assumed replaced by new concepts (the GPU decides; at most that many): the other atoms take a dim-long dot with their own centre (two dim rows read), the R replaced ones and the rows - atoms micro-centres an argmax over an atoms-long sims row; every row writes best value, index, completeness.
#version 450
#include "common.glsl"

#define THREADS 64
#define NONE 0xffffffffu

layout(local_size_x = THREADS) in;

shared float sval[THREADS];
shared uint sidx[THREADS];

// Whether (v, i) beats (w, j): larger value, then lower index.
bool better(float v, uint i, float w, uint j) {
    return i != NONE && (j == NONE || v > w || (v == w && i < j));
}

// Leaves the workgroup's best (value, index) in sval[0], sidx[0].
void reduce_best(uint t, float bv, uint bi) {
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
}

#if STEP == 0
layout(std430, set = 0, binding = 0) readonly buffer Unit { float unit[]; };
layout(std430, set = 0, binding = 1) readonly buffer CentreUnit { float centre_unit[]; };
layout(std430, set = 0, binding = 2) buffer Sims { float sims[]; };
layout(std430, set = 0, binding = 3) buffer BestValue { float best_value[]; };
layout(std430, set = 0, binding = 4) buffer BestIndex { uint best_index[]; };

layout(push_constant) uniform Params {
    uint first;
    uint count;
    uint centres_count;
    uint dim;
} pc;

void main() {
    uint g = linear_group();
    if (g >= pc.count) {
        return;
    }
    uint r = pc.first + g;
    uint t = gl_LocalInvocationID.x;
    float bv = uintBitsToFloat(0xff800000u);
    uint bi = NONE;
    for (uint c = t; c < pc.centres_count; c += THREADS) {
        float s = 0.0;
        for (uint k = 0u; k < pc.dim; k++) {
            s += unit[r * pc.dim + k] * centre_unit[c * pc.dim + k];
        }
        sims[r * pc.centres_count + c] = s;
        if (better(s, c, bv, bi)) {
            bv = s;
            bi = c;
        }
    }
    reduce_best(t, bv, bi);
    if (t == 0u) {
        best_value[r] = sval[0];
        best_index[r] = sidx[0];
    }
}
#elif STEP == 1
layout(std430, set = 0, binding = 0) readonly buffer BestValue { float best_value[]; };
// [product x, y, z, 0, argmax x, y, z, 0, novel].
layout(std430, set = 0, binding = 1) buffer Gate { uint gate[]; };

layout(push_constant) uniform Params {
    uint atoms;
    uint micro_count;
    float threshold;
    uint product_x;
    uint product_y;
    uint argmax_x;
    uint argmax_y;
} pc;

void main() {
    if (gl_LocalInvocationID.x != 0u) {
        return;
    }
    bool novel = false;
    for (uint j = 0u; j < pc.micro_count; j++) {
        // The same test as kmeans_novelty.comp's.
        novel = novel || best_value[pc.atoms + j] < pc.threshold;
    }
    gate[0] = novel ? pc.product_x : 0u;
    gate[1] = pc.product_y;
    gate[2] = 1u;
    gate[3] = 0u;
    gate[4] = novel ? pc.argmax_x : 0u;
    gate[5] = pc.argmax_y;
    gate[6] = 1u;
    gate[7] = 0u;
    gate[8] = novel ? 1u : 0u;
}
#else
layout(std430, set = 0, binding = 0) readonly buffer Unit { float unit[]; };
layout(std430, set = 0, binding = 1) readonly buffer CentreUnit { float centre_unit[]; };
layout(std430, set = 0, binding = 2) readonly buffer Sims { float sims[]; };
layout(std430, set = 0, binding = 3) readonly buffer Replaced { uint replaced[]; };
layout(std430, set = 0, binding = 4) readonly buffer Gate { uint gate[]; };
layout(std430, set = 0, binding = 5) buffer BestValue { float best_value[]; };
layout(std430, set = 0, binding = 6) buffer BestIndex { uint best_index[]; };
layout(std430, set = 0, binding = 7) buffer RowComplete { uint row_complete[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint atoms;
    uint micro_count;
    uint dim;
} pc;

void main() {
    uint r = linear_group();
    if (r >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    bool own = r < pc.atoms;
    for (uint j = 0u; j < pc.micro_count; j++) {
        own = own && replaced[j] != r;
    }
    float bv = uintBitsToFloat(0xff800000u);
    uint bi = NONE;
    if (own) {
        // Its cosine to its own centre, as the product would give it.
        float s = 0.0;
        for (uint k = t; k < pc.dim; k += THREADS) {
            s += unit[r * pc.dim + k] * centre_unit[r * pc.dim + k];
        }
        sval[t] = s;
        barrier();
        for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
            if (t < h) {
                sval[t] += sval[t + h];
            }
            barrier();
        }
        if (t == 0u) {
            best_value[r] = sval[0];
            best_index[r] = r;
        }
    } else {
        for (uint c = t; c < pc.atoms; c += THREADS) {
            float v = sims[r * pc.atoms + c];
            if (better(v, c, bv, bi)) {
                bv = v;
                bi = c;
            }
        }
        reduce_best(t, bv, bi);
        if (t == 0u) {
            best_value[r] = sval[0];
            best_index[r] = sidx[0];
        }
    }
    if (t == 0u) {
        row_complete[r] = (r >= pc.atoms || gate[8] != 0u) ? 1u : 0u;
    }
}
#endif

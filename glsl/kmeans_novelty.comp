// Room for a concept the dictionary has not seen, once it is full (K
// fixed): each micro-centre whose best cosine to the atoms is below
// `threshold` replaces, as a warm-start centre, the lighter atom of the most
// similar pair of atoms not yet touched this round. The Lloyd pass that
// follows then merges that pair's points into the other atom and gives the
// new concept its own (the STREAM scheme's re-clustering into K, paper Sec. III-C).
// Rows 0..atoms-1 of best_value/best_index are each atom's most similar
// other atom, rows atoms.. the micro-centres' most similar atom.
// replaced[j] receives the atom slot micro-centre j took, or 0xffffffff, so
// that the first Lloyd assignment only recomputes those columns of the
// similarities (kmeans_patch_sims.comp). A single workgroup; atoms <= 65536. CPU reference: engine/reference/src/kmeans.rs.
// @cost flops=micro_count + min(micro_count, atoms / 2) * (atoms + 1) bytes=8 * atoms + 8 * micro_count + min(micro_count, atoms / 2) * (8 * dim + 8)
// worst case (which micro-centres are new is decided on the GPU): every micro-centre new and placed (at most atoms / 2 pairs): each scans the atoms' best cosines
// for the best free pair (one compare per atom) and copies a dim row; reads best_value/best_index once, writes `replaced`.
#version 450

#define THREADS 256
#define NONE 0xffffffffu
#define MAX_ATOMS 65536u

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer BestValue { float best_value[]; };
layout(std430, set = 0, binding = 1) readonly buffer BestIndex { uint best_index[]; };
layout(std430, set = 0, binding = 2) readonly buffer Weights { float weights[]; };
layout(std430, set = 0, binding = 3) readonly buffer Micro { float micro[]; };
layout(std430, set = 0, binding = 4) buffer Centres { float centres[]; };
layout(std430, set = 0, binding = 5) buffer Replaced { uint replaced[]; };

layout(push_constant) uniform Params {
    uint atoms;
    uint micro_count;
    uint dim;
    float threshold;
} pc;

shared uint touched[MAX_ATOMS / 32u];
shared float sval[THREADS];
shared uint sidx[THREADS];

bool is_touched(uint k) {
    return (touched[k / 32u] & (1u << (k % 32u))) != 0u;
}

bool better(float v, uint i, float w, uint j) {
    return i != NONE && (j == NONE || v > w || (v == w && i < j));
}

void main() {
    uint t = gl_LocalInvocationID.x;
    for (uint w = t; w < MAX_ATOMS / 32u; w += THREADS) {
        touched[w] = 0u;
    }
    for (uint j = t; j < pc.micro_count; j += THREADS) {
        replaced[j] = NONE;
    }
    barrier();
    for (uint j = 0u; j < pc.micro_count; j++) {
        if (!(best_value[pc.atoms + j] < pc.threshold)) {
            continue;
        }
        float bv = uintBitsToFloat(0xff800000u);
        uint bi = NONE;
        for (uint k = t; k < pc.atoms; k += THREADS) {
            uint other = best_index[k];
            if (other == NONE || is_touched(k) || is_touched(other)) {
                continue;
            }
            if (better(best_value[k], k, bv, bi)) {
                bv = best_value[k];
                bi = k;
            }
        }
        sval[t] = bv;
        sidx[t] = bi;
        barrier();
        for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
            // Nested: naga evaluates both operands of `&&`, and
            // sval[t + h] is past the array for t >= h.
            if (t < h) {
                if (better(sval[t + h], sidx[t + h], sval[t], sidx[t])) {
                    sval[t] = sval[t + h];
                    sidx[t] = sidx[t + h];
                }
            }
            barrier();
        }
        uint a = sidx[0];
        barrier();
        if (a == NONE) {
            break; // every pair is taken; the rest are absorbed by Lloyd
        }
        uint b = best_index[a];
        uint lighter = weights[b] < weights[a] ? b : a;
        for (uint k = t; k < pc.dim; k += THREADS) {
            centres[lighter * pc.dim + k] = micro[j * pc.dim + k];
        }
        if (t == 0u) {
            replaced[j] = lighter;
            touched[a / 32u] |= 1u << (a % 32u);
            touched[b / 32u] |= 1u << (b % 32u);
        }
        barrier();
    }
}

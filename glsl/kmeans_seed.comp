// Farthest-point seeding of the per-keyframe micro-clusters (paper Sec. III-C):
// the first seed is the heaviest point, each next one the point least
// similar (by cosine) to all seeds so far; ties go to the lowest index. The
// seeds' rows of the raw points are copied to the centres. A single
// workgroup: n is a keyframe's region count. CPU reference:
// engine/reference/src/kmeans.rs.
// @cost flops=n + max(seeds - 1, 0) * n * (2 * dim + 3) bytes=4 * n + (4 * n * dim + 8 * n) * min(max(seeds - 1, 0), 1) + 8 * seeds * dim
// heaviest-point argmax, then per further seed: each point's dim-long dot with the seed, a max and an argmax compare; reads mass, unit rows and closest once,
// writes closest, copies seeds rows of points to centres.
#version 450

#define THREADS 256
#define NONE 0xffffffffu

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Points { float points[]; };
layout(std430, set = 0, binding = 1) readonly buffer Unit { float unit[]; };
layout(std430, set = 0, binding = 2) readonly buffer Mass { float mass[]; };
layout(std430, set = 0, binding = 3) buffer Closest { float closest[]; };
layout(std430, set = 0, binding = 4) buffer Centres { float centres[]; };

layout(push_constant) uniform Params {
    uint n;
    uint dim;
    uint seeds;
} pc;

shared float sval[THREADS];
shared uint sidx[THREADS];
shared uint chosen;

// Whether (v, i) beats (w, j) for "larger value, then lower index".
bool better(float v, uint i, float w, uint j) {
    return i != NONE && (j == NONE || v > w || (v == w && i < j));
}

// Reduces the per-thread candidates to `chosen`.
void pick(float v, uint i) {
    uint t = gl_LocalInvocationID.x;
    sval[t] = v;
    sidx[t] = i;
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
        chosen = sidx[0];
    }
    barrier();
}

void main() {
    uint t = gl_LocalInvocationID.x;
    float bv = uintBitsToFloat(0xff800000u);
    uint bi = NONE;
    for (uint i = t; i < pc.n; i += THREADS) {
        if (better(mass[i], i, bv, bi)) {
            bv = mass[i];
            bi = i;
        }
    }
    pick(bv, bi);
    for (uint j = 0u; j < pc.seeds; j++) {
        uint s = chosen;
        for (uint k = t; k < pc.dim; k += THREADS) {
            centres[j * pc.dim + k] = points[s * pc.dim + k];
        }
        if (j + 1u == pc.seeds) {
            break;
        }
        // Farthest = smallest best cosine: maximise its negation.
        bv = uintBitsToFloat(0xff800000u);
        bi = NONE;
        for (uint i = t; i < pc.n; i += THREADS) {
            float c = 0.0;
            for (uint k = 0u; k < pc.dim; k++) {
                c += unit[i * pc.dim + k] * unit[s * pc.dim + k];
            }
            float best = j == 0u ? c : max(closest[i], c);
            closest[i] = best;
            if (better(-best, i, bv, bi)) {
                bv = -best;
                bi = i;
            }
        }
        pick(bv, bi);
    }
}

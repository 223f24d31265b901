// Best column of each row of a rows x cols matrix: the largest value and its
// index (ties: the lowest index). With exclude_diagonal != 0, column r is
// skipped in row r (nearest *other* atom). A row with no candidate gets
// value -inf and index 0xffffffff. One workgroup per row. CPU reference:
// engine/reference/src/kmeans.rs.
// @cost flops=2 * rows * cols bytes=4 * rows * cols + 8 * rows
// per element: the value and tie compares; reads the matrix, writes value
// and index per row. (Also dispatched indirectly behind a k-means gate: the
// push fields give the work when the gate opens.)
#version 450
#include "common.glsl"

#define THREADS 64
#define NONE 0xffffffffu

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer M { float mat[]; };
layout(std430, set = 0, binding = 1) buffer BestValue { float best_value[]; };
layout(std430, set = 0, binding = 2) buffer BestIndex { uint best_index[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    uint exclude_diagonal;
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
    float bv = uintBitsToFloat(0xff800000u);
    uint bi = NONE;
    for (uint c = t; c < pc.cols; c += THREADS) {
        if (pc.exclude_diagonal != 0u && c == row) {
            continue;
        }
        float v = mat[row * pc.cols + c];
        if (better(v, c, bv, bi)) {
            bv = v;
            bi = c;
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
        best_value[row] = sval[0];
        best_index[row] = sidx[0];
    }
}

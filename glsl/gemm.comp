// Tiled single-precision GEMM, row-major:  C = alpha * op(A) * op(B) + beta * C
// with op(A) M x K and op(B) K x N. Variants by which operand is transposed:
//   gemm_nn: A is M x K,  B is K x N
//   gemm_tn: A is K x M (A^T used), B is K x N
//   gemm_nt: A is M x K,  B is N x K (B^T used)
// Each 16x16 workgroup computes a 64x64 tile of C, 4x4 per thread, staging
// 16-deep slabs of A and B in shared memory. beta = 0 never reads C, so C may
// start as garbage. CPU reference: engine/reference/src/gemm.rs.
// @kernel gemm_nn TRANS_A=0 TRANS_B=0
// @kernel gemm_tn TRANS_A=1 TRANS_B=0
// @kernel gemm_nt TRANS_A=0 TRANS_B=1
// @push Gemm
// @cost flops=2 * m * n * k bytes=4 * (m * k + k * n + m * n) + 4 * m * n * min(1, max(beta, 0 - beta) * 1000000)
// 2mnk as Gemm::flops(); reads A, B once, writes C, and reads C only when
// beta != 0 (the min/max term is 1 for |beta| >= 1e-6, 0 for beta = 0).
#version 450
#include "shared.glsl"

#define T 16
#define TILE GEMM_TILE
#define DEPTH 16
#define LOADS (TILE * DEPTH / (T * T))

layout(local_size_x = T, local_size_y = T) in;

layout(std430, set = 0, binding = 0) readonly buffer A { float a[]; };
layout(std430, set = 0, binding = 1) readonly buffer B { float b[]; };
layout(std430, set = 0, binding = 2) buffer C { float c[]; };

layout(push_constant) uniform Params {
    uint m;
    uint n;
    uint k;
    uint lda;
    uint ldb;
    uint ldc;
    float alpha;
    float beta;
} pc;

// Flattened [DEPTH][TILE + 1] slabs: the same kernel written with 2-D arrays
// gave wrong products through naga's GLSL front end, so GLSL kernels here keep
// arrays one-dimensional. The +1 column avoids bank conflicts on the
// transposed loads.
#define LDS (TILE + 1)
shared float as_[DEPTH * LDS];
shared float bs[DEPTH * LDS];

float load_a(uint row, uint kk) {
    if (row >= pc.m || kk >= pc.k) {
        return 0.0;
    }
#if TRANS_A == 0
    return a[row * pc.lda + kk];
#else
    return a[kk * pc.lda + row];
#endif
}

float load_b(uint kk, uint col) {
    if (col >= pc.n || kk >= pc.k) {
        return 0.0;
    }
#if TRANS_B == 0
    return b[kk * pc.ldb + col];
#else
    return b[col * pc.ldb + kk];
#endif
}

void store(uint row, uint col, float acc) {
    if (row >= pc.m || col >= pc.n) {
        return;
    }
    uint idx = row * pc.ldc + col;
    float v = pc.alpha * acc;
    if (pc.beta != 0.0) {
        v += pc.beta * c[idx];
    }
    c[idx] = v;
}

// Row `row` of this thread's 4x4 block: columns col, col+T, col+2T, col+3T.
void store_row(uint row, uint col, vec4 v) {
    store(row, col, v.x);
    store(row, col + T, v.y);
    store(row, col + 2u * T, v.z);
    store(row, col + 3u * T, v.w);
}

void main() {
    uint tx = gl_LocalInvocationID.x;
    uint ty = gl_LocalInvocationID.y;
    uint tid = ty * T + tx;
    uint row0 = gl_WorkGroupID.y * TILE;
    uint col0 = gl_WorkGroupID.x * TILE;

    // 4x4 accumulators as four vec4 rows, named rather than indexed: private
    // arrays with loop indices stay in memory on some drivers (lavapipe).
    vec4 c0 = vec4(0.0);
    vec4 c1 = vec4(0.0);
    vec4 c2 = vec4(0.0);
    vec4 c3 = vec4(0.0);

    for (uint k0 = 0u; k0 < pc.k; k0 += DEPTH) {
        // TILE x DEPTH elements of each operand, LOADS per thread.
        for (uint l = 0u; l < LOADS; l++) {
            uint e = l * (T * T) + tid;
#if TRANS_A == 0
            uint ar = e / DEPTH;
            uint ak = e % DEPTH;
#else
            uint ak = e / TILE;
            uint ar = e % TILE;
#endif
            as_[ak * LDS + ar] = load_a(row0 + ar, k0 + ak);
#if TRANS_B == 0
            uint bk = e / TILE;
            uint bc = e % TILE;
#else
            uint bc = e / DEPTH;
            uint bk = e % DEPTH;
#endif
            bs[bk * LDS + bc] = load_b(k0 + bk, col0 + bc);
        }
        barrier();
        for (uint kk = 0u; kk < DEPTH; kk++) {
            uint ao = kk * LDS + ty;
            uint bo = kk * LDS + tx;
            vec4 bv = vec4(bs[bo], bs[bo + T], bs[bo + 2u * T], bs[bo + 3u * T]);
            c0 += as_[ao] * bv;
            c1 += as_[ao + T] * bv;
            c2 += as_[ao + 2u * T] * bv;
            c3 += as_[ao + 3u * T] * bv;
        }
        barrier();
    }

    store_row(row0 + ty, col0 + tx, c0);
    store_row(row0 + ty + T, col0 + tx, c1);
    store_row(row0 + ty + 2u * T, col0 + tx, c2);
    store_row(row0 + ty + 3u * T, col0 + tx, c3);
}

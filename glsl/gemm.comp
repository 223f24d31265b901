// Tiled single-precision GEMM, row-major:  C = alpha * op(A) * op(B) + beta * C
// with op(A) M x K and op(B) K x N. Variants by which operand is transposed:
//   gemm_nn: A is M x K,  B is K x N
//   gemm_tn: A is K x M (A^T used), B is K x N
//   gemm_nt: A is M x K,  B is N x K (B^T used)
// Each 16x16 workgroup computes a 64x64 tile of C, 4x4 per thread, staging
// 16-deep slabs of A and B in shared memory. beta = 0 never reads C, so C may
// start as garbage. CPU reference: engine/src/reference/gemm.rs.
// @kernel gemm_nn TRANS_A=0 TRANS_B=0
// @kernel gemm_tn TRANS_A=1 TRANS_B=0
// @kernel gemm_nt TRANS_A=0 TRANS_B=1
#version 450

#define TILE 64
#define DEPTH 16
#define T 16
#define R 4

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

void main() {
    uint tx = gl_LocalInvocationID.x;
    uint ty = gl_LocalInvocationID.y;
    uint tid = ty * T + tx;
    uint row0 = gl_WorkGroupID.y * TILE;
    uint col0 = gl_WorkGroupID.x * TILE;

    float acc[R * R];
    for (uint i = 0u; i < R * R; i++) {
        acc[i] = 0.0;
    }

    for (uint k0 = 0u; k0 < pc.k; k0 += DEPTH) {
        // 64x16 elements of each operand, 4 per thread.
        for (uint l = 0u; l < 4u; l++) {
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
            float ar[R];
            float br[R];
            for (uint i = 0u; i < R; i++) {
                ar[i] = as_[kk * LDS + ty + i * T];
                br[i] = bs[kk * LDS + tx + i * T];
            }
            for (uint i = 0u; i < R; i++) {
                for (uint j = 0u; j < R; j++) {
                    acc[i * R + j] += ar[i] * br[j];
                }
            }
        }
        barrier();
    }

    for (uint i = 0u; i < R; i++) {
        uint row = row0 + ty + i * T;
        if (row >= pc.m) {
            continue;
        }
        for (uint j = 0u; j < R; j++) {
            uint col = col0 + tx + j * T;
            if (col >= pc.n) {
                continue;
            }
            uint idx = row * pc.ldc + col;
            float v = pc.alpha * acc[i * R + j];
            if (pc.beta != 0.0) {
                v += pc.beta * c[idx];
            }
            c[idx] = v;
        }
    }
}

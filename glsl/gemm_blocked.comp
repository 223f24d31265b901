// Register-blocked single-precision GEMM for CPU Vulkan drivers, row-major:
//   C = alpha * op(A) * op(B) + beta * C,  op(A) M x K, op(B) K x N.
// Same contract and variants as glsl/gemm.comp (CPU reference:
// engine/reference/src/gemm.rs), without shared memory or barriers: on a
// CPU driver every invocation is a SIMD lane, shared memory is ordinary
// memory reached lane by lane and a barrier splits the kernel in two. Each
// invocation instead computes an 8 x 8 block of C from 16-byte loads, 4 deep
// in K: 16 loads feed 256 multiply-adds. An 8 x 8 workgroup covers the same
// 64 x 64 tile as gemm.comp, so both share one dispatch shape.
//
// The 16-byte loads need the dimension they run along to be a multiple of 4
// (`Gemm::vector_loads_fit`): K for A in gemm_nn/gemm_nt and for B in
// gemm_nt, N for B in gemm_nn/gemm_tn, M for A in gemm_tn. Other shapes
// take the `_scalar` variants, which read the same four elements one by one
// and give zero past the end. Rows and columns past the edge are clamped on
// load and skipped on store; rows of K past its end read as zero.
// @kernel gemm_blocked_nn TRANS_A=0 TRANS_B=0 VEC4=1
// @kernel gemm_blocked_tn TRANS_A=1 TRANS_B=0 VEC4=1
// @kernel gemm_blocked_nt TRANS_A=0 TRANS_B=1 VEC4=1
// @kernel gemm_blocked_nn_scalar TRANS_A=0 TRANS_B=0 VEC4=0
// @kernel gemm_blocked_tn_scalar TRANS_A=1 TRANS_B=0 VEC4=0
// @kernel gemm_blocked_nt_scalar TRANS_A=0 TRANS_B=1 VEC4=0
// @push Gemm
// @cost flops=2 * m * n * k bytes=4 * (m * k + k * n + m * n) + 4 * m * n * min(1, max(beta, 0 - beta) * 1000000)
// 2mnk as Gemm::flops(); reads A, B once, writes C, and reads C only when
// beta != 0 (the min/max term is 1 for |beta| >= 1e-6, 0 for beta = 0).
#version 450

layout(local_size_x = 8, local_size_y = 8) in;

#if VEC4 == 1
layout(std430, set = 0, binding = 0) readonly buffer A { vec4 a[]; };
layout(std430, set = 0, binding = 1) readonly buffer B { vec4 b[]; };
#else
layout(std430, set = 0, binding = 0) readonly buffer A { float a[]; };
layout(std430, set = 0, binding = 1) readonly buffer B { float b[]; };
#endif
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

// One row of the block, 4 columns wide: acc += sum_j ar[j] * (row j of B).
vec4 fma4(vec4 acc, vec4 ar, vec4 b0, vec4 b1, vec4 b2, vec4 b3) {
    return acc + ar.x * b0 + ar.y * b1 + ar.z * b2 + ar.w * b3;
}

// Elements [i, i + 4) of row `row` of the stored A or B (`ld` columns, of
// which the first `len` hold data): one 16-byte load (`ld`, `i` multiples of
// 4 and i + 4 <= len), or four loads with zero past `len`.
#if VEC4 == 1
vec4 load_a(uint row, uint i, uint len) {
    return a[(row * pc.lda + i) >> 2];
}
vec4 load_b(uint row, uint i, uint len) {
    return b[(row * pc.ldb + i) >> 2];
}
// Where a 4-wide group starting at `i` is read: clamped inside `len`.
uint group_start(uint i, uint len) {
    return min(i, len - 4u);
}
#else
vec4 load_a(uint row, uint i, uint len) {
    uint o = row * pc.lda + i;
    return vec4(i < len ? a[o] : 0.0, i + 1u < len ? a[o + 1u] : 0.0,
                i + 2u < len ? a[o + 2u] : 0.0, i + 3u < len ? a[o + 3u] : 0.0);
}
vec4 load_b(uint row, uint i, uint len) {
    uint o = row * pc.ldb + i;
    return vec4(i < len ? b[o] : 0.0, i + 1u < len ? b[o + 1u] : 0.0,
                i + 2u < len ? b[o + 2u] : 0.0, i + 3u < len ? b[o + 3u] : 0.0);
}
uint group_start(uint i, uint len) {
    return i;
}
#endif

// Row kk of the stored A (gemm_tn) or B (gemm_nn, gemm_tn), zero past K.
vec4 k_row_a(uint kk, uint i, uint len) {
    return kk < pc.k ? load_a(kk, i, len) : vec4(0.0);
}
vec4 k_row_b(uint kk, uint i, uint len) {
    return kk < pc.k ? load_b(kk, i, len) : vec4(0.0);
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

void store8(uint row, uint col, vec4 lo, vec4 hi) {
    store(row, col, lo.x);
    store(row, col + 1u, lo.y);
    store(row, col + 2u, lo.z);
    store(row, col + 3u, lo.w);
    store(row, col + 4u, hi.x);
    store(row, col + 5u, hi.y);
    store(row, col + 6u, hi.z);
    store(row, col + 7u, hi.w);
}

void main() {
    uint row0 = gl_WorkGroupID.y * 64u + gl_LocalInvocationID.y * 8u;
    uint col0 = gl_WorkGroupID.x * 64u + gl_LocalInvocationID.x * 8u;
    uint last_row = pc.m - 1u;
    uint last_col = pc.n - 1u;

    // Accumulators by name: private arrays stay in memory on some drivers.
    vec4 c0l = vec4(0.0), c0h = vec4(0.0), c1l = vec4(0.0), c1h = vec4(0.0);
    vec4 c2l = vec4(0.0), c2h = vec4(0.0), c3l = vec4(0.0), c3h = vec4(0.0);
    vec4 c4l = vec4(0.0), c4h = vec4(0.0), c5l = vec4(0.0), c5h = vec4(0.0);
    vec4 c6l = vec4(0.0), c6h = vec4(0.0), c7l = vec4(0.0), c7h = vec4(0.0);

#if TRANS_A == 0
    // Rows of A (clamped), read 4 deep along K.
    uint ra0 = min(row0, last_row), ra1 = min(row0 + 1u, last_row);
    uint ra2 = min(row0 + 2u, last_row), ra3 = min(row0 + 3u, last_row);
    uint ra4 = min(row0 + 4u, last_row), ra5 = min(row0 + 5u, last_row);
    uint ra6 = min(row0 + 6u, last_row), ra7 = min(row0 + 7u, last_row);
#else
    // Columns of the stored A (its rows in op(A)), 4 wide, clamped.
    uint ma0 = group_start(row0, pc.m);
    uint ma1 = group_start(row0 + 4u, pc.m);
#endif
#if TRANS_B == 0
    uint nb0 = group_start(col0, pc.n);
    uint nb1 = group_start(col0 + 4u, pc.n);
#else
    uint cb0 = min(col0, last_col), cb1 = min(col0 + 1u, last_col);
    uint cb2 = min(col0 + 2u, last_col), cb3 = min(col0 + 3u, last_col);
    uint cb4 = min(col0 + 4u, last_col), cb5 = min(col0 + 5u, last_col);
    uint cb6 = min(col0 + 6u, last_col), cb7 = min(col0 + 7u, last_col);
#endif

    for (uint kk = 0u; kk < pc.k; kk += 4u) {
        // a0..a7: rows of the block, elements kk..kk+3 of op(A).
#if TRANS_A == 0
        vec4 a0 = load_a(ra0, kk, pc.k), a1 = load_a(ra1, kk, pc.k);
        vec4 a2 = load_a(ra2, kk, pc.k), a3 = load_a(ra3, kk, pc.k);
        vec4 a4 = load_a(ra4, kk, pc.k), a5 = load_a(ra5, kk, pc.k);
        vec4 a6 = load_a(ra6, kk, pc.k), a7 = load_a(ra7, kk, pc.k);
#else
        vec4 k0l = k_row_a(kk, ma0, pc.m), k0h = k_row_a(kk, ma1, pc.m);
        vec4 k1l = k_row_a(kk + 1u, ma0, pc.m), k1h = k_row_a(kk + 1u, ma1, pc.m);
        vec4 k2l = k_row_a(kk + 2u, ma0, pc.m), k2h = k_row_a(kk + 2u, ma1, pc.m);
        vec4 k3l = k_row_a(kk + 3u, ma0, pc.m), k3h = k_row_a(kk + 3u, ma1, pc.m);
        vec4 a0 = vec4(k0l.x, k1l.x, k2l.x, k3l.x), a1 = vec4(k0l.y, k1l.y, k2l.y, k3l.y);
        vec4 a2 = vec4(k0l.z, k1l.z, k2l.z, k3l.z), a3 = vec4(k0l.w, k1l.w, k2l.w, k3l.w);
        vec4 a4 = vec4(k0h.x, k1h.x, k2h.x, k3h.x), a5 = vec4(k0h.y, k1h.y, k2h.y, k3h.y);
        vec4 a6 = vec4(k0h.z, k1h.z, k2h.z, k3h.z), a7 = vec4(k0h.w, k1h.w, k2h.w, k3h.w);
#endif
        // bjl, bjh: row kk+j of op(B), columns col0..col0+3 and +4..+7.
#if TRANS_B == 0
        vec4 b0l = k_row_b(kk, nb0, pc.n), b0h = k_row_b(kk, nb1, pc.n);
        vec4 b1l = k_row_b(kk + 1u, nb0, pc.n), b1h = k_row_b(kk + 1u, nb1, pc.n);
        vec4 b2l = k_row_b(kk + 2u, nb0, pc.n), b2h = k_row_b(kk + 2u, nb1, pc.n);
        vec4 b3l = k_row_b(kk + 3u, nb0, pc.n), b3h = k_row_b(kk + 3u, nb1, pc.n);
#else
        vec4 q0 = load_b(cb0, kk, pc.k), q1 = load_b(cb1, kk, pc.k);
        vec4 q2 = load_b(cb2, kk, pc.k), q3 = load_b(cb3, kk, pc.k);
        vec4 q4 = load_b(cb4, kk, pc.k), q5 = load_b(cb5, kk, pc.k);
        vec4 q6 = load_b(cb6, kk, pc.k), q7 = load_b(cb7, kk, pc.k);
        vec4 b0l = vec4(q0.x, q1.x, q2.x, q3.x), b0h = vec4(q4.x, q5.x, q6.x, q7.x);
        vec4 b1l = vec4(q0.y, q1.y, q2.y, q3.y), b1h = vec4(q4.y, q5.y, q6.y, q7.y);
        vec4 b2l = vec4(q0.z, q1.z, q2.z, q3.z), b2h = vec4(q4.z, q5.z, q6.z, q7.z);
        vec4 b3l = vec4(q0.w, q1.w, q2.w, q3.w), b3h = vec4(q4.w, q5.w, q6.w, q7.w);
#endif
        c0l = fma4(c0l, a0, b0l, b1l, b2l, b3l); c0h = fma4(c0h, a0, b0h, b1h, b2h, b3h);
        c1l = fma4(c1l, a1, b0l, b1l, b2l, b3l); c1h = fma4(c1h, a1, b0h, b1h, b2h, b3h);
        c2l = fma4(c2l, a2, b0l, b1l, b2l, b3l); c2h = fma4(c2h, a2, b0h, b1h, b2h, b3h);
        c3l = fma4(c3l, a3, b0l, b1l, b2l, b3l); c3h = fma4(c3h, a3, b0h, b1h, b2h, b3h);
        c4l = fma4(c4l, a4, b0l, b1l, b2l, b3l); c4h = fma4(c4h, a4, b0h, b1h, b2h, b3h);
        c5l = fma4(c5l, a5, b0l, b1l, b2l, b3l); c5h = fma4(c5h, a5, b0h, b1h, b2h, b3h);
        c6l = fma4(c6l, a6, b0l, b1l, b2l, b3l); c6h = fma4(c6h, a6, b0h, b1h, b2h, b3h);
        c7l = fma4(c7l, a7, b0l, b1l, b2l, b3l); c7h = fma4(c7h, a7, b0h, b1h, b2h, b3h);
    }

    // A clamped half (a 4-wide load at the edge) only ever feeds rows or
    // columns past M or N, which are not stored.
    store8(row0, col0, c0l, c0h);
    store8(row0 + 1u, col0, c1l, c1h);
    store8(row0 + 2u, col0, c2l, c2h);
    store8(row0 + 3u, col0, c3l, c3h);
    store8(row0 + 4u, col0, c4l, c4h);
    store8(row0 + 5u, col0, c5l, c5h);
    store8(row0 + 6u, col0, c6l, c6h);
    store8(row0 + 7u, col0, c7l, c7h);
}

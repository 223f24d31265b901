// Feature loss per decoded region and its gradient (paper Eq. 6, first two terms):
//     loss_m = w_m * (lambda_cos * (1 - cos(p_m, t_m)) + lambda_l2 * |p_m - t_m|^2 / d)
//     grad_m = dloss_m / dp_m
// with cos = p.t / (max(|p|, eps) max(|t|, eps)), so an all-zero row has a
// defined loss and gradient. One workgroup per row; `grad` and `row_loss`
// are overwritten. CPU reference: engine/reference/src/loss.rs
// (`feature_loss`).
// @cost flops=17 * rows * cols + 45 * rows bytes=12 * rows * cols + 8 * rows
// per element: four fma sums and a sub (9), the gradient (8); per row two
// sqrts, a few divisions. Reads pred, target, weight; writes grad, row_loss.
#version 450
#include "common.glsl"

#define THREADS 256

layout(local_size_x = THREADS) in;

layout(std430, set = 0, binding = 0) readonly buffer Pred { float pred[]; };
layout(std430, set = 0, binding = 1) readonly buffer Target { float target[]; };
layout(std430, set = 0, binding = 2) readonly buffer Weight { float weight[]; };
layout(std430, set = 0, binding = 3) buffer Grad { float grad[]; };
layout(std430, set = 0, binding = 4) buffer RowLoss { float row_loss[]; };

layout(push_constant) uniform Params {
    uint rows;
    uint cols;
    float lambda_cos;
    float lambda_l2;
    float eps;
} pc;

// (p.t, |p|^2, |t|^2, |p - t|^2) per thread, then summed.
shared vec4 partial[THREADS];

void main() {
    uint row = linear_group();
    if (row >= pc.rows) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint base = row * pc.cols;
    vec4 s = vec4(0.0);
    for (uint j = t; j < pc.cols; j += THREADS) {
        float p = pred[base + j];
        float q = target[base + j];
        float e = p - q;
        s += vec4(p * q, p * p, q * q, e * e);
    }
    partial[t] = s;
    barrier();
    for (uint h = THREADS / 2u; h > 0u; h /= 2u) {
        if (t < h) {
            partial[t] += partial[t + h];
        }
        barrier();
    }
    vec4 tot = partial[0];
    float w = weight[row];
    float a = sqrt(tot.y);
    float b = sqrt(tot.z);
    float ac = max(a, pc.eps);
    float bc = max(b, pc.eps);
    float cosv = tot.x / (ac * bc);
    // d cos / d p = t / (ac bc) - [a > eps] cos p / a^2
    float radial = a > pc.eps ? cosv / (a * a) : 0.0;
    float inv_ab = 1.0 / (ac * bc);
    float l2 = 2.0 * pc.lambda_l2 / float(pc.cols);
    for (uint j = t; j < pc.cols; j += THREADS) {
        float p = pred[base + j];
        float q = target[base + j];
        float dcos = q * inv_ab - radial * p;
        grad[base + j] = w * (-pc.lambda_cos * dcos + l2 * (p - q));
    }
    if (t == 0u) {
        row_loss[row] = w * (pc.lambda_cos * (1.0 - cosv) + pc.lambda_l2 * tot.w / float(pc.cols));
    }
}

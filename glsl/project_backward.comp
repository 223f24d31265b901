// Chain rule from the per-(view, Gaussian) gradients of image mean, conic,
// depth and opacity (accumulated by raster_backward) to every Gaussian's
// mean, log-scale, quaternion (through its normalisation) and opacity logit.
// One thread per Gaussian, looping over the views, so views combine without
// atomics. Overwrites those four gradient fields, or adds to them when
// `accumulate` is set (a batch streamed through the rasterizer one chunk of
// views at a time; colour and query gradients come from raster_backward). CPU reference: engine/reference/src/raster.rs
// (`projection_backward`).
// @cost caller
// Only visible pairs (tile count > 0) are differentiated. Host, with
// pairs = n_gaussians * n_views and V = the batch's visible pairs:
//   flops = pairs + 785 * V + 11 * n_gaussians * accumulate
//     (a tile-count test per pair; per visible pair the projection again
//     ~350 (see project_forward.comp) and its chain rule ~435: conic
//     inverse 22, J cov J^T 72, camera-frame centre 50, W^T v_t 18,
//     W^T v_cov W 75, M and dM 63, log-scale 21, rotation and quaternion
//     VJP 83+27, opacity 4; accumulating adds 11 per Gaussian)
//   bytes = 88 * n_gaussians + 44 * n_gaussians * accumulate
//           + 128 * n_views + 4 * pairs + 28 * V
//     (44 parameter bytes read and 44 gradient bytes written per Gaussian,
//     the old gradients read when accumulating; a tile count per pair; 28
//     bytes of splat gradient per visible pair)
#version 450
#include "common.glsl"
#include "splat.glsl"

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Views { View views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Means { float means[]; };
layout(std430, set = 0, binding = 2) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 3) readonly buffer Quats { vec4 quats[]; };
layout(std430, set = 0, binding = 4) readonly buffer Logits { float opacity_logits[]; };
layout(std430, set = 0, binding = 5) readonly buffer TileCounts { uint tile_counts[]; };
layout(std430, set = 0, binding = 6) readonly buffer GradSplats { Splat grad_splats[]; };
layout(std430, set = 0, binding = 7) buffer GradMeans { float grad_means[]; };
layout(std430, set = 0, binding = 8) buffer GradLogScales { float grad_log_scales[]; };
layout(std430, set = 0, binding = 9) buffer GradQuats { vec4 grad_quats[]; };
layout(std430, set = 0, binding = 10) buffer GradLogits { float grad_opacity_logits[]; };

layout(push_constant) uniform Params {
    uint n_gaussians;
    uint n_views;
    uint accumulate;
} pc;

// dL/dq for R = quat_to_rotmat(q), q = (w, x, y, z) unit; vr[col][row].
vec4 quat_to_rotmat_vjp(vec4 q, mat3 vr) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    float r00 = vr[0][0], r01 = vr[1][0], r02 = vr[2][0];
    float r10 = vr[0][1], r11 = vr[1][1], r12 = vr[2][1];
    float r20 = vr[0][2], r21 = vr[1][2], r22 = vr[2][2];
    return 2.0 * vec4(
        -z * r01 + y * r02 + z * r10 - x * r12 - y * r20 + x * r21,
        y * r01 + z * r02 + y * r10 - 2.0 * x * r11 - w * r12 + z * r20 + w * r21 - 2.0 * x * r22,
        -2.0 * y * r00 + x * r01 + w * r02 + x * r10 + z * r12 - w * r20 + z * r21 - 2.0 * y * r22,
        -2.0 * z * r00 - w * r01 + x * r02 + w * r10 - 2.0 * z * r11 + y * r12 + x * r20 + y * r21);
}

void main() {
    uint g = linear_group() * 256u + gl_LocalInvocationIndex;
    if (g >= pc.n_gaussians) {
        return;
    }
    vec3 mean = vec3(means[3u * g], means[3u * g + 1u], means[3u * g + 2u]);
    vec3 log_scale = vec3(log_scales[3u * g], log_scales[3u * g + 1u], log_scales[3u * g + 2u]);
    vec4 quat = quats[g];
    float logit = opacity_logits[g];

    vec3 v_mean = vec3(0.0);
    vec3 v_log_scale = vec3(0.0);
    vec4 v_quat = vec4(0.0);
    float v_logit = 0.0;
    for (uint vi = 0u; vi < pc.n_views; vi++) {
        uint pair = vi * pc.n_gaussians + g;
        if (tile_counts[pair] == 0u) {
            continue;
        }
        View v = views[vi];
        Projection p = project_gaussian(v, mean, log_scale, quat, logit);
        if (!p.visible) {
            continue;
        }
        vec4 gs0 = grad_splats[pair].mean_depth_opacity;
        vec3 gconic = grad_splats[pair].conic.xyz;
        v_logit += gs0.w * p.opacity * (1.0 - p.opacity);

        // Conic = inverse 2-D covariance.
        mat2 conic = mat2(p.conic.x, p.conic.y, p.conic.y, p.conic.z);
        mat2 vc = mat2(gconic.x, 0.5 * gconic.y, 0.5 * gconic.y, gconic.z);
        mat2 v2 = -(conic * vc * conic);

        // 2-D covariance = J cov_c J^T.
        mat3 v_cov_c = v2[0][0] * outerProduct(p.j0, p.j0) + v2[1][0] * outerProduct(p.j0, p.j1)
            + v2[0][1] * outerProduct(p.j1, p.j0) + v2[1][1] * outerProduct(p.j1, p.j1);
        vec3 v_j0 = 2.0 * (p.cov_c * (v2[0][0] * p.j0 + v2[1][0] * p.j1));
        vec3 v_j1 = 2.0 * (p.cov_c * (v2[0][1] * p.j0 + v2[1][1] * p.j1));

        // Image mean uses the unclamped centre; J the clamped one.
        float fx = v.intrinsics.x, fy = v.intrinsics.y;
        float tz = p.t.z;
        float tz2 = tz * tz;
        vec3 v_t = vec3(fx / tz * gs0.x, fy / tz * gs0.y,
                        -(fx * p.t.x * gs0.x + fy * p.t.y * gs0.y) / tz2 + gs0.z);
        v_t.z += -fx / tz2 * v_j0.x - fy / tz2 * v_j1.y;
        if (p.clamped.x) {
            v_t.z += fx * p.lim.x / tz2 * v_j0.z;
        } else {
            v_t.x += -fx / tz2 * v_j0.z;
            v_t.z += 2.0 * fx * p.t.x / (tz2 * tz) * v_j0.z;
        }
        if (p.clamped.y) {
            v_t.z += fy * p.lim.y / tz2 * v_j1.z;
        } else {
            v_t.y += -fy / tz2 * v_j1.z;
            v_t.z += 2.0 * fy * p.t.y / (tz2 * tz) * v_j1.z;
        }

        // Camera frame to world.
        mat3 w = view_rotation(v);
        v_mean += transpose(w) * v_t;
        mat3 v_cov = transpose(w) * v_cov_c * w;

        // cov = M M^T with M = R diag(s).
        mat3 m = mat3(p.rot[0] * p.scale.x, p.rot[1] * p.scale.y, p.rot[2] * p.scale.z);
        mat3 v_m = 2.0 * (v_cov * m);
        v_log_scale += vec3(dot(p.rot[0], v_m[0]), dot(p.rot[1], v_m[1]), dot(p.rot[2], v_m[2]))
            * p.scale;
        mat3 v_rot = mat3(v_m[0] * p.scale.x, v_m[1] * p.scale.y, v_m[2] * p.scale.z);
        vec4 q = quat / p.qnorm;
        vec4 v_qhat = quat_to_rotmat_vjp(q, v_rot);
        v_quat += (v_qhat - dot(v_qhat, q) * q) / p.qnorm;
    }
    if (pc.accumulate != 0u) {
        v_mean += vec3(grad_means[3u * g], grad_means[3u * g + 1u], grad_means[3u * g + 2u]);
        v_log_scale += vec3(grad_log_scales[3u * g], grad_log_scales[3u * g + 1u],
                            grad_log_scales[3u * g + 2u]);
        v_quat += grad_quats[g];
        v_logit += grad_opacity_logits[g];
    }
    grad_means[3u * g] = v_mean.x;
    grad_means[3u * g + 1u] = v_mean.y;
    grad_means[3u * g + 2u] = v_mean.z;
    grad_log_scales[3u * g] = v_log_scale.x;
    grad_log_scales[3u * g + 1u] = v_log_scale.y;
    grad_log_scales[3u * g + 2u] = v_log_scale.z;
    grad_quats[g] = v_quat;
    grad_opacity_logits[g] = v_logit;
}

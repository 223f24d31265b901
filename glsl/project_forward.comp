// Projects every Gaussian into every view of the batch: one thread per
// (view, Gaussian) pair, pair index = view * n_gaussians + gaussian. Writes
// the splat the blending kernels use, its tile rectangle and tile count (0
// when culled), and a 0/1 visibility flag for stream compaction.
// CPU reference: engine/reference/src/raster.rs (`project`).
// @cost caller
// Culling is data-dependent (visible = pairs with tile count > 0, the
// count the host reads back in `measure`). Host: with pairs = n_gaussians
// * n_views and V = visible pairs (before `measure` knows V, V = pairs, an
// upper bound):
//   flops = 20 * pairs + 335 * V
//     (every pair: world-to-camera transform 18 + near/far test 2; a pair
//     that passes every test: quaternion norm and rotation 51, exp(scale)
//     30, covariance M M^T 39 + W cov W^T 75, Jacobian and 2-D covariance
//     53, conic 11, image mean 4, opacity sigmoid 16, extent and tile
//     rectangle 56;
//     pairs culled after the depth test but before the last test are
//     counted at 20, a floor)
//   bytes = 44 * n_gaussians + 128 * n_views + 8 * pairs + 40 * V
//     (mean, log-scale, quaternion, logit read once per Gaussian; views;
//     tile count + flag written per pair; splat 32 + rect 8 per visible)
#version 450
#include "common.glsl"
#include "splat.glsl"

layout(local_size_x = 256) in;

layout(std430, set = 0, binding = 0) readonly buffer Views { View views[]; };
layout(std430, set = 0, binding = 1) readonly buffer Means { float means[]; };
layout(std430, set = 0, binding = 2) readonly buffer LogScales { float log_scales[]; };
layout(std430, set = 0, binding = 3) readonly buffer Quats { vec4 quats[]; };
layout(std430, set = 0, binding = 4) readonly buffer Logits { float opacity_logits[]; };
// Per pair: (mean x, mean y, depth, opacity), (conic a, b, c, 0).
layout(std430, set = 0, binding = 5) buffer Splats { Splat splats[]; };
// Per pair: x0 | y0 << 16, x1 | y1 << 16 (inclusive tile rectangle).
layout(std430, set = 0, binding = 6) buffer Rects { TileRect rects[]; };
layout(std430, set = 0, binding = 7) buffer TileCounts { uint tile_counts[]; };
layout(std430, set = 0, binding = 8) buffer Flags { uint visible[]; };

layout(push_constant) uniform Params {
    uint n_gaussians;
    uint n_views;
} pc;

void main() {
    uint pair = linear_group() * 256u + gl_LocalInvocationIndex;
    if (pair >= pc.n_gaussians * pc.n_views) {
        return;
    }
    uint g = pair % pc.n_gaussians;
    View v = views[pair / pc.n_gaussians];
    vec3 mean = vec3(means[3u * g], means[3u * g + 1u], means[3u * g + 2u]);
    vec3 log_scale = vec3(log_scales[3u * g], log_scales[3u * g + 1u], log_scales[3u * g + 2u]);
    Projection p = project_gaussian(v, mean, log_scale, quats[g], opacity_logits[g]);
    uint count = 0u;
    if (p.visible) {
        count = (p.tiles.z - p.tiles.x + 1u) * (p.tiles.w - p.tiles.y + 1u);
        splats[pair] = Splat(vec4(p.mean2d, p.depth, p.opacity), vec4(p.conic, 0.0));
        rects[pair] = TileRect(p.tiles.x | (p.tiles.y << 16), p.tiles.z | (p.tiles.w << 16));
    }
    tile_counts[pair] = count;
    visible[pair] = count > 0u ? 1u : 0u;
}

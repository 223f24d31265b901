// Shared by the Gaussian projection kernels (forward and backward). The math
// and its conventions are documented in engine/reference/src/raster.rs; keep
// the two in step.

// TILE_SIZE, MAX_ALPHA, MIN_ALPHA, LOW_PASS and `View` (one camera of the
// batch) are declared once for the host and the kernels in
// shaders/layouts.rs.
#include "shared.glsl"

// Columns of the rotation of a unit quaternion (w, x, y, z).
mat3 quat_to_rotmat(vec4 q) {
    float w = q.x, x = q.y, y = q.z, z = q.w;
    return mat3(
        vec3(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)));
}

mat3 view_rotation(View v) {
    return transpose(mat3(v.row0.xyz, v.row1.xyz, v.row2.xyz));
}

// Everything the projection computes, for the forward pass and its backward.
struct Projection {
    bool visible;
    vec2 mean2d;
    vec3 conic;      // (a, b, c) of [[a, b], [b, c]] = inverse 2-D covariance
    vec3 cov2d;      // same packing, low pass included
    float depth;
    float opacity;
    uvec4 tiles;     // inclusive tile rectangle x0, y0, x1, y1
    mat3 rot;        // rotation of the normalised quaternion
    vec3 scale;
    vec3 t;          // camera-frame centre
    mat3 cov_c;      // camera-frame 3-D covariance
    vec3 j0;         // rows of the projection Jacobian
    vec3 j1;
    bvec2 clamped;   // whether tx/tz, ty/tz hit the guard band
    vec2 lim;        // the clamped tx/tz, ty/tz
    float qnorm;
};

Projection project_gaussian(View v, vec3 mean, vec3 log_scale, vec4 quat, float logit) {
    Projection p;
    p.visible = false;
    mat3 w = view_rotation(v);
    p.t = w * mean + vec3(v.row0.w, v.row1.w, v.row2.w);
    // Written so that NaN fails every test.
    if (!(p.t.z >= v.clip.x && p.t.z <= v.clip.y)) {
        return p;
    }
    p.qnorm = length(quat);
    if (!(p.qnorm > 1e-12 && p.qnorm < 3.0e38)) {
        return p;
    }
    p.rot = quat_to_rotmat(quat / p.qnorm);
    p.scale = exp(log_scale);
    mat3 m = p.rot * mat3(vec3(p.scale.x, 0.0, 0.0), vec3(0.0, p.scale.y, 0.0),
                          vec3(0.0, 0.0, p.scale.z));
    mat3 cov = m * transpose(m);
    p.cov_c = w * cov * transpose(w);

    float fx = v.intrinsics.x, fy = v.intrinsics.y;
    float tz = p.t.z;
    vec2 r = p.t.xy / tz;
    p.lim = vec2(clamp(r.x, v.guard.x, v.guard.y), clamp(r.y, v.guard.z, v.guard.w));
    p.clamped = bvec2(p.lim.x != r.x, p.lim.y != r.y);
    p.j0 = vec3(fx / tz, 0.0, -fx * p.lim.x / tz);
    p.j1 = vec3(0.0, fy / tz, -fy * p.lim.y / tz);
    vec3 cj0 = p.cov_c * p.j0;
    vec3 cj1 = p.cov_c * p.j1;
    p.cov2d = vec3(dot(p.j0, cj0) + LOW_PASS, dot(p.j0, cj1), dot(p.j1, cj1) + LOW_PASS);
    float det = p.cov2d.x * p.cov2d.z - p.cov2d.y * p.cov2d.y;
    if (!(det > 0.0)) {
        return p;
    }
    p.conic = vec3(p.cov2d.z, -p.cov2d.y, p.cov2d.x) / det;
    p.mean2d = vec2(fx * r.x + v.intrinsics.z, fy * r.y + v.intrinsics.w);
    p.depth = tz;
    p.opacity = 1.0 / (1.0 + exp(-logit));
    if (!(p.opacity >= MIN_ALPHA)) {
        return p;
    }
    float ext = min(3.33, sqrt(2.0 * log(p.opacity * 255.0)));
    vec2 rad = ceil(ext * sqrt(vec2(p.cov2d.x, p.cov2d.z)));
    vec2 lo = p.mean2d - rad;
    vec2 hi = p.mean2d + rad;
    vec2 last = vec2(float(v.size.x) - 1.0, float(v.size.y) - 1.0);
    if (!(hi.x >= 0.0 && hi.y >= 0.0 && lo.x <= last.x && lo.y <= last.y)) {
        return p;
    }
    // Clamped to the image before converting, so huge boxes stay in range.
    vec2 t0 = floor(max(lo, vec2(0.0)) / float(TILE_SIZE));
    vec2 t1 = floor(min(hi, last) / float(TILE_SIZE));
    p.tiles = uvec4(uint(t0.x), uint(t0.y), uint(t1.x), uint(t1.y));
    p.visible = true;
    return p;
}

// Backward pass of the blending kernel (glsl/raster_forward.comp): one
// 256-thread workgroup per tile, one thread per pixel, walking the tile's
// depth-sorted list front to back again up to each pixel's last contributor.
// For every (pixel, Gaussian) it forms the gradients of the Gaussian's
// colour, query, depth, opacity, image mean and conic, and adds them into
// per-Gaussian (colour, query) and per-(view, Gaussian) (the rest) buffers.
// CPU reference: engine/reference/src/raster.rs (`backward`).
//
// WGSL because the accumulation needs float atomics (or a compare-and-swap
// loop where the device lacks them) and, where available, subgroup sums that
// cut the atomics by the subgroup size; naga's GLSL front end has neither.
//
// With C_<=i the channels accumulated up to and including Gaussian i, the
// gradient of the blending weight alpha_i is, per channel k,
//   v_C_k * (f_ik T_i - (C_final_k - C_<=i,k) / (1 - alpha_i))
// plus (v_alpha_out - background . v_rgb) * T_final / (1 - alpha_i): the
// front-to-back form, which replays the forward order exactly.
//
// COLUMNS variants give each of 16 invocations one 16-pixel tile column
// instead of one pixel (see glsl/raster_forward.comp for why CPU drivers
// want that): a Gaussian's data is loaded once per column, its gradients
// are summed over the column in registers before the subgroup sum and the
// atomics, and branches become selects, since those drivers run both sides
// anyway. There each 8 invocations of a tile are one subgroup (the host
// picks the SUBGROUP column variants only for subgroups of exactly 8): a
// shuffle butterfly leaves the subgroup's sums in every invocation, and
// each adds a share of them, so every atomic instruction does 8 useful
// additions. CPU drivers run subgroup reductions and atomics lane by lane,
// and flushing a Gaussian from one invocation cost as much as blending it.
// (Two columns per invocation halve the flushes but took lavapipe's
// compiler 3 to 4.5 times as long, 13.5 s against 4.2 s on a cold driver
// cache, for no measurable gain at run time.)
//
// @capabilities SHADER_FLOAT32_ATOMIC SUBGROUP
// @select COLUMNS ATTACHED SUBGROUP CAS
// @kernel raster_backward SUBGROUP=1 CAS=0 COLUMNS=0
// @kernel raster_backward_cas SUBGROUP=1 CAS=1 COLUMNS=0
// @kernel raster_backward_plain SUBGROUP=0 CAS=0 COLUMNS=0
// @kernel raster_backward_plain_cas SUBGROUP=0 CAS=1 COLUMNS=0
// @kernel raster_backward_columns SUBGROUP=1 CAS=0 COLUMNS=1 ATTACHED=0
// @kernel raster_backward_columns_cas SUBGROUP=1 CAS=1 COLUMNS=1 ATTACHED=0
// @kernel raster_backward_columns_plain SUBGROUP=0 CAS=0 COLUMNS=1 ATTACHED=0
// @kernel raster_backward_columns_plain_cas SUBGROUP=0 CAS=1 COLUMNS=1 ATTACHED=0
// @kernel raster_backward_columns_attached SUBGROUP=1 CAS=0 COLUMNS=1 ATTACHED=1
// @kernel raster_backward_columns_attached_cas SUBGROUP=1 CAS=1 COLUMNS=1 ATTACHED=1
// @kernel raster_backward_columns_attached_plain SUBGROUP=0 CAS=0 COLUMNS=1 ATTACHED=1
// @kernel raster_backward_columns_attached_plain_cas SUBGROUP=0 CAS=1 COLUMNS=1 ATTACHED=1
// @cost caller
// Per-tile list lengths and per-pixel walks are data. Host, with I, P, V,
// U as for raster_forward.comp (I tile-list entries, P pixels, V visible
// pairs, U = min(n_gaussians, V)), 256 * I pairs tested (every entry by
// every pixel of its tile: an upper bound), n_tiles, detach_query, R the
// pooled region rows (query_source 1), and CostModel constants
// (tools/src/bench/raster.rs):
// flops
//   pixel variants (raster_backward, _cas, _plain, _plain_cas):
//     25 * 256 * I + 80 * P  (TEST per tested pair; per pixel c_final,
//     background term, 32 upstream query scales. The per-contributor
//     GRAD_DETACHED 132 + GRAD_QUERY 256 * (1 - detach_query) is not
//     host-known at dispatch: add it times contributors where known)
//   raster_backward_columns[_cas|_plain|_plain_cas]:
//     210 * 256 * I + 680 * I + 80 * P
//   raster_backward_columns_attached[_cas|_plain|_plain_cas]:
//     280 * 256 * I + 680 * I + 80 * P
//     (branchless: every tested (entry, pixel) forms all its gradients
//     with selects, 210, +70 for the attached query terms of the alpha
//     gradient, a 32-channel dot product and the running sums; per entry
//     680 for two flushes of 42 atomic adds and the sums over 8 lanes
//     before them: one per subgroup of 8 columns, two per tile; the _plain
//     ones flush from all 16 invocations, counted the same as a floor)
// bytes = 4 * I + 32 * V + 4 * n_tiles + 44 * P + Q + X + A, where
//   X = 140 * U for the pixel and _attached variants, 12 * U for the
//     detached column ones (colour, query per Gaussian, distinct once);
//   Q = query_image 128 * P * (1 - detach_query) (pixel variants) or
//     128 * P (_attached), plus the upstream query gradient: 128 * P
//     (query_source 0), 4 * P + 132 * R (1), 0 (2);
//   A = atomics, 42 gradient words of 8 bytes per flush (CAS the same,
//     retries not counted): 672 * I for the SUBGROUP column variants (each
//     of a tile's two subgroups flushes every entry), 336 * I for the
//     SUBGROUP pixel ones (a floor, one flush per entry as CostModel
//     ENTRY_GRAD_BYTES; they do up to 256 / subgroup size), 336 * I for the
//     pixel _plain ones too as a floor (they flush once per contributor),
//     5376 * I for the column _plain ones (each of the 16 invocations
//     flushes every entry).
//
// In the COLUMNS variants whether the query gradients reach opacity and
// geometry is fixed at compile time (ATTACHED), since a run-time branch
// costs its full work there even when not taken.
//
// The upstream gradient of a pixel's query (`query_source`) is read from a
// per-pixel image (QUERY_GRAD_FROM_IMAGE), from pooled region rows through
// the pixel's region (QUERY_GRAD_FROM_REGIONS: rows first_row + r, divided
// by the region's pixel count, the adjoint of region pooling, so training
// needs no per-pixel query gradient image), or is zero (QUERY_GRAD_ZERO:
// no feature loss).

#include "raster.wgsl"

#if COLUMNS
// Pixels per invocation (one tile column), and invocations per workgroup.
const ROWS: u32 = 16u;
const INVOCATIONS: u32 = 16u;
#else
const ROWS: u32 = 1u;
const INVOCATIONS: u32 = 256u;
#endif

struct Params {
    n_gaussians: u32,
    n_views: u32,
    n_tiles: u32,
    // 1: the query channels' gradients do not reach opacity or geometry.
    detach_query: u32,
    bg_r: f32,
    bg_g: f32,
    bg_b: f32,
    query_source: u32,
    first_row: u32,
    // Where the regions' CSR offsets start in pixel_region.
    offsets_at: u32,
}

var<immediate> pc: Params;

@group(0) @binding(0) var<storage, read> views: array<View>;
@group(0) @binding(1) var<storage, read> colors: array<f32>;
@group(0) @binding(2) var<storage, read> queries: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> splats: array<Splat>;
@group(0) @binding(4) var<storage, read> pairs: array<u32>;
@group(0) @binding(5) var<storage, read> ranges: array<TileRange>;
@group(0) @binding(6) var<storage, read> rgbd: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> query_image: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read> state: array<PixelState>;
@group(0) @binding(9) var<storage, read> grad_rgbd: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read> grad_alpha: array<f32>;
// Per pixel (query_source 0) or per pooled region row (1).
@group(0) @binding(11) var<storage, read> grad_query: array<vec4<f32>>;
#if CAS
@group(0) @binding(12) var<storage, read_write> grad_colors: array<atomic<u32>>;
@group(0) @binding(13) var<storage, read_write> grad_queries: array<atomic<u32>>;
// Per (view, Gaussian) pair: (mean x, mean y, depth, opacity), (conic a, b, c, -).
@group(0) @binding(14) var<storage, read_write> grad_splats: array<atomic<u32>>;
#else
@group(0) @binding(12) var<storage, read_write> grad_colors: array<atomic<f32>>;
@group(0) @binding(13) var<storage, read_write> grad_queries: array<atomic<f32>>;
@group(0) @binding(14) var<storage, read_write> grad_splats: array<atomic<f32>>;
#endif
// Region of each pixel, numbered within the batch (query_source 1), then
// from offsets_at the regions' CSR offsets: region r covers
// pixel_region[offsets_at + r + 1] - pixel_region[offsets_at + r] pixels.
// One binding for both keeps the kernel within 16 storage buffers.
@group(0) @binding(15) var<storage, read> pixel_region: array<u32>;

// Where pixel p's upstream query gradient is: grad_query[base + c] * scale
// for the 8 vec4 c (scale 0: none).
struct QueryUpstream {
    base: u32,
    scale: f32,
}

fn query_upstream(p: u32) -> QueryUpstream {
    var u = QueryUpstream(8u * p, 1.0);
    if (pc.query_source == QUERY_GRAD_FROM_REGIONS) {
        let r = pixel_region[p];
        if (r == NO_REGION) {
            u = QueryUpstream(0u, 0.0);
        } else {
            let size = pixel_region[pc.offsets_at + r + 1u] - pixel_region[pc.offsets_at + r];
            u = QueryUpstream(8u * (pc.first_row + r), 1.0 / f32(max(size, 1u)));
        }
    } else if (pc.query_source != QUERY_GRAD_FROM_IMAGE) {
        u = QueryUpstream(0u, 0.0);
    }
    return u;
}

// Selected, so a stale or non-finite row never reaches a pixel it does
// not belong to.
fn upstream_query(u: QueryUpstream, c: u32) -> vec4<f32> {
    return select(vec4<f32>(0.0), grad_query[u.base + c] * u.scale, u.scale != 0.0);
}

#if CAS
// One CAS loop per buffer: WGSL cannot pass storage pointers to functions.
fn add_color(i: u32, v: f32) {
    var old = atomicLoad(&grad_colors[i]);
    loop {
        let r = atomicCompareExchangeWeak(&grad_colors[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) { break; }
        old = r.old_value;
    }
}
fn add_query(i: u32, v: f32) {
    var old = atomicLoad(&grad_queries[i]);
    loop {
        let r = atomicCompareExchangeWeak(&grad_queries[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) { break; }
        old = r.old_value;
    }
}
fn add_splat(i: u32, v: f32) {
    var old = atomicLoad(&grad_splats[i]);
    loop {
        let r = atomicCompareExchangeWeak(&grad_splats[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) { break; }
        old = r.old_value;
    }
}
#else
fn add_color(i: u32, v: f32) { atomicAdd(&grad_colors[i], v); }
fn add_query(i: u32, v: f32) { atomicAdd(&grad_queries[i], v); }
fn add_splat(i: u32, v: f32) { atomicAdd(&grad_splats[i], v); }
#endif

// One (pixel, Gaussian) contribution's gradients.
struct Grads {
    rgbd: vec4<f32>,            // colour, depth
    query: array<vec4<f32>, 8>,
    mean_opacity: vec4<f32>,    // mean x, mean y, opacity, -
    conic: vec4<f32>,           // a, b, c, -
}

fn flush(g: Grads, gaussian: u32, pair: u32) {
    add_color(3u * gaussian, g.rgbd.x);
    add_color(3u * gaussian + 1u, g.rgbd.y);
    add_color(3u * gaussian + 2u, g.rgbd.z);
    for (var c = 0u; c < 8u; c++) {
        add_query(32u * gaussian + 4u * c, g.query[c].x);
        add_query(32u * gaussian + 4u * c + 1u, g.query[c].y);
        add_query(32u * gaussian + 4u * c + 2u, g.query[c].z);
        add_query(32u * gaussian + 4u * c + 3u, g.query[c].w);
    }
    add_splat(SPLAT_WORDS * pair, g.mean_opacity.x);
    add_splat(SPLAT_WORDS * pair + 1u, g.mean_opacity.y);
    add_splat(SPLAT_WORDS * pair + 2u, g.rgbd.w);
    add_splat(SPLAT_WORDS * pair + 3u, g.mean_opacity.z);
    add_splat(SPLAT_WORDS * pair + 4u, g.conic.x);
    add_splat(SPLAT_WORDS * pair + 5u, g.conic.y);
    add_splat(SPLAT_WORDS * pair + 6u, g.conic.z);
}

#if SUBGROUP
// Sum over the 8 invocations of a column-layout subgroup, in every
// invocation.
fn lane_sum(x: vec4<f32>) -> vec4<f32> {
    var y = x + subgroupShuffleXor(x, 1u);
    y += subgroupShuffleXor(y, 2u);
    return y + subgroupShuffleXor(y, 4u);
}
#endif

var<workgroup> sh_pair: array<u32, BLEND_BATCH>;
var<workgroup> sh_splat: array<vec4<f32>, BLEND_BATCH>;
var<workgroup> sh_conic: array<vec4<f32>, BLEND_BATCH>;

#if COLUMNS
@compute @workgroup_size(16)
#else
@compute @workgroup_size(256)
#endif
fn raster_backward(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) t: u32,
#if SUBGROUP
    @builtin(subgroup_invocation_id) lane: u32,
#endif
) {
    let tile = wid.y * nwg.x + wid.x;
    if (tile >= pc.n_tiles) {
        return;
    }
    var vi = 0u;
    for (var k = 1u; k < pc.n_views; k++) {
        if (views[k].offsets.x <= tile) {
            vi = k;
        }
    }
    let v = views[vi];
    let local_tile = tile - v.offsets.x;
#if COLUMNS
    let px0 = (local_tile % v.size.z) * TILE_SIZE + t;
    let py0 = (local_tile / v.size.z) * TILE_SIZE;
    let bg = vec3<f32>(pc.bg_r, pc.bg_g, pc.bg_b);
#if ATTACHED
#else
    // Keeps the query bindings in the interface every variant shares.
    if (pc.n_tiles == 0xffffffffu) {
        _ = queries[0];
        _ = query_image[0];
    }
#endif

    // Each pixel's forward results, upstream gradients and running sums,
    // indexed by constants only (unrolled below).
    var walked: array<u32, ROWS>;
    var c_final: array<vec4<f32>, ROWS>;
    var v_rgbd: array<vec4<f32>, ROWS>;
    var bg_term: array<f32, ROWS>;
    var trans: array<f32, ROWS>;
    var c_acc: array<vec4<f32>, ROWS>;
    var v_q: array<vec4<f32>, 128>;
#if ATTACHED
    // The query terms of the alpha gradient need the rendered and the
    // running query only through their dot products with the upstream
    // gradient: sum_c v_q,c . (q_final,c - q_<=i,c) = vq_final - vq_acc.
    // Two numbers per pixel instead of 64, which quartered the driver's
    // compile time.
    var vq_final: array<f32, ROWS>;
    var vq_acc: array<f32, ROWS>;
#endif
    var my_walk = 0u;
#unroll K 16
    {
        let px = px0;
        let py = py0 + K;
        walked[K] = 0u;
        var t_final = 1.0;
        c_final[K] = vec4<f32>(0.0);
        v_rgbd[K] = vec4<f32>(0.0);
        trans[K] = 1.0;
        c_acc[K] = vec4<f32>(0.0);
        var v_alpha_out = 0.0;
#unroll C 8
        v_q[8u * K + C] = vec4<f32>(0.0);
#endunroll
#if ATTACHED
        vq_final[K] = 0.0;
        vq_acc[K] = 0.0;
#endif
        if (px < v.size.x && py < v.size.y) {
            let p = v.offsets.y + py * v.size.x + px;
            let st = state[p];
            walked[K] = st.walked;
            t_final = st.transmittance;
            let out = rgbd[p];
            c_final[K] = vec4<f32>(out.xyz - t_final * bg, out.w);
            v_rgbd[K] = grad_rgbd[p];
            v_alpha_out = grad_alpha[p];
            let up = query_upstream(p);
#unroll C 8
            v_q[8u * K + C] = upstream_query(up, C);
#if ATTACHED
            vq_final[K] += dot(v_q[8u * K + C], query_image[8u * p + C]);
#endif
#endunroll
        }
        bg_term[K] = (v_alpha_out - dot(bg, v_rgbd[K].xyz)) * t_final;
        my_walk = max(my_walk, walked[K]);
    }
#endunroll

    let tile_walk = tile_max(t, my_walk);
    let start = ranges[tile].start;

    for (var base = 0u; base < tile_walk; base += BLEND_BATCH) {
        workgroupBarrier();
        for (var e = t; e < BLEND_BATCH; e += INVOCATIONS) {
            if (base + e < tile_walk) {
                let pair = pairs[start + base + e];
                sh_pair[e] = pair;
                sh_splat[e] = splats[pair].mean_depth_opacity;
                sh_conic[e] = splats[pair].conic;
            }
        }
        workgroupBarrier();
        let count = min(BLEND_BATCH, tile_walk - base);
        for (var j = 0u; j < count; j++) {
            let pair = sh_pair[j];
            let gaussian = pair % pc.n_gaussians;
            let s = sh_splat[j];
            let conic = sh_conic[j].xyz;
            // Loaded once for the column.
            let f_rgbd = vec4<f32>(
                colors[3u * gaussian],
                colors[3u * gaussian + 1u],
                colors[3u * gaussian + 2u],
                s.z
            );
#if ATTACHED
            var f_q: array<vec4<f32>, 8>;
#unroll C 8
            f_q[C] = queries[8u * gaussian + C];
#endunroll
#endif
            var g: Grads;
            g.rgbd = vec4<f32>(0.0);
#unroll C 8
            g.query[C] = vec4<f32>(0.0);
#endunroll
            g.mean_opacity = vec4<f32>(0.0);
            g.conic = vec4<f32>(0.0);
#unroll K 16
            {
                let d = s.xy - vec2<f32>(f32(px0), f32(py0 + K));
                let sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
                let vis = exp(-sigma);
                let alpha = min(MAX_ALPHA, s.w * vis);
                let hit = base + j < walked[K] && sigma >= 0.0 && alpha >= MIN_ALPHA;
                let w = alpha * trans[K];
                let acc = c_acc[K] + w * f_rgbd;
                let ra = 1.0 / (1.0 - alpha);
                var v_alpha = bg_term[K] * ra
                    + dot(v_rgbd[K], f_rgbd * trans[K] - (c_final[K] - acc) * ra);
                // Selected, not multiplied by a zero weight: a non-finite
                // value must not reach pixels the Gaussian does not cover.
                c_acc[K] = select(c_acc[K], acc, hit);
                g.rgbd = select(g.rgbd, g.rgbd + w * v_rgbd[K], hit);
#unroll C 8
                g.query[C] = select(g.query[C], g.query[C] + w * v_q[8u * K + C], hit);
#endunroll
#if ATTACHED
                {
                    // sum_c v_q,c . (f_c T - (q_final,c - q_<=i,c) / (1 - alpha)).
                    var vf = 0.0;
#unroll C 8
                    vf += dot(v_q[8u * K + C], f_q[C]);
#endunroll
                    let vqa = vq_acc[K] + w * vf;
                    vq_acc[K] = select(vq_acc[K], vqa, hit);
                    v_alpha += vf * trans[K] - (vq_final[K] - vqa) * ra;
                }
#endif
                // Clamped alphas do not depend on opacity or shape.
                let shaped = hit && s.w * vis <= MAX_ALPHA;
                let v_sigma = -s.w * vis * v_alpha;
                g.conic = select(g.conic, g.conic + vec4<f32>(
                    0.5 * v_sigma * d.x * d.x,
                    v_sigma * d.x * d.y,
                    0.5 * v_sigma * d.y * d.y,
                    0.0
                ), shaped);
                g.mean_opacity = select(g.mean_opacity, g.mean_opacity + vec4<f32>(
                    v_sigma * (conic.x * d.x + conic.y * d.y),
                    v_sigma * (conic.y * d.x + conic.z * d.y),
                    vis * v_alpha,
                    0.0
                ), shaped);
                trans[K] = select(trans[K], trans[K] * (1.0 - alpha), hit);
            }
#endunroll
#if SUBGROUP
            g.rgbd = lane_sum(g.rgbd);
#unroll C 8
            g.query[C] = lane_sum(g.query[C]);
#endunroll
            g.mean_opacity = lane_sum(g.mean_opacity);
            g.conic = lane_sum(g.conic);
            // Every lane holds the sums; lane l adds query channels 4l..4l+3,
            // colour channel l and splat gradient l.
            var mine = g.query[0];
#unroll C 8
            mine = select(mine, g.query[C], lane == C);
#endunroll
            add_query(32u * gaussian + 4u * lane, mine.x);
            add_query(32u * gaussian + 4u * lane + 1u, mine.y);
            add_query(32u * gaussian + 4u * lane + 2u, mine.z);
            add_query(32u * gaussian + 4u * lane + 3u, mine.w);
            if (lane < 3u) {
                add_color(3u * gaussian + lane, select(select(g.rgbd.z, g.rgbd.y, lane == 1u), g.rgbd.x, lane == 0u));
            }
            if (lane < 7u) {
                // Splat gradient order: mean x, mean y, depth, opacity, conic a, b, c.
                let sv = array<f32, 7>(g.mean_opacity.x, g.mean_opacity.y, g.rgbd.w, g.mean_opacity.z, g.conic.x, g.conic.y, g.conic.z);
                var v = sv[0];
#unroll C 7
                v = select(v, sv[C], lane == C);
#endunroll
                add_splat(SPLAT_WORDS * pair + lane, v);
            }
#else
            flush(g, gaussian, pair);
#endif
        }
    }
#else
    let px = (local_tile % v.size.z) * TILE_SIZE + t % TILE_SIZE;
    let py = (local_tile / v.size.z) * TILE_SIZE + t / TILE_SIZE;
    let inside = px < v.size.x && py < v.size.y;
    let pix = vec2<f32>(f32(px), f32(py));
    let bg = vec3<f32>(pc.bg_r, pc.bg_g, pc.bg_b);
    let detach = pc.detach_query != 0u;

    // This pixel's forward results and upstream gradients.
    var walked = 0u;
    var t_final = 1.0;
    var c_final = vec4<f32>(0.0);
    var q_final: array<vec4<f32>, 8>;
    var v_rgbd = vec4<f32>(0.0);
    var v_q: array<vec4<f32>, 8>;
    var v_alpha_out = 0.0;
    if (inside) {
        let p = v.offsets.y + py * v.size.x + px;
        let s = state[p];
        walked = s.walked;
        t_final = s.transmittance;
        let out = rgbd[p];
        c_final = vec4<f32>(out.xyz - t_final * bg, out.w);
        v_rgbd = grad_rgbd[p];
        v_alpha_out = grad_alpha[p];
        let up = query_upstream(p);
        for (var c = 0u; c < 8u; c++) {
            v_q[c] = upstream_query(up, c);
        }
        // The rendered query matters only when its gradients reach opacity
        // and geometry; a render without query channels leaves it stale
        // (or absent).
        if (!detach) {
            for (var c = 0u; c < 8u; c++) {
                q_final[c] = query_image[8u * p + c];
            }
        }
    }
    // The background term of every alpha gradient.
    let bg_term = (v_alpha_out - dot(bg, v_rgbd.xyz)) * t_final;

    let tile_walk = tile_max(t, walked);
    let start = ranges[tile].start;

    var trans = 1.0;
    var c_acc = vec4<f32>(0.0);
    var q_acc: array<vec4<f32>, 8>;
    for (var c = 0u; c < 8u; c++) {
        q_acc[c] = vec4<f32>(0.0);
    }

    for (var base = 0u; base < tile_walk; base += BLEND_BATCH) {
        workgroupBarrier();
        if (base + t < tile_walk) {
            let pair = pairs[start + base + t];
            sh_pair[t] = pair;
            sh_splat[t] = splats[pair].mean_depth_opacity;
            sh_conic[t] = splats[pair].conic;
        }
        workgroupBarrier();
        let count = min(BLEND_BATCH, tile_walk - base);
        for (var j = 0u; j < count; j++) {
            var g: Grads;
            g.rgbd = vec4<f32>(0.0);
            for (var c = 0u; c < 8u; c++) {
                g.query[c] = vec4<f32>(0.0);
            }
            g.mean_opacity = vec4<f32>(0.0);
            g.conic = vec4<f32>(0.0);
            var contributes = false;
            let pair = sh_pair[j];
            let gaussian = pair % pc.n_gaussians;
            if (base + j < walked) {
                let s = sh_splat[j];
                let conic = sh_conic[j].xyz;
                let d = s.xy - pix;
                let sigma = 0.5 * (conic.x * d.x * d.x + conic.z * d.y * d.y) + conic.y * d.x * d.y;
                let vis = exp(-sigma);
                let alpha = min(MAX_ALPHA, s.w * vis);
                if (sigma >= 0.0 && alpha >= MIN_ALPHA) {
                    contributes = true;
                    let w = alpha * trans;
                    let f_rgbd = vec4<f32>(
                        colors[3u * gaussian],
                        colors[3u * gaussian + 1u],
                        colors[3u * gaussian + 2u],
                        s.z
                    );
                    c_acc += w * f_rgbd;
                    let ra = 1.0 / (1.0 - alpha);
                    var v_alpha = bg_term * ra
                        + dot(v_rgbd, f_rgbd * trans - (c_final - c_acc) * ra);
                    g.rgbd = w * v_rgbd;
                    for (var c = 0u; c < 8u; c++) {
                        let f = queries[8u * gaussian + c];
                        q_acc[c] += w * f;
                        g.query[c] = w * v_q[c];
                        if (!detach) {
                            v_alpha += dot(v_q[c], f * trans - (q_final[c] - q_acc[c]) * ra);
                        }
                    }
                    // Clamped alphas do not depend on opacity or shape.
                    if (s.w * vis <= MAX_ALPHA) {
                        let v_sigma = -s.w * vis * v_alpha;
                        g.conic = vec4<f32>(
                            0.5 * v_sigma * d.x * d.x,
                            v_sigma * d.x * d.y,
                            0.5 * v_sigma * d.y * d.y,
                            0.0
                        );
                        g.mean_opacity = vec4<f32>(
                            v_sigma * (conic.x * d.x + conic.y * d.y),
                            v_sigma * (conic.y * d.x + conic.z * d.y),
                            vis * v_alpha,
                            0.0
                        );
                    }
                    trans *= 1.0 - alpha;
                }
            }
#if SUBGROUP
            if (subgroupAny(contributes)) {
                g.rgbd = subgroupAdd(g.rgbd);
                for (var c = 0u; c < 8u; c++) {
                    g.query[c] = subgroupAdd(g.query[c]);
                }
                g.mean_opacity = subgroupAdd(g.mean_opacity);
                g.conic = subgroupAdd(g.conic);
                if (lane == 0u) {
                    flush(g, gaussian, pair);
                }
            }
#else
            if (contributes) {
                flush(g, gaussian, pair);
            }
#endif
        }
    }
#endif
}

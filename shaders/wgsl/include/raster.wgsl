// Shared by the blending kernels that replay a tile's list in WGSL
// (raster_backward.wgsl, raster_pool.wgsl): the constants and view layout
// of glsl/raster_forward.comp, and the workgroup's walk length.

const TILE_SIZE: u32 = 16u;
const BATCH: u32 = 256u;
const MAX_ALPHA: f32 = 0.99;
const MIN_ALPHA: f32 = 1.0 / 255.0;
// A pixel in no region.
const NO_REGION: u32 = 0xffffffffu;

// Mirrors `View` in glsl/splat.glsl.
struct View {
    row0: vec4<f32>,
    row1: vec4<f32>,
    row2: vec4<f32>,
    intrinsics: vec4<f32>,
    guard: vec4<f32>,
    clip: vec4<f32>,
    size: vec4<u32>,
    offsets: vec4<u32>,
}

var<workgroup> wg_walk_atomic: atomic<u32>;
var<workgroup> wg_walk: u32;

// The largest `mine` over the workgroup (invocation `t`), uniform: how far
// the tile walks its list.
fn tile_max(t: u32, mine: u32) -> u32 {
    if (t == 0u) {
        atomicStore(&wg_walk_atomic, 0u);
    }
    workgroupBarrier();
    atomicMax(&wg_walk_atomic, mine);
    workgroupBarrier();
    if (t == 0u) {
        wg_walk = atomicLoad(&wg_walk_atomic);
    }
    return workgroupUniformLoad(&wg_walk);
}

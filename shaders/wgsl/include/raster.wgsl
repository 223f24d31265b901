// Shared by the blending kernels that replay a tile's list in WGSL
// (raster_backward.wgsl, raster_pool.wgsl): the constants and view layout
// of glsl/raster_forward.comp (declared once in shaders/layouts.rs), and
// the workgroup's walk length.

#include "shared.wgsl"

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

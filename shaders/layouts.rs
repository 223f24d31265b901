//! The one declaration of what the host and the kernels share: constants
//! and the structs they exchange through buffers. `shaders/build.rs` writes
//! it out three times, so no copy is kept by hand:
//! * `#include "shared.glsl"`: `#define`s and GLSL structs for `glsl/`;
//! * `#include "shared.wgsl"`: `const`s and WGSL structs for `shaders/wgsl/`;
//! * `latentam_shaders::shared`: Rust constants and `#[repr(C)]` structs.
//!
//! Struct fields are 16-byte vectors or 4-byte scalars with any vector at
//! a 16-byte offset, and a struct holding a vector is a multiple of 16
//! bytes, so the Rust layout equals std430's; the build checks that and
//! compares each struct with naga's layout in every kernel that uses it.
//! Each struct `FooBar` also gets `FOO_BAR_WORDS`, its size in 4-byte
//! words, for kernels that address its fields in a flat array (atomics).

/// A constant's type.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum ConstType {
    /// `uint` / `u32`.
    U32,
    /// `float` / `f32`.
    F32,
}

/// A constant: `value` is an expression valid in GLSL, WGSL and Rust alike
/// (a literal, or literals and operators); the build adds the `u` suffix
/// of unsigned GLSL and WGSL literals.
pub struct Constant {
    pub name: &'static str,
    pub ty: ConstType,
    pub value: &'static str,
    pub doc: &'static str,
}

/// A field's type.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum FieldType {
    /// `vec4` / `vec4<f32>` / `[f32; 4]`.
    Vec4,
    /// `uvec4` / `vec4<u32>` / `[u32; 4]`.
    UVec4,
    /// `float` / `f32`.
    F32,
    /// `uint` / `u32`.
    U32,
}

/// A struct field.
pub struct Field {
    pub name: &'static str,
    pub ty: FieldType,
    pub doc: &'static str,
}

/// A struct read by kernels from a buffer the host fills (or back).
pub struct Struct {
    pub name: &'static str,
    pub doc: &'static str,
    pub fields: &'static [Field],
}

pub const CONSTANTS: &[Constant] = &[
    Constant {
        name: "QUERY_GRAD_FROM_IMAGE",
        ty: ConstType::U32,
        value: "0",
        doc: "raster_backward's `query_source`: each pixel's query gradient is read from a \
              per-pixel image.",
    },
    Constant {
        name: "QUERY_GRAD_FROM_REGIONS",
        ty: ConstType::U32,
        value: "1",
        doc: "raster_backward's `query_source`: a pixel's query gradient is its region's pooled \
              row divided by the region's pixel count (the adjoint of region pooling).",
    },
    Constant {
        name: "QUERY_GRAD_ZERO",
        ty: ConstType::U32,
        value: "2",
        doc: "raster_backward's `query_source`: no query gradient (no feature loss).",
    },
    Constant {
        name: "TILE_SIZE",
        ty: ConstType::U32,
        value: "16",
        doc: "Side in pixels of the square screen tiles Gaussians are binned into.",
    },
    Constant {
        name: "BLEND_BATCH",
        ty: ConstType::U32,
        value: "256",
        doc: "Gaussians a tile's workgroup loads into shared memory per round of blending.",
    },
    Constant {
        name: "MAX_ALPHA",
        ty: ConstType::F32,
        value: "0.99",
        doc: "Largest alpha a single Gaussian may contribute to a pixel.",
    },
    Constant {
        name: "MIN_ALPHA",
        ty: ConstType::F32,
        value: "1.0 / 255.0",
        doc: "Contributions with a smaller alpha are skipped.",
    },
    Constant {
        name: "MIN_TRANSMITTANCE",
        ty: ConstType::F32,
        value: "1e-4",
        doc: "A pixel stops blending when its transmittance would fall below this.",
    },
    Constant {
        name: "LOW_PASS",
        ty: ConstType::F32,
        value: "0.3",
        doc: "Low-pass filter added to the diagonal of every 2-D covariance (pixels²).",
    },
    Constant {
        name: "NO_REGION",
        ty: ConstType::U32,
        value: "0xffffffff",
        doc: "Region index of a pixel that lies in no region.",
    },
    Constant {
        name: "SCAN_BLOCK",
        ty: ConstType::U32,
        value: "1024",
        doc: "Elements one workgroup of the prefix scan covers.",
    },
    Constant {
        name: "GEMM_TILE",
        ty: ConstType::U32,
        value: "64",
        doc: "Rows and columns of C one workgroup of either GEMM kernel computes.",
    },
];

pub const STRUCTS: &[Struct] = &[Struct {
    name: "View",
    doc: "One camera of a rasterizer batch.",
    fields: &[
        Field {
            name: "row0",
            ty: FieldType::Vec4,
            doc: "World-to-camera `[R|t]`, row 0.",
        },
        Field {
            name: "row1",
            ty: FieldType::Vec4,
            doc: "World-to-camera `[R|t]`, row 1.",
        },
        Field {
            name: "row2",
            ty: FieldType::Vec4,
            doc: "World-to-camera `[R|t]`, row 2.",
        },
        Field {
            name: "intrinsics",
            ty: FieldType::Vec4,
            doc: "`fx, fy, cx, cy`.",
        },
        Field {
            name: "guard",
            ty: FieldType::Vec4,
            doc: "Clamp range of tx/tz (lo, hi) and ty/tz (lo, hi) in the projection's Jacobian.",
        },
        Field {
            name: "clip",
            ty: FieldType::Vec4,
            doc: "Near and far depth; the rest unused.",
        },
        Field {
            name: "size",
            ty: FieldType::UVec4,
            doc: "Width, height, tiles across, tiles down.",
        },
        Field {
            name: "offsets",
            ty: FieldType::UVec4,
            doc: "First tile and first pixel of the view in the batch; the rest unused.",
        },
    ],
},
Struct {
    name: "Splat",
    doc: "A Gaussian projected into one view of a batch (one per Gaussian and view); its gradients use the same layout.",
    fields: &[
        Field {
            name: "mean_depth_opacity",
            ty: FieldType::Vec4,
            doc: "Screen position x, y (pixels), camera depth (metres), opacity.",
        },
        Field {
            name: "conic",
            ty: FieldType::Vec4,
            doc: "Inverse 2-D covariance (xx, xy, yy); w unused.",
        },
    ],
},
Struct {
    name: "TileRect",
    doc: "The tiles a projected Gaussian covers, inclusive, each corner packed as column | row << 16.",
    fields: &[
        Field {
            name: "first",
            ty: FieldType::U32,
            doc: "Top-left tile.",
        },
        Field {
            name: "last",
            ty: FieldType::U32,
            doc: "Bottom-right tile.",
        },
    ],
},
Struct {
    name: "TileRange",
    doc: "A tile's run `[start, end)` in the depth-sorted intersection list; zero-filled for empty tiles.",
    fields: &[
        Field {
            name: "start",
            ty: FieldType::U32,
            doc: "First intersection of the tile.",
        },
        Field {
            name: "end",
            ty: FieldType::U32,
            doc: "One past its last intersection.",
        },
    ],
},
Struct {
    name: "PixelState",
    doc: "What the forward blend leaves per pixel for the backward pass to replay.",
    fields: &[
        Field {
            name: "walked",
            ty: FieldType::U32,
            doc: "Entries of the tile's list the pixel walked before it stopped.",
        },
        Field {
            name: "transmittance",
            ty: FieldType::F32,
            doc: "Transmittance left after the last blended Gaussian.",
        },
    ],
}];

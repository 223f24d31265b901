//! One assembled input frame: colour, depth, intrinsics, pose and (when the
//! log has them) region embeddings and evaluation labels, all owned.
//!
//! Pixel data stays in the encoding the log used (packed rows, no per-pixel
//! conversion at ingest); the accessors convert on demand.

use glam::{DQuat, DVec3};

use super::messages::Pose;

/// Pixel layout of a colour image.
///
/// ```
/// use latentam_io::PixelFormat;
///
/// let format = PixelFormat::from_ros("bgr8").expect("a supported encoding");
/// assert_eq!(format.bytes_per_pixel(), 3);
/// assert_eq!(format.ros_name(), "bgr8");
/// assert!(PixelFormat::from_ros("yuv422").is_none()); // not supported
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// 3 bytes: R, G, B.
    Rgb8,
    /// 3 bytes: B, G, R.
    Bgr8,
    /// 4 bytes: R, G, B, A.
    Rgba8,
    /// 4 bytes: B, G, R, A.
    Bgra8,
    /// 1 byte of grey.
    Mono8,
}

impl PixelFormat {
    /// From a `sensor_msgs/Image` encoding string.
    pub fn from_ros(encoding: &str) -> Option<Self> {
        Some(match encoding {
            "rgb8" => PixelFormat::Rgb8,
            "bgr8" => PixelFormat::Bgr8,
            "rgba8" => PixelFormat::Rgba8,
            "bgra8" => PixelFormat::Bgra8,
            "mono8" | "8UC1" => PixelFormat::Mono8,
            _ => return None,
        })
    }
    /// The `sensor_msgs/Image` encoding string.
    pub fn ros_name(self) -> &'static str {
        match self {
            PixelFormat::Rgb8 => "rgb8",
            PixelFormat::Bgr8 => "bgr8",
            PixelFormat::Rgba8 => "rgba8",
            PixelFormat::Bgra8 => "bgra8",
            PixelFormat::Mono8 => "mono8",
        }
    }
    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => 3,
            PixelFormat::Rgba8 | PixelFormat::Bgra8 => 4,
            PixelFormat::Mono8 => 1,
        }
    }
}

/// A colour image with packed rows.
///
/// ```
/// use latentam_io::{ColorImage, PixelFormat};
///
/// // Two pixels from a BGR camera: red, then blue.
/// let data = vec![0, 0, 255, 255, 0, 0];
/// let image = ColorImage { width: 2, height: 1, format: PixelFormat::Bgr8, data };
/// assert_eq!(image.rgb(0, 0), [255, 0, 0]);
/// let rgb: Vec<u8> = image.to_rgb8(); // packed RGB, e.g. for a PNG encoder
/// assert_eq!(rgb, vec![255, 0, 0, 0, 0, 255]);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct ColorImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Layout of `data`.
    pub format: PixelFormat,
    /// `width × height × bytes_per_pixel` bytes, row-major.
    pub data: Vec<u8>,
}

impl ColorImage {
    /// The pixel at `(x, y)` as RGB.
    pub fn rgb(&self, x: u32, y: u32) -> [u8; 3] {
        let bpp = self.format.bytes_per_pixel();
        let i = (y as usize * self.width as usize + x as usize) * bpp;
        let p = &self.data[i..i + bpp];
        match self.format {
            PixelFormat::Rgb8 | PixelFormat::Rgba8 => [p[0], p[1], p[2]],
            PixelFormat::Bgr8 | PixelFormat::Bgra8 => [p[2], p[1], p[0]],
            PixelFormat::Mono8 => [p[0]; 3],
        }
    }
    /// The whole image as packed RGB bytes.
    pub fn to_rgb8(&self) -> Vec<u8> {
        if self.format == PixelFormat::Rgb8 {
            return self.data.clone();
        }
        let mut out = Vec::with_capacity(self.width as usize * self.height as usize * 3);
        for y in 0..self.height {
            for x in 0..self.width {
                out.extend_from_slice(&self.rgb(x, y));
            }
        }
        out
    }
}

/// Depth samples as the log stored them.
///
/// ```
/// use latentam_io::{DepthData, DepthImage};
///
/// // A `32FC1` image in metres; NaN marks a pixel without a return.
/// let data = DepthData::Metres(vec![2.0, f32::NAN]);
/// let depth = DepthImage { width: 2, height: 1, data };
/// assert_eq!(depth.to_metres(), vec![2.0, 0.0]); // invalid samples become 0
/// ```
#[derive(Clone, Debug, PartialEq)]
pub enum DepthData {
    /// Integer units (`16UC1` / `mono16`); 0 = invalid.
    Units {
        /// The samples.
        values: Vec<u16>,
        /// Metres per unit (0.001 for millimetres).
        metres_per_unit: f32,
    },
    /// Metres (`32FC1`); 0, NaN, ±∞, negatives and values below
    /// [`MIN_DEPTH_M`] (denormals) are invalid.
    Metres(Vec<f32>),
}

/// Smallest depth in metres a `32FC1` sample may hold and count: a tenth
/// of a millimetre, far below what any RGB-D sensor measures (denormal
/// floats and −0.0 are not measurements).
pub const MIN_DEPTH_M: f32 = 1e-4;

/// A depth image.
///
/// ```
/// use latentam_io::{DepthData, DepthImage};
///
/// // A `16UC1` image in millimetres, as most RGB-D drivers publish.
/// let data = DepthData::Units { values: vec![2000, 0], metres_per_unit: 0.001 };
/// let mut depth = DepthImage { width: 2, height: 1, data };
/// assert_eq!(depth.metres(0), Some(2.0));
/// assert_eq!(depth.metres(1), None); // 0 = no return
/// depth.invalidate_beyond(1.5); // ignore everything past 1.5 m
/// assert!(!depth.has_valid_sample());
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Row-major samples.
    pub data: DepthData,
}

impl DepthImage {
    /// Depth of sample `i` in metres, `None` where invalid.
    pub fn metres(&self, i: usize) -> Option<f32> {
        let z = match &self.data {
            DepthData::Units {
                values,
                metres_per_unit,
            } => {
                let v = values[i];
                if v == 0 {
                    return None;
                }
                v as f32 * metres_per_unit
            }
            DepthData::Metres(values) => values[i],
        };
        (z.is_finite() && z >= MIN_DEPTH_M).then_some(z)
    }
    /// All samples in metres, invalid ones as 0 (the engine's convention).
    pub fn to_metres(&self) -> Vec<f32> {
        (0..self.len())
            .map(|i| self.metres(i).unwrap_or(0.0))
            .collect()
    }
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }
    /// Whether the image has no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Marks samples beyond `max_metres` invalid (0).
    pub fn invalidate_beyond(&mut self, max_metres: f32) {
        match &mut self.data {
            DepthData::Units {
                values,
                metres_per_unit,
            } => {
                // Most sensors' whole 16-bit range is within the limit.
                if u16::MAX as f32 * *metres_per_unit > max_metres {
                    let mpu = *metres_per_unit;
                    values
                        .iter_mut()
                        .filter(|v| **v as f32 * mpu > max_metres)
                        .for_each(|v| *v = 0);
                }
            }
            DepthData::Metres(values) => values
                .iter_mut()
                .filter(|z| **z > max_metres)
                .for_each(|z| *z = 0.0),
        }
    }
    /// Whether at least one sample is valid (stops at the first).
    pub fn has_valid_sample(&self) -> bool {
        match &self.data {
            DepthData::Units { values, .. } => values.iter().any(|&v| v != 0),
            DepthData::Metres(values) => values.iter().any(|z| z.is_finite() && *z >= MIN_DEPTH_M),
        }
    }
}

/// Pinhole intrinsics in pixels, OpenCV convention (pixel centres at
/// integer coordinates).
///
/// ```
/// use latentam_io::Intrinsics;
///
/// let k = Intrinsics { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 };
/// // Back-project pixel (u, v) with depth z into the camera frame.
/// let (u, v, z) = (319.5, 239.5, 2.0);
/// let point = [(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z];
/// assert_eq!(point, [0.0, 0.0, 2.0]); // the principal point lies on the optical axis
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    /// Image columns.
    pub width: u32,
    /// Image rows.
    pub height: u32,
    /// Focal length along x.
    pub fx: f64,
    /// Focal length along y.
    pub fy: f64,
    /// Principal point x.
    pub cx: f64,
    /// Principal point y.
    pub cy: f64,
}

/// A per-pixel label image (regions or semantic classes).
///
/// ```
/// use latentam_io::LabelImage;
///
/// let semantic = LabelImage { width: 2, height: 2, labels: vec![0, 0, 7, 7] };
/// let class_at = |x: u32, y: u32| semantic.labels[(y * semantic.width + x) as usize];
/// assert_eq!(class_at(1, 1), 7);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct LabelImage {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
    /// Row-major labels.
    pub labels: Vec<u16>,
}

/// Element type of embedding data.
///
/// ```
/// use latentam_io::{decode_floats, encode_floats, Dtype};
///
/// let dtype = Dtype::parse("float16").expect("a known dtype");
/// let bytes = encode_floats(&[0.5, -1.0], dtype);
/// assert_eq!(bytes.len(), 2 * dtype.size());
/// assert_eq!(decode_floats(&bytes, dtype), vec![0.5, -1.0]);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dtype {
    /// IEEE half, little-endian.
    F16,
    /// IEEE single, little-endian.
    F32,
}

impl Dtype {
    /// From a message's `dtype` string.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "f16" | "float16" => Some(Dtype::F16),
            "f32" | "float32" => Some(Dtype::F32),
            _ => None,
        }
    }
    /// The message's `dtype` string.
    pub fn name(self) -> &'static str {
        match self {
            Dtype::F16 => "f16",
            Dtype::F32 => "f32",
        }
    }
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            Dtype::F16 => 2,
            Dtype::F32 => 4,
        }
    }
}

/// Where a frame's embeddings live in the image.
///
/// ```
/// use latentam_io::EmbeddingLayout;
/// # fn f(frame: &latentam_io::Frame) {
/// if let Some(e) = &frame.embeddings {
///     match &e.layout {
///         EmbeddingLayout::Regions(mask) => println!("{} regions on a {}×{} mask", e.count, mask.width, mask.height),
///         EmbeddingLayout::Grid { rows, cols } => println!("a {rows}×{cols} feature grid"),
///     }
/// }
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub enum EmbeddingLayout {
    /// One embedding per region of a label image (`MaskFeatures`).
    Regions(LabelImage),
    /// One embedding per cell of a regular grid (`FeatureGrid`), row-major.
    Grid {
        /// Grid rows.
        rows: u32,
        /// Grid columns.
        cols: u32,
    },
}

/// The target embeddings of one frame.
///
/// ```
/// use latentam_io::{encode_floats, Dtype, EmbeddingLayout, Embeddings};
///
/// // A 1×2 feature grid of 3-d embeddings.
/// let values = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
/// let grid = Embeddings {
///     layout: EmbeddingLayout::Grid { rows: 1, cols: 2 },
///     count: 2,
///     dim: 3,
///     dtype: Dtype::F32,
///     data: encode_floats(&values, Dtype::F32),
///     model: "clip-vit-b16".into(),
/// };
/// assert_eq!(grid.to_f32(), values);
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Embeddings {
    /// Regions or grid.
    pub layout: EmbeddingLayout,
    /// Number of vectors.
    pub count: u32,
    /// Vector length.
    pub dim: u32,
    /// Element type of `data`.
    pub dtype: Dtype,
    /// `count × dim` little-endian values.
    pub data: Vec<u8>,
    /// Embedding model id as written in the log.
    pub model: String,
}

impl Embeddings {
    /// All vectors as `count × dim` floats.
    pub fn to_f32(&self) -> Vec<f32> {
        decode_floats(&self.data, self.dtype)
    }
}

/// The embedding model a model id names: an `oracle:` prefix (embeddings
/// built from labels for that model's space) is the same space.
pub fn embedding_space(model: &str) -> &str {
    model.strip_prefix("oracle:").unwrap_or(model)
}

/// Little-endian f16/f32 bytes to floats.
pub fn decode_floats(data: &[u8], dtype: Dtype) -> Vec<f32> {
    match dtype {
        Dtype::F32 => data
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect(),
        Dtype::F16 => data
            .chunks_exact(2)
            .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
            .collect(),
    }
}

/// Floats to little-endian f16/f32 bytes.
pub fn encode_floats(values: &[f32], dtype: Dtype) -> Vec<u8> {
    match dtype {
        Dtype::F32 => values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        Dtype::F16 => values
            .iter()
            .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
            .collect(),
    }
}

/// A camera-to-world pose: `p_world = rotation · p_camera + translation`,
/// camera axes as OpenCV (x right, y down, z forward).
///
/// ```
/// use glam::{DQuat, DVec3};
/// use latentam_io::CameraPose;
///
/// let pose = CameraPose { rotation: DQuat::IDENTITY, translation: DVec3::new(0.0, 0.0, 1.5) };
/// // A point 2 m in front of the camera, in world coordinates.
/// let p_world = pose.rotation * DVec3::new(0.0, 0.0, 2.0) + pose.translation;
/// assert_eq!(p_world, DVec3::new(0.0, 0.0, 3.5));
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraPose {
    /// Unit quaternion.
    pub rotation: DQuat,
    /// Camera centre in the world.
    pub translation: DVec3,
}

impl From<CameraPose> for Pose {
    fn from(p: CameraPose) -> Pose {
        Pose {
            translation: p.translation,
            rotation: p.rotation,
        }
    }
}

/// Everything the mapper needs about one moment of the stream.
///
/// ```no_run
/// use latentam_io::{CameraPose, ColorImage, DepthData, DepthImage, Frame, Intrinsics, PixelFormat};
/// # fn f(mut integrate: impl FnMut(&Frame) -> latentam_io::Result<()>, rgb: Vec<u8>, depth_mm: Vec<u16>, pose: CameraPose) -> latentam_io::Result<()> {
/// // A frame straight from the robot's own camera driver and localisation.
/// let (width, height) = (640, 480);
/// let frame = Frame {
///     stamp_ns: 1_700_000_000_000_000_000,
///     pose,
///     intrinsics: Intrinsics { width, height, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 },
///     color: ColorImage { width, height, format: PixelFormat::Rgb8, data: rgb },
///     depth: DepthImage { width, height, data: DepthData::Units { values: depth_mm, metres_per_unit: 0.001 } },
///     embeddings: None, // geometry and colour only
///     semantic: None,
/// };
/// integrate(&frame)?; // `latentam::Mapper::integrate`
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    /// `header.stamp` of the colour image, nanoseconds.
    pub stamp_ns: i64,
    /// Camera-to-world pose at `stamp_ns`.
    pub pose: CameraPose,
    /// Intrinsics of the colour image.
    pub intrinsics: Intrinsics,
    /// The colour image.
    pub color: ColorImage,
    /// Depth registered to the colour image (same size).
    pub depth: DepthImage,
    /// Region embeddings, when the log has them for this frame.
    pub embeddings: Option<Embeddings>,
    /// Semantic class ids for evaluation, when the log has them.
    pub semantic: Option<LabelImage>,
}

#[cfg(test)]
mod depth_tests {
    use super::*;

    /// Denormal floats and −0.0 in a `32FC1` image are not depth: a frame
    /// of them has no valid sample (and is refused as such), not points at
    /// the camera centre.
    #[test]
    fn denormal_and_negative_zero_depth_is_invalid() {
        let tiny = f32::from_bits(1); // the smallest denormal
        let depth = DepthImage {
            width: 4,
            height: 1,
            data: DepthData::Metres(vec![tiny, -0.0, 1e-39, f32::MIN_POSITIVE]),
        };
        assert!(!depth.has_valid_sample());
        assert_eq!(depth.to_metres(), vec![0.0; 4]);
        let near = DepthImage {
            width: 1,
            height: 1,
            data: DepthData::Metres(vec![0.25]),
        };
        assert_eq!(near.metres(0), Some(0.25));
    }
}

//! The ROS 2 message types the engine reads and writes, decoded in place.
//!
//! Each type borrows its strings and arrays from the serialized bytes
//! ([`Seq`] for numeric arrays, `&[u8]` for payloads), so decoding an image
//! message costs a few field reads whatever the image size.

use glam::{DQuat, DVec3};

use super::cdr::{CdrError, CdrReader, CdrWriter, Endian, Seq};

/// A message type with a CDR layout.
///
/// ```
/// use latentam_io::{Header, Pose, PoseStamped, RosMessage};
///
/// let msg = PoseStamped { header: Header::at(1_000, "map"), pose: Pose::IDENTITY };
/// let bytes = msg.encode(); // little-endian CDR, as ROS 2 publishes it
/// let back = PoseStamped::decode(&bytes)?;
/// assert_eq!(back.header.frame_id, "map");
/// assert_eq!(PoseStamped::TYPE_NAME, "geometry_msgs/msg/PoseStamped");
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
pub trait RosMessage<'a>: Sized {
    /// `pkg/msg/Type`.
    const TYPE_NAME: &'static str;
    /// Reads the fields after the encapsulation header.
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError>;
    /// Writes the fields.
    fn encode_fields(&self, w: &mut CdrWriter);

    /// Decodes a whole serialized message.
    fn decode(bytes: &'a [u8]) -> Result<Self, CdrError> {
        Self::decode_fields(&mut CdrReader::new(bytes)?)
    }
    /// Encodes to little-endian CDR, as ROS 2 does.
    fn encode(&self) -> Vec<u8> {
        self.encode_with(Endian::Little)
    }
    /// Encodes in the given byte order.
    fn encode_with(&self, endian: Endian) -> Vec<u8> {
        let mut w = CdrWriter::new(endian);
        self.encode_fields(&mut w);
        w.finish()
    }
}

/// `builtin_interfaces/Time`.
///
/// ```
/// use latentam_io::Time;
///
/// let t = Time::from_nanos(1_500_000_000);
/// assert_eq!((t.sec, t.nanosec), (1, 500_000_000));
/// assert_eq!(t.as_nanos(), 1_500_000_000);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub struct Time {
    /// Seconds (may be negative in principle).
    pub sec: i32,
    /// Nanoseconds within the second.
    pub nanosec: u32,
}

impl Time {
    /// Nanoseconds since the epoch: within ±2.2·10¹⁸ (an `i32` of seconds),
    /// so this and differences of two stamps cannot overflow an `i64`.
    pub fn as_nanos(self) -> i64 {
        self.sec as i64 * 1_000_000_000 + self.nanosec as i64
    }
    /// The time `ns` nanoseconds after the epoch (saturating at the `i32`
    /// seconds range).
    pub fn from_nanos(ns: i64) -> Self {
        let sec = ns.div_euclid(1_000_000_000);
        Time {
            sec: sec.clamp(i32::MIN as i64, i32::MAX as i64) as i32,
            nanosec: ns.rem_euclid(1_000_000_000) as u32,
        }
    }
}

/// `std_msgs/Header`.
///
/// ```
/// use latentam_io::Header;
///
/// let header = Header::at(1_700_000_000_123_000_000, "camera_color_optical_frame");
/// assert_eq!(header.stamp.nanosec, 123_000_000);
/// assert_eq!(header.stamp.as_nanos(), 1_700_000_000_123_000_000);
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Header<'a> {
    /// Acquisition time.
    pub stamp: Time,
    /// Coordinate frame of the data.
    pub frame_id: &'a str,
}

impl<'a> Header<'a> {
    /// A header at `ns` nanoseconds in frame `frame_id`.
    pub fn at(ns: i64, frame_id: &'a str) -> Self {
        Header {
            stamp: Time::from_nanos(ns),
            frame_id,
        }
    }
    fn decode(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let sec = r.read("header.stamp.sec")?;
        let nanosec: u32 = r.read("header.stamp.nanosec")?;
        if nanosec >= 1_000_000_000 {
            return Err(r.invalid(
                "header.stamp.nanosec",
                format!("{nanosec} is not below 10^9"),
            ));
        }
        Ok(Header {
            stamp: Time { sec, nanosec },
            frame_id: r.string("header.frame_id")?,
        })
    }
    fn encode(&self, w: &mut CdrWriter) {
        w.put(self.stamp.sec);
        w.put(self.stamp.nanosec);
        w.string(self.frame_id);
    }
}

/// `sensor_msgs/Image`.
///
/// ```
/// use latentam_io::{Header, Image, PixelFormat, RosMessage};
///
/// let rgb = vec![0u8; 4 * 2 * 3]; // 4×2 pixels
/// let msg = Image::packed(Header::at(1_000, "camera"), 4, 2, "rgb8", &rgb);
/// assert_eq!(msg.step, 12);
/// let bytes = msg.encode();
/// let decoded = Image::decode(&bytes)?; // borrows `data` from `bytes`
/// assert_eq!(PixelFormat::from_ros(decoded.encoding), Some(PixelFormat::Rgb8));
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Image<'a> {
    /// Stamp and frame.
    pub header: Header<'a>,
    /// Rows.
    pub height: u32,
    /// Columns.
    pub width: u32,
    /// Pixel encoding, e.g. `rgb8`, `16UC1`, `32FC1`.
    pub encoding: &'a str,
    /// Whether multi-byte pixels are big-endian.
    pub is_bigendian: bool,
    /// Bytes per row (at least `width` × bytes per pixel).
    pub step: u32,
    /// `step × height` bytes, borrowed from the message.
    pub data: &'a [u8],
}

impl<'a> RosMessage<'a> for Image<'a> {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/Image";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(Image {
            header: Header::decode(r)?,
            height: r.read("height")?,
            width: r.read("width")?,
            encoding: r.string("encoding")?,
            is_bigendian: r.read::<u8>("is_bigendian")? != 0,
            step: r.read("step")?,
            data: r.bytes("data")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.height);
        w.put(self.width);
        w.string(self.encoding);
        w.put(self.is_bigendian as u8);
        w.put(self.step);
        w.bytes(self.data);
    }
}

impl<'a> Image<'a> {
    /// A little-endian image whose rows are packed (`step` = the data
    /// length over the rows), as writers produce.
    pub fn packed(
        header: Header<'a>,
        width: u32,
        height: u32,
        encoding: &'a str,
        data: &'a [u8],
    ) -> Self {
        Image {
            header,
            height,
            width,
            encoding,
            is_bigendian: false,
            step: (data.len() / height.max(1) as usize) as u32,
            data,
        }
    }
}

/// `sensor_msgs/CompressedImage`.
///
/// ```no_run
/// use latentam_io::{CompressedImage, Compression, Header, LogWriter};
/// # fn f(jpeg: &[u8]) -> Result<(), latentam_io::InputError> {
/// let mut log = LogWriter::create("out.mcap".as_ref(), Compression::Zstd)?;
/// let msg = CompressedImage { header: Header::at(1_000, "camera"), format: "jpeg", data: jpeg };
/// log.write("/camera/color/image_raw/compressed", 1_000, &msg)?;
/// log.finish()?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub struct CompressedImage<'a> {
    /// Stamp and frame.
    pub header: Header<'a>,
    /// `jpeg`, `png`, or for depth `16UC1; compressedDepth png`.
    pub format: &'a str,
    /// The compressed bytes, borrowed.
    pub data: &'a [u8],
}

impl<'a> RosMessage<'a> for CompressedImage<'a> {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/CompressedImage";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(CompressedImage {
            header: Header::decode(r)?,
            format: r.string("format")?,
            data: r.bytes("data")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(self.format);
        w.bytes(self.data);
    }
}

/// `sensor_msgs/CameraInfo`.
///
/// ```
/// use latentam_io::{CameraInfo, Header};
///
/// let info = CameraInfo::pinhole(Header::at(0, "camera"), 640, 480, [525.0, 525.0, 319.5, 239.5]);
/// let [fx, _, cx, _, fy, cy, ..] = info.k;
/// assert_eq!((fx, fy, cx, cy), (525.0, 525.0, 319.5, 239.5));
/// assert_eq!((info.width, info.height), (640, 480));
/// ```
#[derive(Clone, Debug)]
pub struct CameraInfo<'a> {
    /// Stamp and frame.
    pub header: Header<'a>,
    /// Image rows the calibration applies to.
    pub height: u32,
    /// Image columns.
    pub width: u32,
    /// `plumb_bob`, `rational_polynomial`, ... (empty = none).
    pub distortion_model: &'a str,
    /// Distortion coefficients.
    pub d: Seq<'a, f64>,
    /// Row-major 3×3 intrinsic matrix.
    pub k: [f64; 9],
    /// Rectification rotation.
    pub r: [f64; 9],
    /// Row-major 3×4 projection matrix.
    pub p: [f64; 12],
    /// Horizontal binning (0 or 1 = none).
    pub binning_x: u32,
    /// Vertical binning.
    pub binning_y: u32,
    /// Region of interest `[x_offset, y_offset, height, width]` (all zero =
    /// full image) and `do_rectify`.
    pub roi: ([u32; 4], bool),
}

impl<'a> RosMessage<'a> for CameraInfo<'a> {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/CameraInfo";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(CameraInfo {
            header: Header::decode(r)?,
            height: r.read("height")?,
            width: r.read("width")?,
            distortion_model: r.string("distortion_model")?,
            d: r.seq("d")?,
            k: r.fixed("k")?,
            r: r.fixed("r")?,
            p: r.fixed("p")?,
            binning_x: r.read("binning_x")?,
            binning_y: r.read("binning_y")?,
            roi: (r.fixed("roi")?, r.bool("roi.do_rectify")?),
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.height);
        w.put(self.width);
        w.string(self.distortion_model);
        w.seq(&self.d.to_vec());
        w.array(&self.k);
        w.array(&self.r);
        w.array(&self.p);
        w.put(self.binning_x);
        w.put(self.binning_y);
        w.array(&self.roi.0);
        w.bool(self.roi.1);
    }
}

impl<'a> CameraInfo<'a> {
    /// A distortion-free pinhole calibration (what the converters write).
    pub fn pinhole(
        header: Header<'a>,
        width: u32,
        height: u32,
        [fx, fy, cx, cy]: [f64; 4],
    ) -> Self {
        CameraInfo {
            header,
            height,
            width,
            distortion_model: "plumb_bob",
            d: Seq::new(&[0u8; 40], Endian::Little),
            k: [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
            r: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            p: [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
            binning_x: 0,
            binning_y: 0,
            roi: ([0; 4], false),
        }
    }
}

/// A rigid transform (rotation then translation), in double precision:
/// `geometry_msgs/Pose` and `geometry_msgs/Transform` alike.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::Pose;
///
/// let base_in_map = Pose { translation: DVec3::new(2.0, 0.0, 0.0), ..Pose::IDENTITY };
/// let camera_in_base = Pose { translation: DVec3::new(0.0, 0.0, 0.3), ..Pose::IDENTITY };
/// let camera_in_map = base_in_map.compose(&camera_in_base).checked()?; // finite, unit quaternion
/// assert_eq!(camera_in_map.translation, DVec3::new(2.0, 0.0, 0.3));
/// # Ok::<(), latentam_io::Rejection>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    /// Position / translation.
    pub translation: DVec3,
    /// Orientation / rotation, as read (not normalised).
    pub rotation: DQuat,
}

impl Pose {
    /// The identity.
    pub const IDENTITY: Pose = Pose {
        translation: DVec3::ZERO,
        rotation: DQuat::IDENTITY,
    };

    fn decode(r: &mut CdrReader<'_>, field: &'static str) -> Result<Self, CdrError> {
        let [x, y, z] = r.fixed::<f64, 3>(field)?;
        let [qx, qy, qz, qw] = r.fixed::<f64, 4>(field)?;
        Ok(Pose {
            translation: DVec3::new(x, y, z),
            rotation: DQuat::from_xyzw(qx, qy, qz, qw),
        })
    }
    fn encode(&self, w: &mut CdrWriter) {
        w.array(&self.translation.to_array());
        let q = self.rotation;
        w.array(&[q.x, q.y, q.z, q.w]);
    }
}

/// `geometry_msgs/PoseStamped`.
///
/// ```no_run
/// use latentam_io::{Header, LogWriter, PoseStamped};
/// # fn f(log: &mut LogWriter<std::io::BufWriter<std::fs::File>>, stamp_ns: i64, pose: latentam_io::CameraPose) -> Result<(), latentam_io::InputError> {
/// // Record the robot's camera pose beside its images.
/// let msg = PoseStamped { header: Header::at(stamp_ns, "map"), pose: pose.into() };
/// log.write("/camera/pose", stamp_ns as u64, &msg)?;
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy, Debug)]
pub struct PoseStamped<'a> {
    /// Stamp and the frame the pose is expressed in.
    pub header: Header<'a>,
    /// The pose.
    pub pose: Pose,
}

impl<'a> RosMessage<'a> for PoseStamped<'a> {
    const TYPE_NAME: &'static str = "geometry_msgs/msg/PoseStamped";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(PoseStamped {
            header: Header::decode(r)?,
            pose: Pose::decode(r, "pose")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        self.pose.encode(w);
    }
}

/// `nav_msgs/Odometry` (the twist is read past, not kept).
///
/// ```
/// use latentam_io::{Header, Odometry, Pose, RosMessage};
///
/// let header = Header::at(1_000, "odom");
/// let odom = Odometry { header, child_frame_id: "camera_optical", pose: Pose::IDENTITY };
/// let bytes = odom.encode(); // the twist is written as zeros
/// let back = Odometry::decode(&bytes)?;
/// assert_eq!((back.header.frame_id, back.child_frame_id), ("odom", "camera_optical"));
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct Odometry<'a> {
    /// Stamp and the parent frame.
    pub header: Header<'a>,
    /// The frame whose pose this is.
    pub child_frame_id: &'a str,
    /// Pose of `child_frame_id` in `header.frame_id`.
    pub pose: Pose,
}

impl<'a> RosMessage<'a> for Odometry<'a> {
    const TYPE_NAME: &'static str = "nav_msgs/msg/Odometry";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        let child_frame_id = r.string("child_frame_id")?;
        let pose = Pose::decode(r, "pose.pose")?;
        r.array::<f64>("pose.covariance", 36)?;
        r.array::<f64>("twist", 6 + 36)?;
        Ok(Odometry {
            header,
            child_frame_id,
            pose,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.string(self.child_frame_id);
        self.pose.encode(w);
        w.array(&[0.0f64; 36 + 6 + 36]);
    }
}

/// `geometry_msgs/TransformStamped`.
///
/// ```
/// use glam::DVec3;
/// use latentam_io::{Header, Pose, TfBuffer, TransformStamped};
///
/// // The camera mounted 30 cm above the robot's base (a `/tf_static` entry).
/// let mount = TransformStamped {
///     header: Header::at(0, "base_link"),
///     child_frame_id: "camera_color_optical_frame",
///     transform: Pose { translation: DVec3::new(0.0, 0.0, 0.3), ..Pose::IDENTITY },
/// };
/// TfBuffer::default().insert(&mount, true)?;
/// # Ok::<(), latentam_io::Rejection>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct TransformStamped<'a> {
    /// Stamp and the parent frame.
    pub header: Header<'a>,
    /// The child frame.
    pub child_frame_id: &'a str,
    /// Pose of the child in the parent.
    pub transform: Pose,
}

/// `tf2_msgs/TFMessage` (on `/tf` and `/tf_static`).
///
/// ```
/// use latentam_io::{Header, Pose, RosMessage, TfBuffer, TfMessage, TransformStamped};
///
/// # let t = TransformStamped { header: Header::at(5, "odom"), child_frame_id: "base_link", transform: Pose::IDENTITY };
/// # let bytes = TfMessage { transforms: vec![t] }.encode();
/// let mut tf = TfBuffer::default();
/// for t in &TfMessage::decode(&bytes)?.transforms { // one `/tf` message
///     tf.insert(t, false)?;
/// }
/// assert_eq!(tf.latest(), Some(5));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
#[derive(Clone, Debug)]
pub struct TfMessage<'a> {
    /// The transforms.
    pub transforms: Vec<TransformStamped<'a>>,
}

impl<'a> RosMessage<'a> for TfMessage<'a> {
    const TYPE_NAME: &'static str = "tf2_msgs/msg/TFMessage";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        // header (≥ 12 bytes) + child string (≥ 4) + 7 doubles.
        let count = r.sequence_len("transforms", 12 + 4 + 56)?;
        let mut transforms = Vec::with_capacity(count);
        for _ in 0..count {
            transforms.push(TransformStamped {
                header: Header::decode(r)?,
                child_frame_id: r.string("transforms.child_frame_id")?,
                transform: Pose::decode(r, "transforms.transform")?,
            });
        }
        Ok(TfMessage { transforms })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        w.put(self.transforms.len() as u32);
        for t in &self.transforms {
            t.header.encode(w);
            w.string(t.child_frame_id);
            t.transform.encode(w);
        }
    }
}

/// `latentam_msgs/MaskFeatures`: one embedding per region of a label image.
///
/// ```
/// use latentam_io::cdr::{Endian, Seq};
/// use latentam_io::{encode_floats, Dtype, Header, MaskFeatures};
///
/// // Two regions on a 2×2 mask (one pixel in none), with 4-d embeddings.
/// let labels: Vec<u8> = [0u16, 0, 1, 65535].iter().flat_map(|l| l.to_le_bytes()).collect();
/// let data = encode_floats(&[1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0], Dtype::F16);
/// let msg = MaskFeatures {
///     header: Header::at(1_000, "camera"), height: 2, width: 2,
///     labels: Seq::new(&labels, Endian::Little), count: 2, dim: 4,
///     dtype: "f16", data: &data, model: "clip-vit-b16",
/// };
/// assert_eq!(msg.labels.get(2), Some(1));
/// ```
#[derive(Clone, Copy, Debug)]
pub struct MaskFeatures<'a> {
    /// Stamp of the colour image the regions belong to.
    pub header: Header<'a>,
    /// Label image rows.
    pub height: u32,
    /// Label image columns.
    pub width: u32,
    /// Row-major region index per pixel, 65535 = none.
    pub labels: Seq<'a, u16>,
    /// Number of regions.
    pub count: u32,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32` (little-endian).
    pub dtype: &'a str,
    /// `count × dim` vectors.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

impl<'a> RosMessage<'a> for MaskFeatures<'a> {
    const TYPE_NAME: &'static str = "latentam_msgs/msg/MaskFeatures";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(MaskFeatures {
            header: Header::decode(r)?,
            height: r.read("height")?,
            width: r.read("width")?,
            labels: r.seq("labels")?,
            count: r.read("count")?,
            dim: r.read("dim")?,
            dtype: r.string("dtype")?,
            data: r.bytes("data")?,
            model: r.string("model")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.height);
        w.put(self.width);
        w.seq(&self.labels.to_vec());
        w.put(self.count);
        w.put(self.dim);
        w.string(self.dtype);
        w.bytes(self.data);
        w.string(self.model);
    }
}

/// `latentam_msgs/FeatureGrid`: embeddings on a coarse grid.
///
/// ```
/// use latentam_io::{encode_floats, Compression, Dtype, FeatureGrid, Header, LogWriter};
///
/// let values = vec![0.5f32; 2 * 3 * 8]; // a 2×3 grid of 8-d embeddings
/// let data = encode_floats(&values, Dtype::F32);
/// let grid = FeatureGrid {
///     header: Header::at(1_000, "camera"), rows: 2, cols: 3, dim: 8,
///     dtype: "f32", data: &data, model: "clip-vit-b16",
/// };
/// let mut log = LogWriter::new(std::io::Cursor::new(Vec::new()), Compression::Zstd)?;
/// log.write("/camera/embeddings", 1_000, &grid)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct FeatureGrid<'a> {
    /// Stamp of the colour image.
    pub header: Header<'a>,
    /// Grid rows.
    pub rows: u32,
    /// Grid columns.
    pub cols: u32,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32`.
    pub dtype: &'a str,
    /// `rows × cols × dim` values.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

impl<'a> RosMessage<'a> for FeatureGrid<'a> {
    const TYPE_NAME: &'static str = "latentam_msgs/msg/FeatureGrid";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(FeatureGrid {
            header: Header::decode(r)?,
            rows: r.read("rows")?,
            cols: r.read("cols")?,
            dim: r.read("dim")?,
            dtype: r.string("dtype")?,
            data: r.bytes("data")?,
            model: r.string("model")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.rows);
        w.put(self.cols);
        w.put(self.dim);
        w.string(self.dtype);
        w.bytes(self.data);
        w.string(self.model);
    }
}

/// `latentam_msgs/TextEmbeddings`: the query vocabulary.
///
/// ```
/// use latentam_io::cdr::{Endian, Seq};
/// use latentam_io::{encode_floats, Compression, Dtype, Header, LogWriter, TextEmbeddings};
///
/// let ids: Vec<u8> = [3u16, 7].iter().flat_map(|i| i.to_le_bytes()).collect();
/// let data = encode_floats(&[1.0, 0.0, 0.0, 1.0], Dtype::F32); // one 2-d vector per name
/// let vocabulary = TextEmbeddings {
///     header: Header::at(0, ""), names: vec!["chair", "table"], ids: Seq::new(&ids, Endian::Little),
///     dim: 2, dtype: "f32", data: &data, model: "clip-vit-b16",
/// };
/// let mut log = LogWriter::new(std::io::Cursor::new(Vec::new()), Compression::Zstd)?;
/// log.write("/vocabulary", 0, &vocabulary)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug)]
pub struct TextEmbeddings<'a> {
    /// Stamp.
    pub header: Header<'a>,
    /// Class names.
    pub names: Vec<&'a str>,
    /// Class id of each name, as in the semantic label images.
    pub ids: Seq<'a, u16>,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32`.
    pub dtype: &'a str,
    /// `names.len() × dim` values.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

impl<'a> RosMessage<'a> for TextEmbeddings<'a> {
    const TYPE_NAME: &'static str = "latentam_msgs/msg/TextEmbeddings";
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        Ok(TextEmbeddings {
            header: Header::decode(r)?,
            names: r.strings("names")?,
            ids: r.seq("ids")?,
            dim: r.read("dim")?,
            dtype: r.string("dtype")?,
            data: r.bytes("data")?,
            model: r.string("model")?,
        })
    }
    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.strings(&self.names);
        w.seq(&self.ids.to_vec());
        w.put(self.dim);
        w.string(self.dtype);
        w.bytes(self.data);
        w.string(self.model);
    }
}

//! `sensor_msgs`: images, compressed images and camera calibrations.

use super::common::Header;
use super::message::RosMessage;
use crate::cdr::{CdrError, CdrReader, CdrWriter};
use crate::cdr::{Endian, Seq};

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

cdr_message! {
    Image = "sensor_msgs/msg/Image" {
        header: header,
        height: read,
        width: read,
        encoding: string,
        is_bigendian: flag,
        step: read,
        data: bytes,
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

cdr_message! {
    CompressedImage = "sensor_msgs/msg/CompressedImage" {
        header: header,
        format: string,
        data: bytes,
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

cdr_message! {
    CameraInfo = "sensor_msgs/msg/CameraInfo" {
        header: header,
        height: read,
        width: read,
        distortion_model: string,
        d: seq,
        k: fixed,
        r: fixed,
        p: fixed,
        binning_x: read,
        binning_y: read,
        roi: roi,
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

//! Image messages to owned pixels: raw `sensor_msgs/Image` rows are packed
//! with one copy per row (one per image when rows carry no padding);
//! compressed ones are decoded (JPEG, PNG, `compressedDepth`).

use std::io::Cursor;

use super::frame::{ColorImage, DepthData, DepthImage, LabelImage, PixelFormat};
use super::messages::{CompressedImage, Image};
use latentam_base::Rejection;

/// Rejects images larger than this many pixels per side. RGB-D cameras
/// give 640×480 to 1280×720 (a few reach 4K); a corrupt or hostile size
/// field must not make the engine allocate gigabytes.
pub const MAX_IMAGE_SIDE: u32 = 8192;

/// Rejects images of more pixels than this (32 Mi, 8192×4096: 8K UHD's
/// 7680×4320 fits). Decoded, that is at most 128 MiB of RGBA colour or
/// 64 MiB of 16-bit depth, which bounds what one compressed image can make
/// the engine allocate however small the file.
pub const MAX_IMAGE_PIXELS: u64 = 8192 * 4096;

fn within_limits(width: u32, height: u32) -> bool {
    width > 0
        && height > 0
        && width <= MAX_IMAGE_SIDE
        && height <= MAX_IMAGE_SIDE
        && width as u64 * height as u64 <= MAX_IMAGE_PIXELS
}

fn check_size(what: &'static str, width: u32, height: u32) -> Result<(), Rejection> {
    if !within_limits(width, height) {
        return Err(Rejection::new(
            what,
            format!(
                "image size {width}×{height} is empty or beyond the limit of {MAX_IMAGE_SIDE} \
                 per side and {MAX_IMAGE_PIXELS} pixels"
            ),
        ));
    }
    Ok(())
}

/// The size a compressed image must have, when the frame it belongs to
/// already says (its camera info, or the other image of the pair).
///
/// ```no_run
/// use latentam_io::codec::{color_from_compressed, ExpectedSize};
/// # fn f(msg: &latentam_io::CompressedImage<'_>) {
/// // A 640×480 camera: a 1920×1080 JPEG is refused before it is decoded.
/// let expected = ExpectedSize {
///     width: 640,
///     height: 480,
///     kind: "colour: size mismatch",
///     from: "the camera info",
/// };
/// match color_from_compressed(msg, Some(expected)) {
///     Ok(image) => println!("{}×{}", image.width, image.height),
///     Err(why) => eprintln!("skipped: {why:?}"),
/// }
/// # }
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ExpectedSize {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// The rejection kind when the image declares another size.
    pub kind: &'static str,
    /// Where the size comes from, for the message, e.g. "the depth image".
    pub from: &'static str,
}

/// Checks the size a compressed image's header declares, before a byte of
/// it is decoded: a few kilobytes of PNG can declare gigabytes of pixels,
/// which would otherwise be allocated (and decoded) before being refused.
fn check_declared(
    what: &'static str,
    format: &str,
    (width, height): (u32, u32),
    expected: Option<ExpectedSize>,
) -> Result<(), Rejection> {
    if let Some(e) = expected {
        if (width, height) != (e.width, e.height) {
            return Err(Rejection::new(
                e.kind,
                format!(
                    "the {format} declares {width}×{height} pixels but {} is {}×{}; \
                     refused before decoding",
                    e.from, e.width, e.height
                ),
            ));
        }
    }
    if !within_limits(width, height) {
        return Err(Rejection::new(
            what,
            format!(
                "the {format} declares {width}×{height} pixels, empty or beyond the limit of \
                 {MAX_IMAGE_SIDE} per side and {MAX_IMAGE_PIXELS} pixels; refused before decoding"
            ),
        ));
    }
    Ok(())
}

/// The rows of `msg` without their padding, checking `step` and the data
/// length against the declared size.
///
/// The rows go into `out` (cleared first; pass a recycled buffer to avoid
/// fresh page faults).
fn packed_rows<T: bytemuck::Pod>(
    msg: &Image<'_>,
    bytes_per_pixel: usize,
    what: &'static str,
    mut out: Vec<T>,
) -> Result<Vec<T>, Rejection> {
    check_size(what, msg.width, msg.height)?;
    let row = msg.width as usize * bytes_per_pixel;
    let step = msg.step as usize;
    let rows = msg.height as usize;
    if step < row {
        return Err(Rejection::new(
            what,
            format!(
                "step {step} is shorter than a row of {} {} pixels ({row} bytes)",
                msg.width, msg.encoding
            ),
        ));
    }
    // Sizes are bounded by `check_size` (a row is at most 64 KiB) but
    // `step` is the message's own u32, so the totals are taken in u64.
    // `rows ≥ 1` by `check_size`.
    let (need, most) = (
        step as u64 * (rows as u64 - 1) + row as u64,
        step as u64 * rows as u64,
    );
    let len = msg.data.len() as u64;
    if len < need || len > most {
        return Err(Rejection::new(
            what,
            format!(
                "data has {} bytes; {}×{} {} with step {step} needs {}",
                msg.data.len(),
                msg.width,
                msg.height,
                msg.encoding,
                most
            ),
        ));
    }
    // From here `step * (rows - 1) + row <= data.len()`, so every slice
    // below is in range and no product overflows.
    // One copy straight into the typed buffer (message bytes may be
    // unaligned, so they cannot be reinterpreted in place).
    out.clear();
    out.resize(row * rows / size_of::<T>(), T::zeroed());
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out);
    if step == row {
        bytes.copy_from_slice(&msg.data[..row * rows]);
    } else {
        for (y, dst) in bytes.chunks_exact_mut(row).enumerate() {
            dst.copy_from_slice(&msg.data[y * step..y * step + row]);
        }
    }
    Ok(out)
}

/// Whether samples of a message with `is_bigendian` need byte swapping.
fn needs_swap(is_bigendian: bool) -> bool {
    is_bigendian != cfg!(target_endian = "big")
}

fn u16_samples(bytes: &[u8], big_endian: bool) -> Vec<u16> {
    if needs_swap(big_endian) {
        bytes
            .chunks_exact(2)
            .map(|b| u16::from_ne_bytes([b[1], b[0]]))
            .collect()
    } else {
        bytemuck::pod_collect_to_vec(bytes)
    }
}

/// A colour image from a raw image message.
pub fn color_from_image(msg: &Image<'_>) -> Result<ColorImage, Rejection> {
    color_from_image_into(msg, Vec::new())
}

/// [`color_from_image`] into a given (recycled) buffer.
pub(crate) fn color_from_image_into(
    msg: &Image<'_>,
    buf: Vec<u8>,
) -> Result<ColorImage, Rejection> {
    let format = PixelFormat::from_ros(msg.encoding).ok_or_else(|| {
        Rejection::new(
            "colour: unsupported encoding",
            format!(
                "encoding `{}` (accepted: rgb8, bgr8, rgba8, bgra8, mono8)",
                msg.encoding
            ),
        )
    })?;
    let data = packed_rows(msg, format.bytes_per_pixel(), "colour: size mismatch", buf)?;
    Ok(ColorImage {
        width: msg.width,
        height: msg.height,
        format,
        data,
    })
}

/// A colour image from a JPEG or PNG `CompressedImage`, refused before
/// decoding when its header declares a size other than `expected`'s or
/// beyond [`MAX_IMAGE_SIDE`] / [`MAX_IMAGE_PIXELS`].
pub fn color_from_compressed(
    msg: &CompressedImage<'_>,
    expected: Option<ExpectedSize>,
) -> Result<ColorImage, Rejection> {
    let format = msg.format.to_ascii_lowercase();
    let is_png = msg.data.starts_with(b"\x89PNG");
    if format.contains("png") || (is_png && !format.contains("jp")) {
        decode_png_color(msg.data, expected)
    } else if format.contains("jpeg")
        || format.contains("jpg")
        || msg.data.starts_with(&[0xff, 0xd8])
    {
        jpeg(msg.data, expected)
    } else {
        Err(Rejection::new(
            "colour: unsupported encoding",
            format!("compressed format `{}` (accepted: jpeg, png)", msg.format),
        ))
    }
}

/// Decodes a JPEG file to RGB (grey JPEGs to mono).
pub fn decode_jpeg(bytes: &[u8]) -> Result<ColorImage, Rejection> {
    jpeg(bytes, None)
}

fn jpeg(bytes: &[u8], expected: Option<ExpectedSize>) -> Result<ColorImage, Rejection> {
    let bad = |e: String| Rejection::new("colour: corrupt compressed image", format!("JPEG: {e}"));
    let mut decoder = zune_jpeg::JpegDecoder::new(Cursor::new(bytes));
    decoder.decode_headers().map_err(|e| bad(e.to_string()))?;
    let info = decoder
        .info()
        .ok_or_else(|| bad("no image header".into()))?;
    check_declared(
        "colour: size mismatch",
        "JPEG",
        (info.width as u32, info.height as u32),
        expected,
    )?;
    let pixels = decoder.decode().map_err(|e| bad(e.to_string()))?;
    let (width, height) = (info.width as u32, info.height as u32);
    let n = width as usize * height as usize;
    let format = match pixels.len() / n.max(1) {
        3 => PixelFormat::Rgb8,
        4 => PixelFormat::Rgba8,
        1 => PixelFormat::Mono8,
        c => return Err(bad(format!("{c} channels per pixel"))),
    };
    if pixels.len() != n * format.bytes_per_pixel() {
        return Err(bad("decoded size disagrees with the header".into()));
    }
    Ok(ColorImage {
        width,
        height,
        format,
        data: pixels,
    })
}

/// Decodes a PNG to packed samples: (width, height, colour type, bit depth,
/// bytes). `accept` sees the decoded colour type and bit depth (from the
/// header) before anything is decoded.
fn decode_png(
    bytes: &[u8],
    what: &'static str,
    strip_16: bool,
    expected: Option<ExpectedSize>,
    accept: impl FnOnce(png::ColorType, png::BitDepth) -> Result<(), Rejection>,
) -> Result<(u32, u32, png::ColorType, png::BitDepth, Vec<u8>), Rejection> {
    let bad = |e: String| Rejection::new(what, format!("PNG: {e}"));
    let mut decoder = png::Decoder::new(Cursor::new(bytes));
    let mut t = png::Transformations::EXPAND;
    if strip_16 {
        t |= png::Transformations::STRIP_16;
    }
    decoder.set_transformations(t);
    let mut reader = decoder.read_info().map_err(|e| bad(e.to_string()))?;
    let (w, h) = (reader.info().width, reader.info().height);
    check_declared(what, "PNG", (w, h), expected)?;
    // The type after the transformations, which is what is decoded.
    let (color, depth) = reader.output_color_type();
    accept(color, depth)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| bad("image too large".into()))?;
    let mut buf = vec![0u8; size];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| bad(e.to_string()))?;
    buf.truncate(info.buffer_size());
    Ok((
        info.width,
        info.height,
        info.color_type,
        info.bit_depth,
        buf,
    ))
}

fn decode_png_color(bytes: &[u8], expected: Option<ExpectedSize>) -> Result<ColorImage, Rejection> {
    let what = "colour: corrupt compressed image";
    let (width, height, color, _, mut data) =
        decode_png(bytes, what, true, expected, |_, _| Ok(()))?;
    let format = match color {
        png::ColorType::Rgb => PixelFormat::Rgb8,
        png::ColorType::Rgba => PixelFormat::Rgba8,
        png::ColorType::Grayscale => PixelFormat::Mono8,
        png::ColorType::GrayscaleAlpha => {
            data = data.chunks_exact(2).map(|p| p[0]).collect();
            PixelFormat::Mono8
        }
        png::ColorType::Indexed => {
            return Err(Rejection::new(what, "PNG palette was not expanded"))
        }
    };
    Ok(ColorImage {
        width,
        height,
        format,
        data,
    })
}

/// A depth image from a raw image message: `16UC1`/`mono16` in units of
/// `metres_per_unit`, or `32FC1` in metres.
pub fn depth_from_image(msg: &Image<'_>, metres_per_unit: f32) -> Result<DepthImage, Rejection> {
    depth_from_image_into(msg, metres_per_unit, Vec::new())
}

/// [`depth_from_image`] with a given (recycled) buffer for integer depth.
pub(crate) fn depth_from_image_into(
    msg: &Image<'_>,
    metres_per_unit: f32,
    buf: Vec<u16>,
) -> Result<DepthImage, Rejection> {
    let data = match msg.encoding {
        "16UC1" | "mono16" => {
            let mut values: Vec<u16> = packed_rows(msg, 2, "depth: size mismatch", buf)?;
            if needs_swap(msg.is_bigendian) {
                values.iter_mut().for_each(|v| *v = v.swap_bytes());
            }
            DepthData::Units {
                values,
                metres_per_unit,
            }
        }
        "32FC1" => {
            let mut values: Vec<f32> = packed_rows(msg, 4, "depth: size mismatch", Vec::new())?;
            if needs_swap(msg.is_bigendian) {
                values
                    .iter_mut()
                    .for_each(|v| *v = f32::from_bits(v.to_bits().swap_bytes()));
            }
            DepthData::Metres(values)
        }
        other => {
            return Err(Rejection::new(
                "depth: unsupported encoding",
                format!("encoding `{other}` (accepted: 16UC1, mono16, 32FC1)"),
            ))
        }
    };
    Ok(DepthImage {
        width: msg.width,
        height: msg.height,
        data,
    })
}

/// A depth image from a `compressedDepth` message (`16UC1; compressedDepth
/// png`, or `32FC1; compressedDepth png` with inverse-depth quantisation):
/// a 12-byte configuration header (format, quantisation A and B) then a PNG.
/// Refused before decoding when the PNG declares a size other than
/// `expected`'s or beyond the limits.
pub fn depth_from_compressed(
    msg: &CompressedImage<'_>,
    metres_per_unit: f32,
    expected: Option<ExpectedSize>,
) -> Result<DepthImage, Rejection> {
    let what = "depth: corrupt compressed image";
    let original = msg.format.split(';').next().unwrap_or("").trim();
    if !msg.format.contains("compressedDepth") {
        return Err(Rejection::new(
            "depth: unsupported encoding",
            format!(
                "compressed depth format `{}` (accepted: `16UC1; compressedDepth png`, \
                 `32FC1; compressedDepth png`)",
                msg.format
            ),
        ));
    }
    let (png_bytes, quant) = if msg.data.starts_with(b"\x89PNG") {
        (msg.data, None)
    } else if msg.data.len() > 12 && msg.data[12..].starts_with(b"\x89PNG") {
        // Slices of exactly 4 bytes, within the `len > 12` checked above.
        let a = f32::from_le_bytes(msg.data[4..8].try_into().expect("4 bytes"));
        let b = f32::from_le_bytes(msg.data[8..12].try_into().expect("4 bytes"));
        (&msg.data[12..], Some((a, b)))
    } else {
        return Err(Rejection::new(
            what,
            "no PNG after the compressedDepth header",
        ));
    };
    let (width, height, values) = png_u16(png_bytes, expected).map_err(|e| {
        // A size the frame rules out keeps its own kind.
        if expected.is_some_and(|x| x.kind == e.kind) {
            e
        } else {
            Rejection::new(what, e.detail)
        }
    })?;
    let data = match original {
        "32FC1" => {
            let (a, b) = quant.ok_or_else(|| {
                Rejection::new(
                    what,
                    "32FC1 compressedDepth without its quantisation header",
                )
            })?;
            DepthData::Metres(
                values
                    .iter()
                    .map(|&v| if v == 0 { 0.0 } else { a / (v as f32 - b) })
                    .collect(),
            )
        }
        _ => DepthData::Units {
            values,
            metres_per_unit,
        },
    };
    Ok(DepthImage {
        width,
        height,
        data,
    })
}

/// Decodes a 16-bit grey PNG (depth or label images) to row-major samples.
pub fn decode_png_u16(bytes: &[u8]) -> Result<(u32, u32, Vec<u16>), Rejection> {
    png_u16(bytes, None)
}

fn png_u16(
    bytes: &[u8],
    expected: Option<ExpectedSize>,
) -> Result<(u32, u32, Vec<u16>), Rejection> {
    let what = "depth: corrupt compressed image";
    let (width, height, _, _, bytes) = decode_png(bytes, what, false, expected, |color, depth| {
        if color != png::ColorType::Grayscale || depth != png::BitDepth::Sixteen {
            return Err(Rejection::new(
                what,
                format!("PNG is {color:?} {depth:?}, expected 16-bit grey"),
            ));
        }
        Ok(())
    })?;
    // PNG stores 16-bit samples big-endian.
    Ok((width, height, u16_samples(&bytes, true)))
}

/// Decodes an 8- or 16-bit grey PNG to row-major samples (label images
/// written either way).
pub fn decode_png_labels(bytes: &[u8]) -> Result<(u32, u32, Vec<u16>), Rejection> {
    let what = "labels: corrupt image";
    let (width, height, color, depth, bytes) = decode_png(bytes, what, false, None, |_, _| Ok(()))?;
    match (color, depth) {
        (png::ColorType::Grayscale, png::BitDepth::Sixteen) => {
            Ok((width, height, u16_samples(&bytes, true)))
        }
        (png::ColorType::Grayscale, png::BitDepth::Eight) => {
            Ok((width, height, bytes.iter().map(|&b| b as u16).collect()))
        }
        _ => Err(Rejection::new(
            what,
            format!("PNG is {color:?} {depth:?}, expected 8- or 16-bit grey"),
        )),
    }
}

/// Size and format (`"jpeg"` or `"png"`) of a compressed colour image,
/// from its header only.
pub fn compressed_image_size(bytes: &[u8]) -> Result<(u32, u32, &'static str), Rejection> {
    let what = "colour: corrupt compressed image";
    if bytes.starts_with(b"\x89PNG") {
        let reader = png::Decoder::new(Cursor::new(bytes))
            .read_info()
            .map_err(|e| Rejection::new(what, format!("PNG: {e}")))?;
        Ok((reader.info().width, reader.info().height, "png"))
    } else if bytes.starts_with(&[0xff, 0xd8]) {
        let mut decoder = zune_jpeg::JpegDecoder::new(Cursor::new(bytes));
        decoder
            .decode_headers()
            .map_err(|e| Rejection::new(what, format!("JPEG: {e}")))?;
        let info = decoder
            .info()
            .ok_or_else(|| Rejection::new(what, "JPEG: no image header"))?;
        Ok((info.width as u32, info.height as u32, "jpeg"))
    } else {
        Err(Rejection::new(
            "colour: unsupported encoding",
            "neither a PNG nor a JPEG file",
        ))
    }
}

/// Writes `values` (row-major, `width × height`) as a 16-bit grey PNG.
///
/// Panics if `values` does not hold `width × height` samples (a caller
/// bug: the converter passes what [`decode_png_u16`] returned).
pub fn encode_png_u16(width: u32, height: u32, values: &[u16]) -> Vec<u8> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width, height);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        let mut w = enc.write_header().expect("writing to a Vec cannot fail");
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        w.write_image_data(&bytes).expect("size matches the header");
    }
    out
}

/// The `compressedDepth` payload for 16-bit depth: a zeroed 12-byte
/// configuration header, then the PNG.
pub fn encode_compressed_depth_u16(width: u32, height: u32, values: &[u16]) -> Vec<u8> {
    let mut out = vec![0u8; 12];
    out.extend_from_slice(&encode_png_u16(width, height, values));
    out
}

/// Class or region labels from a `16UC1`/`mono16` image message.
pub fn labels_from_image(msg: &Image<'_>) -> Result<LabelImage, Rejection> {
    if !matches!(msg.encoding, "16UC1" | "mono16") {
        return Err(Rejection::new(
            "labels: unsupported encoding",
            format!("encoding `{}` (accepted: 16UC1, mono16)", msg.encoding),
        ));
    }
    let mut labels: Vec<u16> = packed_rows(msg, 2, "labels: size mismatch", Vec::new())?;
    if needs_swap(msg.is_bigendian) {
        labels.iter_mut().for_each(|v| *v = v.swap_bytes());
    }
    Ok(LabelImage {
        width: msg.width,
        height: msg.height,
        labels,
    })
}

#[cfg(test)]
#[path = "codec_tests.rs"]
mod tests;

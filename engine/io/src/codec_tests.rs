//! Tests of the image codecs: raw rows and their padding, depth encodings,
//! compressedDepth payloads, and sizes refused before decoding.

use super::*;
use crate::messages::Header;

fn image<'a>(encoding: &'a str, w: u32, h: u32, step: u32, data: &'a [u8]) -> Image<'a> {
    Image {
        header: Header::default(),
        height: h,
        width: w,
        encoding,
        is_bigendian: false,
        step,
        data,
    }
}

#[test]
fn row_padding_is_removed_and_sizes_are_checked() {
    // 2×2 bgr8 with 2 bytes of row padding.
    let data = [1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0];
    let c = color_from_image(&image("bgr8", 2, 2, 8, &data)).unwrap();
    assert_eq!(c.data, [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
    assert_eq!(c.rgb(1, 1), [12, 11, 10]);
    assert_eq!(c.to_rgb8()[..3], [3, 2, 1]);
    for (step, len) in [(8, 13), (5, 16), (8, 17)] {
        let e = color_from_image(&image("bgr8", 2, 2, step, &data_of(len))).unwrap_err();
        assert_eq!(e.kind, "colour: size mismatch", "{e}");
    }
    assert_eq!(
        color_from_image(&image("yuv422", 2, 2, 8, &data))
            .unwrap_err()
            .kind,
        "colour: unsupported encoding"
    );
    assert!(color_from_image(&image("rgb8", 0, 2, 0, &[])).is_err());
    assert!(color_from_image(&image("rgb8", 100_000, 1, 300_000, &[])).is_err());
}

fn data_of(n: usize) -> Vec<u8> {
    vec![0; n]
}

#[test]
fn depth_encodings_and_invalid_samples() {
    let mm: Vec<u8> = [0u16, 1500, 65535, 2]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let d = depth_from_image(&image("16UC1", 2, 2, 4, &mm), 0.001).unwrap();
    assert_eq!(d.metres(0), None);
    assert!((d.metres(1).unwrap() - 1.5).abs() < 1e-6);
    assert!((d.to_metres()[3] - 0.002).abs() < 1e-9);
    let mut be = image("mono16", 2, 2, 4, &mm);
    be.is_bigendian = true;
    let swapped = depth_from_image(&be, 0.001).unwrap();
    let want = u16::from_be_bytes(1500u16.to_le_bytes()) as f32 * 0.001;
    assert!((swapped.metres(1).unwrap() - want).abs() < 1e-6);
    let f: Vec<u8> = [1.25f32, f32::NAN, -1.0, f32::INFINITY]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let d = depth_from_image(&image("32FC1", 2, 2, 8, &f), 0.001).unwrap();
    assert_eq!(d.to_metres(), vec![1.25, 0.0, 0.0, 0.0]);
    assert!(d.has_valid_sample());
    let zeros = depth_from_image(&image("16UC1", 2, 2, 4, &[0; 8]), 0.001).unwrap();
    assert!(!zeros.has_valid_sample());
}

#[test]
fn compressed_depth_round_trip_and_corruption() {
    let values: Vec<u16> = (0..12).map(|i| i * 1000).collect();
    let payload = encode_compressed_depth_u16(4, 3, &values);
    let msg = CompressedImage {
        header: Header::default(),
        format: "16UC1; compressedDepth png",
        data: &payload,
    };
    let d = depth_from_compressed(&msg, 0.001, None).unwrap();
    assert_eq!((d.width, d.height), (4, 3));
    assert_eq!(
        d.data,
        DepthData::Units {
            values: values.clone(),
            metres_per_unit: 0.001
        }
    );
    for cut in [5, 20, 40] {
        let bad = CompressedImage {
            data: &payload[..cut],
            ..msg
        };
        assert!(
            depth_from_compressed(&bad, 0.001, None).is_err(),
            "cut {cut}"
        );
    }
    let jpeg = CompressedImage {
        format: "jpeg",
        ..msg
    };
    assert_eq!(
        depth_from_compressed(&jpeg, 0.001, None).unwrap_err().kind,
        "depth: unsupported encoding"
    );
    // A colour PNG is not depth.
    let grey8 = CompressedImage {
        format: "png",
        data: &payload[12..],
        ..msg
    };
    let c = color_from_compressed(&grey8, None).unwrap();
    assert_eq!((c.width, c.height, c.format), (4, 3, PixelFormat::Mono8));
}

/// A valid all-zero PNG of `side × side` pixels (8-bit grey, or 16-bit
/// when `wide`), written row by row so that building it allocates one
/// row, not the image: a few hundred kilobytes for 16384².
fn zero_png(side: u32, wide: bool) -> Vec<u8> {
    use std::io::Write;
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, side, side);
    enc.set_color(png::ColorType::Grayscale);
    let bytes_per_pixel = if wide {
        enc.set_depth(png::BitDepth::Sixteen);
        2
    } else {
        enc.set_depth(png::BitDepth::Eight);
        1
    };
    enc.set_compression(png::Compression::Fast);
    let mut header = enc.write_header().unwrap();
    let mut w = header.stream_writer().unwrap();
    let row = vec![0u8; side as usize * bytes_per_pixel];
    for _ in 0..side {
        w.write_all(&row).unwrap();
    }
    w.finish().unwrap();
    header.finish().unwrap();
    out
}

#[test]
fn huge_declared_sizes_are_refused_before_decoding() {
    let huge = zero_png(16384, false);
    assert!(huge.len() < 4 << 20, "{} bytes", huge.len());
    let msg = CompressedImage {
        header: Header::default(),
        format: "png",
        data: &huge,
    };
    // Decoding 256 MiB of pixels takes seconds; the header alone, none.
    let started = std::time::Instant::now();
    let e = color_from_compressed(&msg, None).unwrap_err();
    assert_eq!(e.kind, "colour: corrupt compressed image", "{e}");
    assert!(
        e.detail.contains("declares 16384×16384 pixels")
            && e.detail.contains("refused before decoding"),
        "{e}"
    );
    assert!(decode_png_labels(&huge).is_err());
    assert!(started.elapsed() < std::time::Duration::from_millis(500));

    // Within 8192 per side but over the pixel limit; and depth.
    let wide = zero_png(8192, true);
    let mut payload = vec![0u8; 12];
    payload.extend_from_slice(&wide);
    let depth = CompressedImage {
        format: "16UC1; compressedDepth png",
        data: &payload,
        ..msg
    };
    let e = depth_from_compressed(&depth, 0.001, None).unwrap_err();
    assert_eq!(e.kind, "depth: corrupt compressed image", "{e}");
    assert!(e.detail.contains("declares 8192×8192 pixels"), "{e}");
    assert!(decode_png_u16(&wide).is_err());
}

#[test]
fn a_size_the_frame_rules_out_is_refused_before_decoding() {
    let values: Vec<u16> = (0..12).collect();
    let payload = encode_compressed_depth_u16(4, 3, &values);
    let depth = CompressedImage {
        header: Header::default(),
        format: "16UC1; compressedDepth png",
        data: &payload,
    };
    let expect = |width, height, kind| ExpectedSize {
        width,
        height,
        kind,
        from: "the camera info",
    };
    let e = depth_from_compressed(
        &depth,
        0.001,
        Some(expect(640, 480, "depth: size mismatch")),
    )
    .unwrap_err();
    assert_eq!(e.kind, "depth: size mismatch");
    assert_eq!(
        e.detail,
        "the PNG declares 4×3 pixels but the camera info is 640×480; refused before decoding"
    );
    let d = depth_from_compressed(&depth, 0.001, Some(expect(4, 3, "depth: size mismatch")));
    let d = d.unwrap();
    assert_eq!((d.width, d.height), (4, 3));

    let colour = CompressedImage {
        format: "png",
        data: &payload[12..],
        ..depth
    };
    let e = color_from_compressed(&colour, Some(expect(4, 4, "frame: depth size differs")))
        .unwrap_err();
    assert_eq!(e.kind, "frame: depth size differs");
    assert!(color_from_compressed(&colour, Some(expect(4, 3, "x"))).is_ok());
}

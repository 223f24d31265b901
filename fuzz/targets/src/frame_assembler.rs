//! Structured message streams (valid, malformed and inconsistent
//! messages with jittered stamps) through the frame assembler under both
//! bad-input policies: it may reject anything but must not panic, and
//! every frame it hands out must be internally consistent.

use arbitrary::{Arbitrary, Unstructured};
use glam::{DQuat, DVec3};
use latentam_io::{
    cdr, AssemblyConfig, BadInputPolicy, CameraInfo, Channel, CompressedImage, FrameAssembler,
    Header, Image, MaskFeatures, Pose, PoseStamped, RawMessage, RosMessage,
};

#[derive(Arbitrary, Debug)]
enum Msg {
    Color {
        dt: i16,
        w: u8,
        h: u8,
        enc: u8,
        pad: u8,
        short: u8,
    },
    Compressed {
        dt: i16,
        bytes: Vec<u8>,
    },
    Depth {
        dt: i16,
        w: u8,
        h: u8,
        enc: u8,
        fill: u16,
        short: u8,
    },
    Info {
        dt: i16,
        w: u8,
        h: u8,
        f: i8,
        dist: bool,
    },
    Pose {
        dt: i16,
        x: i8,
        q: [i8; 4],
    },
    Mask {
        dt: i16,
        w: u8,
        h: u8,
        count: u8,
        dim: u8,
        label: u16,
        dtype: bool,
        extra: u8,
    },
    Raw {
        role: u8,
        bytes: Vec<u8>,
    },
}

const ENCODINGS: [&str; 6] = ["rgb8", "bgr8", "mono8", "16UC1", "32FC1", "yuv422"];

/// One input: a stop-or-skip policy and up to 64 messages, built from
/// `data` as `arbitrary` builds them.
pub fn run(data: &[u8]) {
    let Ok((stop, msgs)) = <(bool, Vec<Msg>)>::arbitrary_take_rest(Unstructured::new(data)) else {
        return;
    };
    let channels = [
        Channel::ros2("/camera/color/image_raw", Image::TYPE_NAME),
        Channel::ros2("/camera/depth/image_raw", Image::TYPE_NAME),
        Channel::ros2("/camera/color/camera_info", CameraInfo::TYPE_NAME),
        Channel::ros2("/camera/pose", PoseStamped::TYPE_NAME),
        Channel::ros2("/camera/embeddings", MaskFeatures::TYPE_NAME),
        Channel::ros2("/camera/color/image_raw", CompressedImage::TYPE_NAME),
    ];
    let config = AssemblyConfig {
        on_bad_input: if stop {
            BadInputPolicy::Stop
        } else {
            BadInputPolicy::Skip
        },
        max_pending: 8,
        ..AssemblyConfig::default()
    };
    let mut asm = FrameAssembler::new(config, true, false);
    let mut t = 1_000_000_000i64;
    for (k, m) in msgs.iter().take(64).enumerate() {
        t += 10_000_000;
        let at = |dt: i16| t + dt as i64 * 100_000;
        let (role, bytes) = match m {
            Msg::Color {
                dt,
                w,
                h,
                enc,
                pad,
                short,
            } => {
                let e = ENCODINGS[*enc as usize % ENCODINGS.len()];
                let (w, h) = (*w as u32 % 24, *h as u32 % 24);
                let step = w * 3 + *pad as u32 % 4;
                let data = vec![k as u8; ((step * h) as usize).saturating_sub(*short as usize % 3)];
                (
                    0,
                    Image {
                        header: Header::at(at(*dt), "c"),
                        height: h,
                        width: w,
                        encoding: e,
                        is_bigendian: false,
                        step,
                        data: &data,
                    }
                    .encode(),
                )
            }
            Msg::Compressed { dt, bytes } => (
                5,
                CompressedImage {
                    header: Header::at(at(*dt), "c"),
                    format: "png",
                    data: bytes,
                }
                .encode(),
            ),
            Msg::Depth {
                dt,
                w,
                h,
                enc,
                fill,
                short,
            } => {
                let e = ENCODINGS[*enc as usize % ENCODINGS.len()];
                let (w, h) = (*w as u32 % 24, *h as u32 % 24);
                let data: Vec<u8> = (0..w * h).flat_map(|_| fill.to_le_bytes()).collect();
                let data = &data[..data.len().saturating_sub(*short as usize % 3)];
                (
                    1,
                    Image {
                        header: Header::at(at(*dt), "c"),
                        height: h,
                        width: w,
                        encoding: e,
                        is_bigendian: *fill % 7 == 0,
                        step: w * 2,
                        data,
                    }
                    .encode(),
                )
            }
            Msg::Info { dt, w, h, f, dist } => {
                let mut info = CameraInfo::pinhole(
                    Header::at(at(*dt), "c"),
                    *w as u32 % 24,
                    *h as u32 % 24,
                    [*f as f64, 5.0, 3.0, 2.0],
                );
                let d = [0.1f64; 5].map(|v| v.to_le_bytes()).concat();
                if *dist {
                    info.d = cdr::Seq::new(&d, cdr::Endian::Little);
                }
                (2, info.encode())
            }
            Msg::Pose { dt, x, q } => {
                let q = q.map(|v| v as f64 / 64.0);
                let pose = Pose {
                    translation: DVec3::splat(*x as f64),
                    rotation: DQuat::from_xyzw(q[0], q[1], q[2], q[3]),
                };
                (
                    3,
                    PoseStamped {
                        header: Header::at(at(*dt), "map"),
                        pose,
                    }
                    .encode(),
                )
            }
            Msg::Mask {
                dt,
                w,
                h,
                count,
                dim,
                label,
                dtype,
                extra,
            } => {
                let (w, h) = (*w as u32 % 24, *h as u32 % 24);
                let labels: Vec<u8> = (0..w * h)
                    .flat_map(|i| {
                        if i % 3 == 0 {
                            label.to_le_bytes()
                        } else {
                            0u16.to_le_bytes()
                        }
                    })
                    .collect();
                let size = if *dtype { 2 } else { 4 };
                let data =
                    vec![0x3cu8; *count as usize * *dim as usize * size + *extra as usize % 2];
                (
                    4,
                    MaskFeatures {
                        header: Header::at(at(*dt), "c"),
                        height: h,
                        width: w,
                        labels: cdr::Seq::new(&labels, cdr::Endian::Little),
                        count: *count as u32,
                        dim: *dim as u32 % 9,
                        dtype: if *dtype { "f16" } else { "f32" },
                        data: &data,
                        model: "m",
                    }
                    .encode(),
                )
            }
            Msg::Raw { role, bytes } => (*role as usize % channels.len(), bytes.clone()),
        };
        let raw = RawMessage {
            channel: &channels[role],
            log_time: t as u64,
            data: &bytes,
        };
        if asm.push(raw).is_err() {
            return;
        }
        while let Some(f) = asm.pop() {
            assert_eq!(
                (f.color.width, f.color.height),
                (f.depth.width, f.depth.height)
            );
            assert!(f.depth.has_valid_sample());
            assert!((f.pose.rotation.length() - 1.0).abs() < 1e-6);
            assert_eq!(
                f.color.data.len(),
                (f.color.width * f.color.height) as usize * f.color.format.bytes_per_pixel()
            );
            asm.recycle(f);
        }
    }
    let _ = asm.finish();
    while let Some(f) = asm.pop() {
        assert!(f.depth.has_valid_sample());
    }
}

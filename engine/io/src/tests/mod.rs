//! Round trips through the writer and the reader, pairing, and bad input,
//! one file per subject; here, the synthetic logs they share.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{DQuat, DVec3};

use super::*;

mod bad_input;
mod input_checks;
mod integrity;
mod pairing;
mod registration;
mod round_trips;
mod topic_plans;

pub(crate) use latentam_base::files::testing::TempDir;

const W: u32 = 8;
const H: u32 = 6;
const MS: i64 = 1_000_000;

fn depth_bytes(fill: u16) -> Vec<u8> {
    (0..W * H)
        .flat_map(|i| (fill + i as u16).to_le_bytes())
        .collect()
}

fn color_bytes(seed: u8) -> Vec<u8> {
    (0..W * H * 3)
        .map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed))
        .collect()
}

fn pose_at(t: i64) -> Pose {
    let s = t as f64 * 1e-9;
    Pose {
        translation: DVec3::new(s, 2.0 * s, -s),
        rotation: DQuat::from_rotation_y(0.3 * s),
    }
}

/// What a synthetic log holds; each field can be broken by a test.
struct Spec {
    frames: usize,
    color_period: i64,
    depth_period: i64,
    depth_offset: i64,
    pose_period: i64,
    embeddings: bool,
    compression: Compression,
    depth_frame: &'static str,
}

impl Default for Spec {
    fn default() -> Self {
        Spec {
            frames: 6,
            color_period: 100 * MS,
            depth_period: 50 * MS,
            depth_offset: 3 * MS,
            pose_period: 20 * MS,
            embeddings: true,
            compression: Compression::Zstd,
            depth_frame: "cam",
        }
    }
}

type Tweak<'a> = &'a dyn Fn(&mut LogWriter<std::io::BufWriter<std::fs::File>>, usize, i64);

fn write_log(path: &Path, spec: &Spec, tweak: Tweak<'_>) {
    let mut log = LogWriter::create(path, spec.compression).unwrap();
    let t0 = 1_000_000_000_000i64;
    let end = t0 + spec.color_period * spec.frames as i64;
    let mut events: Vec<(i64, u8)> = Vec::new();
    for i in 0..spec.frames as i64 {
        events.push((t0 + i * spec.color_period, 0));
    }
    let mut t = t0 + spec.depth_offset;
    while t < end {
        events.push((t, 1));
        t += spec.depth_period;
    }
    let mut t = t0 - spec.pose_period;
    while t <= end + spec.pose_period {
        events.push((t, 2));
        t += spec.pose_period;
    }
    events.sort();
    let mut frame = 0;
    for (t, kind) in events {
        let lt = t as u64;
        match kind {
            0 => {
                let info = CameraInfo::pinhole(Header::at(t, "cam"), W, H, [5.0, 5.0, 3.5, 2.5]);
                log.write("/camera/color/camera_info", lt, &info).unwrap();
                let data = color_bytes(frame as u8);
                let img = Image::packed(Header::at(t, "cam"), W, H, "rgb8", &data);
                log.write("/camera/color/image_raw", lt, &img).unwrap();
                if spec.embeddings {
                    let labels: Vec<u16> = (0..W * H)
                        .map(|i| if i % 5 == 0 { u16::MAX } else { (i % 3) as u16 })
                        .collect();
                    let values: Vec<f32> = (0..3 * 4).map(|i| i as f32 + frame as f32).collect();
                    let data = encode_floats(&values, Dtype::F16);
                    let lbytes: Vec<u8> = labels.iter().flat_map(|l| l.to_le_bytes()).collect();
                    let m = MaskFeatures {
                        header: Header::at(t + MS, "cam"),
                        height: H,
                        width: W,
                        labels: cdr::Seq::new(&lbytes, cdr::Endian::Little),
                        count: 3,
                        dim: 4,
                        dtype: "f16",
                        data: &data,
                        model: "test-model",
                    };
                    log.write("/camera/embeddings", lt + MS as u64, &m).unwrap();
                }
                tweak(&mut log, frame, t);
                frame += 1;
            }
            1 => {
                let data = depth_bytes(1000 + (t / MS % 100) as u16);
                let img = Image {
                    header: Header::at(t, spec.depth_frame),
                    height: H,
                    width: W,
                    encoding: "16UC1",
                    is_bigendian: false,
                    step: W * 2,
                    data: &data,
                };
                log.write("/camera/depth/image_raw", lt, &img).unwrap();
            }
            _ => {
                let p = PoseStamped {
                    header: Header::at(t, "map"),
                    pose: pose_at(t),
                };
                log.write("/camera/pose", lt, &p).unwrap();
            }
        }
    }
    log.metadata(
        "latentam",
        BTreeMap::from([
            ("source".to_string(), "test".to_string()),
            (
                "semantic_classes".to_string(),
                r#"{"0": "undefined", "10": "wall", "93": "door"}"#.to_string(),
            ),
        ]),
    )
    .unwrap();
    log.finish().unwrap();
}

fn read_all(path: &Path, config: AssemblyConfig) -> (Vec<Frame>, IngestReport) {
    let mut frames = McapFrames::open(path, config).unwrap();
    let v: Vec<Frame> = (&mut frames).map(|f| f.unwrap()).collect();
    (v, frames.report().clone())
}

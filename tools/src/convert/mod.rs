//! `latentam convert`: public RGB-D datasets to the engine's MCAP layout
//! (DESIGN §3 topics), with embeddings from per-frame feature files or,
//! for evaluation, oracle embeddings from label images.
//!
//! Colour files are copied into `CompressedImage` messages as they are
//! (no re-encoding); depth is rescaled to millimetres and written as
//! `16UC1; compressedDepth png`.

pub mod datasets;
pub mod features;
pub mod npy;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use latentam_io::{
    cdr, codec, encode_floats, CameraInfo, CompressedImage, Compression, Dtype, FeatureGrid,
    Header, Image, LogWriter, MaskFeatures, Pose, PoseStamped, TextEmbeddings, TfMessage,
    TransformStamped, MAX_RECORD_BYTES,
};

pub use datasets::{Dataset, DepthCamera};
use features::{FeatureDir, FrameFeatures, LoadedFeatures, Oracle};
pub use latentam_io::DepthRegistration;

/// Where a log's embeddings come from.
pub enum EmbeddingSource {
    /// None: geometry and colour only.
    None,
    /// A folder of per-frame feature files.
    Features(FeatureDir),
    /// Label images + class vectors (evaluation only).
    Oracle(Oracle),
}

/// Whether depth is re-projected into the colour camera.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Registration {
    /// As the dataset reader says (7-Scenes: yes, with its measured colour
    /// lens; the others are registered already).
    #[default]
    Dataset,
    /// Keep depth as recorded, and the depth camera as the camera.
    Off,
    /// Depth comes from this camera.
    Given(DepthCamera),
}

/// How to convert.
pub struct ConvertOptions {
    /// Embeddings.
    pub embeddings: EmbeddingSource,
    /// The colour camera's `[fx, fy, cx, cy]` instead of the dataset's.
    pub intrinsics: Option<[f64; 4]>,
    /// Depth registration.
    pub registration: Registration,
    /// With a depth lens apart from the colour one: write its depth as
    /// recorded, in its own optical frame ([`DEPTH_FRAME`]) with its
    /// calibration on `/camera/depth/camera_info` and the transform between
    /// the lenses on `/tf_static`, as a driver records a raw depth stream,
    /// and leave the registration to the reader (the poses are still the
    /// colour lens's).
    pub raw_depth: bool,
    /// Depth units per metre instead of the dataset's.
    pub depth_units_per_metre: Option<f64>,
    /// Element type of written embeddings.
    pub dtype: Dtype,
    /// Chunk compression.
    pub compression: Compression,
    /// Convert at most this many colour frames.
    pub max_frames: Option<usize>,
    /// Name of the dataset kind, for the log's metadata.
    pub kind: String,
    /// The source folder, for the log's metadata.
    pub source: PathBuf,
}

/// What was written.
#[derive(Debug, Default, serde::Serialize)]
pub struct ConvertSummary {
    /// Colour frames written.
    pub frames: usize,
    /// Depth images written.
    pub depth: usize,
    /// Pose messages written.
    pub poses: usize,
    /// Frames written with embeddings.
    pub with_embeddings: usize,
    /// Frames for which an embedding source had no file.
    pub without_embeddings: usize,
    /// Frames left out by the dataset reader, with why.
    pub skipped: Vec<String>,
    /// Facts about the conversion.
    pub notes: Vec<String>,
}

const FRAME: &str = "camera_color_optical_frame";

/// The depth lens's optical frame, with [`ConvertOptions::raw_depth`].
pub const DEPTH_FRAME: &str = "camera_depth_optical_frame";

fn u16_bytes(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

enum Event<'a> {
    Color(&'a datasets::Stamped),
    Depth(&'a datasets::Stamped),
    Pose(i64, &'a latentam_io::Pose),
}

impl Event<'_> {
    fn stamp(&self) -> i64 {
        match self {
            Event::Color(s) | Event::Depth(s) => s.stamp_ns,
            Event::Pose(t, _) => *t,
        }
    }
}

fn stem(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default()
}

fn check_intrinsics(what: &str, k: &[f64; 4]) -> anyhow::Result<()> {
    if k.iter().any(|v| !v.is_finite()) || k[0] <= 0.0 || k[1] <= 0.0 {
        bail!("{what} {k:?} are not valid");
    }
    Ok(())
}

/// The re-projection of `camera`'s depth into the colour camera
/// `colour`, with the colour images' size (that of the first one), the
/// poses moved to the colour lens when they were the depth lens's, and a
/// note saying so.
fn register_to_colour(
    dataset: &mut Dataset,
    camera: &DepthCamera,
    colour: [f64; 4],
    raw: bool,
) -> anyhow::Result<(DepthRegistration, usize, usize)> {
    let reg = DepthRegistration {
        depth: camera.intrinsics,
        colour,
        rotation: glam::DQuat::IDENTITY,
        translation: camera.translation,
    };
    let first = &dataset.color[0].path;
    let bytes =
        latentam_io::read_input(first).with_context(|| format!("reading {}", first.display()))?;
    let (w, h, _) = codec::compressed_image_size(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: {e}", first.display()))?;
    if camera.poses_are_depth {
        for (_, p) in &mut dataset.poses {
            *p = reg.colour_pose(p);
        }
    }
    let [fx, _, cx, cy] = reg.depth;
    if raw {
        if camera.poses_are_depth {
            dataset
                .notes
                .push("poses moved from the depth lens to the colour lens".into());
        }
        return Ok((reg, w as usize, h as usize));
    }
    dataset.notes.push(format!(
        "depth registered to the colour camera (depth lens f {fx:.1} c ({cx:.1}, {cy:.1}), \
         {:.1} cm away){}; --no-registration keeps it as recorded",
        reg.translation.length() * 100.0,
        if camera.poses_are_depth {
            ", poses moved from the depth lens to the colour lens"
        } else {
            ""
        }
    ));
    Ok((reg, w as usize, h as usize))
}

/// Writes `dataset` to `out` (through `out.partial`, renamed at the end),
/// calling `progress(colour frames done, total)`.
pub fn convert(
    mut dataset: Dataset,
    options: &ConvertOptions,
    out: &Path,
    mut progress: impl FnMut(usize, usize),
) -> anyhow::Result<ConvertSummary> {
    let depth_camera = match options.registration {
        Registration::Dataset => dataset.depth_camera,
        Registration::Off => None,
        Registration::Given(c) => Some(c),
    };
    // Unregistered, the depth camera is the camera.
    let recorded = match (options.registration, dataset.depth_camera) {
        (Registration::Off, Some(c)) => Some(c.intrinsics),
        _ => dataset.intrinsics,
    };
    let intrinsics = options
        .intrinsics
        .or(recorded)
        .context("the dataset does not state its intrinsics; pass --intrinsics fx,fy,cx,cy")?;
    check_intrinsics("intrinsics", &intrinsics)?;
    if let Some(c) = &depth_camera {
        check_intrinsics("depth intrinsics", &c.intrinsics)?;
        let t = c.translation;
        if !(t.is_finite() && t.length() <= 1.0) {
            bail!("depth camera offset {t} m is not a lens beside the colour one (at most 1 m)");
        }
    }
    let units = options
        .depth_units_per_metre
        .unwrap_or(dataset.depth_units_per_metre);
    if !(units.is_finite() && units > 0.0) {
        bail!("depth units per metre must be positive, got {units}");
    }
    if let Some(n) = options.max_frames {
        dataset.color.truncate(n);
        if let Some(last) = dataset.color.last().map(|c| c.stamp_ns) {
            // Depth within the pairing tolerance of the last frame, poses
            // within the interpolation gap.
            dataset
                .depth
                .retain(|d| d.stamp_ns <= last.saturating_add(20_000_000));
            dataset
                .poses
                .retain(|p| p.0 <= last.saturating_add(200_000_000));
        }
    }
    if dataset.color.is_empty() {
        bail!("no frames to convert");
    }
    let registration = match depth_camera {
        Some(c) => Some(register_to_colour(
            &mut dataset,
            &c,
            intrinsics,
            options.raw_depth,
        )?),
        None => {
            if dataset.depth_camera.is_some() {
                dataset.notes.push(
                    "depth is not registered to colour (a few pixels apart, more at silhouettes)"
                        .into(),
                );
            }
            None
        }
    };
    // ROS stamps are absolute times; datasets without them start at 0.
    let offset = if dataset.color[0].stamp_ns < 1_000_000_000_000 {
        latentam_cli_epoch()
    } else {
        0
    };
    let mut events: Vec<Event<'_>> = dataset.color.iter().map(Event::Color).collect();
    events.extend(dataset.depth.iter().map(Event::Depth));
    events.extend(dataset.poses.iter().map(|(t, p)| Event::Pose(*t, p)));
    events.sort_by_key(|e| (e.stamp(), matches!(e, Event::Color(_)) as u8));
    // The latest stamp must stay an i64 once offset (`offset ≥ 0`, and the
    // events are sorted), so `stamp + offset` below cannot overflow.
    if let Some(last) = events.last() {
        if last.stamp().checked_add(offset).is_none() {
            bail!(
                "stamp {} ns is out of range after the synthetic offset of {offset} ns \
                 given to stamps near 0",
                last.stamp()
            );
        }
    }

    let partial = latentam_base::files::PartialFile::new(out)?;
    let mut log = LogWriter::create(partial.path(), options.compression)?;
    let mut summary = ConvertSummary {
        skipped: std::mem::take(&mut dataset.skipped),
        notes: std::mem::take(&mut dataset.notes),
        ..ConvertSummary::default()
    };
    if let EmbeddingSource::Oracle(o) = &options.embeddings {
        // `Oracle::new` checks 2 ≤ classes ≤ 65536, so `names[1..]` exists
        // and every id fits a u16.
        let names: Vec<&str> = o.names[1..].iter().map(String::as_str).collect();
        let ids: Vec<u16> = (1..o.names.len()).map(|i| i as u16).collect();
        let ids_bytes = u16_bytes(&ids);
        let data = encode_floats(&o.vectors[1..].concat(), options.dtype);
        let t = dataset.color[0].stamp_ns + offset;
        log.write(
            "/vocabulary",
            t as u64,
            &TextEmbeddings {
                header: Header::at(t, "map"),
                names,
                ids: cdr::Seq::new(&ids_bytes, cdr::Endian::Little),
                dim: o.dim() as u32,
                dtype: options.dtype.name(),
                data: &data,
                model: &o.model,
            },
        )?;
    }
    // Raw depth: the depth lens placed in the colour lens's frame.
    let raw = registration.as_ref().filter(|_| options.raw_depth);
    if let Some((reg, _, _)) = raw {
        let t = dataset.color[0].stamp_ns + offset;
        log.write(
            "/tf_static",
            t as u64,
            &TfMessage {
                transforms: vec![TransformStamped {
                    header: Header::at(t, FRAME),
                    child_frame_id: DEPTH_FRAME,
                    transform: Pose {
                        translation: reg.translation,
                        rotation: reg.rotation,
                    },
                }],
            },
        )?;
        summary.notes.push(format!(
            "depth written as recorded in `{DEPTH_FRAME}`, with its camera info and /tf_static, \
             for the reader to register"
        ));
    }
    let total = dataset.color.len();
    let mut first_dim: Option<(usize, String)> = None;
    let mut first_layout: Option<bool> = None;
    for e in &events {
        let t = e.stamp() + offset;
        let lt = t as u64;
        let header = Header::at(t, FRAME);
        match e {
            Event::Pose(_, p) => {
                log.write(
                    "/camera/pose",
                    lt,
                    &PoseStamped {
                        header: Header::at(t, "world"),
                        pose: **p,
                    },
                )?;
                summary.poses += 1;
            }
            Event::Depth(s) => {
                let bytes = latentam_io::read_input(&s.path)
                    .with_context(|| format!("reading {}", s.path.display()))?;
                let (w, h, mut values) = codec::decode_png_u16(&bytes)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", s.path.display()))?;
                if (units - 1000.0).abs() > 1e-9 {
                    let k = 1000.0 / units;
                    for v in &mut values {
                        *v = (*v as f64 * k).round().min(u16::MAX as f64) as u16;
                    }
                }
                let (w, h, header) = match (&registration, raw) {
                    (Some((reg, _, _)), Some(_)) => {
                        let header = Header::at(t, DEPTH_FRAME);
                        log.write(
                            "/camera/depth/camera_info",
                            lt,
                            &CameraInfo::pinhole(header, w, h, reg.depth),
                        )?;
                        (w, h, header)
                    }
                    (Some((reg, cw, ch)), None) => {
                        values = reg.register(w as usize, h as usize, &values, 1000.0, *cw, *ch);
                        (*cw as u32, *ch as u32, header)
                    }
                    (None, _) => (w, h, header),
                };
                // `values` holds the w × h samples `decode_png_u16` returned
                // (at most codec::MAX_IMAGE_PIXELS of them), as the encoder requires.
                let data = codec::encode_compressed_depth_u16(w, h, &values);
                log.write(
                    "/camera/depth/image_raw",
                    lt,
                    &CompressedImage {
                        header,
                        format: "16UC1; compressedDepth png",
                        data: &data,
                    },
                )?;
                summary.depth += 1;
            }
            Event::Color(s) => {
                let bytes = latentam_io::read_input(&s.path)
                    .with_context(|| format!("reading {}", s.path.display()))?;
                check_payload(&s.path.display().to_string(), bytes.len())?;
                let (w, h, format) = codec::compressed_image_size(&bytes)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", s.path.display()))?;
                log.write(
                    "/camera/color/camera_info",
                    lt,
                    &CameraInfo::pinhole(header, w, h, intrinsics),
                )?;
                log.write(
                    "/camera/color/image_raw",
                    lt,
                    &CompressedImage {
                        header,
                        format,
                        data: &bytes,
                    },
                )?;
                let name = stem(&s.path);
                let loaded = match &options.embeddings {
                    EmbeddingSource::None => None,
                    EmbeddingSource::Features(dir) => dir.load(&name)?,
                    EmbeddingSource::Oracle(o) => match o.load(&name)? {
                        Some(frame) => {
                            let (lw, lh) = (frame.width, frame.height);
                            let class_bytes = u16_bytes(&frame.classes);
                            log.write(
                                "/camera/semantic",
                                lt,
                                &Image::packed(header, lw, lh, "16UC1", &class_bytes),
                            )?;
                            Some(LoadedFeatures {
                                features: frame.features,
                                dim: o.dim(),
                                model: o.model.clone(),
                            })
                        }
                        None => None,
                    },
                };
                match loaded {
                    Some(f) => {
                        let grid = matches!(f.features, FrameFeatures::Grid { .. });
                        if *first_layout.get_or_insert(grid) != grid {
                            bail!(
                                "{name}: {} after frames with {}; one log holds one kind (mask regions or a feature grid)",
                                if grid { "a feature grid" } else { "mask regions" },
                                if grid { "mask regions" } else { "a feature grid" }
                            );
                        }
                        match &first_dim {
                            None => first_dim = Some((f.dim, f.model.clone())),
                            Some((d, m)) if *d != f.dim || *m != f.model => bail!(
                                "{name}: embeddings of dimension {} from `{}` after {d} from `{m}`; one log holds one embedding space",
                                f.dim,
                                f.model
                            ),
                            Some(_) => {}
                        }
                        write_features(&mut log, header, lt, &f, options.dtype)?;
                        summary.with_embeddings += 1;
                    }
                    None if !matches!(options.embeddings, EmbeddingSource::None) => {
                        summary.without_embeddings += 1
                    }
                    None => {}
                }
                summary.frames += 1;
                progress(summary.frames, total);
            }
        }
    }
    let mut meta = BTreeMap::from([
        (
            "converter".to_string(),
            format!("latentam convert {}", options.kind),
        ),
        ("source".to_string(), options.source.display().to_string()),
        (
            "depth".to_string(),
            format!("millimetres, converted from {units} units per metre"),
        ),
        (
            "embeddings".to_string(),
            match &options.embeddings {
                EmbeddingSource::None => "none".to_string(),
                EmbeddingSource::Features(_) => "per-frame feature files".to_string(),
                EmbeddingSource::Oracle(_) => {
                    "oracle: label images and class vectors (evaluation only)".to_string()
                }
            },
        ),
    ]);
    if offset != 0 {
        meta.insert("stamps".into(), "synthetic (the dataset has none)".into());
    }
    for (i, n) in summary.notes.iter().enumerate() {
        meta.insert(format!("note_{i}"), n.clone());
    }
    log.metadata("latentam", meta)?;
    log.finish()?;
    partial.commit()?;
    Ok(summary)
}

/// Stamps given to datasets without time stamps start here
/// (2023-11-14T22:13:20Z), so they look like real ROS times.
fn latentam_cli_epoch() -> i64 {
    1_700_000_000_000_000_000
}

/// Refuses a payload too large for one message: the reader takes records
/// of at most [`MAX_RECORD_BYTES`], and CDR cannot encode 4 GiB at all.
pub fn check_payload(what: &str, len: usize) -> anyhow::Result<()> {
    if len > MAX_RECORD_BYTES {
        bail!("{what}: {len} bytes, more than one message may hold ({MAX_RECORD_BYTES} bytes)");
    }
    Ok(())
}

fn write_features<W: std::io::Write + std::io::Seek>(
    log: &mut LogWriter<W>,
    header: Header<'_>,
    lt: u64,
    f: &LoadedFeatures,
    dtype: Dtype,
) -> anyhow::Result<()> {
    match &f.features {
        FrameFeatures::Regions {
            width,
            height,
            labels,
            count,
            vectors,
        } => {
            let label_bytes = u16_bytes(labels);
            let data = encode_floats(vectors, dtype);
            check_payload("region embeddings", data.len())?;
            log.write(
                "/camera/embeddings",
                lt,
                &MaskFeatures {
                    header,
                    height: *height,
                    width: *width,
                    labels: cdr::Seq::new(&label_bytes, cdr::Endian::Little),
                    count: *count,
                    dim: f.dim as u32,
                    dtype: dtype.name(),
                    data: &data,
                    model: &f.model,
                },
            )?;
        }
        FrameFeatures::Grid {
            rows,
            cols,
            vectors,
        } => {
            let data = encode_floats(vectors, dtype);
            check_payload("grid embeddings", data.len())?;
            log.write(
                "/camera/embeddings",
                lt,
                &FeatureGrid {
                    header,
                    rows: *rows,
                    cols: *cols,
                    dim: f.dim as u32,
                    dtype: dtype.name(),
                    data: &data,
                    model: &f.model,
                },
            )?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(max_frames: Option<usize>) -> ConvertOptions {
        ConvertOptions {
            embeddings: EmbeddingSource::None,
            intrinsics: None,
            registration: Registration::Dataset,
            raw_depth: false,
            depth_units_per_metre: None,
            dtype: Dtype::F16,
            compression: Compression::None,
            max_frames,
            kind: "test".into(),
            source: PathBuf::from("test"),
        }
    }

    fn dataset(color: i64, pose: i64) -> Dataset {
        Dataset {
            color: vec![datasets::Stamped {
                stamp_ns: color,
                path: PathBuf::from("/nonexistent/latentam/colour.png"),
            }],
            poses: vec![(pose, latentam_io::Pose::IDENTITY)],
            intrinsics: Some([500.0, 500.0, 320.0, 240.0]),
            depth_units_per_metre: 1000.0,
            ..Dataset::default()
        }
    }

    #[test]
    fn stamps_at_the_ends_of_the_range_are_errors_not_overflows() {
        let out = std::env::temp_dir().join(format!(
            "latentam-convert-stamps-{}.mcap",
            std::process::id()
        ));
        // A synthetic offset (colour stamps near 0) past a pose at the end
        // of the range.
        let e = convert(dataset(0, i64::MAX), &options(None), &out, |_, _| {}).unwrap_err();
        assert!(format!("{e:#}").contains("out of range"), "{e:#}");
        // --max-frames keeps what lies within a margin after the last
        // colour stamp, which is at the end of the range here: the only
        // error left is the missing colour file.
        let last = i64::MAX - 5;
        let e = convert(dataset(last, last), &options(Some(1)), &out, |_, _| {}).unwrap_err();
        assert!(format!("{e:#}").contains("colour.png"), "{e:#}");
        assert!(!out.exists());
    }

    #[test]
    fn depth_cameras_that_cannot_be_beside_the_colour_lens_are_refused() {
        let out = std::env::temp_dir().join(format!(
            "latentam-convert-depth-camera-{}.mcap",
            std::process::id()
        ));
        let given = |intrinsics, translation: [f64; 3]| ConvertOptions {
            raw_depth: false,
            registration: Registration::Given(DepthCamera {
                intrinsics,
                translation: translation.into(),
                poses_are_depth: false,
            }),
            ..options(None)
        };
        let e = convert(
            dataset(0, 0),
            &given([0.0, 585.0, 320.0, 240.0], [0.0; 3]),
            &out,
            |_, _| {},
        )
        .unwrap_err();
        assert!(format!("{e:#}").contains("depth intrinsics"), "{e:#}");
        let e = convert(
            dataset(0, 0),
            &given([585.0, 585.0, 320.0, 240.0], [5.0, 0.0, 0.0]),
            &out,
            |_, _| {},
        )
        .unwrap_err();
        assert!(format!("{e:#}").contains("at most 1 m"), "{e:#}");
        assert!(!out.exists());
    }

    #[test]
    fn payloads_larger_than_a_message_are_refused() {
        assert!(check_payload("x", MAX_RECORD_BYTES).is_ok());
        let e = check_payload("frame.jpg", MAX_RECORD_BYTES + 1).unwrap_err();
        assert!(e.to_string().contains("frame.jpg"), "{e}");
    }
}

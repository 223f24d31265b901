//! `latentam convert`: public RGB-D datasets to the engine's MCAP layout
//! (the topics of docs/input-logs.md), with embeddings from per-frame feature files or,
//! for evaluation, oracle embeddings from label images.
//!
//! Colour files are copied into `CompressedImage` messages as they are
//! (no re-encoding); depth is rescaled to millimetres and written as
//! `16UC1; compressedDepth png`.

pub mod datasets;
pub mod features;
pub mod oracle;
mod writing;

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use latentam::frames::Dtype;
use latentam::logs::{Compression, MAX_RECORD_BYTES};
use latentam::messages::{codec, Pose};

pub use datasets::{Dataset, DepthCamera};
use features::FeatureDir;
pub use latentam::frames::DepthRegistration;
use oracle::Oracle;

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
    Pose(i64, &'a Pose),
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
    let bytes = latentam::files::read_input(first)
        .with_context(|| format!("reading {}", first.display()))?;
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
    let cameras = Cameras::resolve(&dataset, options)?;
    if let Some(n) = options.max_frames {
        keep_first_frames(&mut dataset, n);
    }
    if dataset.color.is_empty() {
        bail!("no frames to convert");
    }
    let registration = match cameras.depth {
        Some(c) => Some(register_to_colour(
            &mut dataset,
            &c,
            cameras.intrinsics,
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
    let summary = ConvertSummary {
        skipped: std::mem::take(&mut dataset.skipped),
        notes: std::mem::take(&mut dataset.notes),
        ..ConvertSummary::default()
    };
    let (events, offset) = timeline(&dataset)?;
    let partial = latentam::files::PartialFile::new(out)?;
    let mut log = writing::LogOut::create(
        partial.path(),
        options,
        &cameras,
        registration,
        offset,
        summary,
    )?;
    log.write_start(dataset.color[0].stamp_ns)?;
    let total = dataset.color.len();
    for e in &events {
        log.write_event(e)?;
        if matches!(e, Event::Color(_)) {
            progress(log.summary().frames, total);
        }
    }
    let summary = log.finish()?;
    partial.commit()?;
    Ok(summary)
}

/// The cameras a conversion writes: the colour intrinsics, the depth
/// camera to register from (if any) and depth units per metre, from the
/// options where they say, else the dataset, each checked.
struct Cameras {
    intrinsics: [f64; 4],
    depth: Option<DepthCamera>,
    units_per_metre: f64,
}

impl Cameras {
    fn resolve(dataset: &Dataset, options: &ConvertOptions) -> anyhow::Result<Self> {
        let depth = match options.registration {
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
        if let Some(c) = &depth {
            check_intrinsics("depth intrinsics", &c.intrinsics)?;
            let t = c.translation;
            if !(t.is_finite() && t.length() <= 1.0) {
                bail!(
                    "depth camera offset {t} m is not a lens beside the colour one (at most 1 m)"
                );
            }
        }
        let units_per_metre = options
            .depth_units_per_metre
            .unwrap_or(dataset.depth_units_per_metre);
        if !(units_per_metre.is_finite() && units_per_metre > 0.0) {
            bail!("depth units per metre must be positive, got {units_per_metre}");
        }
        Ok(Cameras {
            intrinsics,
            depth,
            units_per_metre,
        })
    }
}

/// Keeps the first `n` colour frames, and the depth and poses that can
/// still pair with them: depth within the pairing tolerance of the last
/// frame, poses within the interpolation gap.
fn keep_first_frames(dataset: &mut Dataset, n: usize) {
    dataset.color.truncate(n);
    if let Some(last) = dataset.color.last().map(|c| c.stamp_ns) {
        dataset
            .depth
            .retain(|d| d.stamp_ns <= last.saturating_add(20_000_000));
        dataset
            .poses
            .retain(|p| p.0 <= last.saturating_add(200_000_000));
    }
}

/// Every colour image, depth image and pose of `dataset` in time order,
/// and the offset added to their stamps: ROS stamps are absolute times, so
/// a dataset whose stamps start near 0 is moved to [`latentam_cli_epoch`].
fn timeline(dataset: &Dataset) -> anyhow::Result<(Vec<Event<'_>>, i64)> {
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
    // events are sorted), so `stamp + offset` when writing cannot overflow.
    if let Some(last) = events.last() {
        if last.stamp().checked_add(offset).is_none() {
            bail!(
                "stamp {} ns is out of range after the synthetic offset of {offset} ns \
                 given to stamps near 0",
                last.stamp()
            );
        }
    }
    Ok((events, offset))
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
            poses: vec![(pose, Pose::IDENTITY)],
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

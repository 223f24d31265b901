//! Readers for the folder layouts of public RGB-D datasets: what frames
//! there are, when, and where the camera was.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use glam::{DMat3, DQuat, DVec3};
use latentam::messages::Pose;

/// An image file and its stamp.
#[derive(Clone, Debug, PartialEq)]
pub struct Stamped {
    /// Nanoseconds.
    pub stamp_ns: i64,
    /// The file.
    pub path: PathBuf,
}

/// A dataset's content, ready to be written as a log.
#[derive(Debug, Default)]
pub struct Dataset {
    /// Colour images.
    pub color: Vec<Stamped>,
    /// Depth images (16-bit PNG).
    pub depth: Vec<Stamped>,
    /// Camera-to-world poses of the colour camera's optical frame.
    pub poses: Vec<(i64, Pose)>,
    /// The colour camera's `[fx, fy, cx, cy]`, when the dataset states them.
    pub intrinsics: Option<[f64; 4]>,
    /// Where depth comes from a second lens: that lens, and whether the
    /// poses are the depth camera's. Depth is then registered to colour.
    pub depth_camera: Option<DepthCamera>,
    /// Depth units per metre of the PNGs.
    pub depth_units_per_metre: f64,
    /// Frames left out, with why.
    pub skipped: Vec<String>,
    /// Facts the user should know about the conversion.
    pub notes: Vec<String>,
}

/// A depth camera beside the colour camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthCamera {
    /// `[fx, fy, cx, cy]` in pixels.
    pub intrinsics: [f64; 4],
    /// The depth camera's origin in the colour camera's optical frame
    /// (metres); the two are taken as parallel.
    pub translation: DVec3,
    /// The dataset's poses are the depth camera's, not the colour one's.
    pub poses_are_depth: bool,
}

impl Dataset {
    /// A frame whose colour, depth and pose share one stamp.
    fn push_frame(&mut self, stamp_ns: i64, color: PathBuf, depth: PathBuf, pose: Pose) {
        self.color.push(Stamped {
            stamp_ns,
            path: color,
        });
        self.depth.push(Stamped {
            stamp_ns,
            path: depth,
        });
        self.poses.push((stamp_ns, pose));
    }
}

fn read_text(path: &Path) -> anyhow::Result<String> {
    latentam::files::read_input_to_string(path)
        .with_context(|| format!("reading {}", path.display()))
}

/// A camera-to-world pose from a row-major 4×4 matrix, checked to be rigid.
pub fn pose_from_matrix(m: &[f64]) -> Result<Pose, String> {
    if m.len() != 16 {
        return Err(format!("{} numbers, expected 16", m.len()));
    }
    if m.iter().any(|v| !v.is_finite()) {
        return Err("non-finite entries".into());
    }
    let r = DMat3::from_cols(
        DVec3::new(m[0], m[4], m[8]),
        DVec3::new(m[1], m[5], m[9]),
        DVec3::new(m[2], m[6], m[10]),
    );
    let err = (r.transpose() * r - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .map(|v| v.abs())
        .fold(0.0, f64::max);
    if err > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 {
        return Err(format!(
            "rotation is not orthonormal (error {err:.2e}, det {:.4})",
            r.determinant()
        ));
    }
    if m[12..15].iter().any(|v| v.abs() > 1e-9) || (m[15] - 1.0).abs() > 1e-9 {
        return Err("last row is not 0 0 0 1".into());
    }
    Ok(Pose {
        translation: DVec3::new(m[3], m[7], m[11]),
        rotation: DQuat::from_mat3(&r).normalize(),
    })
}

fn numbers(text: &str, origin: &str) -> anyhow::Result<Vec<f64>> {
    text.split_whitespace()
        .map(|t| {
            t.parse::<f64>()
                .with_context(|| format!("{origin}: `{t}` is not a number"))
        })
        .collect()
}

fn stamp_of(index: usize, fps: f64) -> i64 {
    (index as f64 * 1e9 / fps).round() as i64
}

/// The 7-Scenes colour lens relative to its depth lens, measured on
/// redkitchen 0-299 by aligning depth silhouettes with colour edges over 30
/// frames: `u_c = cx + focal_ratio (u - cx) - parallax_px_m / z`,
/// `v_c = cy + focal_ratio (v - cy) + row_shift` (the Kinect v1 colour
/// camera's ~525 px focal length, 2.3 cm beside the depth lens). It raised
/// the colour agreement of the same surface seen from frames 4 apart from
/// 25.5 to 28.1 dB.
struct SevenScenesColourLens {
    focal_ratio: f64,
    row_shift: f64,
    parallax_px_m: f64,
}

const SEVEN_SCENES_COLOUR_LENS: SevenScenesColourLens = SevenScenesColourLens {
    focal_ratio: 0.905,
    row_shift: -1.0,
    parallax_px_m: 12.0,
};

/// Microsoft 7-Scenes: `frame-XXXXXX.color.{jpg,png}`,
/// `frame-XXXXXX.depth.png` (mm) and `frame-XXXXXX.pose.txt` (4×4
/// camera-to-world). The dataset has no time stamps; frames are placed
/// `1/fps` apart.
pub fn seven_scenes(dir: &Path, fps: f64) -> anyhow::Result<Dataset> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .with_context(|| format!("reading {}", dir.display()))?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| {
            n.starts_with("frame-") && (n.ends_with(".color.jpg") || n.ends_with(".color.png"))
        })
        .collect();
    names.sort();
    if names.is_empty() {
        bail!(
            "{}: no frame-XXXXXX.color.jpg files (not a 7-Scenes sequence folder)",
            dir.display()
        );
    }
    let mut d = Dataset {
        depth_units_per_metre: 1000.0,
        ..Dataset::default()
    };
    let intr = dir.join("camera-intrinsics.txt");
    let depth_intrinsics = if intr.is_file() {
        let k = numbers(&read_text(&intr)?, &intr.display().to_string())?;
        if k.len() != 9 {
            bail!("{}: expected a 3×3 matrix", intr.display());
        }
        [k[0], k[4], k[2], k[5]]
    } else {
        d.notes.push(
            "no camera-intrinsics.txt: using the 7-Scenes values fx = fy = 585, cx = 320, cy = 240"
                .into(),
        );
        [585.0, 585.0, 320.0, 240.0]
    };
    // 7-Scenes states only the depth camera (its poses come from
    // KinectFusion on depth) and leaves colour unregistered and
    // uncalibrated: see SEVEN_SCENES_COLOUR_LENS.
    let [fx, fy, cx, cy] = depth_intrinsics;
    let SevenScenesColourLens {
        focal_ratio,
        row_shift,
        parallax_px_m,
    } = SEVEN_SCENES_COLOUR_LENS;
    let colour_fx = focal_ratio * fx;
    d.intrinsics = Some([colour_fx, focal_ratio * fy, cx, cy + row_shift]);
    d.depth_camera = Some(DepthCamera {
        intrinsics: depth_intrinsics,
        // A constant parallax of `p` pixel-metres at focal length f is the
        // depth lens sitting p / f metres along the colour camera's x.
        translation: DVec3::new(-parallax_px_m / colour_fx, 0.0, 0.0),
        poses_are_depth: true,
    });
    for (i, name) in names.iter().enumerate() {
        // Every name was kept for ending in `.color.jpg` or `.color.png`.
        let id = &name[..name.find(".color").expect("filtered")];
        let depth = dir.join(format!("{id}.depth.png"));
        let pose_file = dir.join(format!("{id}.pose.txt"));
        if !depth.is_file() || !pose_file.is_file() {
            d.skipped.push(format!("{id}: missing depth or pose file"));
            continue;
        }
        let pose = pose_from_matrix(&numbers(
            &read_text(&pose_file)?,
            &pose_file.display().to_string(),
        )?);
        let pose = match pose {
            Ok(p) => p,
            Err(why) => {
                d.skipped.push(format!("{id}: pose {why}"));
                continue;
            }
        };
        d.push_frame(stamp_of(i, fps), dir.join(name), depth, pose);
    }
    d.notes.push(format!("stamps are synthetic at {fps} Hz"));
    Ok(d)
}

/// Replica in the NICE-SLAM layout: `results/frameXXXXXX.jpg`,
/// `results/depthXXXXXX.png` (6553.5 units per metre unless
/// `cam_params.json` says otherwise), `traj.txt` (one row-major 4×4
/// camera-to-world per line), `cam_params.json` intrinsics. Frames are
/// placed `1/fps` apart.
pub fn replica(dir: &Path, fps: f64) -> anyhow::Result<Dataset> {
    let results = dir.join("results");
    let mut names: Vec<String> = std::fs::read_dir(&results)
        .with_context(|| {
            format!(
                "reading {} (not a Replica NICE-SLAM folder?)",
                results.display()
            )
        })?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter(|n| n.starts_with("frame") && (n.ends_with(".jpg") || n.ends_with(".png")))
        .collect();
    names.sort();
    if names.is_empty() {
        bail!("{}: no frameXXXXXX.jpg files", results.display());
    }
    let traj_path = dir.join("traj.txt");
    let traj = read_text(&traj_path)?;
    let rows: Vec<&str> = traj.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut d = Dataset {
        depth_units_per_metre: 6553.5,
        ..Dataset::default()
    };
    let params = dir.join("cam_params.json");
    if params.is_file() {
        let v = latentam::files::parse_json(&read_text(&params)?)
            .map_err(|e| anyhow::anyhow!("{}: {e}", params.display()))?;
        let cam = v.get("camera").unwrap_or(&v);
        let get = |k: &str| cam.get(k).and_then(|x| x.as_f64());
        match (get("fx"), get("fy"), get("cx"), get("cy")) {
            (Some(fx), Some(fy), Some(cx), Some(cy)) => d.intrinsics = Some([fx, fy, cx, cy]),
            _ => bail!("{}: camera.fx, fy, cx, cy expected", params.display()),
        }
        if let Some(s) = get("scale") {
            d.depth_units_per_metre = s;
        }
    } else {
        d.notes.push("no cam_params.json: using the NICE-SLAM Replica values fx = fy = 600, cx = 599.5, cy = 339.5".into());
        d.intrinsics = Some([600.0, 600.0, 599.5, 339.5]);
    }
    for (i, name) in names.iter().enumerate() {
        let digits: String = name.chars().filter(|c| c.is_ascii_digit()).collect();
        let index: usize = digits
            .parse()
            .with_context(|| format!("{name}: no frame number"))?;
        let depth = results.join(format!("depth{digits}.png"));
        let Some(row) = rows.get(index) else {
            d.skipped.push(format!(
                "{name}: traj.txt has no line {}",
                index.saturating_add(1)
            ));
            continue;
        };
        if !depth.is_file() {
            d.skipped.push(format!("{name}: no {}", depth.display()));
            continue;
        }
        let pose = match pose_from_matrix(&numbers(row, &traj_path.display().to_string())?) {
            Ok(p) => p,
            Err(why) => {
                d.skipped.push(format!("{name}: pose {why}"));
                continue;
            }
        };
        d.push_frame(stamp_of(i, fps), results.join(name), depth, pose);
    }
    d.notes.push(format!(
        "Replica has no time stamps; frames are placed at {fps} Hz"
    ));
    Ok(d)
}

fn tum_list(path: &Path) -> anyhow::Result<Vec<(i64, Vec<String>)>> {
    let mut out = Vec::new();
    for (n, line) in read_text(path)?.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut parts = line.split_whitespace();
        let t: f64 = parts
            .next()
            .and_then(|s| s.parse().ok())
            .with_context(|| format!("{}:{}: no time stamp", path.display(), n + 1))?;
        // Seconds as i64 nanoseconds: finite and within ±292 years of 1970
        // (`as` would saturate NaN, ∞ and the rest into stamps that then
        // overflow).
        let ns = (t * 1e9).round();
        if !(ns.is_finite() && ns.abs() < i64::MAX as f64) {
            bail!(
                "{}:{}: time stamp {t} s is out of range",
                path.display(),
                n + 1
            );
        }
        out.push((ns as i64, parts.map(str::to_string).collect()));
    }
    Ok(out)
}

/// `name`, a file an index (`what`) lists, within the dataset folder
/// `dir`: an absolute name or one that climbs out with `..` is refused, so
/// an index cannot make the converter read files elsewhere.
fn inside(dir: &Path, name: &str, what: &str) -> anyhow::Result<PathBuf> {
    use std::path::Component;
    let rel = Path::new(name);
    if !rel
        .components()
        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
    {
        anyhow::bail!(
            "{what} lists {}, which is not inside the dataset folder",
            latentam::text::shown(name)
        );
    }
    Ok(dir.join(rel))
}

/// TUM RGB-D: `rgb.txt` and `depth.txt` (`timestamp filename`),
/// `groundtruth.txt` (`timestamp tx ty tz qx qy qz qw`, the colour
/// camera's optical centre in the world), depth PNGs at 5000 units per
/// metre. Intrinsics are the published ones for `freiburg1/2/3` when the
/// folder name says which; otherwise pass them.
pub fn tum(dir: &Path) -> anyhow::Result<Dataset> {
    let mut d = Dataset {
        depth_units_per_metre: 5000.0,
        ..Dataset::default()
    };
    for (t, rest) in tum_list(&dir.join("rgb.txt"))? {
        let name = rest.first().context("rgb.txt line without a file name")?;
        d.color.push(Stamped {
            stamp_ns: t,
            path: inside(dir, name, "rgb.txt")?,
        });
    }
    for (t, rest) in tum_list(&dir.join("depth.txt"))? {
        let name = rest.first().context("depth.txt line without a file name")?;
        d.depth.push(Stamped {
            stamp_ns: t,
            path: inside(dir, name, "depth.txt")?,
        });
    }
    let gt = dir.join("groundtruth.txt");
    for (t, rest) in tum_list(&gt)? {
        let v: Vec<f64> = rest.iter().filter_map(|s| s.parse().ok()).collect();
        if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
            d.skipped.push(format!(
                "groundtruth.txt at {t} ns: expected 7 finite numbers"
            ));
            continue;
        }
        d.poses.push((
            t,
            Pose {
                translation: DVec3::new(v[0], v[1], v[2]),
                rotation: DQuat::from_xyzw(v[3], v[4], v[5], v[6]),
            },
        ));
    }
    if d.color.is_empty() {
        bail!("{}: rgb.txt lists no images", dir.display());
    }
    let name = dir
        .file_name()
        .map(|n| n.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    d.intrinsics = if name.contains("freiburg1") {
        Some([517.3, 516.5, 318.6, 255.3])
    } else if name.contains("freiburg2") {
        Some([520.9, 521.0, 325.1, 249.7])
    } else if name.contains("freiburg3") {
        Some([535.4, 539.2, 320.1, 247.6])
    } else {
        None
    };
    if name.contains("freiburg1") || name.contains("freiburg2") {
        d.notes
            .push("TUM freiburg1/2 images have small lens distortion that is not removed".into());
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matrices_must_be_rigid() {
        let mut m = [
            1.0, 0.0, 0.0, 1.0, 0.0, 0.0, -1.0, 2.0, 0.0, 1.0, 0.0, 3.0, 0.0, 0.0, 0.0, 1.0,
        ];
        let p = pose_from_matrix(&m).unwrap();
        assert_eq!(p.translation, DVec3::new(1.0, 2.0, 3.0));
        assert!((p.rotation * DVec3::Y - DVec3::Z).length() < 1e-12);
        m[0] = 2.0;
        assert!(pose_from_matrix(&m).is_err());
        m[0] = f64::NEG_INFINITY;
        assert!(pose_from_matrix(&m).unwrap_err().contains("non-finite"));
        assert!(pose_from_matrix(&m[..12]).is_err());
    }

    /// A folder removed on drop.
    struct Scratch(std::path::PathBuf);

    impl Scratch {
        fn new(tag: &str) -> Self {
            let p = std::env::temp_dir()
                .join(format!("latentam-datasets-{tag}-{}", std::process::id()));
            let _ = std::fs::remove_dir_all(&p);
            std::fs::create_dir_all(&p).unwrap();
            Scratch(p)
        }
    }

    impl Drop for Scratch {
        fn drop(&mut self) {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }

    #[test]
    fn tum_stamps_out_of_range_are_errors() {
        let dir = Scratch::new("tum-stamps");
        for stamp in ["nan", "inf", "-inf", "1e300", "-1e11"] {
            std::fs::write(dir.0.join("rgb.txt"), format!("{stamp} rgb/a.png\n")).unwrap();
            std::fs::write(dir.0.join("depth.txt"), "").unwrap();
            std::fs::write(dir.0.join("groundtruth.txt"), "").unwrap();
            let err = format!("{:#}", tum(&dir.0).unwrap_err());
            assert!(
                err.contains("rgb.txt:1") && err.contains("out of range"),
                "{err}"
            );
        }
    }

    #[test]
    fn tum_indexes_cannot_lead_outside_the_dataset() {
        let dir = Scratch::new("tum-outside");
        std::fs::write(dir.0.join("depth.txt"), "").unwrap();
        std::fs::write(dir.0.join("groundtruth.txt"), "").unwrap();
        for name in ["../outside.png", "/etc/passwd", "rgb/../../x.png"] {
            std::fs::write(dir.0.join("rgb.txt"), format!("1.0 {name}\n")).unwrap();
            let err = format!("{:#}", tum(&dir.0).unwrap_err());
            assert!(err.contains("not inside the dataset folder"), "{err}");
        }
        std::fs::write(dir.0.join("rgb.txt"), "1.0 ./rgb/a.png\n").unwrap();
        let d = tum(&dir.0).unwrap();
        assert_eq!(d.color[0].path, dir.0.join("./rgb/a.png"));
    }

    #[test]
    fn replica_frame_numbers_past_usize_are_skipped_not_overflowed() {
        let dir = Scratch::new("replica-index");
        std::fs::create_dir_all(dir.0.join("results")).unwrap();
        let name = format!("frame{}.jpg", usize::MAX);
        std::fs::write(dir.0.join("results").join(&name), b"").unwrap();
        std::fs::write(dir.0.join("traj.txt"), "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n").unwrap();
        let d = replica(&dir.0, 30.0).unwrap();
        assert!(d.color.is_empty());
        assert_eq!(
            d.skipped,
            [format!("{name}: traj.txt has no line {}", usize::MAX)]
        );
    }
}

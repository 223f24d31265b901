//! Camera trajectories in the TUM RGB-D format, which the usual trajectory
//! evaluation tools (`evo`, the TUM benchmark scripts) read.
//!
//! One pose a line, `timestamp tx ty tz qx qy qz qw`, separated by spaces:
//! the timestamp in seconds, the camera-to-world translation in metres and
//! the rotation as a unit quaternion, scalar last (the TUM order, unlike the
//! engine's own `w, x, y, z`). Lines starting with `#` are comments.
//!
//! Written precision:
//! * timestamps are printed from the integer nanoseconds as
//!   `<seconds>.<9 digits>` (a stamp before 1970, which a ROS header may
//!   carry, with a leading `-`), never through a float, so a stamp survives a
//!   round trip exactly (an `f64` of seconds since 1970 only keeps about a
//!   quarter of a microsecond);
//! * translations with 6 decimals (1 µm, far below any sensor's accuracy,
//!   and columns that stay readable and diffable);
//! * quaternion components with 9 decimals (about 1e-9 rad).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use glam::{DQuat, DVec3};

use super::frame::CameraPose;
use latentam_base::files::write_atomically;
use latentam_base::{Error, Result};

/// The header line [`write_tum`] writes.
const HEADER: &str = "# timestamp tx ty tz qx qy qz qw";

/// Quaternions shorter than this are not rotations, whatever their
/// direction.
const MIN_QUATERNION_NORM: f64 = 1e-6;

/// Writes `poses` (stamp in nanoseconds, camera-to-world pose) to `path` in
/// the TUM RGB-D format (see the module documentation for the precision).
///
/// The quaternion is written normalised. A pose with a non-finite or zero
/// component is [`Error::BadInput`], checked before any file is
/// touched. The write is atomic, as for
/// `latentam_core::map::write_ply`.
pub fn write_tum(path: &Path, poses: &[(i64, CameraPose)]) -> Result<()> {
    let mut text = String::with_capacity(HEADER.len() + 1 + poses.len() * 96);
    text.push_str(HEADER);
    text.push('\n');
    for (i, (stamp_ns, pose)) in poses.iter().enumerate() {
        let t = pose.translation;
        let Some(q) = normalised(pose.rotation).filter(|_| t.is_finite()) else {
            return Err(Error::bad_input(
                format!("{}: pose {i} (stamp {stamp_ns} ns)", path.display()),
                format!("not finite or with a zero rotation: {pose:?}"),
            ));
        };
        let sign = if *stamp_ns < 0 { "-" } else { "" };
        let magnitude = stamp_ns.unsigned_abs();
        let (secs, nanos) = (magnitude / 1_000_000_000, magnitude % 1_000_000_000);
        // Writing to a String cannot fail.
        let _ = writeln!(
            text,
            "{sign}{secs}.{nanos:09} {:.6} {:.6} {:.6} {:.9} {:.9} {:.9} {:.9}",
            t.x, t.y, t.z, q.x, q.y, q.z, q.w
        );
    }
    write_atomically(path, |out| out.write_all(text.as_bytes()))
}

/// Reads a TUM RGB-D trajectory: one `(stamp_ns, pose)` per line, in file
/// order.
///
/// Blank lines and lines starting with `#` are skipped. Timestamps may have
/// any number of decimals (beyond nanoseconds they are rounded) or be in
/// exponent notation, and are negative before 1970; quaternions are
/// normalised. A line without exactly eight numbers, a timestamp outside
/// ±9.2·10⁹ s (an `i64` of nanoseconds), a non-finite value or a zero
/// quaternion is [`Error::Damaged`] naming the file and line.
pub fn read_tum(path: &Path) -> Result<Vec<(i64, CameraPose)>> {
    let text = super::read_input_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let mut poses = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let bad = |why: String| Error::damaged(path, format!("line {}: {why}", i + 1));
        let fields: Vec<&str> = line.split_ascii_whitespace().collect();
        let Some((stamp, rest)) = fields.split_first().filter(|(_, rest)| rest.len() == 7) else {
            return Err(bad(format!(
                "expected `timestamp tx ty tz qx qy qz qw`, found {} fields",
                fields.len()
            )));
        };
        let stamp_ns = parse_stamp(stamp).ok_or_else(|| bad(format!("bad timestamp `{stamp}`")))?;
        let mut v = [0.0f64; 7];
        for (slot, field) in v.iter_mut().zip(rest) {
            *slot = field
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| bad(format!("`{field}` is not a finite number")))?;
        }
        let rotation = normalised(DQuat::from_xyzw(v[3], v[4], v[5], v[6]))
            .ok_or_else(|| bad("the quaternion has zero length".to_owned()))?;
        poses.push((
            stamp_ns,
            CameraPose {
                rotation,
                translation: DVec3::new(v[0], v[1], v[2]),
            },
        ));
    }
    Ok(poses)
}

/// `q / |q|`, or `None` when `q` is not finite or (nearly) zero.
fn normalised(q: DQuat) -> Option<DQuat> {
    let n = q.length();
    (q.is_finite() && n.is_finite() && n >= MIN_QUATERNION_NORM).then(|| q / n)
}

/// Seconds as written in a TUM file to nanoseconds: decimals are taken
/// digit by digit so nothing is lost to floating point; anything else a
/// float parser accepts (exponents) goes through `f64`.
fn parse_stamp(s: &str) -> Option<i64> {
    let (negative, unsigned) = match s.strip_prefix('-') {
        Some(rest) => (true, rest),
        None => (false, s),
    };
    let (int, frac) = unsigned.split_once('.').unwrap_or((unsigned, ""));
    let all_digits = |d: &str| d.bytes().all(|b| b.is_ascii_digit());
    if !int.is_empty() && all_digits(int) && all_digits(frac) {
        let secs: i128 = int.parse().ok()?;
        let mut nanos = 0i128;
        for (k, b) in frac.bytes().take(9).enumerate() {
            nanos += i128::from(b - b'0') * 10i128.pow(8 - k as u32);
        }
        if frac.as_bytes().get(9).is_some_and(|&b| b >= b'5') {
            nanos += 1;
        }
        let magnitude = secs.checked_mul(1_000_000_000)?.checked_add(nanos)?;
        return i64::try_from(if negative { -magnitude } else { magnitude }).ok();
    }
    let secs: f64 = s.parse().ok()?;
    let ns = (secs * 1e9).round();
    // `i64::MAX as f64` rounds up to 2^63, which itself does not fit.
    (ns.is_finite() && ns >= i64::MIN as f64 && ns < i64::MAX as f64).then_some(ns as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_base::files::testing::TempDir;

    fn pose(i: u32) -> CameraPose {
        let f = f64::from(i);
        CameraPose {
            rotation: DQuat::from_euler(glam::EulerRot::XYZ, 0.1 * f, -0.7 + f, 2.0 - 0.3 * f),
            translation: DVec3::new(1.25 * f, -3.5 + f, 1e-3 * f),
        }
    }

    #[test]
    fn round_trip() {
        let dir = TempDir::new("tum");
        let path = dir.path().join("trajectory.txt");
        let poses: Vec<(i64, CameraPose)> = (0..20)
            .map(|i| {
                (
                    1_700_000_000_000_000_000 + i64::from(i) * 33_333_333,
                    pose(i),
                )
            })
            .collect();
        write_tum(&path, &poses).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        assert!(text.starts_with("# timestamp tx ty tz qx qy qz qw\n1700000000.000000000 "));
        assert_eq!(text.lines().count(), 21);

        let back = read_tum(&path).unwrap();
        assert_eq!(back.len(), poses.len());
        for ((s0, p0), (s1, p1)) in poses.iter().zip(&back) {
            assert_eq!(s0, s1);
            assert!((p0.translation - p1.translation).abs().max_element() <= 5e-7);
            assert!(p0.rotation.dot(p1.rotation).abs() > 1.0 - 1e-12);
            assert!((p1.rotation.length() - 1.0).abs() < 1e-12);
        }
    }

    #[test]
    fn stamps_are_exact() {
        let dir = TempDir::new("tum");
        let path = dir.path().join("stamps.txt");
        let stamps = [
            0,
            1,
            999_999_999,
            1_000_000_000,
            1_700_000_000_123_456_789,
            i64::MAX,
            -1,
            -1_500_000_000,
            i64::MIN,
        ];
        let poses: Vec<_> = stamps.iter().map(|&s| (s, pose(1))).collect();
        write_tum(&path, &poses).unwrap();
        let text = std::fs::read_to_string(&path).unwrap();
        let written: Vec<&str> = text
            .lines()
            .skip(1)
            .map(|l| l.split(' ').next().unwrap())
            .collect();
        assert_eq!(
            written,
            [
                "0.000000000",
                "0.000000001",
                "0.999999999",
                "1.000000000",
                "1700000000.123456789",
                "9223372036.854775807",
                "-0.000000001",
                "-1.500000000",
                "-9223372036.854775808",
            ]
        );
        let back: Vec<i64> = read_tum(&path).unwrap().iter().map(|p| p.0).collect();
        assert_eq!(back, stamps);
    }

    #[test]
    fn reads_other_writers() {
        let dir = TempDir::new("tum");
        let path = dir.path().join("other.txt");
        std::fs::write(
            &path,
            "# ground truth trajectory\n# file: 'rgbd_dataset_freiburg1_xyz.bag'\n\n\
             1305031098.6659 1.3563 0.6305 1.6380 0.6132 0.5962 -0.3311 -0.3986\r\n\
             \t1305031098.67590051 1 2 3 0 0 0 2  \n\
             1.5e9 0 0 0 0 0 1 0\n",
        )
        .unwrap();
        let poses = read_tum(&path).unwrap();
        assert_eq!(poses.len(), 3);
        assert_eq!(poses[0].0, 1_305_031_098_665_900_000);
        assert_eq!(poses[0].1.translation, DVec3::new(1.3563, 0.6305, 1.6380));
        assert_eq!(poses[1].0, 1_305_031_098_675_900_510, "rounded to the ns");
        assert_eq!(poses[1].1.rotation, DQuat::IDENTITY, "normalised");
        assert_eq!(poses[2].0, 1_500_000_000_000_000_000);
        assert_eq!(poses[2].1.rotation, DQuat::from_xyzw(0.0, 0.0, 1.0, 0.0));
    }

    #[test]
    fn malformed_lines_are_errors() {
        let dir = TempDir::new("tum");
        let path = dir.path().join("bad.txt");
        let good = "1.0 0 0 0 0 0 0 1";
        for (line, needle) in [
            ("1.0 0 0 0 0 0 0", "found 7 fields"),
            ("1.0 0 0 0 0 0 0 1 5", "found 9 fields"),
            ("-1.0.0 0 0 0 0 0 0 1", "bad timestamp"),
            ("--1 0 0 0 0 0 0 1", "bad timestamp"),
            ("9223372036.854775808 0 0 0 0 0 0 1", "bad timestamp"),
            ("1.0.0 0 0 0 0 0 0 1", "bad timestamp"),
            ("abc 0 0 0 0 0 0 1", "bad timestamp"),
            ("99999999999999999999 0 0 0 0 0 0 1", "bad timestamp"),
            ("1e30 0 0 0 0 0 0 1", "bad timestamp"),
            ("1.0 0 nan 0 0 0 0 1", "`nan` is not a finite number"),
            ("1.0 0 0 inf 0 0 0 1", "not a finite number"),
            ("1.0 0 0 0 x 0 0 1", "`x` is not a finite number"),
            ("1.0 0 0 0 0 0 0 0", "zero length"),
        ] {
            std::fs::write(&path, format!("# header\n{good}\n\n{line}\n{good}\n")).unwrap();
            match read_tum(&path) {
                Err(Error::Damaged { path: p, reason }) => {
                    assert_eq!(p, path);
                    assert!(
                        reason.starts_with("line 4: "),
                        "{reason:?} should name line 4"
                    );
                    assert!(
                        reason.contains(needle),
                        "{reason:?} should mention {needle:?}"
                    );
                }
                other => panic!("{line:?}: expected an error, got {other:?}"),
            }
        }
        assert!(matches!(
            read_tum(&dir.path().join("missing.txt")),
            Err(Error::Io { .. })
        ));
    }

    #[test]
    fn bad_poses_are_not_written() {
        let dir = TempDir::new("tum");
        let path = dir.path().join("bad.txt");
        let mut nan = pose(0);
        nan.translation.y = f64::NAN;
        let mut zero = pose(0);
        zero.rotation = DQuat::from_xyzw(0.0, 0.0, 0.0, 0.0);
        for bad in [nan, zero] {
            let result = write_tum(&path, &[(0, pose(1)), (1, bad)]);
            assert!(matches!(result, Err(Error::BadInput { .. })), "{result:?}");
            assert!(!path.exists());
        }
    }
}

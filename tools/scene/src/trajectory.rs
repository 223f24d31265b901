//! Camera paths: the demo's around room A, through the corridor, around
//! room B, and back into room A, so a mapper's local window has to page;
//! any other through waypoints ([`CameraPath`]).

use glam::{Mat3, Vec2, Vec3};

/// Eye height above the floor, metres.
pub const EYE_HEIGHT: f32 = 1.4;
const PITCH: f32 = -0.18;

const WAYPOINTS: [[f32; 2]; 15] = [
    [1.4, 1.4],
    [3.6, 1.3],
    [3.8, 2.6],
    [1.4, 2.7],
    [1.3, 2.0],
    [4.2, 2.0],
    [7.0, 2.0],
    [10.0, 2.0],
    [12.6, 1.3],
    [12.8, 2.7],
    [10.3, 2.7],
    [10.0, 2.0],
    [7.0, 2.0],
    [3.8, 2.0],
    [2.4, 1.6],
];

fn catmull_rom(p0: Vec2, p1: Vec2, p2: Vec2, p3: Vec2, t: f32) -> Vec2 {
    let t2 = t * t;
    let t3 = t2 * t;
    0.5 * (2.0 * p1
        + (p2 - p0) * t
        + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
        + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3)
}

/// Spline samples per segment between two waypoints, for walking the path
/// at constant speed.
const STEPS_PER_SEGMENT: usize = 300;

/// A camera walk: waypoints on the floor joined by a Catmull-Rom spline,
/// walked at constant speed at eye height, looking along the way and
/// around (less in corridors).
#[derive(Clone, Debug)]
pub struct CameraPath {
    waypoints: Vec<Vec2>,
    /// Arc length at each spline sample.
    lengths: Vec<f32>,
    /// Rectangles `[x0, y0, x1, y1]` where the camera looks around less.
    corridors: Vec<[f32; 4]>,
    /// Spline samples over the whole path.
    steps: usize,
}

impl CameraPath {
    /// A path through `waypoints` (at least two), looking around less
    /// inside `corridors`.
    pub fn new(waypoints: Vec<Vec2>, corridors: Vec<[f32; 4]>) -> CameraPath {
        let steps = STEPS_PER_SEGMENT * waypoints.len().saturating_sub(1);
        CameraPath::sampled(waypoints, corridors, steps)
    }

    fn sampled(waypoints: Vec<Vec2>, corridors: Vec<[f32; 4]>, steps: usize) -> CameraPath {
        assert!(waypoints.len() >= 2, "a path needs two waypoints");
        let mut path = CameraPath {
            waypoints,
            lengths: Vec::new(),
            corridors,
            steps,
        };
        let seg = path.segments();
        let mut lengths = vec![0.0f32; steps + 1];
        let mut prev = path.point(0.0);
        for (k, l) in lengths.iter_mut().enumerate().skip(1) {
            let p = path.point(k as f32 / steps as f32 * seg);
            *l = (p - prev).length();
            prev = p;
        }
        for k in 1..=steps {
            lengths[k] += lengths[k - 1];
        }
        path.lengths = lengths;
        path
    }

    /// The demo world's path: around room A, through the corridor, around
    /// room B, and back into room A.
    pub fn demo() -> CameraPath {
        // 4 000 samples, as the demo logs were always made with.
        CameraPath::sampled(
            WAYPOINTS.iter().map(|&p| Vec2::from(p)).collect(),
            vec![[5.0, 0.0, 9.0, 4.0]],
            4000,
        )
    }

    /// Length of one traversal, metres.
    pub fn length(&self) -> f32 {
        *self.lengths.last().expect("at least one sample")
    }

    fn segments(&self) -> f32 {
        (self.waypoints.len() - 1) as f32
    }

    fn point(&self, s: f32) -> Vec2 {
        let n = self.waypoints.len();
        let s = s.clamp(0.0, (n - 1) as f32 - 1e-4);
        let i = s.floor() as usize;
        let p = |k: isize| self.waypoints[(i as isize + k).clamp(0, n as isize - 1) as usize];
        catmull_rom(p(-1), p(0), p(1), p(2), s - i as f32)
    }

    /// The pose of frame `i` of `frames` spread over `laps` traversals,
    /// alternately forwards and backwards so the walk is continuous.
    pub fn pose(&self, i: usize, frames: usize, laps: usize) -> (Mat3, Vec3) {
        let laps = laps.max(1);
        let u = laps as f32 * i as f32 / (frames.max(2) - 1) as f32;
        let lap = (u.floor() as usize).min(laps - 1);
        let f = u - lap as f32;
        let backwards = lap % 2 == 1;
        self.pose_at(if backwards { 1.0 - f } else { f }, backwards)
    }

    /// The pose at fraction `f` of the path's length, looking along the
    /// direction of travel (`backwards`: towards the path's start).
    fn pose_at(&self, f: f32, backwards: bool) -> (Mat3, Vec3) {
        let steps = self.steps;
        let seg = self.segments();
        let target = self.length() * f.clamp(0.0, 1.0);
        let k = self.lengths.partition_point(|&l| l < target).min(steps);
        let s = k as f32 / steps as f32 * seg;
        let pos = self.point(s);
        let mut ahead = self.point((s + 0.05).min(seg)) - self.point((s - 0.05).max(0.0));
        if backwards {
            ahead = -ahead;
        }
        let mut yaw = ahead.y.atan2(ahead.x);
        // Look around while walking, less in corridors.
        let in_corridor = self
            .corridors
            .iter()
            .any(|c| (c[0]..c[2]).contains(&pos.x) && (c[1]..c[3]).contains(&pos.y));
        yaw += if in_corridor { 0.15 } else { 0.6 } * (s * 2.1).sin();
        let forward = Vec3::new(
            yaw.cos() * PITCH.cos(),
            yaw.sin() * PITCH.cos(),
            PITCH.sin(),
        );
        let right = forward.cross(Vec3::Z).normalize();
        let down = forward.cross(right);
        (
            Mat3::from_cols(right, down, forward),
            Vec3::new(pos.x, pos.y, EYE_HEIGHT),
        )
    }
}

/// Camera-to-world rotation (columns: camera x right, y down, z forward;
/// world z up) and position of frame `i` of `frames` on the demo path.
pub fn camera_pose(i: usize, frames: usize) -> (Mat3, Vec3) {
    camera_pose_laps(i, frames, 1)
}

/// The pose of frame `i` of `frames` spread over `laps` traversals of the
/// demo path, alternately forwards and backwards so the walk is continuous
/// (long runs revisit the same rooms again and again).
pub fn camera_pose_laps(i: usize, frames: usize, laps: usize) -> (Mat3, Vec3) {
    CameraPath::demo().pose(i, frames, laps)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn path_is_smooth_inside_the_building_and_visits_both_rooms() {
        let n = 400;
        let mut prev = camera_pose(0, n).1;
        let mut rooms = Vec::new();
        for i in 0..n {
            let (r, p) = camera_pose(i, n);
            assert!((r.determinant() - 1.0).abs() < 1e-4);
            assert!((r * Vec3::Y).z < 0.0, "camera y points down");
            assert!((p - prev).length() < 0.2, "frame {i} jumps");
            assert!(
                (0.3..13.7).contains(&p.x) && (0.3..3.7).contains(&p.y),
                "{p}"
            );
            prev = p;
            let room = if p.x < 5.0 {
                'A'
            } else if p.x > 9.0 {
                'B'
            } else {
                'c'
            };
            if rooms.last() != Some(&room) {
                rooms.push(room);
            }
        }
        assert_eq!(rooms, ['A', 'c', 'B', 'c', 'A']);
    }

    #[test]
    fn laps_walk_the_path_back_and_forth_without_jumps() {
        let (n, laps) = (1200, 3);
        let mut prev = camera_pose_laps(0, n, laps).1;
        let mut turns = 0;
        let mut last_dx = 0.0f32;
        for i in 1..n {
            let (r, p) = camera_pose_laps(i, n, laps);
            assert!((r.determinant() - 1.0).abs() < 1e-4);
            assert!((p - prev).length() < 0.2, "frame {i} jumps");
            // The camera looks roughly where it walks (except where it
            // turns round, at the ends of the path).
            let step = (p - prev).truncate();
            let lap_end = (1..laps).any(|l| (i as i64 - (l * n / laps) as i64).abs() <= 2);
            if step.length() > 1e-3 && !lap_end {
                let forward = (r * Vec3::Z).truncate().normalize();
                assert!(
                    forward.dot(step.normalize()) > -0.2,
                    "frame {i} walks backwards"
                );
            }
            let dx = p.x - prev.x;
            if dx.abs() > 1e-3 && last_dx.abs() > 1e-3 && dx.signum() != last_dx.signum() {
                turns += 1;
            }
            if dx.abs() > 1e-3 {
                last_dx = dx;
            }
            prev = p;
        }
        assert!(turns >= 2, "{turns} turns");
        assert_eq!(camera_pose_laps(0, n, laps).1, camera_pose(0, 400).1);
    }
}

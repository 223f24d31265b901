//! A building of N rooms for long walks (`gen-scene --rooms N`): two rows
//! of rooms along corridors, joined at each end by a hall, and a path that
//! walks through every room once and returns to where it started. A map of
//! it outgrows any fixed memory budget as N grows, and its start region is
//! seen again only at the very end.
//!
//! Row A's rooms span y ∈ [0, 4], row B's y ∈ [6, 10]; room `i` of a row
//! spans x ∈ [9i, 9i + 5], with 4 m corridors (1 m wide) between rooms.
//! The west hall spans x ∈ [-9, -4], the east hall starts 4 m after the
//! longer row; both span y ∈ [0, 10]. Walls are 2.5 m high, as in the
//! demo world.

use glam::{Vec2, Vec3};

use super::geometry::Shape;
use super::layout::{cuboid, rgb, Pattern, Scene};
use super::trajectory::CameraPath;

/// Room width along x, metres.
const ROOM: f32 = 5.0;
/// Distance from one room's start to the next's (room and corridor).
const PERIOD: f32 = 9.0;
/// Centre lines (y) of the two rows' corridors.
const ROW_Y: [f32; 2] = [2.0, 8.0];
/// The rows' interiors along y.
const ROW_SPAN: [[f32; 2]; 2] = [[0.0, 4.0], [6.0, 10.0]];
/// Half the width of a door and of a corridor.
const DOOR: f32 = 0.5;

/// Fewest rooms (one a row).
pub const MIN_ROOMS: usize = 2;
/// Most rooms: 5 km of building, far beyond any walk a log would hold.
pub const MAX_ROOMS: usize = 1000;

/// The building of `rooms` rooms (row A takes the odd one) and the walk
/// through it. `rooms` is clamped to [`MIN_ROOMS`]..=[`MAX_ROOMS`].
pub fn building(rooms: usize) -> (Scene, CameraPath) {
    let rooms = rooms.clamp(MIN_ROOMS, MAX_ROOMS);
    let per_row = [rooms.div_ceil(2), rooms / 2];
    let mut s = Scene::empty();
    let mut corridors = Vec::new();
    let east = PERIOD * per_row[0] as f32;
    let west_end = -PERIOD + ROOM;
    let walls = Scene::wall_thickness();
    for (row, &n) in per_row.iter().enumerate() {
        let y = ROW_Y[row];
        let [y0, y1] = ROW_SPAN[row];
        for i in 0..n {
            let x0 = PERIOD * i as f32;
            let x1 = x0 + ROOM;
            let id = (row * per_row[0] + i) as u32;
            s.room(
                &format!("room {}{}", ["A", "B"][row], i + 1),
                [x0, y0, x1, y1],
                &[(x0 - walls, y - DOOR, y + DOOR), (x1, y - DOOR, y + DOOR)],
                palette(id),
                100 + 10 * id,
            );
            furnish(&mut s, row, x0, id);
        }
        // Corridors between the rooms, from the west hall to the first,
        // and from the last to the east hall.
        let mut ends = vec![west_end];
        ends.extend((0..n).flat_map(|i| {
            let x0 = PERIOD * i as f32;
            [x0, x0 + ROOM]
        }));
        ends.push(east);
        for pair in ends.chunks_exact(2) {
            let (xa, xb) = (pair[0], pair[1]);
            s.room(
                "corridor",
                [xa + walls, y - DOOR, xb - walls, y + DOOR],
                &[(xa, y - DOOR, y + DOOR), (xb - walls, y - DOOR, y + DOOR)],
                [
                    rgb(150, 170, 190),
                    rgb(120, 140, 165),
                    rgb(90, 90, 95),
                    rgb(220, 220, 230),
                ],
                20,
            );
            corridors.push([xa, y - DOOR, xb, y + DOOR]);
        }
    }
    let doors = |x: f32| -> Vec<(f32, f32, f32)> {
        ROW_Y.iter().map(|&y| (x, y - DOOR, y + DOOR)).collect()
    };
    let hall_span = [ROW_SPAN[0][0], ROW_SPAN[1][1]];
    s.room(
        "west hall",
        [-PERIOD, hall_span[0], west_end, hall_span[1]],
        &doors(west_end),
        palette(9001),
        40,
    );
    s.room(
        "east hall",
        [east, hall_span[0], east + ROOM, hall_span[1]],
        &doors(east - walls),
        palette(9002),
        50,
    );
    (s, CameraPath::new(waypoints(per_row, east), corridors))
}

/// The walk: east along row A with a loop in each room, north through the
/// east hall, west along row B, south through the west hall, and back to
/// the start in the first room.
fn waypoints(per_row: [usize; 2], east: f32) -> Vec<Vec2> {
    let mut w = Vec::new();
    let room = |w: &mut Vec<Vec2>, x0: f32, row: usize| {
        let (y, s) = (ROW_Y[row], if row == 0 { 1.0 } else { -1.0 });
        // Row B is walked westwards: the same loop, mirrored.
        let loop_ = [(0.5, 0.0), (1.4, -0.7), (2.5, 0.8), (3.6, -0.7), (4.5, 0.0)];
        let pts: Vec<Vec2> = loop_
            .iter()
            .map(|&(dx, dy)| match row {
                0 => Vec2::new(x0 + dx, y + dy),
                _ => Vec2::new(x0 + ROOM - dx, y + s * dy),
            })
            .collect();
        w.extend(pts);
    };
    for i in 0..per_row[0] {
        room(&mut w, PERIOD * i as f32, 0);
    }
    let hall = |x: f32| {
        [
            Vec2::new(x, ROW_Y[0] + 1.0),
            Vec2::new(x, 5.0),
            Vec2::new(x, ROW_Y[1] - 1.0),
        ]
    };
    w.push(Vec2::new(east + 0.6, ROW_Y[0]));
    let up = hall(east + ROOM / 2.0);
    w.extend(up);
    w.push(Vec2::new(east + 0.6, ROW_Y[1]));
    for i in (0..per_row[1]).rev() {
        room(&mut w, PERIOD * i as f32, 1);
    }
    let west = -PERIOD + ROOM;
    w.push(Vec2::new(west - 0.6, ROW_Y[1]));
    let mut down = hall(-PERIOD + ROOM / 2.0);
    down.reverse();
    w.extend(down);
    w.push(Vec2::new(west - 0.6, ROW_Y[0]));
    // Back where the walk began.
    w.push(w[0]);
    w
}

/// A room's colours, varied by its number.
fn palette(id: u32) -> [Vec3; 4] {
    let h = |k: u32| hash01(id, k);
    let wall = Vec3::new(0.55 + 0.35 * h(1), 0.55 + 0.35 * h(2), 0.55 + 0.35 * h(3));
    let floor = Vec3::new(0.3 + 0.3 * h(4), 0.25 + 0.25 * h(5), 0.2 + 0.2 * h(6));
    [wall, wall * 0.8, floor, Vec3::splat(0.88 + 0.08 * h(7))]
}

/// A number in [0, 1) from a room and a salt.
fn hash01(id: u32, salt: u32) -> f32 {
    let mut h = id.wrapping_mul(0x9e37_79b9) ^ salt.wrapping_mul(0x85eb_ca6b);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Three objects against a room's long walls, clear of the walk: a table
/// or cabinet on the far wall, and a ball, plant pot or lamp near the
/// other wall's corner.
fn furnish(s: &mut Scene, row: usize, x0: f32, id: u32) {
    let [y0, y1] = ROW_SPAN[row];
    let h = |k: u32| hash01(id, k);
    let name = |what: &str| format!("{what} {id}");
    let along = x0 + 0.4 + 2.6 * h(10);
    // A table or a cabinet: a box of its own size and colours.
    let (class, what, [width, depth, height], base, accent, pattern) = if h(11) < 0.5 {
        let (a, b) = (rgb(150, 100, 55), rgb(115, 75, 40));
        (4, "table", [1.2, 0.6, 0.75], a, b, Pattern::Stripes(0.08))
    } else {
        let (a, b) = (rgb(90, 110, 160), rgb(60, 80, 120));
        (6, "cabinet", [1.0, 0.5, 1.6], a, b, Pattern::Checker(0.25))
    };
    s.object(
        class,
        &name(what),
        cuboid(
            [along, y1 - 0.05 - depth, 0.0],
            [along + width, y1 - 0.05, height],
        ),
        base,
        accent,
        pattern,
    );
    s.object(
        5,
        &name("chair"),
        cuboid([x0 + 3.8, y0 + 0.15, 0.0], [x0 + 4.25, y0 + 0.6, 0.9]),
        rgb(200, 60, 50) * (0.6 + 0.4 * h(12)),
        rgb(150, 40, 35),
        Pattern::Noise(0.15),
    );
    let corner = Vec3::new(x0 + 0.5, y0 + 0.5, 0.0);
    if h(13) < 1.0 / 3.0 {
        s.object(
            9,
            &name("ball"),
            Shape::Sphere {
                centre: corner + Vec3::Z * 0.25,
                radius: 0.25,
            },
            rgb(230, 120, 30),
            rgb(250, 250, 250),
            Pattern::Stripes(0.1),
        );
        return;
    }
    // A plant pot or a lamp: a cylinder of its own size and colours.
    let (class, what, radius, height, base, accent, pattern) = if h(13) < 2.0 / 3.0 {
        let (a, b) = (rgb(60, 150, 70), rgb(40, 100, 45));
        (8, "plant pot", 0.25, 0.7, a, b, Pattern::Noise(0.1))
    } else {
        let (a, b) = (rgb(240, 220, 90), rgb(200, 170, 50));
        (7, "lamp", 0.15, 1.5, a, b, Pattern::Stripes(0.05))
    };
    s.object(
        class,
        &name(what),
        Shape::Cylinder {
            base: corner,
            radius,
            height,
        },
        base,
        accent,
        pattern,
    );
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::Shape;
    use crate::render::render;

    /// Distance on the floor plan from `p` to the nearest wall or object.
    fn clearance(scene: &Scene, p: Vec2) -> f32 {
        scene
            .surfaces
            .iter()
            .filter(|s| s.class != 2 && s.class != 3)
            .map(|s| match s.shape {
                Shape::Box { min, max } => {
                    let q = p.clamp(min.truncate(), max.truncate());
                    (q - p).length()
                }
                Shape::Cylinder { base, radius, .. } => (base.truncate() - p).length() - radius,
                Shape::Sphere { centre, radius } => (centre.truncate() - p).length() - radius,
            })
            .fold(f32::INFINITY, f32::min)
    }

    #[test]
    fn twenty_rooms_make_a_long_walk_through_every_room_back_to_its_start() {
        let (scene, path) = building(20);
        assert!(path.length() >= 100.0, "{} m", path.length());
        let frames = (path.length() * 10.0) as usize;
        let start = path.pose(0, frames, 1).1;
        let end = path.pose(frames - 1, frames, 1).1;
        assert!((start - end).length() < 1e-3, "{start} → {end}");
        let mut prev = start;
        let mut visited = std::collections::BTreeSet::new();
        for i in 0..frames {
            let (r, p) = path.pose(i, frames, 1);
            assert!((r.determinant() - 1.0).abs() < 1e-4);
            assert!((p - prev).length() < 0.2, "frame {i} jumps");
            let c = clearance(&scene, p.truncate());
            assert!(c > 0.2, "frame {i} at {p} is {c} m from a wall");
            prev = p;
            // Which room of which row the camera is in.
            for (row, span) in ROW_SPAN.iter().enumerate() {
                let room = (p.x / PERIOD).floor();
                let inside = p.x - room * PERIOD;
                let in_row = (0.0..10.0).contains(&room);
                if in_row
                    && (span[0]..span[1]).contains(&p.y)
                    && (0.5..ROOM - 0.5).contains(&inside)
                {
                    visited.insert((row, room as i32));
                }
            }
        }
        let want: std::collections::BTreeSet<(usize, i32)> = (0..2)
            .flat_map(|row| (0..10).map(move |i| (row, i)))
            .collect();
        assert_eq!(visited, want);
        // 20 rooms, 2 halls, 22 corridors (11 a row).
        let names = |what: &str| {
            scene
                .instances
                .iter()
                .filter(|i| i.name.ends_with(" wall") && i.name.contains(what))
                .count()
        };
        assert_eq!(names("room"), 20);
        assert_eq!(names("hall"), 2);
        assert_eq!(names("corridor"), 22);
        assert_eq!(scene.object_count(), 60);
    }

    #[test]
    fn an_odd_count_and_the_fewest_rooms_are_closed_buildings() {
        for rooms in [MIN_ROOMS, 3, 7] {
            let (scene, path) = building(rooms);
            let frames = (path.length() * 4.0) as usize;
            for i in (0..frames).step_by(7) {
                let (r, p) = path.pose(i, frames, 1);
                assert!(clearance(&scene, p.truncate()) > 0.2, "{rooms} rooms, {p}");
                // Every ray meets a surface: walls, floor and ceiling close
                // the building.
                let view = render(&scene, r, p, 32, 24);
                assert!(
                    view.depth_mm.iter().all(|&d| d > 0),
                    "{rooms} rooms: a ray at {p} escapes"
                );
            }
        }
    }
}

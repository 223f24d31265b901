//! The demo world: two rooms joined by a corridor (z up, metres), fourteen
//! labelled objects (two of them thin, against a wall), and their textures.
//!
//! Room A spans x ∈ [0, 5], the corridor x ∈ [5, 9] (y ∈ [1.5, 2.5]), room
//! B x ∈ [9, 14]; rooms are 4 m deep (y ∈ [0, 4]) and 2.5 m high.

use glam::{Vec2, Vec3};

use super::geometry::Shape;

/// Class names by id (0 = unlabelled), as written to the vocabulary.
pub const CLASSES: [&str; 12] = [
    "unlabelled",
    "wall",
    "floor",
    "ceiling",
    "table",
    "chair",
    "cabinet",
    "lamp",
    "plant pot",
    "ball",
    "door",
    "picture frame",
];

/// How a surface is coloured.
#[derive(Clone, Copy, Debug)]
pub enum Pattern {
    /// Square tiles of the given size.
    Checker(f32),
    /// Stripes along u of the given width.
    Stripes(f32),
    /// Smooth value noise of the given feature size.
    Noise(f32),
}

/// A two-colour procedural texture with a little noise on top, so every
/// surface has gradients for photometric optimisation.
#[derive(Clone, Copy, Debug)]
pub struct Texture {
    /// Main colour (linear 0..1).
    pub base: Vec3,
    /// Second colour.
    pub accent: Vec3,
    /// Layout of the two.
    pub pattern: Pattern,
    /// Noise seed.
    pub seed: u32,
}

fn hash(x: i32, y: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ seed.wrapping_mul(0xcb1a_b31f);
    h ^= h >> 13;
    h = h.wrapping_mul(0x5bd1_e995);
    h ^= h >> 15;
    (h & 0x00ff_ffff) as f32 / 16_777_216.0
}

/// Smooth value noise in [0, 1).
fn value_noise(p: Vec2, seed: u32) -> f32 {
    let i = p.floor();
    let f = p - i;
    let s = f * f * (Vec2::splat(3.0) - 2.0 * f);
    let (x, y) = (i.x as i32, i.y as i32);
    let a = hash(x, y, seed);
    let b = hash(x + 1, y, seed);
    let c = hash(x, y + 1, seed);
    let d = hash(x + 1, y + 1, seed);
    let top = a + (b - a) * s.x;
    let bottom = c + (d - c) * s.x;
    top + (bottom - top) * s.y
}

impl Texture {
    /// Colour at surface coordinates `uv` (metres).
    pub fn colour(&self, uv: Vec2) -> Vec3 {
        let mix = match self.pattern {
            Pattern::Checker(size) => {
                let c = (uv / size).floor();
                ((c.x + c.y) as i32).rem_euclid(2) as f32
            }
            Pattern::Stripes(width) => ((uv.x / width).floor() as i32).rem_euclid(2) as f32,
            Pattern::Noise(size) => value_noise(uv / size, self.seed),
        };
        let grain = value_noise(uv * 9.0, self.seed ^ 0x9e37) - 0.5;
        (self.base.lerp(self.accent, mix) + Vec3::splat(0.12 * grain)).clamp(Vec3::ZERO, Vec3::ONE)
    }
}

/// A labelled solid of the scene.
#[derive(Clone, Copy, Debug)]
pub struct Surface {
    /// Geometry.
    pub shape: Shape,
    /// Class id (index into [`CLASSES`]).
    pub class: u16,
    /// Instance id (index into [`Scene::instances`], from 1).
    pub instance: u16,
    /// Colouring.
    pub texture: Texture,
}

/// One labelled thing (an object, or the walls/floor/ceiling of a room).
#[derive(Clone, Debug)]
pub struct Instance {
    /// Class id.
    pub class: u16,
    /// Human-readable name, e.g. `room A wall`.
    pub name: String,
}

/// The whole world.
pub struct Scene {
    /// Every solid.
    pub surfaces: Vec<Surface>,
    /// Instances by id; index 0 is "nothing".
    pub instances: Vec<Instance>,
}

/// The ceiling height.
pub const HEIGHT: f32 = 2.5;
const WALL: f32 = 0.1;

pub(crate) fn rgb(r: u8, g: u8, b: u8) -> Vec3 {
    Vec3::new(r as f32, g as f32, b as f32) / 255.0
}

pub(crate) fn cuboid(min: [f32; 3], max: [f32; 3]) -> Shape {
    Shape::Box {
        min: Vec3::from(min),
        max: Vec3::from(max),
    }
}

impl Scene {
    fn instance(&mut self, class: u16, name: String) -> u16 {
        self.instances.push(Instance { class, name });
        (self.instances.len() - 1) as u16
    }

    fn add(&mut self, shape: Shape, class: u16, instance: u16, texture: Texture) {
        self.surfaces.push(Surface {
            shape,
            class,
            instance,
            texture,
        });
    }

    /// Walls, floor and ceiling of one room-like space: `extent` is its
    /// interior (x0, y0, x1, y1); `openings` are y-ranges cut into its
    /// x0/x1 walls (doors to the corridor).
    pub(crate) fn room(
        &mut self,
        name: &str,
        extent: [f32; 4],
        openings: &[(f32, f32, f32)],
        palette: [Vec3; 4],
        seed: u32,
    ) {
        let [x0, y0, x1, y1] = extent;
        let wall = self.instance(1, format!("{name} wall"));
        let floor = self.instance(2, format!("{name} floor"));
        let ceiling = self.instance(3, format!("{name} ceiling"));
        let wall_tex = Texture {
            base: palette[0],
            accent: palette[1],
            pattern: Pattern::Stripes(0.35),
            seed,
        };
        // Walls along y (at y0 and y1) are full length.
        for y in [y0 - WALL, y1] {
            self.add(
                cuboid([x0 - WALL, y, 0.0], [x1 + WALL, y + WALL, HEIGHT]),
                1,
                wall,
                wall_tex,
            );
        }
        // Walls along x, with door openings.
        for x in [x0 - WALL, x1] {
            let mut start = y0;
            let mut cuts: Vec<(f32, f32)> = openings
                .iter()
                .filter(|o| (o.0 - x).abs() < 0.2 || (o.0 - (x + WALL)).abs() < 0.2)
                .map(|o| (o.1, o.2))
                .collect();
            cuts.sort_by(|a, b| a.0.total_cmp(&b.0));
            for (a, b) in cuts {
                if a > start {
                    self.add(
                        cuboid([x, start, 0.0], [x + WALL, a, HEIGHT]),
                        1,
                        wall,
                        wall_tex,
                    );
                }
                start = b;
            }
            if y1 > start {
                self.add(
                    cuboid([x, start, 0.0], [x + WALL, y1, HEIGHT]),
                    1,
                    wall,
                    wall_tex,
                );
            }
        }
        self.add(
            cuboid([x0 - WALL, y0 - WALL, -WALL], [x1 + WALL, y1 + WALL, 0.0]),
            2,
            floor,
            Texture {
                base: palette[2],
                accent: palette[2] * 0.6,
                pattern: Pattern::Checker(0.5),
                seed: seed + 1,
            },
        );
        self.add(
            cuboid(
                [x0 - WALL, y0 - WALL, HEIGHT],
                [x1 + WALL, y1 + WALL, HEIGHT + WALL],
            ),
            3,
            ceiling,
            Texture {
                base: palette[3],
                accent: palette[3] * 0.85,
                pattern: Pattern::Noise(0.6),
                seed: seed + 2,
            },
        );
    }

    pub(crate) fn object(
        &mut self,
        class: u16,
        name: &str,
        shape: Shape,
        base: Vec3,
        accent: Vec3,
        pattern: Pattern,
    ) {
        let id = self.instance(class, name.to_string());
        let seed = 1000 + id as u32;
        self.add(
            shape,
            class,
            id,
            Texture {
                base,
                accent,
                pattern,
                seed,
            },
        );
    }

    /// A world with nothing in it yet (instance 0 is "nothing").
    pub(crate) fn empty() -> Scene {
        Scene {
            surfaces: Vec::new(),
            instances: vec![Instance {
                class: 0,
                name: "nothing".into(),
            }],
        }
    }

    /// Thickness of walls, floors and ceilings, metres.
    pub(crate) fn wall_thickness() -> f32 {
        WALL
    }

    /// The demo world. It has no random parts: seeds only change the
    /// trajectory noise and the embeddings.
    //
    // Long because it is data: every surface and object of the demo world
    // in one place, to be read as a floor plan.
    pub fn two_rooms() -> Scene {
        let mut s = Scene::empty();
        let door = (1.5, 2.5);
        s.room(
            "room A",
            [0.0, 0.0, 5.0, 4.0],
            &[(5.0, door.0, door.1)],
            [
                rgb(205, 190, 160),
                rgb(170, 150, 120),
                rgb(140, 95, 60),
                rgb(235, 235, 225),
            ],
            10,
        );
        s.room(
            "corridor",
            [5.0 + WALL, door.0, 9.0 - WALL, door.1],
            &[(5.0, door.0, door.1), (9.0 - WALL, door.0, door.1)],
            [
                rgb(150, 170, 190),
                rgb(120, 140, 165),
                rgb(90, 90, 95),
                rgb(220, 220, 230),
            ],
            20,
        );
        s.room(
            "room B",
            [9.0, 0.0, 14.0, 4.0],
            &[(9.0 - WALL, door.0, door.1)],
            [
                rgb(170, 200, 165),
                rgb(135, 170, 130),
                rgb(110, 110, 130),
                rgb(240, 236, 220),
            ],
            30,
        );
        let wood = (rgb(150, 100, 55), rgb(115, 75, 40));
        // Room A.
        s.object(
            4,
            "table A",
            cuboid([1.6, 3.2, 0.0], [2.8, 3.8, 0.75]),
            wood.0,
            wood.1,
            Pattern::Stripes(0.08),
        );
        s.object(
            5,
            "chair A",
            cuboid([3.2, 3.3, 0.0], [3.65, 3.75, 0.9]),
            rgb(200, 60, 50),
            rgb(150, 40, 35),
            Pattern::Noise(0.15),
        );
        s.object(
            6,
            "cabinet A",
            cuboid([0.1, 0.3, 0.0], [0.6, 1.3, 1.6]),
            rgb(90, 110, 160),
            rgb(60, 80, 120),
            Pattern::Checker(0.25),
        );
        s.object(
            7,
            "lamp A",
            Shape::Cylinder {
                base: Vec3::new(4.5, 0.5, 0.0),
                radius: 0.15,
                height: 1.5,
            },
            rgb(240, 220, 90),
            rgb(200, 170, 50),
            Pattern::Stripes(0.05),
        );
        s.object(
            8,
            "plant pot A",
            Shape::Cylinder {
                base: Vec3::new(0.5, 3.4, 0.0),
                radius: 0.25,
                height: 0.7,
            },
            rgb(60, 150, 70),
            rgb(40, 100, 45),
            Pattern::Noise(0.1),
        );
        // A thin object on a wall: 2.5 cm proud, so depth barely tells it
        // from the wall and only colour and embeddings separate them.
        s.object(
            11,
            "picture frame A",
            cuboid([3.3, 3.975, 1.2], [4.2, 4.0, 1.8]),
            rgb(60, 90, 170),
            rgb(230, 200, 80),
            Pattern::Noise(0.08),
        );
        s.object(
            9,
            "ball A",
            Shape::Sphere {
                centre: Vec3::new(2.5, 0.5, 0.25),
                radius: 0.25,
            },
            rgb(230, 120, 30),
            rgb(250, 250, 250),
            Pattern::Stripes(0.1),
        );
        // Room B.
        s.object(
            4,
            "table B",
            cuboid([10.5, 0.2, 0.0], [11.7, 0.8, 0.75]),
            wood.0 * 0.8,
            wood.1 * 0.8,
            Pattern::Stripes(0.08),
        );
        s.object(
            5,
            "chair B",
            cuboid([12.0, 0.25, 0.0], [12.45, 0.7, 0.9]),
            rgb(60, 60, 200),
            rgb(40, 40, 140),
            Pattern::Noise(0.15),
        );
        s.object(
            6,
            "cabinet B",
            cuboid([13.4, 2.5, 0.0], [13.9, 3.6, 1.8]),
            rgb(180, 180, 185),
            rgb(130, 130, 140),
            Pattern::Checker(0.25),
        );
        s.object(
            7,
            "lamp B",
            Shape::Cylinder {
                base: Vec3::new(9.5, 3.5, 0.0),
                radius: 0.15,
                height: 1.5,
            },
            rgb(250, 240, 150),
            rgb(210, 190, 80),
            Pattern::Stripes(0.05),
        );
        s.object(
            8,
            "plant pot B",
            Shape::Cylinder {
                base: Vec3::new(13.5, 0.5, 0.0),
                radius: 0.25,
                height: 0.7,
            },
            rgb(40, 130, 90),
            rgb(25, 90, 60),
            Pattern::Noise(0.1),
        );
        // A closed door, 4 cm proud of the wall.
        s.object(
            10,
            "door B",
            cuboid([12.1, 3.96, 0.0], [13.0, 4.0, 2.05]),
            rgb(120, 80, 60),
            rgb(95, 60, 45),
            Pattern::Stripes(0.3),
        );
        s.object(
            9,
            "ball B",
            Shape::Sphere {
                centre: Vec3::new(11.5, 3.4, 0.3),
                radius: 0.3,
            },
            rgb(200, 40, 160),
            rgb(250, 250, 250),
            Pattern::Checker(0.15),
        );
        s
    }

    /// Number of labelled objects (instances that are not structure).
    pub fn object_count(&self) -> usize {
        self.instances.iter().filter(|i| i.class >= 4).count()
    }
}

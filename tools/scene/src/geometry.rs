//! Ray casting against the few primitive shapes the demo scene is built
//! from (axis-aligned boxes, upright cylinders, spheres).

use glam::{Vec2, Vec3};

/// A solid primitive.
#[derive(Clone, Copy, Debug)]
pub enum Shape {
    /// Axis-aligned box.
    Box { min: Vec3, max: Vec3 },
    /// Cylinder standing on `base` (centre of its bottom disc), axis +z.
    Cylinder {
        base: Vec3,
        radius: f32,
        height: f32,
    },
    /// Sphere.
    Sphere { centre: Vec3, radius: f32 },
}

/// Where a ray meets a shape.
#[derive(Clone, Copy, Debug)]
pub struct Hit {
    /// Ray parameter (distance in units of the ray direction's length).
    pub t: f32,
    /// Outward unit normal.
    pub normal: Vec3,
    /// Surface coordinates in metres, for texturing.
    pub uv: Vec2,
}

/// Texture coordinates on a face with the given normal axis: the two
/// world coordinates along the face.
fn planar_uv(p: Vec3, axis: usize) -> Vec2 {
    match axis {
        0 => Vec2::new(p.y, p.z),
        1 => Vec2::new(p.x, p.z),
        _ => Vec2::new(p.x, p.y),
    }
}

impl Shape {
    /// The axis-aligned box that holds the shape: (min, max).
    pub fn bounds(&self) -> (Vec3, Vec3) {
        match *self {
            Shape::Box { min, max } => (min, max),
            Shape::Sphere { centre, radius } => (centre - radius, centre + radius),
            Shape::Cylinder {
                base,
                radius,
                height,
            } => (
                base - Vec3::new(radius, radius, 0.0),
                base + Vec3::new(radius, radius, height),
            ),
        }
    }

    /// The nearest hit with `t > t_min`, if any.
    pub fn intersect(&self, origin: Vec3, dir: Vec3, t_min: f32) -> Option<Hit> {
        match *self {
            Shape::Box { min, max } => hit_box(min, max, origin, dir, t_min),
            Shape::Sphere { centre, radius } => hit_sphere(centre, radius, origin, dir, t_min),
            Shape::Cylinder {
                base,
                radius,
                height,
            } => hit_cylinder(base, radius, height, origin, dir, t_min),
        }
    }
}

/// The slab test against an axis-aligned box.
fn hit_box(min: Vec3, max: Vec3, origin: Vec3, dir: Vec3, t_min: f32) -> Option<Hit> {
    let inv = dir.recip();
    let t0 = (min - origin) * inv;
    let t1 = (max - origin) * inv;
    let near = t0.min(t1);
    let far = t0.max(t1);
    let t_near = near.max_element();
    let t_far = far.min_element();
    if t_near > t_far || t_far <= t_min {
        return None;
    }
    // Rays starting inside a box see its inside faces (walls
    // are seen from the room side either way).
    let (t, axis, sign) = if t_near > t_min {
        let axis = (0..3)
            .max_by(|&a, &b| near[a].total_cmp(&near[b]))
            .unwrap_or(0);
        (t_near, axis, -dir[axis].signum())
    } else {
        let axis = (0..3)
            .min_by(|&a, &b| far[a].total_cmp(&far[b]))
            .unwrap_or(0);
        (t_far, axis, -dir[axis].signum())
    };
    let mut normal = Vec3::ZERO;
    normal[axis] = sign;
    Some(Hit {
        t,
        normal,
        uv: planar_uv(origin + dir * t, axis),
    })
}

fn hit_sphere(centre: Vec3, radius: f32, origin: Vec3, dir: Vec3, t_min: f32) -> Option<Hit> {
    let oc = origin - centre;
    let a = dir.dot(dir);
    let b = oc.dot(dir);
    let c = oc.dot(oc) - radius * radius;
    let disc = b * b - a * c;
    if disc < 0.0 {
        return None;
    }
    let s = disc.sqrt();
    let t = [(-b - s) / a, (-b + s) / a]
        .into_iter()
        .find(|&t| t > t_min)?;
    let p = origin + dir * t;
    let n = (p - centre) / radius;
    Some(Hit {
        t,
        normal: n,
        uv: Vec2::new(n.y.atan2(n.x) * radius, n.z.asin() * radius),
    })
}

/// A closed cylinder standing on `base` along +z: its side and two caps.
fn hit_cylinder(
    base: Vec3,
    radius: f32,
    height: f32,
    origin: Vec3,
    dir: Vec3,
    t_min: f32,
) -> Option<Hit> {
    let mut best: Option<Hit> = None;
    let mut consider = |h: Hit| {
        if h.t > t_min && best.is_none_or(|b| h.t < b.t) {
            best = Some(h);
        }
    };
    // Side.
    let o = origin - base;
    let a = dir.x * dir.x + dir.y * dir.y;
    if a > 1e-12 {
        let b = o.x * dir.x + o.y * dir.y;
        let c = o.x * o.x + o.y * o.y - radius * radius;
        let disc = b * b - a * c;
        if disc >= 0.0 {
            let s = disc.sqrt();
            for t in [(-b - s) / a, (-b + s) / a] {
                let p = o + dir * t;
                if (0.0..=height).contains(&p.z) {
                    let n = Vec3::new(p.x, p.y, 0.0) / radius;
                    consider(Hit {
                        t,
                        normal: n,
                        uv: Vec2::new(p.y.atan2(p.x) * radius, p.z),
                    });
                }
            }
        }
    }
    // Caps.
    if dir.z.abs() > 1e-12 {
        for (z, nz) in [(0.0, -1.0), (height, 1.0)] {
            let t = (z - o.z) / dir.z;
            let p = o + dir * t;
            if p.x * p.x + p.y * p.y <= radius * radius {
                consider(Hit {
                    t,
                    normal: Vec3::new(0.0, 0.0, nz),
                    uv: Vec2::new(p.x, p.y),
                });
            }
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hits_are_on_the_surface_with_outward_normals() {
        let shapes = [
            Shape::Box {
                min: Vec3::new(1.0, -1.0, -1.0),
                max: Vec3::new(2.0, 1.0, 1.0),
            },
            Shape::Sphere {
                centre: Vec3::new(3.0, 0.0, 0.0),
                radius: 0.5,
            },
            Shape::Cylinder {
                base: Vec3::new(3.0, 0.0, -1.0),
                radius: 0.5,
                height: 2.0,
            },
        ];
        let expect_t = [1.0, 2.5, 2.5];
        for (s, want) in shapes.iter().zip(expect_t) {
            let h = s.intersect(Vec3::ZERO, Vec3::X, 1e-4).unwrap();
            assert!((h.t - want).abs() < 1e-5, "{s:?}: {h:?}");
            assert!((h.normal - -Vec3::X).length() < 1e-5, "{s:?}: {h:?}");
            assert!(s.intersect(Vec3::ZERO, -Vec3::X, 1e-4).is_none());
        }
        // From inside a box the far face is hit, normal facing the ray.
        let room = Shape::Box {
            min: Vec3::splat(-1.0),
            max: Vec3::splat(1.0),
        };
        let h = room
            .intersect(Vec3::ZERO, Vec3::new(0.0, 0.0, 2.0), 1e-4)
            .unwrap();
        assert!((h.t - 0.5).abs() < 1e-6);
        assert_eq!(h.normal, -Vec3::Z);
        // Cylinder caps from above.
        let cyl = shapes[2];
        let h = cyl
            .intersect(Vec3::new(3.0, 0.1, 5.0), -Vec3::Z, 1e-4)
            .unwrap();
        assert!((h.t - 4.0).abs() < 1e-5 && h.normal == Vec3::Z);
    }
}

//! Voxel keys, the identity of a Gaussian in the global map, and the
//! blocks they group into.

use glam::DVec3;

/// Voxels per edge of a block: the cube the spatial index groups Gaussians
/// by, and the unit the GPU window pages in and out (see
/// `LocalWindow`). At the default 1 cm voxel a block
/// is 0.64 m. Against the default 6 m radius, the 4 300 blocks that touch
/// the sphere hold 1.24 times its volume, and a plan walks the ~10 600
/// blocks of its bounding cube, well under a millisecond. Edges of 32 and
/// 16 voxels would bring the overshoot to 1.12 and 1.06 but multiply the
/// blocks to walk (and to keep a row list for) by 8 and 64; 128 would
/// overshoot by 1.56.
pub const BLOCK_VOXELS: i32 = 64;

/// A hash map keyed by voxel: every window sync plans, gathers and writes
/// back hundreds of thousands of keys, and SipHash (the standard default,
/// hardened against adversarial keys, which map coordinates are not)
/// spent more time hashing them than the GPU spent moving the Gaussians.
pub type KeyMap<V> = rustc_hash::FxHashMap<VoxelKey, V>;

/// A set of voxels (see [`KeyMap`]).
pub type KeySet = rustc_hash::FxHashSet<VoxelKey>;

/// Integer coordinates of a voxel of edge `s_v`: `floor(p / s_v)`.
///
/// ```
/// use glam::DVec3;
/// use latentam_core::map::{GlobalMap, VoxelKey};
///
/// let map = GlobalMap::new(0.01);
/// let key = VoxelKey::of(DVec3::new(0.015, -0.001, 2.0), map.voxel_size()).expect("a finite point");
/// assert_eq!((key.x, key.y, key.z), (1, -1, 200));
/// // Gaussians in that voxel or the 26 around it.
/// let near = key.neighbourhood().filter_map(|k| map.get(k)).count();
/// assert_eq!(near, 0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct VoxelKey {
    /// x index.
    pub x: i32,
    /// y index.
    pub y: i32,
    /// z index.
    pub z: i32,
}

impl VoxelKey {
    /// The voxel holding point `p` (metres), or `None` for a non-finite
    /// point or one beyond the `i32` index range.
    pub fn of(p: DVec3, voxel_size: f64) -> Option<Self> {
        let v = (p / voxel_size).floor();
        let ok = |c: f64| c.is_finite() && c >= i32::MIN as f64 && c <= i32::MAX as f64;
        (ok(v.x) && ok(v.y) && ok(v.z)).then_some(VoxelKey {
            x: v.x as i32,
            y: v.y as i32,
            z: v.z as i32,
        })
    }

    /// Centre of the voxel, metres.
    pub fn centre(self, voxel_size: f64) -> DVec3 {
        (DVec3::new(self.x as f64, self.y as f64, self.z as f64) + 0.5) * voxel_size
    }

    /// The key `d` voxels away along each axis.
    pub fn offset(self, dx: i32, dy: i32, dz: i32) -> Self {
        VoxelKey {
            x: self.x.saturating_add(dx),
            y: self.y.saturating_add(dy),
            z: self.z.saturating_add(dz),
        }
    }

    /// The voxel and its 26 neighbours.
    pub fn neighbourhood(self) -> impl Iterator<Item = VoxelKey> {
        (-1..=1).flat_map(move |dx| {
            (-1..=1).flat_map(move |dy| (-1..=1).map(move |dz| self.offset(dx, dy, dz)))
        })
    }

    /// The key of the coarser cell of `ratio³` voxels holding this one.
    pub fn coarse(self, ratio: i32) -> VoxelKey {
        VoxelKey {
            x: self.x.div_euclid(ratio),
            y: self.y.div_euclid(ratio),
            z: self.z.div_euclid(ratio),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_floor_and_centres_round_trip() {
        let k = VoxelKey::of(DVec3::new(0.015, -0.001, 2.0), 0.01).unwrap();
        assert_eq!((k.x, k.y, k.z), (1, -1, 200));
        let c = k.centre(0.01);
        assert!((c - DVec3::new(0.015, -0.005, 2.005)).length() < 1e-12);
        assert_eq!(VoxelKey::of(c, 0.01), Some(k));
        assert!(VoxelKey::of(DVec3::new(f64::NAN, 0.0, 0.0), 0.01).is_none());
        assert!(VoxelKey::of(DVec3::new(1e30, 0.0, 0.0), 0.01).is_none());
        assert_eq!(k.neighbourhood().count(), 27);
        assert_eq!(
            VoxelKey {
                x: -1,
                y: 99,
                z: 100
            }
            .coarse(100),
            VoxelKey { x: -1, y: 0, z: 1 }
        );
    }
}

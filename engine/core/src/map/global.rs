//! The global map: every Gaussian, on the CPU, keyed by its voxel.

use glam::DVec3;

pub use super::gaussian::Gaussian;
use super::spill::{SpillFile, Spilled};
pub use super::voxel::BLOCK_VOXELS;
use super::voxel::{KeyMap, VoxelKey};
use latentam_base::Result;

/// Voxels per edge of the occupancy grid used for overlap tests: seeds are
/// centimetres apart, so "is this surface mapped" is asked at a few voxels.
pub const OCCUPANCY_VOXELS: i32 = 4;

/// Cell edges (in voxels) of the occupancy grids: "is there surface within
/// about d" is asked at the level matching d (see
/// [`GlobalMap::is_mapped_within`]). Level 1 (`OCCUPANCY_VOXELS`) also
/// answers [`GlobalMap::is_near_occupied`].
const OCCUPANCY_LEVELS: [i32; 4] = [2, OCCUPANCY_VOXELS, 8, 16];

/// The Gaussians of one block of the global map, stored together: paging
/// moves blocks, so a block that comes into the window is read as one run
/// and a block is the unit a later tier (disk) would move whole.
///
/// The arrays are in insertion order; a removal moves the block's last
/// Gaussian into the hole.
#[derive(Clone, Debug, Default)]
pub struct Block {
    keys: Vec<VoxelKey>,
    gaussians: Vec<Gaussian>,
    /// Each voxel's index in the arrays, by its place in the block
    /// ([`in_block`]): a block's own index is small and local, where one
    /// map for every voxel grew with the map and missed the cache on
    /// every lookup.
    slot: rustc_hash::FxHashMap<u32, u32>,
    /// When the map last used it ([`GlobalMap::touch`]): the least
    /// recently used blocks are spilled first.
    used: u64,
}

impl Block {
    /// The voxel keys, in the order of [`Block::gaussians`].
    pub fn keys(&self) -> &[VoxelKey] {
        &self.keys
    }

    /// The Gaussians, in the order of [`Block::keys`].
    pub fn gaussians(&self) -> &[Gaussian] {
        &self.gaussians
    }

    /// Gaussians in the block.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    /// Whether the block holds none (a map never keeps an empty block).
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    fn index_of(&self, key: VoxelKey) -> Option<usize> {
        self.slot.get(&in_block(key)).map(|&i| i as usize)
    }

    /// Approximate heap bytes.
    fn bytes(&self) -> usize {
        self.keys.capacity() * size_of::<VoxelKey>()
            + self.gaussians.capacity() * size_of::<Gaussian>()
            // A hashbrown entry and its control byte.
            + self.slot.capacity() * (size_of::<(u32, u32)>() + 1)
    }
}

/// A voxel's place inside its block: the three coordinates modulo
/// [`BLOCK_VOXELS`], packed six bits each.
fn in_block(key: VoxelKey) -> u32 {
    let c = |v: i32| v.rem_euclid(BLOCK_VOXELS) as u32;
    c(key.x) | (c(key.y) << 6) | (c(key.z) << 12)
}

const _: () = assert!(BLOCK_VOXELS <= 64, "in_block packs six bits an axis");

/// The global map: at most one Gaussian per voxel of edge `voxel_size`; a
/// Gaussian keeps the key of the voxel it was inserted in (means move by
/// far less than a voxel during mapping). Gaussians are stored by block
/// ([`Block`]), so radius queries and paging cost the blocks they touch,
/// not the map size.
///
/// ```
/// use latentam_core::map::{Gaussian, GlobalMap};
/// use bytemuck::Zeroable;
///
/// let mut map = GlobalMap::new(0.01);
/// let g = Gaussian { mean: [0.105, 0.0, 1.0], ..Gaussian::zeroed() };
/// let key = map.insert(g).expect("voxel was free");
/// assert!(map.insert(g).is_none(), "one Gaussian per voxel");
/// assert_eq!(map.within(glam::DVec3::new(0.1, 0.0, 1.0), 0.05), vec![key]);
/// let block = map.block(GlobalMap::block_of(key)).expect("its block");
/// assert_eq!(block.keys(), &[key]);
/// ```
pub struct GlobalMap {
    voxel_size: f64,
    /// The blocks in host memory.
    blocks: KeyMap<Block>,
    /// Gaussians in host memory.
    len: usize,
    /// Gaussians per occupancy cell, one grid per `OCCUPANCY_LEVELS`, of
    /// every block (in memory or spilled): "is this surface mapped" does
    /// not depend on where a block is.
    occupancy: [KeyMap<u32>; 4],
    /// The disk tier: where spilled blocks are, and their file (created
    /// at the first spill).
    spilled: KeyMap<Spilled>,
    spilled_len: usize,
    spill: Option<SpillFile>,
    spill_dir: std::path::PathBuf,
    /// Counts keyframes, for least-recently-used order.
    clock: u64,
    /// Blocks spilled and read back so far.
    spill_counts: SpillCounts,
}

/// Blocks the disk tier wrote and read, since the map was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SpillCounts {
    /// Blocks written to disk.
    pub written: u64,
    /// Blocks read back into memory.
    pub read: u64,
}

impl std::fmt::Debug for GlobalMap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GlobalMap")
            .field("voxel_size", &self.voxel_size)
            .field("in_memory", &self.len)
            .field("spilled", &self.spilled_len)
            .finish_non_exhaustive()
    }
}

impl GlobalMap {
    /// An empty map with voxels of `voxel_size` metres.
    pub fn new(voxel_size: f64) -> Self {
        assert!(
            voxel_size > 0.0 && voxel_size.is_finite(),
            "voxel size must be positive"
        );
        GlobalMap {
            voxel_size,
            blocks: KeyMap::default(),
            len: 0,
            occupancy: Default::default(),
            spilled: KeyMap::default(),
            spilled_len: 0,
            spill: None,
            spill_dir: std::env::temp_dir(),
            clock: 0,
            spill_counts: SpillCounts::default(),
        }
    }

    /// Spills go to a scratch file in `dir` (the OS temporary directory
    /// unless set; see [`GlobalMap::spill_to_budget`]). Takes effect for
    /// the next scratch file.
    pub fn set_spill_dir(&mut self, dir: impl Into<std::path::PathBuf>) {
        self.spill_dir = dir.into();
    }

    /// Voxel edge, metres.
    pub fn voxel_size(&self) -> f64 {
        self.voxel_size
    }

    /// Number of Gaussians, in memory and spilled.
    pub fn len(&self) -> usize {
        self.len + self.spilled_len
    }

    /// Whether the map is empty.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Gaussians spilled to disk.
    pub fn spilled_len(&self) -> usize {
        self.spilled_len
    }

    /// Whether voxel `key`'s block is spilled to disk.
    pub fn is_spilled(&self, key: VoxelKey) -> bool {
        self.spilled.contains_key(&Self::block_of(key))
    }

    /// Blocks spilled to disk.
    pub fn spilled_blocks(&self) -> usize {
        self.spilled.len()
    }

    /// Bytes of the disk tier's scratch file.
    pub fn disk_bytes(&self) -> u64 {
        self.spill.as_ref().map_or(0, SpillFile::bytes)
    }

    /// Blocks written to disk and read back since the map was made.
    pub fn spill_counts(&self) -> SpillCounts {
        self.spill_counts
    }

    /// The voxel of point `p`.
    pub fn key_of(&self, p: DVec3) -> Option<VoxelKey> {
        VoxelKey::of(p, self.voxel_size)
    }

    /// Whether voxel `key` holds a Gaussian in memory (a spilled block's
    /// are not seen until it is read back: [`GlobalMap::load_near`]).
    pub fn contains(&self, key: VoxelKey) -> bool {
        self.blocks
            .get(&Self::block_of(key))
            .is_some_and(|b| b.slot.contains_key(&in_block(key)))
    }

    /// Whether a Gaussian lies in the occupancy cell of `p` (edge
    /// [`OCCUPANCY_VOXELS`] voxels) or one of its 26 neighbours: `p` is on
    /// or within about a cell of mapped surface.
    pub fn is_near_occupied(&self, p: DVec3) -> bool {
        self.occupied_around(p, 1)
    }

    /// Whether a Gaussian lies within about `distance` of `p` (at least
    /// `distance`, at most about three times it; distances beyond 16
    /// voxels are asked at 16): the grid whose cells are just under
    /// `distance` is asked for `p`'s cell and its 26 neighbours.
    pub fn is_mapped_within(&self, p: DVec3, distance: f64) -> bool {
        let voxels = distance / self.voxel_size;
        match OCCUPANCY_LEVELS.iter().rposition(|&r| r as f64 <= voxels) {
            Some(level) => self.occupied_around(p, level),
            None => self
                .key_of(p)
                .is_some_and(|k| k.neighbourhood().any(|n| self.contains(n))),
        }
    }

    fn occupied_around(&self, p: DVec3, level: usize) -> bool {
        self.key_of(p).is_some_and(|k| {
            k.coarse(OCCUPANCY_LEVELS[level])
                .neighbourhood()
                .any(|n| self.occupancy[level].contains_key(&n))
        })
    }

    /// Inserts `g` in the voxel of its mean; `None` (and nothing changes)
    /// if that voxel is taken or the mean is not finite.
    pub fn insert(&mut self, g: Gaussian) -> Option<VoxelKey> {
        let key = self.key_of(DVec3::from(g.mean.map(f64::from)))?;
        self.insert_at(key, g).then_some(key)
    }

    /// Inserts `g` under `key` (a saved map's key: optimised means may
    /// have left their seeding voxel); false if the voxel is taken, or
    /// its block is spilled (read it back first: a block is never in
    /// memory and on disk at once).
    pub fn insert_at(&mut self, key: VoxelKey, g: Gaussian) -> bool {
        let block_key = Self::block_of(key);
        if self.spilled.contains_key(&block_key) {
            return false;
        }
        let clock = self.clock;
        let block = self.blocks.entry(block_key).or_default();
        block.used = clock;
        let index = block.keys.len() as u32;
        match block.slot.entry(in_block(key)) {
            std::collections::hash_map::Entry::Occupied(_) => return false,
            std::collections::hash_map::Entry::Vacant(v) => v.insert(index),
        };
        block.keys.push(key);
        block.gaussians.push(g);
        self.len += 1;
        for (grid, &r) in self.occupancy.iter_mut().zip(&OCCUPANCY_LEVELS) {
            *grid.entry(key.coarse(r)).or_default() += 1;
        }
        true
    }

    /// The Gaussian in voxel `key`, if its block is in memory.
    pub fn get(&self, key: VoxelKey) -> Option<&Gaussian> {
        let block = self.blocks.get(&Self::block_of(key))?;
        block.index_of(key).map(|i| &block.gaussians[i])
    }

    /// Overwrites the Gaussian in voxel `key` (write-back from the GPU
    /// window); `false` if the voxel is empty.
    pub fn write_back(&mut self, key: VoxelKey, g: Gaussian) -> bool {
        let Some(block) = self.blocks.get_mut(&Self::block_of(key)) else {
            return false;
        };
        match block.index_of(key) {
            Some(i) => {
                block.gaussians[i] = g;
                true
            }
            None => false,
        }
    }

    /// Removes the Gaussian in voxel `key` (pruning), if its block is in
    /// memory.
    pub fn remove(&mut self, key: VoxelKey) -> Option<Gaussian> {
        let block_key = Self::block_of(key);
        let block = self.blocks.get_mut(&block_key)?;
        let at = block.slot.remove(&in_block(key))? as usize;
        // The block's last Gaussian takes its place.
        block.keys.swap_remove(at);
        let g = block.gaussians.swap_remove(at);
        if let Some(&moved) = block.keys.get(at) {
            block.slot.insert(in_block(moved), at as u32);
        }
        if block.keys.is_empty() {
            self.blocks.remove(&block_key);
        }
        self.len -= 1;
        for (grid, &r) in self.occupancy.iter_mut().zip(&OCCUPANCY_LEVELS) {
            let occ = key.coarse(r);
            match grid.get_mut(&occ) {
                Some(n) if *n > 1 => *n -= 1,
                _ => {
                    grid.remove(&occ);
                }
            }
        }
        Some(g)
    }

    /// Keys of the Gaussians in memory whose mean is within `radius` of
    /// `centre`, in key order.
    pub fn within(&self, centre: DVec3, radius: f64) -> Vec<VoxelKey> {
        let mut out = Vec::new();
        self.visit_within(centre, radius, |key, _| out.push(key));
        out.sort_unstable();
        out
    }

    /// Calls `take(key, squared distance)` for every Gaussian within
    /// `radius` of `centre`, in no particular order.
    fn visit_within(&self, centre: DVec3, radius: f64, mut take: impl FnMut(VoxelKey, f64)) {
        let r2 = radius * radius;
        for (_, _, block) in self.blocks_in_box(centre, radius) {
            for (key, g) in block.keys.iter().zip(&block.gaussians) {
                let m = DVec3::from(g.mean.map(f64::from));
                let d2 = (m - centre).length_squared();
                if d2 <= r2 {
                    take(*key, d2);
                }
            }
        }
    }

    /// The occupied blocks in the box of half-edge `radius` around
    /// `centre`, with their keys and lower corners: the box's blocks or
    /// the occupied ones, whichever are fewer, so the time is bounded by
    /// the map, not by radius ÷ block size.
    fn blocks_in_box(&self, centre: DVec3, radius: f64) -> Vec<(VoxelKey, DVec3, &Block)> {
        let edge = self.voxel_size * BLOCK_VOXELS as f64;
        let lo = ((centre - radius) / edge).floor();
        let hi = ((centre + radius) / edge).floor();
        let mut out = Vec::new();
        if !lo.is_finite() || !hi.is_finite() {
            return out;
        }
        let corner = |b: VoxelKey| DVec3::new(b.x as f64, b.y as f64, b.z as f64) * edge;
        let span = hi - lo + 1.0;
        if span.x * span.y * span.z > self.blocks.len() as f64 {
            let (lo, hi) = (lo.as_ivec3(), hi.as_ivec3());
            for (k, block) in &self.blocks {
                if (lo.x..=hi.x).contains(&k.x)
                    && (lo.y..=hi.y).contains(&k.y)
                    && (lo.z..=hi.z).contains(&k.z)
                {
                    out.push((*k, corner(*k), block));
                }
            }
        } else {
            for x in lo.x as i32..=hi.x as i32 {
                for y in lo.y as i32..=hi.y as i32 {
                    for z in lo.z as i32..=hi.z as i32 {
                        let k = VoxelKey { x, y, z };
                        if let Some(block) = self.blocks.get(&k) {
                            out.push((k, corner(k), block));
                        }
                    }
                }
            }
        }
        out
    }

    /// The block of voxel `key` (see [`BLOCK_VOXELS`]).
    pub fn block_of(key: VoxelKey) -> VoxelKey {
        key.coarse(BLOCK_VOXELS)
    }

    /// The Gaussians of `block`, if it holds any.
    pub fn block(&self, block: VoxelKey) -> Option<&Block> {
        self.blocks.get(&block)
    }

    /// Gaussians in `block`, in memory or spilled.
    pub fn block_len(&self, block: VoxelKey) -> usize {
        match self.blocks.get(&block) {
            Some(b) => b.len(),
            None => self.spilled.get(&block).map_or(0, |s| s.count as usize),
        }
    }

    /// The keys of the Gaussians in `block`, in the block's order.
    pub fn block_keys(&self, block: VoxelKey) -> impl Iterator<Item = VoxelKey> + '_ {
        self.blocks
            .get(&block)
            .into_iter()
            .flat_map(|b| b.keys.iter().copied())
    }

    /// Occupied blocks, in memory and spilled.
    pub fn blocks(&self) -> usize {
        self.blocks.len() + self.spilled.len()
    }

    /// The blocks in memory that come within `radius` of `centre`, with
    /// the squared distance from `centre` to the nearest point of each
    /// (0 for the block holding it) and its Gaussians, nearest first (ties
    /// by block). Costs the blocks in the sphere's bounding box or the
    /// occupied blocks, whichever are fewer: never a Gaussian.
    pub fn blocks_near(&self, centre: DVec3, radius: f64) -> Vec<(f64, VoxelKey, usize)> {
        let edge = self.voxel_size * BLOCK_VOXELS as f64;
        let r2 = radius * radius;
        let mut out: Vec<(f64, VoxelKey, usize)> = self
            .blocks_in_box(centre, radius)
            .into_iter()
            .filter_map(|(b, min, block)| {
                let nearest = centre.clamp(min, min + edge);
                let d2 = (nearest - centre).length_squared();
                (d2 <= r2).then_some((d2, b, block.len()))
            })
            .collect();
        out.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        out
    }

    /// Every key and Gaussian in memory, block by block in block key
    /// order, and within a block in its own order (so a map loaded from a
    /// save lists its Gaussians as the saved one did, whatever the hash
    /// tables did). The whole map, spilled blocks too, is
    /// [`GlobalMap::for_each_block`]'s.
    pub fn iter(&self) -> impl Iterator<Item = (VoxelKey, &Gaussian)> {
        let mut blocks: Vec<(&VoxelKey, &Block)> = self.blocks.iter().collect();
        blocks.sort_unstable_by_key(|(k, _)| **k);
        blocks
            .into_iter()
            .flat_map(|(_, b)| b.keys.iter().copied().zip(b.gaussians.iter()))
    }

    /// Calls `visit(block, keys, gaussians)` for every block, in memory or
    /// spilled (read from disk one at a time, not kept), in block key
    /// order: the same order as [`GlobalMap::iter`] when nothing is
    /// spilled. Stops at the first error, a spilled block that does not
    /// read back intact included.
    pub fn for_each_block(
        &self,
        mut visit: impl FnMut(VoxelKey, &[VoxelKey], &[Gaussian]) -> Result<()>,
    ) -> Result<()> {
        let mut order: Vec<VoxelKey> = self.blocks.keys().copied().collect();
        order.extend(self.spilled.keys().copied());
        order.sort_unstable();
        for key in order {
            match self.blocks.get(&key) {
                Some(b) => visit(key, &b.keys, &b.gaussians)?,
                None => {
                    let (keys, gaussians) = self.read_spilled(key)?;
                    visit(key, &keys, &gaussians)?
                }
            }
        }
        Ok(())
    }

    /// Every key and Gaussian of the map, spilled blocks too, in the order
    /// of [`GlobalMap::for_each_block`].
    pub fn to_vec(&self) -> Result<Vec<(VoxelKey, Gaussian)>> {
        let mut out = Vec::with_capacity(self.len());
        self.for_each_block(|_, keys, gaussians| {
            out.extend(keys.iter().copied().zip(gaussians.iter().copied()));
            Ok(())
        })?;
        Ok(out)
    }

    /// Every key and Gaussian whose mean is within `radius` of `centre`,
    /// spilled blocks read from disk (not kept), in key order (as
    /// [`GlobalMap::within`]).
    pub fn gaussians_within(
        &self,
        centre: DVec3,
        radius: f64,
    ) -> Result<Vec<(VoxelKey, Gaussian)>> {
        let r2 = radius * radius;
        let mut out: Vec<(VoxelKey, Gaussian)> = Vec::new();
        let mut take = |keys: &[VoxelKey], gaussians: &[Gaussian]| {
            for (k, g) in keys.iter().zip(gaussians) {
                if (DVec3::from(g.mean.map(f64::from)) - centre).length_squared() <= r2 {
                    out.push((*k, *g));
                }
            }
        };
        for (_, _, block) in self.blocks_in_box(centre, radius) {
            take(&block.keys, &block.gaussians);
        }
        for block in self.spilled_near(centre, radius) {
            let (keys, gaussians) = self.read_spilled(block)?;
            take(&keys, &gaussians);
        }
        out.sort_unstable_by_key(|(k, _)| *k);
        Ok(out)
    }

    /// Marks `block` used now (it stays in memory longer than blocks used
    /// before).
    pub fn touch(&mut self, block: VoxelKey) {
        if let Some(b) = self.blocks.get_mut(&block) {
            b.used = self.clock;
        }
    }

    /// Advances the clock that orders blocks by last use (once a
    /// keyframe).
    pub fn tick(&mut self) {
        self.clock += 1;
    }

    /// Writes the least recently used blocks in memory to disk until the
    /// blocks' bytes (their Gaussians, keys and indexes) are within
    /// `budget`, never a block `keep` names (those the GPU window holds,
    /// whose rows it will write back). The occupancy grids and the table of
    /// blocks stay in memory and are not counted: spilling cannot shrink
    /// them, and counting them would spill the blocks near the camera over
    /// and over once they alone outgrew the budget. Returns the blocks
    /// spilled. The first spill creates the scratch file (see
    /// [`GlobalMap::set_spill_dir`]).
    pub fn spill_to_budget(
        &mut self,
        budget: u64,
        keep: impl Fn(VoxelKey) -> bool,
    ) -> Result<usize> {
        let mut bytes = self.block_bytes();
        if bytes <= budget {
            return Ok(0);
        }
        let mut order: Vec<(u64, VoxelKey)> = self
            .blocks
            .iter()
            .filter(|(k, _)| !keep(**k))
            .map(|(k, b)| (b.used, *k))
            .collect();
        order.sort_unstable();
        let mut spilled = 0;
        for (_, key) in order {
            if bytes <= budget {
                break;
            }
            let file = match &mut self.spill {
                Some(f) => f,
                None => self.spill.insert(SpillFile::create(&self.spill_dir)?),
            };
            let block = &self.blocks[&key];
            let at = file.write(key, &block.keys, &block.gaussians)?;
            let block = self.blocks.remove(&key).expect("listed above");
            bytes = bytes.saturating_sub(block.bytes() as u64);
            self.len -= block.len();
            self.spilled_len += block.len();
            self.spilled.insert(key, at);
            self.spill_counts.written += 1;
            spilled += 1;
        }
        Ok(spilled)
    }

    /// Heap bytes of the blocks in memory: what [`GlobalMap::spill_to_budget`]
    /// bounds.
    pub fn block_bytes(&self) -> u64 {
        self.blocks.values().map(|b| b.bytes() as u64).sum()
    }

    /// Reads back into memory every spilled block that comes within
    /// `radius` of `centre`. Returns how many.
    pub fn load_near(&mut self, centre: DVec3, radius: f64) -> Result<usize> {
        let blocks = self.spilled_near(centre, radius);
        for &key in &blocks {
            self.load(key)?;
        }
        Ok(blocks.len())
    }

    /// Reads spilled `block` back into memory; false when it is not
    /// spilled.
    pub fn load(&mut self, block: VoxelKey) -> Result<bool> {
        if !self.spilled.contains_key(&block) {
            return Ok(false);
        }
        let (keys, gaussians) = self.read_spilled(block)?;
        let at = self.spilled.remove(&block).expect("checked above");
        let slot = keys
            .iter()
            .enumerate()
            .map(|(i, k)| (in_block(*k), i as u32))
            .collect();
        let n = keys.len();
        self.blocks.insert(
            block,
            Block {
                keys,
                gaussians,
                slot,
                used: self.clock,
            },
        );
        self.len += n;
        self.spilled_len -= n;
        self.spill_counts.read += 1;
        let file = self.spill.as_mut().expect("a block was spilled");
        if file.forget(at) {
            file.compact(&mut self.spilled)?;
        }
        Ok(true)
    }

    fn read_spilled(&self, block: VoxelKey) -> Result<(Vec<VoxelKey>, Vec<Gaussian>)> {
        let at = self.spilled[&block];
        self.spill
            .as_ref()
            .expect("a block was spilled")
            .read(block, at)
    }

    /// The spilled blocks that come within `radius` of `centre`.
    fn spilled_near(&self, centre: DVec3, radius: f64) -> Vec<VoxelKey> {
        if self.spilled.is_empty() {
            return Vec::new();
        }
        let edge = self.voxel_size * BLOCK_VOXELS as f64;
        let r2 = radius * radius;
        let mut out: Vec<VoxelKey> = self
            .spilled
            .keys()
            .copied()
            .filter(|b| {
                let min = DVec3::new(b.x as f64, b.y as f64, b.z as f64) * edge;
                let nearest = centre.clamp(min, min + edge);
                (nearest - centre).length_squared() <= r2
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Approximate host bytes held (parameters, keys, indexes, occupancy
    /// grids, where the spilled blocks are).
    pub fn bytes(&self) -> u64 {
        // A hashbrown entry of a key and a small value, with its control
        // byte, rounded up.
        let entry = size_of::<VoxelKey>() + 8 + 1;
        let blocks: usize = self.blocks.values().map(Block::bytes).sum();
        let tables = (self.blocks.capacity() * (entry + size_of::<Block>()))
            + self.spilled.capacity() * (entry + size_of::<Spilled>())
            + self
                .occupancy
                .iter()
                .map(|g| g.capacity() * entry)
                .sum::<usize>();
        (blocks + tables) as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use bytemuck::Zeroable;
    use rand::{Rng, SeedableRng};

    fn at(p: [f32; 3]) -> Gaussian {
        Gaussian {
            mean: p,
            ..Gaussian::zeroed()
        }
    }

    #[test]
    fn radius_queries_and_removal_match_a_brute_force_scan() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let mut map = GlobalMap::new(0.01);
        let mut live: Vec<[f32; 3]> = Vec::new();
        for step in 0..6000 {
            if step % 3 == 2 && !live.is_empty() {
                let i = rng.random_range(0..live.len());
                let p = live.swap_remove(i);
                let key = map.key_of(DVec3::from(p.map(f64::from))).unwrap();
                assert_eq!(map.remove(key).unwrap().mean, p);
            } else {
                let p = [
                    rng.random_range(-2.0..2.0f32),
                    rng.random_range(-2.0..2.0f32),
                    rng.random_range(-0.5..0.5f32),
                ];
                if map.insert(at(p)).is_some() {
                    live.push(p);
                }
            }
        }
        assert_eq!(map.len(), live.len());
        for _ in 0..20 {
            let c = DVec3::new(
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
                0.0,
            );
            // Small radii walk the box's cells, large ones the occupied.
            let r = rng.random_range(0.05..6.0);
            let mut want: Vec<VoxelKey> = live
                .iter()
                .filter(|p| (DVec3::from(p.map(f64::from)) - c).length() <= r)
                .map(|p| map.key_of(DVec3::from(p.map(f64::from))).unwrap())
                .collect();
            want.sort_unstable();
            assert_eq!(map.within(c, r), want);
        }
        // A radius of any size costs a pass over the occupied cells.
        assert_eq!(map.within(DVec3::ZERO, 1e300).len(), live.len());
        assert_eq!(
            map.within(DVec3::new(1e30, 0.0, 0.0), 2e30).len(),
            live.len()
        );
        // Every live Gaussian is found by its key, exactly once.
        let mut keys: Vec<VoxelKey> = map.iter().map(|(k, _)| k).collect();
        keys.sort_unstable();
        keys.dedup();
        assert_eq!(keys.len(), live.len());
        for p in &live {
            let k = map.key_of(DVec3::from(p.map(f64::from))).unwrap();
            assert_eq!(map.get(k).unwrap().mean, *p);
        }
        // Blocks hold exactly their own voxels, and their arrays agree
        // with lookups by key.
        let mut blocks: Vec<VoxelKey> = map.iter().map(|(k, _)| GlobalMap::block_of(k)).collect();
        blocks.dedup();
        assert_eq!(blocks.len(), map.blocks(), "iteration goes block by block");
        for b in blocks {
            let block = map.block(b).unwrap();
            assert_eq!(block.len(), map.block_len(b));
            for (k, g) in block.keys().iter().zip(block.gaussians()) {
                assert_eq!(GlobalMap::block_of(*k), b);
                assert_eq!(map.get(*k), Some(g));
            }
        }
        // A map rebuilt in its own order iterates the same way.
        let mut copy = GlobalMap::new(0.01);
        for (k, g) in map.iter() {
            assert!(copy.insert_at(k, *g));
        }
        assert!(map.iter().eq(copy.iter()));
    }

    #[test]
    fn spilled_blocks_come_back_bit_exact_and_whole_map_readers_see_them() {
        let dir = latentam_base::files::testing::TempDir::new("global-spill");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let mut map = GlobalMap::new(0.02);
        map.set_spill_dir(dir.path());
        let mut truth: std::collections::BTreeMap<VoxelKey, Gaussian> = Default::default();
        let bits =
            |g: &Gaussian| -> Vec<u32> { bytemuck::cast_slice(std::slice::from_ref(g)).to_vec() };
        for step in 0..40 {
            // A camera walking along x inserts around itself.
            let cam = DVec3::new(step as f64 * 0.5, 0.0, 0.0);
            map.tick();
            map.load_near(cam, 2.0).unwrap();
            for _ in 0..300 {
                let mut g = Gaussian::zeroed();
                g.mean = [
                    (cam.x + rng.random_range(-2.0..2.0)) as f32,
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.5..0.5),
                ];
                g.color = [rng.random(), rng.random(), rng.random()];
                g.query[7] = rng.random();
                if let Some(k) = map.insert(g) {
                    truth.insert(k, g);
                }
            }
            // Training changes what is near the camera.
            for k in map.within(cam, 1.0) {
                let mut g = *map.get(k).unwrap();
                g.opacity_logit += 1.0;
                assert!(map.write_back(k, g));
                truth.insert(k, g);
            }
            let before = map.len();
            let edge = 0.02 * BLOCK_VOXELS as f64;
            let near_camera = |b: VoxelKey| ((b.x as f64 + 0.5) * edge - cam.x).abs() < 1.5;
            map.spill_to_budget(300_000, near_camera).unwrap();
            assert_eq!(map.len(), before, "spilling keeps every Gaussian");
            assert!(map.block_bytes() <= 300_000 || map.spilled_blocks() > 0);
        }
        assert!(
            map.spilled_blocks() > 10,
            "{} spilled",
            map.spilled_blocks()
        );
        let counts = map.spill_counts();
        assert!(
            counts.written > counts.read && counts.read > 0,
            "{counts:?}"
        );
        // The whole map, from memory and disk, bit for bit.
        let mut seen: Vec<(VoxelKey, Vec<u32>)> = Vec::new();
        map.for_each_block(|b, keys, gaussians| {
            assert!(keys.iter().all(|k| GlobalMap::block_of(*k) == b));
            seen.extend(keys.iter().zip(gaussians).map(|(k, g)| (*k, bits(g))));
            Ok(())
        })
        .unwrap();
        seen.sort_unstable_by_key(|(k, _)| *k);
        let want: Vec<(VoxelKey, Vec<u32>)> = truth.iter().map(|(k, g)| (*k, bits(g))).collect();
        assert_eq!(seen, want);
        // Radius reads see spilled blocks too, without reading them in.
        let start = DVec3::new(0.0, 0.0, 0.0);
        let mut near: Vec<Vec<u32>> = map
            .gaussians_within(start, 1.0)
            .unwrap()
            .iter()
            .map(|(_, g)| bits(g))
            .collect();
        let mut want: Vec<Vec<u32>> = truth
            .values()
            .filter(|g| (DVec3::from(g.mean.map(f64::from)) - start).length() <= 1.0)
            .map(bits)
            .collect();
        near.sort_unstable();
        want.sort_unstable();
        assert_eq!(near, want);
        // Walking back reads the start region in; nothing is lost.
        let spilled = map.spilled_blocks();
        assert!(map.load_near(start, 2.0).unwrap() > 0);
        assert!(map.spilled_blocks() < spilled);
        for (k, g) in map.iter() {
            assert_eq!(bits(g), bits(&truth[&k]));
        }
        // A voxel of a spilled block is not taken twice.
        let (&k, g) = truth
            .iter()
            .find(|(k, _)| !map.contains(**k))
            .expect("something is still spilled");
        assert!(map.is_spilled(k) && map.get(k).is_none());
        assert!(!map.insert_at(k, *g));
    }

    #[test]
    fn blocks_near_a_point_match_a_brute_force_scan() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        // 2 cm voxels: blocks of 1.28 m over a 12 m × 12 m × 1 m slab.
        let mut map = GlobalMap::new(0.02);
        for _ in 0..5000 {
            let p = [
                rng.random_range(-6.0..6.0f32),
                rng.random_range(-6.0..6.0f32),
                rng.random_range(-0.5..0.5f32),
            ];
            map.insert(at(p));
        }
        let edge = 0.02 * BLOCK_VOXELS as f64;
        for _ in 0..30 {
            let c = DVec3::new(
                rng.random_range(-8.0..8.0),
                rng.random_range(-8.0..8.0),
                rng.random_range(-1.0..1.0),
            );
            // Small radii walk the box's blocks, large ones the occupied.
            let r = rng.random_range(0.0..20.0);
            let mut per_block: std::collections::BTreeMap<VoxelKey, usize> = Default::default();
            for (k, _) in map.iter() {
                *per_block.entry(GlobalMap::block_of(k)).or_default() += 1;
            }
            let mut want: Vec<(f64, VoxelKey, usize)> = per_block
                .into_iter()
                .filter_map(|(b, n)| {
                    let lo = DVec3::new(b.x as f64, b.y as f64, b.z as f64) * edge;
                    // Nearest point per axis, written out.
                    let axis = |c: f64, lo: f64| {
                        if c < lo {
                            lo - c
                        } else if c > lo + edge {
                            c - lo - edge
                        } else {
                            0.0
                        }
                    };
                    let d2 =
                        axis(c.x, lo.x).powi(2) + axis(c.y, lo.y).powi(2) + axis(c.z, lo.z).powi(2);
                    (d2 <= r * r).then_some((d2, b, n))
                })
                .collect();
            want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
            let got = map.blocks_near(c, r);
            assert_eq!(got.len(), want.len(), "centre {c}, radius {r}");
            for (g, w) in got.iter().zip(&want) {
                assert_eq!((g.1, g.2), (w.1, w.2));
                assert!((g.0 - w.0).abs() <= 1e-9 * (1.0 + w.0));
            }
            for (_, b, n) in &got {
                assert_eq!(map.block_keys(*b).count(), *n);
                assert!(map.block_keys(*b).all(|k| GlobalMap::block_of(k) == *b));
            }
        }
    }

    #[test]
    fn mapped_within_a_distance_is_asked_at_the_matching_grid() {
        let mut map = GlobalMap::new(0.01);
        let k = map.insert(at([0.0005, 0.0005, 0.0005])).unwrap();
        for d in [0.005, 0.01, 0.02, 0.04, 0.08, 0.16] {
            // Always within `d` …
            assert!(
                map.is_mapped_within(DVec3::new(d * 0.99, 0.0, 0.0), d),
                "{d}"
            );
            // … never beyond about 3 d (two cells of at most d, plus one).
            assert!(
                !map.is_mapped_within(DVec3::new(3.1 * d.max(0.01), 0.0, 0.0), d),
                "{d}"
            );
        }
        map.remove(k).unwrap();
        for d in [0.005, 0.02, 0.16] {
            assert!(
                !map.is_mapped_within(DVec3::ZERO, d),
                "removal updates every grid"
            );
        }
    }

    #[test]
    fn one_gaussian_per_voxel_and_write_back_by_key() {
        let mut map = GlobalMap::new(0.01);
        let k = map.insert(at([0.001, 0.002, 0.003])).unwrap();
        assert!(map.insert(at([0.009, 0.009, 0.009])).is_none());
        assert!(map.insert(at([f32::NAN, 0.0, 0.0])).is_none());
        assert!(map.is_near_occupied(DVec3::new(0.015, 0.0, 0.0)));
        assert!(map.is_near_occupied(DVec3::new(0.075, 0.0, 0.0)));
        assert!(!map.is_near_occupied(DVec3::new(0.085, 0.0, 0.0)));
        let mut g = at([0.004, 0.004, 0.004]);
        g.opacity_logit = 2.0;
        assert!(map.write_back(k, g));
        assert_eq!(map.get(k).unwrap().opacity_logit, 2.0);
        assert!(!map.write_back(k.offset(5, 0, 0), g));
        assert!(map.bytes() > 0);
        map.remove(k).unwrap();
        assert!(
            !map.is_near_occupied(DVec3::new(0.015, 0.0, 0.0)),
            "occupancy follows removal"
        );
    }
}

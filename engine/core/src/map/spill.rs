//! The global map's disk tier: blocks spilled out of host memory when the
//! map outgrows its host budget, read back when the camera returns.
//!
//! One scratch file per map, appended to: each spill writes the block as
//! one record, and the map keeps where each spilled block's latest record
//! is. A record is
//!
//! | bytes | field |
//! |---|---|
//! | 4 | magic `LTMB` |
//! | 12 | the block's key (x, y, z as little-endian `i32`) |
//! | 4 | Gaussians in it, `n` (`u32`) |
//! | 4 | CRC-32 of the key, `n` and the payload |
//! | 12 `n` | the voxel keys |
//! | 184 `n` | the Gaussians ([`Gaussian`], little-endian `f32`) |
//!
//! and a read checks all of it against what the map expects, so a damaged
//! or misplaced record is an error naming the block, never a wrong map.
//!
//! The file is scratch, not a save: it is created fresh (never opened if
//! something is already there) and, on Unix, unlinked at once, so nothing
//! else can reach it by name and a crashed process leaves nothing behind.
//! Saves still go to the run folder. When more than half of the file is
//! records of blocks read back since, the live records are copied to a new
//! file.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::gaussian::Gaussian;
use super::voxel::{KeyMap, VoxelKey, BLOCK_VOXELS};
use latentam_base::{Error, Result};

const MAGIC: [u8; 4] = *b"LTMB";
const HEADER: usize = 24;
const PER_GAUSSIAN: usize = size_of::<VoxelKey>() + size_of::<Gaussian>();
/// Compaction waits until the dead records are at least this large.
const COMPACT_AFTER: u64 = 16 << 20;

/// Where a spilled block's record is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Spilled {
    at: u64,
    /// Gaussians in the block.
    pub(crate) count: u32,
}

impl Spilled {
    fn bytes(&self) -> u64 {
        (HEADER + self.count as usize * PER_GAUSSIAN) as u64
    }
}

/// The scratch file of spilled blocks.
pub(crate) struct SpillFile {
    /// Reads take `&self` (whole-map readers stream blocks from it).
    file: Mutex<File>,
    /// Where it was created (for errors; unlinked on Unix).
    path: PathBuf,
    dir: PathBuf,
    end: u64,
    /// Bytes of records no longer current.
    dead: u64,
}

impl SpillFile {
    /// A new scratch file in `dir`.
    pub(crate) fn create(dir: &Path) -> Result<Self> {
        let (file, path) = create_scratch(dir)?;
        Ok(SpillFile {
            file: Mutex::new(file),
            path,
            dir: dir.to_path_buf(),
            end: 0,
            dead: 0,
        })
    }

    /// Bytes on disk.
    pub(crate) fn bytes(&self) -> u64 {
        self.end
    }

    /// Appends `key`'s block (`keys` and `gaussians` in the block's
    /// order).
    pub(crate) fn write(
        &mut self,
        key: VoxelKey,
        keys: &[VoxelKey],
        gaussians: &[Gaussian],
    ) -> Result<Spilled> {
        debug_assert_eq!(keys.len(), gaussians.len());
        let record = encode(key, keys, gaussians);
        let at = self.end;
        let file = self.file.get_mut().unwrap_or_else(|e| e.into_inner());
        file.seek(SeekFrom::Start(at))
            .and_then(|_| file.write_all(&record))
            .map_err(|source| self.io(source))?;
        self.end += record.len() as u64;
        Ok(Spilled {
            at,
            count: keys.len() as u32,
        })
    }

    /// Reads `key`'s block from `at`: its keys and Gaussians, in order.
    /// Errors, naming the block, when the record is not that block's
    /// intact record.
    pub(crate) fn read(
        &self,
        key: VoxelKey,
        at: Spilled,
    ) -> Result<(Vec<VoxelKey>, Vec<Gaussian>)> {
        let mut record = vec![0u8; at.bytes() as usize];
        {
            let mut file = self.file.lock().unwrap_or_else(|e| e.into_inner());
            file.seek(SeekFrom::Start(at.at))
                .and_then(|_| file.read_exact(&mut record))
                .map_err(|source| self.io(source))?;
        }
        decode(key, at.count, &record).map_err(|why| {
            Error::damaged(
                &self.path,
                format!(
                    "spilled block ({}, {}, {}) at byte {}: {why}",
                    key.x, key.y, key.z, at.at
                ),
            )
        })
    }

    /// The record at `at` is no longer current (its block was read back
    /// or removed). Returns true when the file should be compacted.
    pub(crate) fn forget(&mut self, at: Spilled) -> bool {
        self.dead += at.bytes();
        self.dead >= COMPACT_AFTER && self.dead * 2 > self.end
    }

    /// Copies the current records (`index`) to a new file and updates
    /// where they are.
    pub(crate) fn compact(&mut self, index: &mut KeyMap<Spilled>) -> Result<()> {
        let mut fresh = SpillFile::create(&self.dir)?;
        let mut keys: Vec<VoxelKey> = index.keys().copied().collect();
        keys.sort_unstable();
        for key in keys {
            let at = index[&key];
            let (k, g) = self.read(key, at)?;
            index.insert(key, fresh.write(key, &k, &g)?);
        }
        *self = fresh;
        Ok(())
    }

    fn io(&self, source: std::io::Error) -> Error {
        Error::Io {
            path: self.path.clone(),
            source,
        }
    }

    #[cfg(test)]
    pub(crate) fn corrupt(&mut self, at: u64, xor: u8) {
        let file = self.file.get_mut().unwrap();
        let mut b = [0u8];
        file.seek(SeekFrom::Start(at)).unwrap();
        file.read_exact(&mut b).unwrap();
        b[0] ^= xor;
        file.seek(SeekFrom::Start(at)).unwrap();
        file.write_all(&b).unwrap();
    }
}

/// A fresh file in `dir`, created exclusively (a file or link already
/// there is never opened), unlinked at once on Unix.
fn create_scratch(dir: &Path) -> Result<(File, PathBuf)> {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let io = |path: &Path, source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(|e| io(dir, e))?;
    let path = dir.join(format!(
        "latentam-spill-{}-{}.blocks",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    ));
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create_new(true)
        .open(&path)
        .map_err(|e| io(&path, e))?;
    #[cfg(unix)]
    std::fs::remove_file(&path).map_err(|e| io(&path, e))?;
    Ok((file, path))
}

fn encode(key: VoxelKey, keys: &[VoxelKey], gaussians: &[Gaussian]) -> Vec<u8> {
    let n = keys.len();
    let mut out = Vec::with_capacity(HEADER + n * PER_GAUSSIAN);
    out.extend_from_slice(&MAGIC);
    for v in [key.x, key.y, key.z] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&[0; 4]);
    for k in keys {
        for v in [k.x, k.y, k.z] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    for g in gaussians {
        for v in bytemuck::cast_slice::<_, f32>(std::slice::from_ref(g)) {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    let crc = checksum(&out);
    out[20..24].copy_from_slice(&crc.to_le_bytes());
    out
}

/// CRC-32 of a record's key, count and payload.
fn checksum(record: &[u8]) -> u32 {
    let mut h = crc32fast::Hasher::new();
    h.update(&record[4..20]);
    h.update(&record[HEADER..]);
    h.finalize()
}

fn decode(
    key: VoxelKey,
    count: u32,
    record: &[u8],
) -> std::result::Result<(Vec<VoxelKey>, Vec<Gaussian>), String> {
    let word = |at: usize| u32::from_le_bytes(record[at..at + 4].try_into().expect("4 bytes"));
    if record[..4] != MAGIC {
        return Err("not a block record".into());
    }
    let stored = VoxelKey {
        x: word(4) as i32,
        y: word(8) as i32,
        z: word(12) as i32,
    };
    if stored != key || word(16) != count {
        return Err(format!(
            "the record is of block ({}, {}, {}) with {} Gaussians, not of this one with {count}",
            stored.x,
            stored.y,
            stored.z,
            word(16)
        ));
    }
    if checksum(record) != word(20) {
        return Err("checksum mismatch".into());
    }
    let n = count as usize;
    let keys_end = HEADER + n * size_of::<VoxelKey>();
    let keys = record[HEADER..keys_end]
        .chunks_exact(12)
        .map(|c| {
            let v = |i: usize| i32::from_le_bytes(c[i..i + 4].try_into().expect("4 bytes"));
            VoxelKey {
                x: v(0),
                y: v(4),
                z: v(8),
            }
        })
        .collect::<Vec<_>>();
    if keys.iter().any(|k| k.coarse(BLOCK_VOXELS) != key) {
        return Err("a voxel of another block".into());
    }
    let floats: Vec<f32> = record[keys_end..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
        .collect();
    let gaussians = bytemuck::pod_collect_to_vec::<f32, Gaussian>(&floats);
    Ok((keys, gaussians))
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_base::files::testing::TempDir;
    use rand::{Rng, SeedableRng};

    fn block(rng: &mut impl Rng, key: VoxelKey, n: usize) -> (Vec<VoxelKey>, Vec<Gaussian>) {
        let keys = (0..n)
            .map(|i| VoxelKey {
                x: key.x * 64 + i as i32 % 64,
                y: key.y * 64 + (i / 64) as i32,
                z: key.z * 64,
            })
            .collect();
        let floats: Vec<f32> = (0..n * size_of::<Gaussian>() / 4)
            .map(|_| rng.random_range(-1e3..1e3))
            .collect();
        (keys, bytemuck::pod_collect_to_vec(&floats))
    }

    #[test]
    fn blocks_round_trip_bit_exact_through_writes_and_compaction() {
        let dir = TempDir::new("spill");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let mut file = SpillFile::create(dir.path()).unwrap();
        // Nothing is left by name in the directory on Unix.
        #[cfg(unix)]
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        let mut index = KeyMap::default();
        let mut truth = std::collections::HashMap::new();
        for round in 0..200 {
            let key = VoxelKey {
                x: rng.random_range(-3..3),
                y: rng.random_range(-3..3),
                z: -1,
            };
            let n = rng.random_range(1..400);
            let data = block(&mut rng, key, n);
            if let Some(old) = index.insert(key, file.write(key, &data.0, &data.1).unwrap()) {
                if file.forget(old) || round == 150 {
                    file.compact(&mut index).unwrap();
                }
            }
            truth.insert(key, data);
        }
        for (key, want) in &truth {
            let got = file.read(*key, index[key]).unwrap();
            assert_eq!(got.0, want.0);
            let bits = |g: &[Gaussian]| bytemuck::cast_slice::<_, u32>(g).to_vec();
            assert_eq!(bits(&got.1), bits(&want.1));
        }
    }

    #[test]
    fn a_damaged_or_misplaced_record_is_refused_by_name() {
        let dir = TempDir::new("spill-damage");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let mut file = SpillFile::create(dir.path()).unwrap();
        let a = VoxelKey { x: 1, y: 2, z: 3 };
        let b = VoxelKey { x: -4, y: 0, z: 7 };
        let (ka, ga) = block(&mut rng, a, 50);
        let (kb, gb) = block(&mut rng, b, 20);
        let at_a = file.write(a, &ka, &ga).unwrap();
        let at_b = file.write(b, &kb, &gb).unwrap();
        // Another block's record where this one's should be.
        let err = file.read(a, at_b).unwrap_err().to_string();
        assert!(
            err.contains("block (1, 2, 3)") && err.contains("(-4, 0, 7)"),
            "{err}"
        );
        // Any flipped bit, header or payload.
        for byte in [0, 5, 17, 21, 30, 24 + 12 * 50 + 100, at_a.bytes() - 1] {
            file.corrupt(byte, 0x10);
            let err = file.read(a, at_a).unwrap_err();
            assert!(matches!(err, Error::Damaged { .. }), "{err}");
            assert!(err.to_string().contains("block (1, 2, 3)"), "{err}");
            file.corrupt(byte, 0x10);
        }
        assert!(file.read(a, at_a).is_ok());
        // A record cut short: the file ends before it does.
        let beyond = Spilled {
            at: at_b.at,
            count: at_b.count + 5,
        };
        assert!(file.read(b, beyond).is_err());
    }
}

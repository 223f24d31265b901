//! The driver's compiled pipelines kept on disk between processes, so a
//! warm start does not compile every kernel again (drivers that compile at
//! pipeline creation take seconds to minutes for all of them).
//!
//! One file per device, driver version and build of the kernels, in the
//! user's cache directory. The driver's data is wrapped in a header of our
//! own (magic, length, CRC-32) and its Vulkan header is checked against the
//! device before the driver sees it: a truncated, corrupt or foreign file
//! is ignored with a warning, never handed to a driver. Files are replaced
//! whole (`write_atomically_shared`: written beside under a name of the
//! writer's own, then renamed), so processes starting and ending at once
//! each read a complete file, whichever wrote last.

use std::io::Write;
use std::path::{Path, PathBuf};

use ash::vk;

/// The start of every cache file.
const MAGIC: &[u8; 8] = b"LTAMPC\x00\x01";
/// Magic, payload length (u64) and its CRC-32 (u32), little-endian.
const HEADER_BYTES: usize = 8 + 8 + 4;
/// Larger files are not read: no set of kernels compiles to this much.
const MAX_FILE_BYTES: u64 = 512 << 20;

/// Where a device's cache file lives under `dir`.
pub(crate) fn path_for(dir: &Path, props: &vk::PhysicalDeviceProperties) -> PathBuf {
    let uuid: String = props
        .pipeline_cache_uuid
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect();
    dir.join(format!(
        "pipelines-{:04x}-{:04x}-{:08x}-{uuid}-{:016x}.bin",
        props.vendor_id,
        props.device_id,
        props.driver_version,
        latentam_shaders::BUILD_ID
    ))
}

/// The driver data of the cache file at `path`, when it is whole and was
/// written by this device and driver; `None` (with a warning for a file
/// that exists but cannot be used) otherwise.
pub(crate) fn load(path: &Path, props: &vk::PhysicalDeviceProperties) -> Option<Vec<u8>> {
    match std::fs::metadata(path) {
        Err(_) => return None, // a cold start
        Ok(m) if m.len() > MAX_FILE_BYTES => {
            log::warn!(
                "{}: ignoring a pipeline cache of {} bytes",
                path.display(),
                m.len()
            );
            return None;
        }
        Ok(_) => {}
    }
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) => {
            log::warn!("{}: pipeline cache unreadable: {e}", path.display());
            return None;
        }
    };
    match check(&bytes, props) {
        Ok(()) => Some(bytes[HEADER_BYTES..].to_vec()),
        Err(why) => {
            log::warn!("{}: ignoring the pipeline cache: {why}", path.display());
            None
        }
    }
}

/// Why `bytes` is not a cache file of this device, if it is not.
fn check(bytes: &[u8], props: &vk::PhysicalDeviceProperties) -> Result<(), String> {
    if bytes.len() < HEADER_BYTES || &bytes[..8] != MAGIC {
        return Err("not a latentam pipeline cache".into());
    }
    let len = u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize;
    let crc = u32::from_le_bytes(bytes[16..20].try_into().unwrap());
    let data = &bytes[HEADER_BYTES..];
    if data.len() != len {
        return Err(format!(
            "{} bytes of data where the header says {len}",
            data.len()
        ));
    }
    if crc32fast::hash(data) != crc {
        return Err("checksum mismatch".into());
    }
    // Vulkan's own header: length, version, vendor, device, cache UUID.
    if data.len() < 16 + vk::UUID_SIZE {
        return Err("no Vulkan pipeline cache header".into());
    }
    let word = |i: usize| u32::from_le_bytes(data[4 * i..4 * i + 4].try_into().unwrap());
    let uuid = &data[16..16 + vk::UUID_SIZE];
    if word(1) != vk::PipelineCacheHeaderVersion::ONE.as_raw() as u32
        || word(2) != props.vendor_id
        || word(3) != props.device_id
        || uuid != props.pipeline_cache_uuid
    {
        return Err("written by another device or driver".into());
    }
    Ok(())
}

/// Writes `data` as the cache file at `path`, replacing it whole; another
/// process saving at the same time writes its own file, and the renames are
/// atomic.
pub(crate) fn save(path: &Path, data: &[u8]) -> latentam_base::Result<()> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| latentam_base::Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    latentam_base::files::write_atomically_shared(path, |f| {
        f.write_all(MAGIC)?;
        f.write_all(&(data.len() as u64).to_le_bytes())?;
        f.write_all(&crc32fast::hash(data).to_le_bytes())?;
        f.write_all(data)
    })
}

/// The default directory: `LATENTAM_PIPELINE_CACHE` (`off` for none), else
/// `$XDG_CACHE_HOME/latentam`, else `$HOME/.cache/latentam`.
pub(crate) fn default_dir() -> Option<PathBuf> {
    let env = |k: &str| std::env::var_os(k).filter(|v| !v.is_empty());
    match env("LATENTAM_PIPELINE_CACHE") {
        Some(v) if v == "off" => None,
        Some(v) => Some(PathBuf::from(v)),
        None => env("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .or_else(|| env("HOME").map(|h| PathBuf::from(h).join(".cache")))
            .map(|d| d.join("latentam")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn props() -> vk::PhysicalDeviceProperties {
        vk::PhysicalDeviceProperties {
            vendor_id: 0x10de,
            device_id: 0x2330,
            pipeline_cache_uuid: [7; vk::UUID_SIZE],
            ..Default::default()
        }
    }

    /// A Vulkan pipeline cache header for `props`, then `extra` bytes.
    fn driver_data(p: &vk::PhysicalDeviceProperties, extra: usize) -> Vec<u8> {
        let mut d = Vec::new();
        d.extend(32u32.to_le_bytes());
        d.extend(1u32.to_le_bytes());
        d.extend(p.vendor_id.to_le_bytes());
        d.extend(p.device_id.to_le_bytes());
        d.extend(p.pipeline_cache_uuid);
        d.extend((0..extra).map(|i| i as u8));
        d
    }

    #[test]
    fn a_saved_cache_loads_and_damaged_or_foreign_ones_do_not() {
        let dir = std::env::temp_dir().join(format!("latentam-pcache-{}", std::process::id()));
        let p = props();
        let path = path_for(&dir, &p);
        assert_eq!(load(&path, &p), None, "no file: a cold start");
        let data = driver_data(&p, 1000);
        save(&path, &data).unwrap();
        assert_eq!(load(&path, &p), Some(data.clone()));

        // Another device, another driver's header, a flipped bit, a cut
        // file, a file of something else: each is ignored.
        let other = vk::PhysicalDeviceProperties {
            device_id: 0x2331,
            ..p
        };
        assert_eq!(load(&path, &other), None);
        let bytes = std::fs::read(&path).unwrap();
        for (what, damaged) in [
            ("flipped bit", {
                let mut b = bytes.clone();
                b[HEADER_BYTES + 500] ^= 0x10;
                b
            }),
            ("cut", bytes[..bytes.len() - 7].to_vec()),
            (
                "other file",
                b"ply\nformat binary_little_endian 1.0\n".to_vec(),
            ),
            ("empty", Vec::new()),
        ] {
            std::fs::write(&path, &damaged).unwrap();
            assert_eq!(load(&path, &p), None, "{what}");
        }
        // A whole file whose Vulkan header names another device.
        save(&path, &driver_data(&other, 10)).unwrap();
        assert_eq!(load(&path, &p), None);
        // No partial file is left behind.
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left.len(), 1, "{left:?}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn the_file_name_tells_devices_drivers_and_builds_apart() {
        let p = props();
        let dir = Path::new("/cache");
        let a = path_for(dir, &p);
        let newer_driver = vk::PhysicalDeviceProperties {
            driver_version: 2,
            ..p
        };
        assert_ne!(a, path_for(dir, &newer_driver));
        assert!(a
            .to_string_lossy()
            .contains(&format!("{:016x}", latentam_shaders::BUILD_ID)));
    }
}

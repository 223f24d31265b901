//! Saved states of real maps: a mapped state parses, loads and survives
//! mutations; a diverged map is not saved; checksums catch flipped bytes
//! and edited metadata; headers that lie are refused.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{Map, Value};

use super::fixtures::keyframe;
use super::persist_mutations::{join, parse_mutations, seed, split, ORIGIN};
use crate::mapper::*;
use latentam_gpu::testing::with_context;

#[test]
fn a_mapped_state_parses_loads_and_survives_mutations() {
    use crate::map::{KeyframeConfig, KeyframePolicy, SeedingConfig};
    with_context(|ctx| {
        let cfg = MapperConfig {
            keyframes: KeyframeConfig {
                policy: KeyframePolicy::Interval(1),
                ..KeyframeConfig::default()
            },
            seeding: SeedingConfig {
                stride: 4,
                ..SeedingConfig::default()
            },
            window_capacity: Some(2048),
            replay: 1,
            history_cell: 0.0,
            atoms: 8,
            max_regions: 16,
            min_region_pixels: 4,
            ..MapperConfig::default()
        };
        let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
        for i in 0..3 {
            let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
            f.stamp_ns = i as i64;
            if i == 1 {
                f.embeddings = None;
            }
            mapper.integrate(&f).unwrap();
        }
        let dir = std::env::temp_dir().join(format!("latentam-persist-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.latentam");
        mapper.save_file(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();

        // The unmutated file parses to the mapper's state, and loads.
        let state = SavedState::parse(&bytes, &path).unwrap();
        assert_eq!(state.gaussians(), mapper.pager.global().len());
        assert_eq!(state.resident(), mapper.pager.window().unwrap().len());
        assert_eq!(state.history_len(), 3);
        assert_eq!(state.keyframes(), 3);
        assert_eq!(state.embedding_dim(), Some(32));
        assert_eq!(state.config(), mapper.config());
        let again = SavedState::parse(&state.to_bytes().unwrap(), &path).unwrap();
        assert!(again == state, "parse and write are inverse");
        let loaded = Mapper::load_file(ctx, &path, None).unwrap();
        let gaussians = |m: &Mapper| {
            m.pager
                .global()
                .iter()
                .map(|(k, g)| (k, *g))
                .collect::<Vec<_>>()
        };
        assert_eq!(gaussians(&loaded), gaussians(&mapper));
        assert_eq!(
            loaded.pager.window().unwrap().keys(),
            mapper.pager.window().unwrap().keys()
        );
        assert_eq!(loaded.trajectory(), mapper.trajectory());
        assert_eq!(loaded.exposure, mapper.exposure);
        assert_eq!(loaded.exposure.len(), 3);
        // A resumed run goes on after the last stamp integrated.
        assert_eq!(loaded.stats().last_frame_stamp_ns, Some(2));
        assert_eq!(loaded.stats().frames, 3);
        drop(loaded);
        drop(mapper);

        // Mutations: refused cleanly or accepted; a few accepted ones are
        // put on the GPU too.
        let accepted = parse_mutations(&bytes, 3000, seed() ^ 1);
        let mut applied = 0;
        for (state, what) in accepted.into_iter().take(16) {
            let r = catch_unwind(AssertUnwindSafe(|| {
                Mapper::from_saved(ctx, state, None, None).map(drop)
            }));
            match r {
                Err(_) => panic!("from_saved panicked on an accepted mutation: {what}"),
                Ok(r) => applied += r.is_ok() as usize,
            }
        }
        eprintln!("{applied} accepted mutations loaded");
        std::fs::remove_dir_all(&dir).unwrap();
    });
}

#[test]
fn a_diverged_map_is_not_saved() {
    with_context(|ctx| {
        let dir = std::env::temp_dir().join(format!("latentam-diverged-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.latentam");
        let mut m = Mapper::with_context(
            ctx,
            MapperConfig {
                window_capacity: Some(8192),
                ..MapperConfig::default()
            },
        )
        .unwrap();
        m.integrate(keyframe(glam::DVec3::ZERO)).unwrap();
        m.save_file(&path).unwrap();
        let good = std::fs::read(&path).unwrap();
        // The projection gone infinite, as a learning rate far too large
        // makes it: refused, and the last save stays.
        let head = m.dictionary.head().unwrap();
        let mut w: Vec<f32> = ctx.download(head.w()).unwrap();
        w[5] = f32::INFINITY;
        ctx.upload(head.w(), 0, &w).unwrap();
        let e = m.save_file(&path).unwrap_err().to_string();
        assert!(e.contains("diverged") && e.contains("head/W"), "{e}");
        assert_eq!(std::fs::read(&path).unwrap(), good);
        // A Gaussian of the global map gone NaN, far from the window: the
        // map streams into the file and the save stops there, naming its
        // voxel, leaving the last save and no partial file.
        w[5] = 0.0;
        ctx.upload(m.dictionary.head().unwrap().w(), 0, &w).unwrap();
        let far = crate::map::VoxelKey {
            x: 10_000,
            y: 0,
            z: 0,
        };
        let mut g = *m.pager.global().iter().next().unwrap().1;
        g.query[3] = f32::NAN;
        assert!(m.pager.global_mut().insert_at(far, g));
        let e = m.save_file(&path).unwrap_err().to_string();
        assert!(e.contains("diverged") && e.contains("10000"), "{e}");
        assert_eq!(std::fs::read(&path).unwrap(), good);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).ok();
    });
}

/// A byte changed anywhere in a saved state's tensors (a bit flip on disk,
/// a bad copy) is caught by its checksum, however plausible the changed
/// value: none of the flips loads.
#[test]
fn bit_flips_in_tensor_data_are_all_detected() {
    let bytes = SavedState::example().to_bytes().unwrap();
    let (header, data) = split(&bytes).expect("a well-formed example");
    let start = bytes.len() - data.len();
    let mut rng = ChaCha8Rng::seed_from_u64(seed());
    for _ in 0..64 {
        let mut flipped = bytes.clone();
        let at = rng.random_range(start..bytes.len());
        flipped[at] ^= 1 << rng.random_range(0..8);
        let e = SavedState::parse(&flipped, Path::new(ORIGIN)).err();
        assert!(
            e.as_ref()
                .is_some_and(|e| e.to_string().contains("is damaged")),
            "a flip at byte {at} of {} loaded or failed otherwise: {e:?}",
            bytes.len()
        );
    }
    // The untouched file, rejoined, still loads.
    assert!(SavedState::parse(&join(&header, &data), Path::new(ORIGIN)).is_ok());
}

/// The metadata is under the checksum too: a changed counter, stamp,
/// setting or run id is damage, not another map. Edits sealed again (as a
/// deliberate editor could) still meet the checks behind the checksum: the
/// run id must have the tool's form and be there, and a state that mapped
/// frames must say up to which stamp.
#[test]
fn metadata_is_checksummed_and_run_ids_and_stamps_are_required() {
    let bytes = SavedState::example().to_bytes().unwrap();
    let (header, data) = split(&bytes).expect("a well-formed example");
    let unsealed = |h: &Map<String, Value>| {
        let text = serde_json::to_vec(h).unwrap();
        let mut out = (text.len() as u64).to_le_bytes().to_vec();
        out.extend(text);
        out.extend_from_slice(&data);
        out
    };
    let parse = |file: Vec<u8>| match SavedState::parse(&file, Path::new(ORIGIN)) {
        Ok(_) => panic!("an edited state loaded"),
        Err(e) => e.to_string(),
    };
    let with = |key: &str, value: Option<&str>| {
        let mut h = header.clone();
        let meta = h["__metadata__"].as_object_mut().unwrap();
        match value {
            Some(v) => meta.insert(key.into(), v.into()),
            None => meta.remove(key),
        };
        h
    };
    let min = i64::MIN.to_string();
    for (key, value) in [
        ("last_stamp_ns", Some(min.as_str())),
        ("frames", Some("13")),
        ("run_id", Some("000000000000002f00000001")),
        ("model", None),
    ] {
        let e = parse(unsealed(&with(key, value)));
        assert!(e.contains("is damaged"), "{key}: {e}");
    }
    for (key, value, why) in [
        ("run_id", Some("\u{1b}[2J"), "is not one this tool writes"),
        ("run_id", Some("12"), "is not one this tool writes"),
        ("run_id", Some(""), "is not one this tool writes"),
        ("run_id", None, "no run id"),
        ("last_stamp_ns", None, "no last_stamp_ns"),
    ] {
        let e = parse(join(&with(key, value), &data));
        assert!(e.contains(why), "{key} = {value:?}: {e}");
        assert!(!e.contains('\u{1b}'), "{e:?}");
    }
    // Resealed untouched, it loads.
    assert!(SavedState::parse(&join(&header, &data), Path::new(ORIGIN)).is_ok());
}

/// A header naming a key twice (here the metadata, with another run id
/// first) is refused: JSON readers differ on which one counts.
#[test]
fn a_header_naming_a_key_twice_is_refused() {
    let bytes = SavedState::example().to_bytes().unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = std::str::from_utf8(&bytes[8..8 + n]).unwrap();
    let twice = format!(
        "{{\"__metadata__\": {{\"run_id\": \"ffffffffffffffff\"}}, {}",
        &header[1..]
    );
    let mut file = (twice.len() as u64).to_le_bytes().to_vec();
    file.extend(twice.as_bytes());
    file.extend_from_slice(&bytes[8 + n..]);
    let e = SavedState::parse(&file, Path::new(ORIGIN))
        .unwrap_err()
        .to_string();
    assert!(e.contains("\"__metadata__\" appears twice"), "{e}");
}

/// A header whose tensors do not tile the file (a huge file behind a small
/// header) is refused from the header alone, before the rest is read.
#[test]
fn a_file_larger_than_its_tensors_is_refused_from_its_header() {
    let dir = std::env::temp_dir().join(format!("latentam-sparse-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("state.latentam");
    let bytes = SavedState::example().to_bytes().unwrap();
    let file = std::fs::File::create(&path).unwrap();
    use std::io::Write;
    (&file).write_all(&bytes).unwrap();
    // 3 GiB more, sparse: reading it would cost gigabytes and seconds.
    file.set_len(bytes.len() as u64 + (3u64 << 30)).unwrap();
    drop(file);
    let started = std::time::Instant::now();
    let e = SavedState::read(&path).unwrap_err().to_string();
    assert!(e.contains("bytes after the last tensor"), "{e}");
    assert!(started.elapsed() < std::time::Duration::from_secs(2));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Gaussians no map holds (a zero rotation, a log-scale whose exponential
/// overflows) are refused with the voxel they are in.
#[test]
fn implausible_gaussians_are_refused() {
    for (field, value) in [("quat", 0.0f32), ("log_scale", 88.0)] {
        let mut state = SavedState::example();
        let g = &mut state.map[0].1;
        match field {
            "quat" => g.quat = [value; 4],
            _ => g.log_scale[1] = value,
        }
        let bytes = state.to_bytes().unwrap();
        let e = SavedState::parse(&bytes, Path::new(ORIGIN))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("the Gaussian of voxel")
                && e.contains(field.split('_').next_back().unwrap()),
            "{e}"
        );
    }
}

/// A saved map larger than the host budget loads a chunk at a time, each
/// chunk's blocks spilled before the next is read; the map that results
/// is the saved one, guesses included, and a voxel saved twice is refused
/// even when its first copy was spilled by then.
#[test]
fn a_map_over_the_host_budget_loads_a_chunk_at_a_time() {
    use crate::map::VoxelKey;
    with_context(|ctx| {
        let dir = std::env::temp_dir().join(format!("latentam-streamed-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("state.latentam");
        let mut state = SavedState::example();
        // Three chunks' worth of Gaussians over many blocks, after the
        // example's six (four of them resident).
        let template = state.map[2].1;
        for i in 0..150_000i32 {
            let key = VoxelKey {
                x: 100 + i % 97,
                y: (i / 97) % 89,
                z: i / (97 * 89),
            };
            let mut g = template;
            g.query[0] = i as f32;
            state.map.push((key, g));
            state.guesses.push((i % 3 == 0) as u8);
        }
        std::fs::write(&path, state.to_bytes().unwrap()).unwrap();
        let budget = MapperConfig {
            host_budget: 1,
            spill_dir: Some(dir.to_string_lossy().into_owned()),
            ..state.config().clone()
        };
        let m = Mapper::load_file(ctx, &path, Some(budget.clone())).unwrap();
        let global = m.pager.global();
        assert!(global.spilled_blocks() > 0 && global.spill_counts().written > 0);
        let mut loaded = global.to_vec().unwrap();
        let mut saved = state.map.clone();
        loaded.sort_by_key(|(k, _)| *k);
        saved.sort_by_key(|(k, _)| *k);
        assert!(loaded.len() == saved.len() && loaded == saved);
        for ((key, _), flag) in state.map.iter().zip(&state.guesses) {
            assert_eq!(m.seeder.is_guess(key), *flag == 1, "{key:?}");
        }
        drop(m);

        // The same voxel again in the last chunk: its first copy's block
        // was spilled long before.
        let first = state.map[10];
        state.map.push(first);
        state.guesses.push(0);
        std::fs::write(&path, state.to_bytes().unwrap()).unwrap();
        let e = Mapper::load_file(ctx, &path, Some(budget)).err().unwrap();
        assert!(e.to_string().contains("appears twice"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    });
}

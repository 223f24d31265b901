//! The live handle on the generated scene (lavapipe, with the validation
//! layer): one thread submits a log while two others query and render;
//! every answer comes from one consistent snapshot, no pipeline is
//! compiled after warm-up, and the final map is the one a synchronous run
//! of the same frames makes.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use latentam_core::latent::TextQuery;
use latentam_core::live::{LiveMapper, LiveOptions};
use latentam_core::map::{Gaussian, VoxelKey};
use latentam_core::mapper::{camera_of, Mapper, MapperConfig};
use latentam_gpu::{Context, ContextOptions, Validation};
use latentam_io::{AssemblyConfig, Frame, McapFrames, Vocabulary};

const FRAMES: usize = 40;

fn temp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("latentam-live-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The 160×120 demo scene with 512-d synthetic embeddings.
fn scene() -> (Vec<Frame>, Vocabulary) {
    static SCENE: std::sync::OnceLock<(Vec<Frame>, Vocabulary)> = std::sync::OnceLock::new();
    SCENE.get_or_init(make_scene).clone()
}

fn make_scene() -> (Vec<Frame>, Vocabulary) {
    use latentam_scene::{generate, SceneConfig};
    let dir = temp_dir("scene");
    let path = dir.join("scene.mcap");
    let config = SceneConfig {
        frames: FRAMES,
        ..SceneConfig::default()
    };
    generate(&config, &path, |_| {}).unwrap();
    let mut it = McapFrames::open(&path, AssemblyConfig::default()).unwrap();
    let frames: Vec<Frame> = (&mut it).map(|f| f.unwrap()).collect();
    let vocabulary = it.vocabulary().unwrap().clone();
    std::fs::remove_dir_all(&dir).unwrap();
    (frames, vocabulary)
}

fn context() -> Context {
    Context::new(ContextOptions {
        validation: Validation::Required,
        ..ContextOptions::default()
    })
    .expect("a Vulkan device (lavapipe: apt install mesa-vulkan-drivers)")
}

fn config() -> MapperConfig {
    MapperConfig {
        seed: 5,
        ..MapperConfig::default()
    }
}

/// The global map, by voxel (written back from the GPU first).
fn global_of(mapper: &mut Mapper) -> BTreeMap<VoxelKey, Gaussian> {
    mapper.write_back_window().unwrap();
    let internals = mapper.internals();
    internals.global.iter().map(|(k, g)| (k, *g)).collect()
}

fn assert_no_validation_errors(ctx: Context) {
    let log = ctx.validation_log();
    drop(ctx);
    let errors = log.errors();
    assert!(
        errors.is_empty(),
        "validation errors:\n{}",
        errors.join("\n")
    );
}

#[test]
fn queries_while_mapping_see_consistent_snapshots_and_the_map_matches_a_synchronous_run() {
    let (frames, vocabulary) = scene();
    let ctx = context();
    latentam_core::mapper::warm_up(&ctx).unwrap();

    // The synchronous run.
    let mut sync = Mapper::with_context(&ctx, config()).unwrap();
    for f in &frames {
        sync.integrate(f).unwrap();
    }
    let want = global_of(&mut sync);
    drop(sync);

    // The live run: nothing dropped (the queue holds the whole log), frames
    // at 30 Hz, a querying thread and a rendering thread.
    let mapper = Mapper::with_context(&ctx, config()).unwrap();
    let pipelines = ctx.live_objects().pipelines;
    let options = LiveOptions {
        queue_frames: FRAMES,
        keep_candidates: FRAMES,
        ..LiveOptions::default()
    };
    let live = Arc::new(LiveMapper::start(mapper, options).unwrap());
    let done = Arc::new(AtomicBool::new(false));
    let chair = TextQuery::vocabulary_word(&vocabulary, "chair", 0.1).unwrap();
    let querier = {
        let (live, done, chair) = (live.clone(), done.clone(), chair.clone());
        std::thread::spawn(move || {
            let mut answers = 0;
            while !done.load(Ordering::SeqCst) {
                match live.relevance(&chair) {
                    Ok(a) => {
                        let s = &a.snapshot;
                        assert_eq!(a.scores.len(), s.len());
                        assert_eq!(s.len(), s.stats.gaussians, "a snapshot of one moment");
                        assert_eq!(s.trajectory.len() as u64, s.keyframes);
                        assert!(a.scores.iter().all(|p| (0.0..=1.0).contains(p)));
                        answers += 1;
                    }
                    Err(latentam::Error::NoEmbeddings) => {}
                    Err(e) => panic!("{e}"),
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            answers
        })
    };
    let render_at = camera_of(&frames[FRAMES / 2]);
    let renderer = {
        let (live, done) = (live.clone(), done.clone());
        std::thread::spawn(move || {
            let mut renders = 0;
            while !done.load(Ordering::SeqCst) {
                if live.snapshot().is_empty() {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
                let view = live.render(&render_at).unwrap();
                assert_eq!(view.rgbd.len(), (view.width * view.height) as usize);
                renders += 1;
                std::thread::sleep(Duration::from_millis(50));
            }
            renders
        })
    };
    let mut worst_submit = Duration::ZERO;
    for f in &frames {
        let t = Instant::now();
        live.submit(f.clone()).unwrap();
        worst_submit = worst_submit.max(t.elapsed());
        std::thread::sleep(Duration::from_millis(33));
    }
    assert!(live.wait_idle(Duration::from_secs(600)));
    done.store(true, Ordering::SeqCst);
    let answers = querier.join().unwrap();
    let renders = renderer.join().unwrap();
    assert!(
        answers > 0 && renders > 0,
        "{answers} answers, {renders} renders"
    );
    let status = live.status();
    assert_eq!(status.dropped.total(), 0, "{status:?}");
    assert_eq!(status.submitted, FRAMES as u64);
    assert_eq!(status.integrated, FRAMES as u64);
    assert_eq!(status.keyframes as usize, FRAMES / 4);
    assert!(status.last_keyframe_latency_ms.is_some() && status.last_error.is_none());
    eprintln!(
        "{answers} answers, {renders} renders while mapping; slowest submit {worst_submit:?}"
    );

    // The last snapshot's relevance, from its index, against the GPU
    // decoder on the finished map, Gaussian by Gaussian.
    let last = live.snapshot();
    let index = last.relevance_index().unwrap();
    let from_snapshot = last.relevance(&chair).unwrap();
    let live = Arc::into_inner(live).expect("the threads are done");
    let mut mapper = live.finish().unwrap();
    assert_eq!(
        ctx.live_objects().pipelines,
        pipelines,
        "a pipeline was compiled while mapping"
    );
    let exact = mapper.relevance_decoded(&chair).unwrap();
    let by_mean: HashMap<[u32; 3], f32> = mapper
        .snapshot()
        .unwrap()
        .to_gaussians()
        .iter()
        .zip(&exact)
        .map(|(g, &p)| (g.mean.map(f32::to_bits), p))
        .collect();
    let mut worst = 0f32;
    for (mean, p) in last.gaussians.means.iter().zip(&from_snapshot) {
        let q = by_mean[&mean.map(f32::to_bits)];
        worst = worst.max((p - q).abs());
    }
    eprintln!(
        "index: {:.1} atoms per Gaussian, {} bytes, dropped mass ≤ {:.1e}; worst relevance error {worst:.2e}",
        index.mean_atoms(),
        index.bytes(),
        index.max_dropped_mass()
    );
    assert!(
        worst < 0.02,
        "relevance from the snapshot is off by {worst}"
    );

    // The same map as the synchronous run: the same Gaussians, equal to
    // float rounding, as two synchronous runs are. Gradients are summed
    // with atomic adds in the order the threads come, and Adam scales a
    // gradient that is only rounding noise up to full steps: a rotation of
    // a nearly round Gaussian (and the scale of its roundest axes), or a
    // query entry with no gradient to speak of, walks off by up to ~0.2 in
    // either run (measured on lavapipe: one query entry of one Gaussian in
    // 33 000, and log-scales of a few by 0.01, between two synchronous
    // runs). A GPU orders its atomics differently on every run, and
    // further apart (an H200 moved one opacity logit in 30 000 by 3e-3), so
    // the bounds are on shares: every Gaussian within what no rounding
    // noise reaches, and nearly all within 1e-3.
    let got = global_of(&mut mapper);
    assert_eq!(got.len(), want.len());
    let close = |x: &[f32], y: &[f32], tol: f32| {
        x.iter()
            .zip(y)
            .all(|(x, y)| (x - y).abs() <= tol * y.abs().max(1.0))
    };
    let (mut exact, mut near, mut query_entries_off) = (0, 0, 0);
    for ((ka, a), (kb, b)) in got.iter().zip(&want) {
        assert_eq!(ka, kb);
        let same_surface = close(&a.mean, &b.mean, 1e-2)
            && close(&a.log_scale, &b.log_scale, 1e-1)
            && close(&a.quat, &b.quat, 1e-1)
            && close(&a.color, &b.color, 2e-2)
            && close(&[a.opacity_logit], &[b.opacity_logit], 2e-2);
        assert!(same_surface, "Gaussian at {ka:?}: {a:?} vs {b:?}");
        near += (close(&a.mean, &b.mean, 1e-3)
            && close(&a.log_scale, &b.log_scale, 5e-2)
            && close(&a.quat, &b.quat, 5e-2)
            && close(&a.color, &b.color, 1e-3)
            && close(&[a.opacity_logit], &[b.opacity_logit], 1e-3)) as usize;
        query_entries_off += a
            .query
            .iter()
            .zip(&b.query)
            .filter(|(x, y)| (*x - *y).abs() > 1e-3)
            .count();
        exact += (close(&a.mean, &b.mean, 1e-4)
            && close(&a.color, &b.color, 1e-4)
            && close(&a.query, &b.query, 1e-4)) as usize;
    }
    let n = got.len();
    let summary = format!(
        "{exact} of {n} Gaussians within 1e-4 of the synchronous run, {near} within 1e-3; \
         {query_entries_off} query entries off by > 1e-3"
    );
    eprintln!("{summary}");
    assert!(near * 1000 >= n * 999, "{summary}");
    assert!(exact * 100 >= n * 95, "{summary}");
    assert!(query_entries_off * 100 <= n, "{summary}");
    drop(mapper);
    assert_no_validation_errors(ctx);
}

#[test]
fn a_full_queue_drops_by_policy_and_abort_and_drop_return_promptly() {
    let (frames, _) = scene();
    let ctx = context();
    latentam_core::mapper::warm_up(&ctx).unwrap();
    let mapper = Mapper::with_context(&ctx, config()).unwrap();
    let options = LiveOptions {
        queue_frames: 2,
        ..LiveOptions::default()
    };
    let live = LiveMapper::start(mapper, options).unwrap();
    // Faster than it maps: frames must go.
    for f in &frames {
        live.submit(f.clone()).unwrap();
    }
    assert!(live.wait_idle(Duration::from_secs(600)));
    let s = live.status();
    assert!(s.dropped.not_keyframe + s.dropped.superseded > 0, "{s:?}");
    assert_eq!(s.submitted, s.integrated + s.dropped.total());
    assert!(s.keyframes >= 1);
    let snapshot = live.snapshot();
    assert_eq!(snapshot.keyframes, s.keyframes);

    // Abort while a keyframe runs: it hurries, the queue is dropped.
    for f in &frames {
        live.submit(f.clone()).unwrap();
    }
    let t = Instant::now();
    let mut mapper = live.abort().unwrap();
    eprintln!("abort took {:?}", t.elapsed());
    // The returned mapper maps on, unhurried.
    let before = mapper.stats().keyframes;
    let mut later = frames.last().unwrap().clone();
    later.stamp_ns += 1_000_000_000;
    later.pose.translation.x += 0.5;
    mapper.integrate(&later).unwrap();
    assert!(mapper.stats().keyframes >= before);

    // Dropped without finish, with frames queued: returns within its bound.
    let live = LiveMapper::start(mapper, LiveOptions::default()).unwrap();
    for f in frames.iter().take(6) {
        let mut f = f.clone();
        f.stamp_ns += 2_000_000_000;
        live.submit(f).unwrap();
    }
    let t = Instant::now();
    drop(live);
    assert!(
        t.elapsed() < LiveOptions::default().drop_timeout,
        "{:?}",
        t.elapsed()
    );
    assert_no_validation_errors(ctx);
}

#[test]
fn snapshots_are_taken_for_readers_and_every_n_keyframes_only_when_asked() {
    let (frames, _) = scene();
    let ctx = context();
    latentam_core::mapper::warm_up(&ctx).unwrap();
    let mapped = |options: LiveOptions| {
        let mapper = Mapper::with_context(&ctx, config()).unwrap();
        let live = LiveMapper::start(mapper, options).unwrap();
        for f in frames.iter().take(24) {
            live.submit_waiting(f.clone(), Duration::from_secs(600))
                .unwrap();
        }
        assert!(live.wait_idle(Duration::from_secs(600)));
        live
    };

    // Nobody read: no copy of the map was taken.
    let live = mapped(LiveOptions::default());
    let s = live.status();
    assert!(s.keyframes >= 3, "{s:?}");
    assert_eq!(s.snapshots, 0, "{s:?}");
    // What never waits shows the map the handle started with, and asks
    // for a fresh one.
    assert_eq!(live.latest_snapshot().keyframes, 0);
    // A reader gets the last keyframe's map, in one copy however often
    // it asks while nothing new is mapped.
    let snapshot = live.snapshot();
    assert_eq!(snapshot.keyframes, s.keyframes);
    assert_eq!(snapshot.len(), s.gaussians);
    assert_eq!(snapshot.stats.gpu_bytes, s.gpu_bytes);
    assert_eq!(live.snapshot().keyframes, s.keyframes);
    assert_eq!(live.latest_snapshot().keyframes, s.keyframes);
    assert_eq!(live.status().snapshots, 1);
    let mut mapper = live.finish().unwrap();
    let voxels = |m: &mut Mapper| global_of(m).into_keys().collect::<Vec<_>>();
    let want = voxels(&mut mapper);

    // Every second keyframe, read or not; the same map either way (up to
    // rounding noise: the same voxels).
    let live = mapped(LiveOptions {
        snapshot_every: 2,
        ..LiveOptions::default()
    });
    let s = live.status();
    assert_eq!(s.snapshots, s.keyframes / 2, "{s:?}");
    let mut eager = live.finish().unwrap();
    assert_eq!(voxels(&mut eager), want);
    drop((mapper, eager));
    assert_no_validation_errors(ctx);
}

#[test]
fn a_reader_follows_keyframes_and_outlives_the_handle() {
    let (frames, _) = scene();
    let ctx = context();
    latentam_core::mapper::warm_up(&ctx).unwrap();
    let mapper = Mapper::with_context(&ctx, config()).unwrap();
    let live = LiveMapper::start(mapper, LiveOptions::default()).unwrap();
    let reader = live.reader();
    assert!(reader.last_keyframe().is_none());
    // Nothing mapped yet: the wait ends at its deadline with no keyframe.
    assert_eq!(reader.wait_for_keyframe(0, Duration::from_millis(50)), 0);
    let watcher = {
        let reader = reader.clone();
        std::thread::spawn(move || {
            let seen = reader.wait_for_keyframe(0, Duration::from_secs(600));
            // A snapshot read after the count shows that keyframe.
            (seen, reader.snapshot().keyframes, reader.last_keyframe())
        })
    };
    for f in frames.iter().take(6) {
        live.submit_waiting(f.clone(), Duration::from_secs(600))
            .unwrap();
    }
    let (seen, snapshot_keyframes, image) = watcher.join().unwrap();
    assert!(
        seen >= 1 && snapshot_keyframes >= 1,
        "{seen} {snapshot_keyframes}"
    );
    let image = image.expect("a keyframe's image once a keyframe was counted");
    let source = frames
        .iter()
        .find(|f| f.stamp_ns == image.stamp_ns)
        .unwrap();
    assert_eq!(image.color.data, source.color.data);
    assert_eq!(image.camera.cam_to_world, camera_of(source).cam_to_world);
    assert!(live.wait_idle(Duration::from_secs(600)));
    let rendered = reader.render(&camera_of(source)).unwrap();
    assert_eq!(rendered.width, source.intrinsics.width);
    assert_eq!(reader.status().keyframes, live.status().keyframes);

    // After the handle is gone the reader still reads, and its loans
    // answer `Stopped` instead of waiting for a worker that is gone.
    let mapper = live.finish().unwrap();
    assert!(!reader.is_running());
    assert_eq!(reader.snapshot().keyframes, mapper.stats().keyframes);
    let t = Instant::now();
    assert!(matches!(
        reader.render(&camera_of(source)),
        Err(latentam_core::Error::Stopped(_))
    ));
    assert!(matches!(
        reader.save(temp_dir("reader-save")),
        Err(latentam_core::Error::Stopped(_))
    ));
    assert!(t.elapsed() < Duration::from_secs(5));
    // And waiting on it returns at once.
    let t = Instant::now();
    reader.wait_for_keyframe(u64::MAX, Duration::from_secs(60));
    assert!(t.elapsed() < Duration::from_secs(5));
    drop(mapper);
    assert_no_validation_errors(ctx);
}

//! A live handle whose GPU is lost part-way (`LATENTAM_FAULTS`, read once
//! per process: this file is its own test binary): the failure reaches
//! the caller as a typed error, on the next call and in the status, and
//! nothing panics or hangs.

use std::time::{Duration, Instant};

use latentam_core::live::{LiveMapper, LiveOptions};
use latentam_core::mapper::{Mapper, MapperConfig};
use latentam_gpu::{Context, ContextOptions};
use latentam_io::{AssemblyConfig, Frame, McapFrames};

#[test]
fn a_lost_device_reaches_the_caller_as_a_typed_error() {
    // Enough submissions for the first keyframes, not for the run (about
    // a dozen a keyframe; snapshots add none, since nobody reads).
    std::env::set_var("LATENTAM_FAULTS", "device_lost_after=35");
    let dir = std::env::temp_dir().join(format!("latentam-live-faults-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.mcap");
    let scene = latentam_scene::SceneConfig {
        frames: 24,
        ..Default::default()
    };
    latentam_scene::generate(&scene, &path, |_| {}).unwrap();
    let frames: Vec<Frame> = McapFrames::open(&path, AssemblyConfig::default())
        .unwrap()
        .map(|f| f.unwrap())
        .collect();
    std::fs::remove_dir_all(&dir).unwrap();

    let ctx = Context::new(ContextOptions::default()).unwrap();
    let mapper = Mapper::with_context(&ctx, MapperConfig::default()).unwrap();
    let live = LiveMapper::start(mapper, LiveOptions::default()).unwrap();
    let mut refused = None;
    for f in &frames {
        if let Err(e) = live.submit(f.clone()) {
            refused = Some(e);
            break;
        }
        std::thread::sleep(Duration::from_millis(30));
    }
    assert!(live.wait_idle(Duration::from_secs(300)));
    let status = live.status();
    let stopped = status.stopped.as_deref().expect("the worker stopped");
    assert!(
        matches!(stopped, latentam::Error::DeviceLost { .. }),
        "{stopped:?}"
    );
    assert!((1..6).contains(&status.keyframes), "{status:?}");
    // The next call says so, with the cause to match on.
    let e = refused
        .or_else(|| live.submit(frames[0].clone()).err())
        .expect("submit refuses once the worker stopped");
    match e {
        latentam::Error::Stopped(cause) => {
            assert!(matches!(*cause, latentam::Error::DeviceLost { .. }))
        }
        other => panic!("{other:?}"),
    }
    // Readers still see the last good snapshot (here the one the handle
    // started with: none was asked for before the device was lost).
    let snapshot = live.snapshot();
    assert!(snapshot.keyframes <= status.keyframes);
    assert_eq!(snapshot.len(), snapshot.stats.gaussians);
    // finish reports the failure; nothing hangs.
    let t = Instant::now();
    match live.finish() {
        Err(latentam::Error::Stopped(cause)) => {
            assert!(matches!(*cause, latentam::Error::DeviceLost { .. }))
        }
        Err(other) => panic!("{other:?}"),
        Ok(_) => panic!("a map whose device was lost came back as usable"),
    }
    assert!(t.elapsed() < Duration::from_secs(10));
}

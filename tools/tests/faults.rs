//! What `latentam map` does when things go wrong, with faults injected
//! through `LATENTAM_FAULTS` (see `engine/base/src/faults.rs`) or bad input:
//! a clear error, the exit status says so, and what was mapped is kept.
//! Killing the process (SIGKILL) during mapping and during saves leaves
//! one consistent run in the folder every time.

use std::path::Path;
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{failed_with, gen_scene, latentam_fast as latentam, report, scratch};
use latentam::interchange::read_ply;
use latentam::runs::STATE_FILE;
use latentam::{Context, ContextOptions, Mapper};

fn map(log: &Path, out: &Path, faults: &str, extra: &[&str]) -> Output {
    latentam()
        .env("LATENTAM_FAULTS", faults)
        .arg("map")
        .arg(log)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// Checks that `dir` holds one run: the state loads (with its decoder,
/// checked by `Mapper::load`), and the report and the PLY map describe
/// that state. Returns its keyframes.
fn consistent_run(ctx: &Context, dir: &Path) -> u64 {
    let mapper = Mapper::load(ctx, dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    let stats = mapper.stats();
    let r = report(dir);
    assert_eq!(
        r["run_id"].as_str(),
        stats.run_id.as_deref(),
        "report and state of different runs"
    );
    assert_eq!(r["keyframes"].as_u64(), Some(stats.keyframes));
    assert_eq!(r["gaussians"].as_u64(), Some(stats.gaussians as u64));
    let ply = read_ply(&dir.join("map.ply")).unwrap();
    assert_eq!(ply.gaussians.len(), stats.gaussians);
    let leftovers: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".partial"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    stats.keyframes
}

/// Staging folders and moved-aside runs beside `dir`.
fn beside(dir: &Path) -> Vec<String> {
    let name = dir.file_name().unwrap().to_string_lossy().into_owned();
    std::fs::read_dir(dir.parent().unwrap())
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(&format!(".{name}.")))
        .collect()
}

#[test]
fn faults_give_clear_errors_and_keep_what_was_mapped() {
    let dir = scratch("faults");
    let log = gen_scene(&dir, 32);
    let ctx = Context::new(ContextOptions::default()).unwrap();

    // A full disk while saving: the earlier state stays as it was.
    let run = dir.join("disk");
    assert!(map(&log, &run, "", &["--frames", "12"]).status.success());
    let before = std::fs::read(run.join(STATE_FILE)).unwrap();
    let out = map(
        &log,
        &run,
        "disk_full",
        &["--resume", "--autosave-every", "1"],
    );
    failed_with(&out, &["no space left on device", "not replaced"]);
    assert_eq!(std::fs::read(run.join(STATE_FILE)).unwrap(), before);
    assert_eq!(consistent_run(&ctx, &run), 3);
    assert!(beside(&run).is_empty(), "{:?}", beside(&run));
    // The first failed autosave stops the run (the log has 8 keyframes
    // left), unless asked to go on.
    let stopped = failed_with(&out, &["autosave at keyframe", "failed, so the run stops"]);
    assert_eq!(
        stopped.matches("warning: autosave at keyframe").count(),
        1,
        "{stopped}"
    );
    let out = map(
        &log,
        &run,
        "disk_full",
        &[
            "--resume",
            "--autosave-every",
            "1",
            "--continue-after-failed-autosave",
        ],
    );
    let went_on = failed_with(&out, &["no space left on device", "not replaced"]);
    assert!(!went_on.contains("run stops"), "{went_on}");
    assert!(
        went_on.matches("warning: autosave at keyframe").count() > 1,
        "{went_on}"
    );

    // A destination that renames cannot replace is refused before any
    // frame is mapped.
    let started = Instant::now();
    let out = map(&log, &run, "mount_point", &[]);
    failed_with(
        &out,
        &["is a mount point", "write the run to a folder inside it"],
    );
    assert!(started.elapsed() < Duration::from_secs(20));
    assert_eq!(std::fs::read(run.join(STATE_FILE)).unwrap(), before);

    // A lost device and a failed allocation part-way (after some keyframes:
    // the first submission or allocation counts that get that far are
    // found by trying): the error names it and the folder holds the last
    // autosave, whole.
    for (fault, words) in [
        ("device_lost_after", &["GPU device was lost"][..]),
        ("alloc_fail_after", &["GPU memory", "Out of memory"][..]),
    ] {
        let run = dir.join(fault);
        let mut reached = false;
        for n in [50, 100, 200, 400, 800] {
            let _ = std::fs::remove_dir_all(&run);
            let out = map(
                &log,
                &run,
                &format!("{fault}={n}"),
                &["--autosave-every", "1"],
            );
            if out.status.success() {
                break;
            }
            let stderr = failed_with(&out, words);
            if !run.exists() {
                continue;
            }
            assert!(stderr.contains("its autosave at keyframe"), "{stderr}");
            let r = report(&run);
            assert_eq!(r["ending"], "running", "{r}");
            assert!(consistent_run(&ctx, &run) >= 1);
            reached = true;
            break;
        }
        assert!(reached, "{fault}: no count failed after a keyframe");
    }

    // A log cut off part-way: the frames before the damage are mapped.
    let bytes = std::fs::read(&log).unwrap();
    let cut = dir.join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let run = dir.join("cut");
    failed_with(&map(&cut, &run, "", &[]), &["cut.mcap", "truncated"]);
    let r = report(&run);
    let frames = r["frames"].as_u64().unwrap();
    assert!((4..32).contains(&frames), "{frames} frames");
    assert!(r["ending"]["failed"].as_str().is_some(), "{r}");
    assert!(consistent_run(&ctx, &run) >= 1);
    assert!(!read_ply(&run.join("map.ply")).unwrap().gaussians.is_empty());

    // A GPU budget too small for the first keyframe: nothing is mapped, so
    // an earlier run in the folder stays as it was.
    let run = dir.join("disk");
    let before = std::fs::read(run.join(STATE_FILE)).unwrap();
    failed_with(
        &map(&log, &run, "", &["--set", "gpu_budget=30000000"]),
        &["GPU budget of 30000000 bytes", "set gpu_budget to at least"],
    );
    assert_eq!(std::fs::read(run.join(STATE_FILE)).unwrap(), before);
    assert_eq!(consistent_run(&ctx, &run), 3);
    drop(ctx);
    std::fs::remove_dir_all(&dir).ok();
}

/// Waits up to `limit` for `path` to exist.
fn appears(path: &Path, limit: Duration) -> bool {
    let start = Instant::now();
    while start.elapsed() < limit {
        if path.exists() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
    false
}

#[test]
fn sigkill_at_random_points_always_leaves_one_consistent_run() {
    let dir = scratch("sigkill");
    let frames = 160;
    let log = gen_scene(&dir, frames);
    let run = dir.join("run");
    let state = run.join(STATE_FILE);
    let ctx = Context::new(ContextOptions::default()).unwrap();
    let mut rng_state = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .subsec_nanos() as u64
        | 1;
    eprintln!("kill delays from seed {rng_state}");
    let mut next = move || {
        rng_state ^= rng_state << 13;
        rng_state ^= rng_state >> 7;
        rng_state ^= rng_state << 17;
        rng_state
    };
    // A run that completes first, so the driver's shader cache holds every
    // kernel mapping compiles: drivers write that cache in the background,
    // and runs killed early may never store it, leaving every round to
    // spend its time compiling instead of reaching a save.
    std::fs::create_dir_all(dir.join("warm")).unwrap();
    let warm = latentam()
        .arg("map")
        .arg(gen_scene(&dir.join("warm"), 8))
        .arg("--out")
        .arg(dir.join("warm-run"))
        .arg("--no-trace")
        .output()
        .unwrap();
    assert!(
        warm.status.success(),
        "{}",
        String::from_utf8_lossy(&warm.stderr)
    );
    let (mut saved, mut during_save) = (0u64, 0);
    let mut rounds = Vec::new();
    for round in 0..6 {
        let mut cmd = latentam();
        // Each file of a save lingers before its rename, so kills land in
        // the middle of writing a version.
        cmd.env("LATENTAM_FAULTS", "save_delay_ms=150")
            .arg("map")
            .arg(&log)
            .arg("--out")
            .arg(&run)
            .args(["--autosave-every", "1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if state.exists() {
            cmd.arg("--resume");
        }
        if round >= 2 {
            // The map spilled to disk past a one-byte host budget: saves
            // stream it from the spill file and resumes stream it back.
            cmd.args(["--set", "host_budget=1", "--set"])
                .arg(format!("spill_dir={}", dir.display()));
        }
        let mut child = cmd.spawn().unwrap();
        let spawned = Instant::now();
        if round % 2 == 0 {
            // In the middle of writing a version of the folder.
            let start = Instant::now();
            let mut hit = false;
            while start.elapsed() < Duration::from_secs(120) && !hit {
                hit = beside(&run).iter().any(|n| n.contains(".staging-"));
                std::thread::sleep(Duration::from_millis(2));
            }
            // Somewhere within its files.
            std::thread::sleep(Duration::from_millis(next() % 600));
            during_save += hit as u32;
            rounds.push(format!(
                "round {round}: from {saved} keyframes, {} after {:.1} s",
                if hit {
                    "killed in a save"
                } else {
                    "no save seen"
                },
                spawned.elapsed().as_secs_f64()
            ));
        } else {
            // At a random point of mapping, once a first save exists (how
            // long start-up takes depends on the machine and the shader
            // cache, so a delay from the spawn alone may never reach one).
            let _ = appears(&state, Duration::from_secs(120));
            std::thread::sleep(Duration::from_millis(next() % 2500));
        }
        unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
        let status = child.wait().unwrap();
        assert!(
            status.code().is_none(),
            "round {round}: ended before the kill"
        );
        if run.exists() {
            let k = consistent_run(&ctx, &run);
            assert!(
                k >= saved,
                "round {round}: the run went back from {saved} to {k}"
            );
            saved = k;
        }
    }
    assert!(
        during_save >= 2,
        "{during_save} kills during a save:\n{}",
        rounds.join("\n")
    );
    assert!(saved >= 1, "nothing was ever saved");
    // Resuming from what survived finishes the log, and clears what the
    // kills left beside the folder.
    let out = latentam()
        .arg("map")
        .arg(&log)
        .arg("--out")
        .arg(&run)
        .args(["--resume", "--no-trace", "--set", "host_budget=1", "--set"])
        .arg(format!("spill_dir={}", dir.display()))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(report(&run)["ending"], "complete");
    assert!(report(&run)["disk"]["blocks_written"].as_u64() > Some(0));
    assert_eq!(consistent_run(&ctx, &run), (frames / 4) as u64);
    assert!(beside(&run).is_empty(), "{:?}", beside(&run));
    drop(ctx);
    std::fs::remove_dir_all(&dir).ok();
}

//! A run folder only ever holds one consistent run: runs that map nothing
//! or fail leave it as it was, a second writer is refused, files mixed
//! from two runs are refused when loaded, and a failed frame is not
//! counted as mapped.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

mod common;
use common::{failed_with, gen_scene, latentam_fast as latentam, report, scratch, SCENE_DIM};
use latentam::runs::STATE_FILE;
use latentam::Config as MapperConfig;

fn map(log: &Path, out: &Path, extra: &[&str]) -> Output {
    latentam()
        .arg("map")
        .arg(log)
        .arg("--out")
        .arg(out)
        .args(["--no-trace"])
        .args(extra)
        .output()
        .unwrap()
}

fn ok(out: &Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Every file under a folder, nested folders included (as empty
/// entries), by its path relative to the folder, with its bytes.
fn contents(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(at) = todo.pop() {
        for e in std::fs::read_dir(&at).unwrap() {
            let path = e.unwrap().path();
            let name = path
                .strip_prefix(dir)
                .unwrap()
                .to_string_lossy()
                .into_owned();
            if path.is_dir() {
                out.insert(format!("{name}/"), Vec::new());
                todo.push(path);
            } else {
                out.insert(name, std::fs::read(&path).unwrap());
            }
        }
    }
    out
}

/// Asserts that `dir` holds exactly `before` (naming what differs).
fn unchanged(dir: &Path, before: &BTreeMap<String, Vec<u8>>) {
    let now = contents(dir);
    let differ: Vec<_> = now
        .keys()
        .chain(before.keys())
        .filter(|k| now.get(*k) != before.get(*k))
        .collect();
    assert!(differ.is_empty(), "{} changed: {differ:?}", dir.display());
}

/// A 12-frame log of `dim`-d embeddings in `dir`.
fn scene_of_dim(dir: &Path, dim: usize) -> PathBuf {
    let log = dir.join(format!("scene-{dim}.mcap"));
    ok(&latentam()
        .args(["gen-scene", "--width", "120", "--height", "90"])
        .args(["--frames", "12", "--dim", &dim.to_string()])
        .arg("--out")
        .arg(&log)
        .output()
        .unwrap());
    log
}

#[test]
fn runs_that_map_nothing_or_fail_leave_the_folder_as_it_was() {
    let dir = scratch("runs-nothing");
    let log = gen_scene(&dir, 12);
    let run = dir.join("run");
    ok(&map(&log, &run, &[]));
    let before = contents(&run);
    assert!(before.contains_key("decoder.safetensors"));

    // Every frame refused (no depth within 1 mm): nothing mapped, exit 1
    // with the counts by reason, and the folder untouched.
    let e = failed_with(
        &map(&log, &run, &["--max-depth", "0.001"]),
        &["no map was written", "frame: no valid depth", "12 ×"],
    );
    assert!(e.contains("not replaced"), "{e}");
    unchanged(&run, &before);
    // Positions beyond the world extent, the same.
    failed_with(
        &map(&log, &run, &["--max-extent", "0.001"]),
        &["frame: position beyond the world extent"],
    );
    unchanged(&run, &before);
    // A budget too small for the first keyframe.
    failed_with(
        &map(&log, &run, &["--set", "gpu_budget=1"]),
        &["GPU budget of 1 bytes"],
    );
    unchanged(&run, &before);
    // Keyframes whose depth is all beyond the seeding range: keyframes
    // but no Gaussian is nothing mapped too.
    failed_with(
        &map(&log, &run, &["--set", "seeding.max_depth=0.01"]),
        &["no map was written", "seeded no Gaussian"],
    );
    unchanged(&run, &before);
    // No frame at all.
    failed_with(
        &map(&log, &run, &["--frames", "0"]),
        &["no map was written"],
    );
    unchanged(&run, &before);
    // Nothing is left beside the folder either, but its lock is released.
    let beside: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".run"))
        .collect();
    assert!(beside.is_empty(), "{beside:?}");

    // A folder holding anything but a run is never replaced.
    let notes = dir.join("notes");
    std::fs::create_dir_all(&notes).unwrap();
    std::fs::write(notes.join("thesis.tex"), "precious").unwrap();
    failed_with(
        &map(&log, &notes, &["--frames", "4"]),
        &["not a latentam run folder", ".latentam-run"],
    );
    assert_eq!(
        std::fs::read_to_string(notes.join("thesis.tex")).unwrap(),
        "precious"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// The folder named by `--out` holding a user's files whose names a run
/// also uses (a folder named `trace.json`, their own `config.toml`, the
/// command's own configuration or input log), or a run folder holding the
/// command's own inputs: `map` refuses before the first frame, and every
/// byte stays.
#[test]
fn a_users_files_in_the_out_folder_are_never_deleted() {
    let dir = scratch("runs-users-files");
    let log = gen_scene(&dir, 12);
    let settings = b"# my settings\nvoxel_size = 0.02\n";
    // Per case: the folder, the files planted in it, extra arguments.
    type Case<'a> = (&'a str, Vec<(&'a str, Vec<u8>)>, Vec<String>);
    let cases: Vec<Case> = vec![
        (
            "photos",
            vec![("trace.json/photos/img1.jpg", b"\xff\xd8 photo".to_vec())],
            vec![],
        ),
        (
            "own-files",
            vec![
                ("config.toml", settings.to_vec()),
                ("report.json", b"{\"mine\": 1}".to_vec()),
                ("trajectory.txt", b"0 0 0 0 0 0 0 1\n".to_vec()),
                ("map.ply", b"ply\n".to_vec()),
            ],
            vec![],
        ),
        (
            "myrun",
            vec![("config.toml", settings.to_vec())],
            vec!["--config".into(), "CASE/config.toml".into()],
        ),
        (
            "inlog",
            vec![("trace.json", std::fs::read(&log).unwrap())],
            vec![],
        ),
    ];
    for (name, files, extra) in cases {
        let out = dir.join(name);
        for (file, bytes) in &files {
            let path = out.join(file);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, bytes).unwrap();
        }
        let extra: Vec<String> = extra
            .iter()
            .map(|a| a.replace("CASE", &out.to_string_lossy()))
            .collect();
        let mut args: Vec<&str> = extra.iter().map(String::as_str).collect();
        args.extend(["--frames", "4"]);
        // The input log is the user's file in the folder in the last case.
        let input = match name {
            "inlog" => out.join("trace.json"),
            _ => log.clone(),
        };
        let before = contents(&out);
        let why = match name {
            // The command's own inputs are refused by name first.
            "myrun" | "inlog" => "lies inside",
            _ => "not a latentam run folder",
        };
        failed_with(&map(&input, &out, &args), &[why]);
        unchanged(&out, &before);
    }
    // A run folder of this tool whose config.toml was edited by hand, named
    // as the next run's configuration, and a log kept in it.
    let run = dir.join("run");
    ok(&map(&log, &run, &["--frames", "4"]));
    std::fs::write(run.join("config.toml"), settings).unwrap();
    std::fs::copy(&log, run.join("trace.json")).unwrap();
    let before = contents(&run);
    let config = run.join("config.toml");
    let config_args = ["--config", config.to_str().unwrap(), "--frames", "4"];
    failed_with(&map(&log, &run, &config_args), &["--config", "lies inside"]);
    failed_with(
        &map(&run.join("trace.json"), &run, &["--frames", "4"]),
        &["the log", "lies inside"],
    );
    unchanged(&run, &before);
    // A run folder inside the bag folder it maps: the bag would hold a
    // folder it does not know.
    let bag = dir.join("bag");
    std::fs::create_dir_all(&bag).unwrap();
    std::fs::copy(&log, bag.join("bag_0.mcap")).unwrap();
    let before = contents(&bag);
    failed_with(
        &map(&bag, &bag.join("run"), &["--frames", "4"]),
        &["lies inside the log", "choose an --out outside it"],
    );
    unchanged(&bag, &before);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_failed_frame_is_not_counted_and_resuming_with_settings_applies_them() {
    let dir = scratch("runs-resume");
    let log = gen_scene(&dir, 12);
    let other = scene_of_dim(&dir, 32);
    let run = dir.join("run");
    ok(&map(&log, &run, &["--frames", "6"]));
    let before = contents(&run);
    assert_eq!(report(&run)["keyframes"], 2);

    // A log of another embedding dimension: its first frame is refused
    // before it changes anything, so nothing is written.
    failed_with(
        &map(&other, &run, &["--resume"]),
        &[&format!("32-d embeddings, the map's are {SCENE_DIM}-d")],
    );
    unchanged(&run, &before);

    // A setting that shapes the saved map cannot change on resume.
    failed_with(
        &map(&log, &run, &["--resume", "--set", "voxel_size=0.05"]),
        &["voxel_size = 0.05 asked for", "voxel_size = 0.01"],
    );
    unchanged(&run, &before);
    // Resuming with the right log maps every remaining keyframe, with the
    // run-time settings given now.
    ok(&map(
        &log,
        &run,
        &["--resume", "--set", "stage_two_iterations=7"],
    ));
    let r = report(&run);
    assert_eq!(r["frames_skipped_as_already_mapped"], 6);
    assert_eq!(r["keyframes"], 3);
    let cfg = MapperConfig::from_toml(&std::fs::read_to_string(run.join("config.toml")).unwrap())
        .unwrap();
    assert_eq!(cfg.stage_two_iterations, 7);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_second_writer_is_refused_and_mixed_folders_do_not_load() {
    let dir = scratch("runs-mixed");
    let log = gen_scene(&dir, 16);
    let (a, b) = (dir.join("a"), dir.join("b"));
    ok(&map(&log, &a, &["--frames", "8"]));
    ok(&map(&log, &b, &[]));

    // While one process maps into `a`, another is refused, naming it.
    let mut first = latentam()
        .arg("map")
        .arg(&log)
        .arg("--out")
        .arg(&a)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let lock = dir.join(".a.lock");
    let start = Instant::now();
    while std::fs::read_to_string(&lock).unwrap_or_default() != first.id().to_string() {
        assert!(start.elapsed() < Duration::from_secs(60), "no lock taken");
        std::thread::sleep(Duration::from_millis(5));
    }
    let e = failed_with(
        &map(&log, &a, &[]),
        &["another latentam process", &format!("pid {}", first.id())],
    );
    assert!(!e.contains("panicked"), "{e}");
    first.kill().unwrap();
    first.wait().unwrap();

    // A decoder copied from another run: the state refuses it.
    let mixed = dir.join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    for f in [STATE_FILE, "report.json", "map.ply", "config.toml"] {
        std::fs::copy(a.join(f), mixed.join(f)).unwrap();
    }
    std::fs::copy(
        b.join("decoder.safetensors"),
        mixed.join("decoder.safetensors"),
    )
    .unwrap();
    let query = |dir: &Path| {
        latentam()
            .arg("query")
            .arg(dir)
            .args(["--name", "wall", "--vocabulary"])
            .arg(&log)
            .output()
            .unwrap()
    };
    failed_with(&query(&mixed), &["mixes two runs", "decoder.safetensors"]);
    // A report from another run: eval refuses it.
    std::fs::copy(
        a.join("decoder.safetensors"),
        mixed.join("decoder.safetensors"),
    )
    .unwrap();
    let out = query(&mixed);
    ok(&out);
    // Its stages are announced, so a slow device is not silent.
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("loading the map") && stderr.contains("scoring"),
        "{stderr}"
    );
    std::fs::copy(b.join("report.json"), mixed.join("report.json")).unwrap();
    let eval = || {
        latentam()
            .arg("eval")
            .arg(&mixed)
            .arg(&log)
            .args(["--frames", "2"])
            .output()
            .unwrap()
    };
    failed_with(&eval(), &["mixes two runs", "report.json"]);
    // A report whose run id was removed, or made a number, is no better.
    let mut report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(b.join("report.json")).unwrap()).unwrap();
    for (id, says) in [
        (serde_json::Value::Null, "no run id"),
        (serde_json::json!(7), "not text"),
    ] {
        report["run_id"] = id;
        std::fs::write(mixed.join("report.json"), report.to_string()).unwrap();
        failed_with(&eval(), &["mixes two runs", says]);
    }
    // A report that cannot be read is not a missing one (which would skip
    // the check above): 3 GiB of it (sparse) is refused from its size,
    // unread, and so is a FIFO in its place, by eval and export alike.
    let export = || {
        latentam()
            .arg("export")
            .arg(&mixed)
            .arg("--foxglove")
            .arg(dir.join("out.mcap"))
            .output()
            .unwrap()
    };
    let path = mixed.join("report.json");
    std::fs::File::create(&path)
        .unwrap()
        .set_len(3 << 30)
        .unwrap();
    for out in [eval(), export()] {
        failed_with(&out, &["report.json", "3221225472 bytes, more than"]);
    }
    #[cfg(unix)]
    {
        std::fs::remove_file(&path).unwrap();
        let c = std::ffi::CString::new(path.to_str().unwrap()).unwrap();
        // SAFETY: a NUL-terminated path that outlives the call.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        for out in [eval(), export()] {
            failed_with(&out, &["report.json", "a FIFO"]);
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn states_with_nan_and_vocabularies_of_another_space_are_refused() {
    let dir = scratch("runs-nan");
    let log = gen_scene(&dir, 8);
    let other = scene_of_dim(&dir, 32);
    let run = dir.join("run");
    ok(&map(&log, &run, &[]));

    // Evaluating against a vocabulary of another dimension is an error,
    // not "no vocabulary".
    let eval = |log: &Path| {
        latentam()
            .arg("eval")
            .arg(&run)
            .arg(log)
            .args(["--frames", "2"])
            .output()
            .unwrap()
    };
    failed_with(
        &eval(&other),
        &["32-d", &format!("the map's are {SCENE_DIM}-d")],
    );
    ok(&eval(&log));

    // One NaN in the saved Gaussians: refused at load.
    let path = run.join(STATE_FILE);
    let mut bytes = std::fs::read(&path).unwrap();
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let at = 8 + n + header["map/gaussians"]["data_offsets"][0].as_u64().unwrap() as usize;
    bytes[at + 4..at + 8].copy_from_slice(&f32::NAN.to_le_bytes());
    let query = || {
        latentam()
            .arg("query")
            .arg(&run)
            .args(["--name", "wall", "--vocabulary"])
            .arg(&log)
            .output()
            .unwrap()
    };
    // As damage: the checksum no longer matches.
    std::fs::write(&path, &bytes).unwrap();
    failed_with(&query(), &["is damaged", "checksum"]);
    // As written so (a crafted file, or a writer's bug): the checksum
    // matches, and the value itself is refused.
    let bytes = latentam::runs::archive_join_resealed(header.as_object().unwrap(), &bytes[8 + n..]);
    std::fs::write(&path, &bytes).unwrap();
    failed_with(&query(), &["non-finite"]);
    std::fs::remove_dir_all(&dir).ok();
}

/// The report names the mapped log by an absolute path, so `export` run
/// from another directory reads the vocabulary of the log that was mapped,
/// not of one that happens to have the same relative name there (which
/// it did: a 32-d vocabulary for a 64-d map, and an error).
#[test]
fn the_report_names_the_mapped_log_by_its_absolute_path() {
    let dir = scratch("runs-relative");
    gen_scene(&dir, 8);
    ok(&latentam()
        .current_dir(&dir)
        .args(["map", "scene.mcap", "--out", "run", "--no-trace"])
        .output()
        .unwrap());
    let named = report(&dir.join("run"))["log"]
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(
        std::fs::canonicalize(&named).unwrap(),
        std::fs::canonicalize(dir.join("scene.mcap")).unwrap()
    );
    assert!(Path::new(&named).is_absolute(), "{named}");

    let elsewhere = dir.join("elsewhere");
    std::fs::create_dir_all(&elsewhere).unwrap();
    let other = scene_of_dim(&elsewhere, 32);
    std::fs::rename(&other, elsewhere.join("scene.mcap")).unwrap();
    let out = latentam()
        .current_dir(&elsewhere)
        .arg("export")
        .arg(dir.join("run"))
        .args(["--foxglove", "map.mcap"])
        .output()
        .unwrap();
    ok(&out);
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("/latentam/relevance/"), "{said}");
    std::fs::remove_dir_all(&dir).ok();
}

/// Outputs that resolve to an input of the same command are refused before
/// any work, and the input is left byte for byte.
#[test]
fn outputs_over_the_commands_own_inputs_are_refused() {
    let dir = scratch("own-inputs");
    let log = gen_scene(&dir, 8);
    let run = dir.join("run");
    ok(&map(&log, &run, &[]));
    let state = run.join(STATE_FILE);
    let before = (std::fs::read(&state).unwrap(), std::fs::read(&log).unwrap());
    let log_alias = dir.join("sub/../").join(log.file_name().unwrap());
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let cases: Vec<(Vec<&std::ffi::OsStr>, &str)> = vec![
        (
            vec![
                "query".as_ref(),
                run.as_os_str(),
                "--name".as_ref(),
                "wall".as_ref(),
                "--vocabulary".as_ref(),
                log.as_os_str(),
                "--out".as_ref(),
                state.as_os_str(),
            ],
            "--out",
        ),
        (
            vec![
                "eval".as_ref(),
                run.as_os_str(),
                log.as_os_str(),
                "--json".as_ref(),
                log_alias.as_os_str(),
            ],
            "--json",
        ),
        (
            vec![
                "export".as_ref(),
                run.as_os_str(),
                "--foxglove".as_ref(),
                state.as_os_str(),
            ],
            "--foxglove",
        ),
        (
            vec![
                "export".as_ref(),
                run.as_os_str(),
                "--foxglove".as_ref(),
                log.as_os_str(),
                "--vocabulary".as_ref(),
                log.as_os_str(),
            ],
            "--foxglove",
        ),
        (
            // The mapped log, named only in the run's report.
            vec![
                "export".as_ref(),
                run.as_os_str(),
                "--foxglove".as_ref(),
                log.as_os_str(),
            ],
            "--foxglove",
        ),
    ];
    for (args, flag) in cases {
        let out = latentam().args(&args).output().unwrap();
        let e = failed_with(&out, &[flag, "would write over", "choose another path"]);
        assert_eq!(out.status.code(), Some(1), "{e}");
        let now = (std::fs::read(&state).unwrap(), std::fs::read(&log).unwrap());
        assert!(now == before, "{args:?} changed an input");
    }
    std::fs::remove_dir_all(&dir).ok();
}

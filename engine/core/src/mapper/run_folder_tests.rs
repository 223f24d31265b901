//! Tests of run folders: the lock, staging and swapping in whole, and the
//! user's folders left alone.

use super::*;

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("latentam-runfolder-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

fn commit(folder: &RunFolder, files: &[(&str, &str)]) {
    let s = folder.stage().unwrap();
    for (name, text) in files {
        std::fs::write(s.path().join(name), text).unwrap();
    }
    s.commit().unwrap();
}

#[cfg(unix)]
#[test]
fn a_link_planted_as_the_lock_file_is_refused_and_its_target_kept() {
    let root = scratch("lock-link");
    let victim = root.join("victim.txt");
    std::fs::write(&victim, "keep me").unwrap();
    std::os::unix::fs::symlink(&victim, root.join(".run.lock")).unwrap();
    let err = match RunFolder::lock(root.join("run")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a lock through a link was taken"),
    };
    assert!(err.contains("is a symbolic link"), "{err}");
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep me");
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_commit_replaces_the_whole_folder_and_leaves_nothing_beside_it() {
    let root = scratch("commit");
    let dir = root.join("run");
    let folder = RunFolder::lock(&dir).unwrap();
    commit(&folder, &[("report.json", "1"), ("trace.json", "1")]);
    assert_eq!(names(&dir), [RUN_MARKER, "report.json", "trace.json"]);
    // The second version has no trace: the first's must not linger.
    commit(&folder, &[("report.json", "2")]);
    assert_eq!(names(&dir), [RUN_MARKER, "report.json"]);
    assert_eq!(
        std::fs::read_to_string(dir.join("report.json")).unwrap(),
        "2"
    );
    // Staged and dropped: nothing changes, nothing is left behind.
    {
        let s = folder.stage().unwrap();
        std::fs::write(s.path().join("report.json"), "3").unwrap();
    }
    assert_eq!(
        std::fs::read_to_string(dir.join("report.json")).unwrap(),
        "2"
    );
    assert_eq!(names(&root), [".run.lock", "run"]);
    drop(folder);
    assert_eq!(names(&root), ["run"]);
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_second_writer_is_refused_with_the_owner_pid() {
    let root = scratch("lock");
    let dir = root.join("run");
    let first = RunFolder::lock(&dir).unwrap();
    let e = RunFolder::lock(&dir).unwrap_err();
    match &e {
        Error::Locked { pid, .. } => assert_eq!(*pid, Some(std::process::id())),
        other => panic!("{other}"),
    }
    assert!(e.to_string().contains("another latentam process"), "{e}");
    // The same folder through another spelling is the same lock.
    let e = RunFolder::lock(root.join(".").join("run")).unwrap_err();
    assert!(matches!(e, Error::Locked { .. }), "{e}");
    drop(first);
    RunFolder::lock(&dir).unwrap();
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn folders_that_are_not_runs_are_refused() {
    let root = scratch("foreign");
    let dir = root.join("notes");
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join("thesis.tex"), "precious").unwrap();
    std::fs::write(dir.join("map.ply"), "ours").unwrap();
    let e = RunFolder::lock(&dir).unwrap_err().to_string();
    assert!(
        e.contains("not a latentam run folder") && e.contains(RUN_MARKER),
        "{e}"
    );
    assert!(dir.join("thesis.tex").exists());
    let file = root.join("file");
    std::fs::write(&file, "x").unwrap();
    let e = RunFolder::lock(&file).unwrap_err().to_string();
    assert!(e.contains("not a directory"), "{e}");
    assert!(RunFolder::lock("/").is_err());
    std::fs::remove_dir_all(&root).unwrap();
}

/// Every file under `dir` with its bytes (links as their targets' paths).
fn tree(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let meta = std::fs::symlink_metadata(&path).unwrap();
        if meta.is_dir() {
            out.push((path.clone(), Vec::new()));
            out.extend(tree(&path));
        } else if meta.is_symlink() {
            let target = std::fs::read_link(&path).unwrap();
            out.push((path, target.to_string_lossy().into_owned().into_bytes()));
        } else {
            out.push((path.clone(), std::fs::read(&path).unwrap()));
        }
    }
    out.sort();
    out
}

/// A user's folder that merely holds files with a run's names (their own
/// configuration, a report, a PLY from another tool, a folder named like
/// the trace) is no run folder: it is refused, and every byte stays.
#[test]
fn a_users_folder_with_run_file_names_is_never_replaced() {
    let root = scratch("run-names");
    let planted: &[(&str, &[u8])] = &[
        (
            "config.toml",
            b"# my own settings, with comments\nvoxel_size = 0.02\n",
        ),
        ("report.json", b"{\"mine\": true}"),
        ("trajectory.txt", b"0 0 0 0 0 0 0 1\n"),
        ("map.ply", b"ply\nformat ascii 1.0\nend_header\n"),
        ("trace.json/photos/img1.jpg", b"\xff\xd8 a photo"),
    ];
    for (i, only) in [None, Some(3), Some(4)].into_iter().enumerate() {
        let dir = root.join(format!("proj{i}"));
        for (name, bytes) in planted
            .iter()
            .skip(only.unwrap_or(0))
            .take(only.map_or(9, |_| 1))
        {
            let path = dir.join(name);
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, bytes).unwrap();
        }
        let before = tree(&dir);
        let e = match RunFolder::lock(&dir) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{}: a user's folder was taken as a run", dir.display()),
        };
        assert!(e.contains("not a latentam run folder"), "{e}");
        assert_eq!(tree(&dir), before, "{}", dir.display());
    }
    std::fs::remove_dir_all(&root).unwrap();
}

/// An empty folder becomes a run; a run folder the user put a folder or a
/// file of their own into is refused, with those left as they were.
#[test]
fn only_empty_folders_and_the_tools_own_runs_are_replaced() {
    let root = scratch("marked");
    let dir = root.join("run");
    std::fs::create_dir_all(&dir).unwrap();
    let folder = RunFolder::lock(&dir).unwrap();
    commit(&folder, &[("map.ply", "v1"), ("trace.json", "{}")]);
    drop(folder);
    assert!(folder_version(&dir).is_some());
    // The tool's own run is replaced.
    let folder = RunFolder::lock(&dir).unwrap();
    commit(&folder, &[("map.ply", "v2")]);
    drop(folder);
    assert_eq!(std::fs::read_to_string(dir.join("map.ply")).unwrap(), "v2");
    for (name, bytes) in [
        ("trace.json/photos/img1.jpg", "a photo"),
        ("notes.txt", "mine"),
    ] {
        let path = dir.join(name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(&path, bytes).unwrap();
        let before = tree(&dir);
        let e = match RunFolder::lock(&dir) {
            Err(e) => e.to_string(),
            Ok(_) => panic!("{name}: a run folder holding a user's entry was replaced"),
        };
        assert!(
            e.contains("not part of a latentam run") && e.contains("move them out"),
            "{e}"
        );
        assert_eq!(tree(&dir), before);
        let first = name.split('/').next().unwrap();
        let _ = std::fs::remove_dir_all(dir.join(first));
        let _ = std::fs::remove_file(dir.join(first));
    }
    std::fs::remove_dir_all(&root).unwrap();
}

/// A dangling link as the run folder is refused when it is locked, before
/// any mapping, and stays as it was.
#[cfg(unix)]
#[test]
fn a_link_to_nothing_is_refused_at_once() {
    let root = scratch("dangling");
    let link = root.join("run");
    std::os::unix::fs::symlink(root.join("gone"), &link).unwrap();
    let e = match RunFolder::lock(&link) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a dangling link was taken as a run folder"),
    };
    assert!(e.contains("does not exist") && e.contains("gone"), "{e}");
    assert_eq!(std::fs::read_link(&link).unwrap(), root.join("gone"));
    assert!(!root.join("gone").exists());
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn a_swap_cut_short_is_repaired_when_locked_again() {
    let root = scratch("repair");
    let dir = root.join("run");
    commit(&RunFolder::lock(&dir).unwrap(), &[("report.json", "old")]);
    // A crash between moving the run aside and moving the next in, with
    // a staging folder left behind.
    std::fs::rename(&dir, root.join(".run.old-00ff")).unwrap();
    std::fs::create_dir(root.join(".run.staging-0100")).unwrap();
    std::fs::write(root.join(".run.staging-0100/report.json"), "new").unwrap();
    std::fs::write(root.join(".run.staging-0100").join(RUN_MARKER), "0100").unwrap();
    // A sibling run whose name shares the prefix is not touched.
    std::fs::create_dir(root.join(".run.x.staging-1")).unwrap();
    let folder = RunFolder::lock(&dir).unwrap();
    assert_eq!(
        std::fs::read_to_string(dir.join("report.json")).unwrap(),
        "old"
    );
    assert_eq!(names(&root), [".run.lock", ".run.x.staging-1", "run"]);
    drop(folder);
    std::fs::remove_dir_all(&root).unwrap();
}

/// Folders that only look like the tool's own (a user's backup named
/// like a moved-aside run, a staging name with another id in its
/// marker, a link to a folder) are neither removed nor moved into
/// place.
/// Destinations that could never be committed are refused when the
/// folder is locked, before any mapping: a name without room for the
/// staging folder's, a mount point (by fault injection), a parent
/// without write permission.
/// A reader of a folder that a writer swaps again and again always
/// gets the two files of one version.
#[test]
fn readers_get_one_version_while_a_writer_swaps() {
    let root = scratch("readers");
    let dir = root.join("run");
    commit(
        &RunFolder::lock(&dir).unwrap(),
        &[("report.json", "0"), ("trace.json", "0")],
    );
    let stop = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| {
            let folder = RunFolder::lock(&dir).unwrap();
            let mut n = 0u32;
            while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                n += 1;
                let v = n.to_string();
                commit(&folder, &[("report.json", &v), ("trace.json", &v)]);
            }
        });
        let read = || -> Result<(String, String)> {
            let a =
                std::fs::read_to_string(dir.join("report.json")).map_err(|e| io_error(&dir, e))?;
            std::thread::yield_now();
            let b =
                std::fs::read_to_string(dir.join("trace.json")).map_err(|e| io_error(&dir, e))?;
            Ok((a, b))
        };
        let mut mixed_unguarded = 0;
        for _ in 0..300 {
            let (a, b) = read_one_version(&dir, read).expect("one whole version");
            assert_eq!(a, b, "a read mixed two versions");
            mixed_unguarded += usize::from(read().map_or(true, |(a, b)| a != b));
        }
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        eprintln!("unguarded reads that mixed versions or missed a file: {mixed_unguarded}/300");
    });
    std::fs::remove_dir_all(&root).unwrap();
}

/// Folder names that differ only in bytes that are not UTF-8 are two
/// folders: each has its own lock and staging folders (a lossy name
/// made them share one lock, so the second writer was refused).
#[cfg(unix)]
#[test]
fn names_that_are_not_utf8_keep_their_own_lock() {
    use std::os::unix::ffi::OsStrExt;
    let root = scratch("not-utf8");
    let a = root.join(std::ffi::OsStr::from_bytes(b"run\xff"));
    let b = root.join(std::ffi::OsStr::from_bytes(b"run\xfe"));
    let first = RunFolder::lock(&a).unwrap();
    let second = RunFolder::lock(&b).unwrap();
    for folder in [&first, &second] {
        let staging = folder.stage().unwrap();
        std::fs::write(staging.path().join("state.latentam"), "x").unwrap();
        staging.commit().unwrap();
    }
    assert!(a.join("state.latentam").is_file() && b.join("state.latentam").is_file());
    let locks: Vec<_> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .filter(|n| n.as_bytes().ends_with(b".lock"))
        .collect();
    assert_eq!(locks.len(), 2, "{locks:?}");
    drop((first, second));
    std::fs::remove_dir_all(&root).ok();
}

#[test]
fn destinations_that_cannot_be_committed_fail_at_once() {
    let root = scratch("uncommittable");
    let long = root.join("r".repeat(MAX_NAME_BYTES + 1));
    let e = RunFolder::lock(&long).unwrap_err().to_string();
    assert!(e.contains("at most 221 bytes"), "{e}");
    assert!(RunFolder::lock(root.join("r".repeat(MAX_NAME_BYTES))).is_ok());
    let dir = root.join("run");
    std::fs::create_dir_all(&dir).unwrap();
    assert!(check_committable(&dir, &root, "run".as_ref()).is_ok());
    // The file system's root is on another device than /proc.
    #[cfg(target_os = "linux")]
    {
        let e = check_committable(Path::new("/proc"), Path::new("/"), "proc".as_ref())
            .unwrap_err()
            .to_string();
        assert!(e.contains("is a mount point"), "{e}");
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let locked = root.join("read-only");
        std::fs::create_dir_all(&locked).unwrap();
        std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o555)).unwrap();
        // Root may write anyway; everyone else is refused at once.
        let writable = std::fs::write(locked.join("probe"), b"").is_ok();
        let _ = std::fs::remove_file(locked.join("probe"));
        if !writable {
            assert!(RunFolder::lock(locked.join("run")).is_err());
        }
        std::fs::set_permissions(&locked, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn only_folders_the_tool_made_are_removed_or_moved_back() {
    let root = scratch("marker");
    let dir = root.join("run");
    let user = |name: &str| {
        let p = root.join(name);
        std::fs::create_dir(&p).unwrap();
        std::fs::write(p.join("thesis.tex"), "precious").unwrap();
        p
    };
    // With the run absent, a user's `.run.old-2024` is not renamed to it.
    user(".run.old-2024");
    user(".run.staging-mine");
    let wrong_id = user(".run.staging-00aa");
    std::fs::write(wrong_id.join(RUN_MARKER), "00bb").unwrap();
    let target = user("elsewhere");
    std::fs::write(target.join(RUN_MARKER), "00cc").unwrap();
    #[cfg(unix)]
    std::os::unix::fs::symlink(&target, root.join(".run.old-00cc")).unwrap();
    commit(&RunFolder::lock(&dir).unwrap(), &[("report.json", "new")]);
    commit(&RunFolder::lock(&dir).unwrap(), &[("report.json", "newer")]);
    assert_eq!(
        std::fs::read_to_string(dir.join("report.json")).unwrap(),
        "newer"
    );
    for name in [
        ".run.old-2024",
        ".run.staging-mine",
        ".run.staging-00aa",
        "elsewhere",
    ] {
        let p = root.join(name).join("thesis.tex");
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "precious", "{name}");
    }
    #[cfg(unix)]
    assert!(root.join(".run.old-00cc").exists(), "the link is left too");
    // The run's own versions carry the marker.
    let id = std::fs::read_to_string(dir.join(RUN_MARKER)).unwrap();
    assert!(
        !id.is_empty() && id.bytes().all(|b| b.is_ascii_hexdigit()),
        "{id}"
    );
    std::fs::remove_dir_all(&root).unwrap();
}

#[test]
fn the_fallback_swap_gives_the_same_result() {
    let root = scratch("fallback");
    let dir = root.join("run");
    commit(&RunFolder::lock(&dir).unwrap(), &[("map.ply", "1")]);
    let folder = RunFolder::lock(&dir).unwrap();
    // Exchange refused (as on file systems without it): rename twice.
    let s = folder.stage().unwrap();
    std::fs::write(s.path().join("report.json"), "2").unwrap();
    let old = root.join(format!(".run.old-{}", s.run_id()));
    replace_by_renames(s.path(), &dir, &old).unwrap();
    assert_eq!(names(&dir), [RUN_MARKER, "report.json"]);
    assert!(!old.exists() && !s.path().exists());
    drop(s);
    // A second rename that fails puts the run back.
    let missing = root.join("missing-staging");
    assert!(replace_by_renames(&missing, &dir, &old).is_err());
    assert_eq!(names(&dir), [RUN_MARKER, "report.json"]);
    drop(folder);
    assert!(exchange(&root.join("nope-a"), &root.join("nope-b")).is_err());
    std::fs::remove_dir_all(&root).unwrap();
}

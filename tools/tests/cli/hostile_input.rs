//! FIFOs given as inputs, and escape sequences and huge values in text
//! the binary prints.

use super::*;

/// Makes a FIFO at `path`.
fn mkfifo(path: &std::path::Path) {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(path.as_os_str().as_bytes()).unwrap();
    // SAFETY: `c` is a NUL-terminated path that outlives the call.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

#[test]
fn fifos_given_as_inputs_are_refused_without_blocking() {
    use std::ffi::OsStr;
    use std::process::Stdio;
    use std::time::{Duration, Instant};

    let dir = common::scratch("cli-fifo");
    let fifo = dir.join("x.mcap");
    mkfifo(&fifo);
    // A rosbag2 folder whose split file is a link to the FIFO.
    let bag = dir.join("bag");
    std::fs::create_dir(&bag).unwrap();
    std::os::unix::fs::symlink(&fifo, bag.join("bag_0.mcap")).unwrap();
    // TUM folders: one whose list is a FIFO, one whose images are.
    let tum_list = dir.join("tum-list");
    std::fs::create_dir(&tum_list).unwrap();
    mkfifo(&tum_list.join("rgb.txt"));
    let tum_images = dir.join("tum-images");
    for sub in ["rgb", "depth"] {
        std::fs::create_dir_all(tum_images.join(sub)).unwrap();
        mkfifo(&tum_images.join(sub).join("1.png"));
    }
    for (name, text) in [
        ("rgb.txt", "1.0 rgb/1.png\n"),
        ("depth.txt", "1.0 depth/1.png\n"),
        ("groundtruth.txt", "1.0 0 0 0 0 0 0 1\n"),
    ] {
        std::fs::write(tum_images.join(name), text).unwrap();
    }
    let scene = common::gen_scene(&dir, 3);
    let run = dir.join("run");
    run_ok(&[
        OsStr::new("map"),
        scene.as_os_str(),
        OsStr::new("--out"),
        run.as_os_str(),
    ]);
    let out = dir.join("out");
    let converted = dir.join("converted.mcap");

    let os = |s: &'static str| -> &OsStr { s.as_ref() };
    let cases: Vec<Vec<&OsStr>> = vec![
        vec![os("inspect"), fifo.as_os_str()],
        vec![os("inspect"), bag.as_os_str()],
        vec![os("map"), fifo.as_os_str(), os("--out"), out.as_os_str()],
        vec![os("map"), bag.as_os_str(), os("--out"), out.as_os_str()],
        vec![
            os("map"),
            scene.as_os_str(),
            os("--config"),
            fifo.as_os_str(),
            os("--out"),
            out.as_os_str(),
        ],
        vec![os("config"), os("--config"), fifo.as_os_str()],
        vec![os("eval"), run.as_os_str(), fifo.as_os_str()],
        vec![
            os("query"),
            run.as_os_str(),
            os("--embedding"),
            fifo.as_os_str(),
        ],
        vec![
            os("query"),
            run.as_os_str(),
            os("--name"),
            os("chair"),
            os("--vocabulary"),
            fifo.as_os_str(),
        ],
        vec![
            os("convert"),
            os("tum"),
            tum_list.as_os_str(),
            os("-o"),
            converted.as_os_str(),
        ],
        vec![
            os("convert"),
            os("tum"),
            tum_images.as_os_str(),
            os("--intrinsics"),
            os("500"),
            os("500"),
            os("320"),
            os("240"),
            os("-o"),
            converted.as_os_str(),
        ],
    ];
    for args in cases {
        let mut child = latentam()
            .args(&args)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let started = Instant::now();
        while child.try_wait().unwrap().is_none() {
            if started.elapsed() > Duration::from_secs(20) {
                child.kill().unwrap();
                let _ = child.wait();
                panic!("latentam {args:?} blocked on the FIFO for 20 s");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let output = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(1), "{args:?}: {err}");
        assert!(
            err.contains("a FIFO, not a regular file") && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
    assert!(!out.exists() && !converted.exists());
    std::fs::remove_dir_all(&dir).ok();
}

/// Text from the command line or a file is printed defused: an escape
/// sequence in a value is shown escaped, never sent to the terminal, and a
/// huge value is cut.
#[test]
fn errors_show_escape_sequences_escaped_and_huge_values_cut() {
    let dir = std::env::temp_dir().join(format!("latentam-hygiene-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let missing = dir.join("missing.mcap");
    for value in ["\u{1b}[2J\rerror: forged".to_string(), "9".repeat(100_000)] {
        let out = latentam()
            .arg("map")
            .arg(&missing)
            .arg("--out")
            .arg(dir.join("run"))
            .arg("--set")
            .arg(format!("seeding.stride={value}"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !stderr.contains('\u{1b}') && !stderr.contains('\r'),
            "{stderr:?}"
        );
        assert!(stderr.len() < 10_000, "{} bytes of stderr", stderr.len());
        assert!(stderr.starts_with("error: "), "{stderr:?}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// Text a log carries (topic, type and metadata names and values) and
/// paths a user gives (an `--out` folder named with an escape sequence)
/// reach the terminal escaped: no escape, bell or carriage return is
/// printed as it is, by `inspect` or by `map`.
#[test]
fn text_from_logs_and_paths_is_printed_escaped() {
    use latentam::logs::{Compression, LogWriter};
    use latentam::messages::{CompressedImage, Header, Time};
    let dir = std::env::temp_dir().join(format!("latentam-escapes-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let hostile = "\u{1b}[2J\u{1b}]0;pwned\u{7}\rforged";
    let log = dir.join("hostile.mcap");
    let mut w = LogWriter::create(&log, Compression::None).unwrap();
    // A colour stream named with escapes, whose frame id and format carry
    // them too (the frames do not decode: `inspect` says so, escaped).
    let header = Header {
        stamp: Time { sec: 1, nanosec: 0 },
        frame_id: hostile,
    };
    let image = CompressedImage {
        header,
        format: hostile,
        data: b"not a jpeg",
    };
    w.write(&format!("/camera/color/image_raw{hostile}"), 1, &image)
        .unwrap();
    let values = [(format!("key{hostile}"), hostile.to_string())].into();
    w.metadata(&format!("meta{hostile}"), values).unwrap();
    w.finish().unwrap();
    let defused = |what: &str, out: &std::process::Output| {
        for (stream, bytes) in [("stdout", &out.stdout), ("stderr", &out.stderr)] {
            let text = String::from_utf8_lossy(bytes);
            assert!(
                !text.contains(['\u{1b}', '\u{7}', '\r']),
                "{what} {stream}: {text:?}"
            );
        }
    };
    let inspected = latentam().arg("inspect").arg(&log).output().unwrap();
    let stdout = String::from_utf8_lossy(&inspected.stdout);
    assert!(stdout.contains("image_raw\\u{1b}[2J"), "{stdout}");
    defused("inspect", &inspected);

    let scene = common::gen_scene(&dir, 4);
    let out = dir.join(format!("run{hostile}"));
    let mapped = latentam()
        .arg("map")
        .arg(&scene)
        .arg("--out")
        .arg(&out)
        .arg("--no-trace")
        .output()
        .unwrap();
    assert!(
        mapped.status.success(),
        "{}",
        String::from_utf8_lossy(&mapped.stderr)
    );
    assert!(String::from_utf8_lossy(&mapped.stdout).contains("run\\u{1b}[2J"));
    defused("map", &mapped);
    std::fs::remove_dir_all(&dir).ok();
}

/// A write past the file-size limit (`ulimit -f`) is an error the tool
/// reports, with exit status 1 and no partial file left, not a SIGXFSZ
/// that ends it with nothing said.
#[cfg(unix)]
#[test]
fn a_file_size_limit_is_an_error_not_a_signal() {
    let dir = std::env::temp_dir().join(format!("latentam-fsize-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("scene.mcap");
    // 64 blocks: far less than the log needs.
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg("ulimit -f 64 && exec \"$0\" gen-scene --frames 8 -o \"$1\"")
        .arg(env!("CARGO_BIN_EXE_latentam"))
        .arg(&log)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{:?}: {stderr}", out.status);
    assert!(
        stderr.contains("error:") && stderr.contains("too large"),
        "{stderr}"
    );
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
    assert!(left.is_empty(), "{left:?}");
    std::fs::remove_dir_all(&dir).ok();
}

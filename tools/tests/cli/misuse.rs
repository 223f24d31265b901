//! Command-line misuse of every subcommand: a clear error and exit status.

use super::*;

/// Runs each `(args, exit status, words)` case: it must fail with that
/// status, print the expected words on stderr, and not panic.
fn fails_clearly(cases: &[(Vec<&std::ffi::OsStr>, i32, &str)]) {
    for (args, code, want) in cases {
        let out = latentam().args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(*code), "{args:?}: {err}");
        assert!(
            err.contains(want) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn command_line_misuse_is_a_clear_error() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-misuse-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let run = dir.join("run");
    let log = dir.join("missing.mcap");
    let q = dir.join("q.npy");
    write_npy(&q, &[1.0; 4]);
    let png = dir.join("v.png");
    let os = |s: &'static str| -> &std::ffi::OsStr { s.as_ref() };
    let map = |extra: &[&'static str]| {
        let mut a = vec![os("map"), log.as_os_str(), os("--out"), run.as_os_str()];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let query_view = |view: &'static str| {
        vec![
            os("query"),
            run.as_os_str(),
            os("--embedding"),
            q.as_os_str(),
            os("--view"),
            os(view),
            os("--png"),
            png.as_os_str(),
        ]
    };
    let exit_error = 1;
    let usage_error = 2;
    fails_clearly(&[
        (map(&["--resume"]), exit_error, "holds no saved map"),
        (
            map(&["--tolerance-ms=-1"]),
            exit_error,
            "--tolerance-ms must be",
        ),
        (
            map(&["--depth-scale", "0"]),
            exit_error,
            "--depth-scale must be",
        ),
        (
            map(&["--max-extent", "1e300"]),
            exit_error,
            "--max-extent must be",
        ),
        (
            map(&["--max-depth", "NaN"]),
            exit_error,
            "--max-depth must be",
        ),
        (query_view("1,2,3"), exit_error, "expected 7 finite numbers"),
        (query_view("a,b,c,d,e,f,g"), exit_error, "not numbers"),
        (query_view("0,0,0,0,0,0,2"), exit_error, "has norm 2.0000"),
        (query_view("0,0,0,nan,0,0,1"), exit_error, "finite"),
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--view"),
                os("0,0,0,0,0,0,1"),
            ],
            usage_error,
            "--png",
        ),
        (
            vec![os("query"), run.as_os_str(), os("--name"), os("chair")],
            usage_error,
            "--vocabulary",
        ),
        (
            vec![os("query"), run.as_os_str()],
            usage_error,
            "--embedding",
        ),
        (
            vec![
                os("convert"),
                os("7scenes"),
                dir.as_os_str(),
                os("--fps"),
                os("0"),
                os("-o"),
                log.as_os_str(),
            ],
            exit_error,
            "--fps must be from 0.001 to 1000000 frames per second, got 0.0",
        ),
        (
            // Stamps past i64 (the generator overflowed them), or all one.
            vec![
                os("gen-scene"),
                os("--fps"),
                os("1e-300"),
                os("-o"),
                log.as_os_str(),
            ],
            exit_error,
            "frame rate 1e-300 outside 0.001…1000000 frames per second",
        ),
        (
            vec![
                os("gen-scene"),
                os("--fps"),
                os("1e300"),
                os("-o"),
                log.as_os_str(),
            ],
            exit_error,
            "frame rate 1e300 outside",
        ),
    ]);
    assert!(!run.exists() && !png.exists() && !log.exists());

    // --config files: unknown key, wrong type, out of range, not TOML,
    // missing.
    let mut cases = Vec::new();
    for (name, text, want) in [
        ("unknown.toml", "replya = 3\n", "unknown field `replya`"),
        ("type.toml", "replay = \"x\"\n", "expected u32"),
        (
            "range.toml",
            "voxel_size = 0\n",
            "setting `voxel_size`: 0 must be from 0.0001 to 1 metres",
        ),
        ("syntax.toml", "replay = [\n", "TOML parse error"),
    ] {
        std::fs::write(dir.join(name), text).unwrap();
        cases.push((name, want));
    }
    cases.push(("missing.toml", "No such file"));
    let files: Vec<_> = cases.iter().map(|(name, _)| dir.join(name)).collect();
    fails_clearly(
        &cases
            .iter()
            .zip(&files)
            .map(|((_, want), file)| {
                (
                    vec![os("config"), os("--config"), file.as_os_str()],
                    exit_error,
                    *want,
                )
            })
            .collect::<Vec<_>>(),
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn query_render_and_export_misuse_are_clear_errors() {
    let dir = std::env::temp_dir().join(format!("latentam-cli-query-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let os = |s: &'static str| -> &std::ffi::OsStr { s.as_ref() };
    // Two small logs whose embeddings differ in dimension (11 classes each:
    // 11 × 16 values divide into 22-d rows, which used to be taken for 8
    // texts and crash the softmax).
    let scene = |dim: &str| {
        let log = dir.join(format!("s{dim}.mcap"));
        let mut a = vec![
            os("gen-scene"),
            os("--frames"),
            os("4"),
            os("--width"),
            os("48"),
            os("--height"),
            os("32"),
        ];
        a.extend([os("--dim"), dim.as_ref(), os("-o"), log.as_os_str()]);
        run_ok(&a);
        log
    };
    let (s22, s16) = (scene("22"), scene("16"));
    let run = dir.join("run");
    run_ok(&[os("map"), s22.as_os_str(), os("--out"), run.as_os_str()]);
    let plain = dir.join("plain");
    run_ok(&[
        os("map"),
        s22.as_os_str(),
        os("--out"),
        plain.as_os_str(),
        os("--embeddings-topic"),
        os("/none"),
    ]);
    // Mapped without embeddings: no latent properties, no decoder.
    let ply = std::fs::read(plain.join("map.ply")).unwrap();
    let end = ply.windows(10).position(|w| w == b"end_header").unwrap();
    assert!(!String::from_utf8_lossy(&ply[..end]).contains("latent_"));
    assert!(!plain.join("decoder.safetensors").exists());
    assert!(latentam::interchange::read_ply(&plain.join("map.ply")).is_ok());
    let short = dir.join("short.npy");
    write_npy(&short, &[1.0; 8]);
    let zeros = dir.join("zeros.npy");
    write_npy(&zeros, &[0.0; 22]);
    // `--name NAME --vocabulary LOG`, LOG the 22-d log or the 16-d one.
    let by_name = |name: &'static str, dim: u32, extra: &[&'static str]| {
        let vocabulary = if dim == 16 { &s16 } else { &s22 };
        let mut a = vec![
            os("query"),
            run.as_os_str(),
            os("--name"),
            os(name),
            os("--vocabulary"),
            vocabulary.as_os_str(),
        ];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let nowhere = dir.join("nowhere");
    fails_clearly(&[
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--embedding"),
                short.as_os_str(),
            ],
            1,
            "the query has 8 values; the map's embeddings are 22-d",
        ),
        (
            vec![
                os("query"),
                run.as_os_str(),
                os("--embedding"),
                zeros.as_os_str(),
            ],
            1,
            "all zeros",
        ),
        (
            by_name("sofa", 22, &[]),
            1,
            "`sofa` is not in the vocabulary",
        ),
        (
            by_name("ball", 16, &[]),
            1,
            "16-d embeddings (the vocabulary's",
        ),
        (
            by_name("ball", 22, &["--vocabulary-topic", "/nope"]),
            1,
            "has no vocabulary on /nope",
        ),
        (
            by_name("ball", 22, &["--temperature", "0"]),
            1,
            "--temperature: softmax temperature 0 is outside 0.0009765625..=10",
        ),
        (
            // Past f32's range: infinite, and said so.
            by_name("ball", 22, &["--temperature", "1e308"]),
            1,
            "softmax temperature inf is outside",
        ),
        (
            // Small enough to overflow the scores: refused too.
            by_name("ball", 22, &["--temperature", "1e-45"]),
            1,
            "softmax temperature 0.000000000000000000000000000000000000000000001 is outside",
        ),
        (
            vec![
                os("query"),
                plain.as_os_str(),
                os("--embedding"),
                zeros.as_os_str(),
            ],
            1,
            "mapped without embeddings",
        ),
        (
            vec![
                os("query"),
                nowhere.as_os_str(),
                os("--embedding"),
                short.as_os_str(),
            ],
            1,
            "loading the map",
        ),
    ]);
    let out = dir.join("views").join("v");
    let render = |extra: &[&'static str]| {
        let mut a = vec![os("render"), run.as_os_str(), os("--out"), out.as_os_str()];
        a.extend(extra.iter().map(|s| os(s)));
        a
    };
    let render_frame = |run: &std::path::Path, n: &'static str, extra: &[&'static str]| {
        let mut a = vec![
            os("render").to_owned(),
            run.as_os_str().to_owned(),
            s22.as_os_str().to_owned(),
            os("--frame").to_owned(),
            os(n).to_owned(),
            os("--out").to_owned(),
            out.as_os_str().to_owned(),
        ];
        a.extend(extra.iter().map(|s| os(s).to_owned()));
        a
    };
    let (f99, plain_named, sofa) = (
        render_frame(&run, "99", &[]),
        render_frame(&plain, "0", &["--name", "ball"]),
        render_frame(&run, "0", &["--name", "sofa"]),
    );
    let mut both = render_frame(&run, "0", &["--view"]);
    both.push("0,0,0,0,0,0,1".into());
    fn refs(v: &[std::ffi::OsString]) -> Vec<&std::ffi::OsStr> {
        v.iter().map(|s| s.as_os_str()).collect()
    }
    fails_clearly(&[
        (render(&[]), 2, "--frame"),
        (render(&["--frame", "3"]), 2, "<LOG>"),
        (
            render(&["--view", "0,0,0,0,0,0,1", "--name", "ball"]),
            1,
            "--name needs --vocabulary LOG",
        ),
        (refs(&f99), 1, "has 4 frames: there is no frame 99"),
        (refs(&plain_named), 1, "mapped without embeddings"),
        (refs(&sofa), 1, "`sofa` is not in the vocabulary"),
        (refs(&both), 2, "cannot be used with"),
    ]);
    assert!(
        !dir.join("views").exists(),
        "a failed render wrote pictures"
    );
    let fox = dir.join("fox.mcap");
    let export = |run: &std::path::Path, extra: &[&'static str]| {
        let mut a = vec![
            os("export").to_owned(),
            run.as_os_str().to_owned(),
            os("--foxglove").to_owned(),
            fox.as_os_str().to_owned(),
        ];
        a.extend(extra.iter().map(|s| os(s).to_owned()));
        a
    };
    let mut other_vocabulary = export(&run, &["--vocabulary"]);
    other_vocabulary.push(s16.clone().into());
    let mut unknown_word = export(&run, &["--words", "sofa", "--vocabulary"]);
    unknown_word.push(s22.clone().into());
    fails_clearly(&[
        (
            refs(&export(&plain, &["--words", "ball"])),
            1,
            "--words needs a vocabulary: the map was mapped without embeddings",
        ),
        (refs(&unknown_word), 1, "`sofa` is not in the vocabulary"),
        (
            refs(&other_vocabulary),
            1,
            "16-d embeddings (the vocabulary's",
        ),
        (
            refs(&export(&run, &["--temperature", "0"])),
            1,
            "--temperature: softmax temperature 0 is outside",
        ),
        (
            refs(&export(&run, &["--frame-id", " "])),
            1,
            "--frame-id must name a frame",
        ),
    ]);
    assert!(!fox.exists(), "a failed export wrote a file");
    // A map without embeddings exports its cloud and trajectory only.
    let stdout = run_ok(&refs(&export(&plain, &[])));
    assert!(
        stdout.contains("/latentam/map") && !stdout.contains("/latentam/relevance"),
        "{stdout}"
    );
    assert!(fox.exists());
    std::fs::remove_dir_all(&dir).ok();
}

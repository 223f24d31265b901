//! The user's workflow through the `latentam` binary on a small generated
//! log: map → query → eval → profile, with every output's contents checked
//! against the engine (PLY against the saved state, the decoder file
//! against the GPU relevance, the trajectory against the log's poses),
//! and Ctrl-C during mapping followed by `--resume`.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Output, Stdio};

mod common;
use common::{gen_scene, latentam, run_python, scratch, write_npy, SCENE_DIM};
use latentam::frames::{read_vocabulary, AssemblyConfig, McapFrames};
use latentam::interchange::{read_ply, read_tum, unit_quat};
use latentam::{Config as MapperConfig, Context, ContextOptions, DecoderFile, Mapper};

const FRAMES: usize = 32;
const DIM: usize = SCENE_DIM;

fn ok(out: Output) -> String {
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum();
    let na: f64 = a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    dot / (na * nb).max(1e-30)
}

#[test]
fn map_query_eval_profile_on_a_generated_log() {
    let dir = scratch("workflow");
    let log = gen_scene(&dir, FRAMES);
    let run = dir.join("run");

    // map
    let stdout = ok(latentam()
        .arg("map")
        .arg(&log)
        .arg("--out")
        .arg(&run)
        .args(["--set", "replay=2", "--set", "seed=5"])
        .output()
        .unwrap());
    assert!(stdout.contains("8 keyframes"), "{stdout}");
    let report = json(&run.join("report.json"));
    assert_eq!(report["ending"], "complete");
    assert_eq!(report["frames"], FRAMES as u64);
    assert_eq!(report["keyframes"], (FRAMES / 4) as u64);
    let gaussians = report["gaussians"].as_u64().unwrap() as usize;
    assert!(gaussians > 1000, "{gaussians} Gaussians");
    assert!(report["peak_gpu_bytes"].as_u64().unwrap() > 0);
    // The process's peak RSS as the OS measured it: a mapping process
    // with a Vulkan driver holds tens of megabytes at least.
    let rss = report["peak_rss_bytes"].as_u64().unwrap();
    assert!((50 << 20..64 << 30).contains(&rss), "{rss} bytes");
    // Host waits are counted per keyframe.
    let waits = &report["host_waits_per_keyframe"];
    let (mean, max) = (
        waits["mean"].as_f64().unwrap(),
        waits["max"].as_u64().unwrap(),
    );
    assert!(mean >= 1.0 && max as f64 >= mean, "{waits}");
    // Stage I (one measuring wait; its step is covered by Stage II's) and
    // Stage II (one).
    assert_eq!(
        waits["stage_one_and_two_max"].as_u64().unwrap(),
        2,
        "{waits}"
    );
    assert!(
        waits["dispatches_mean"].as_f64().unwrap() > 100.0,
        "{waits}"
    );
    let calls = &report["keyframe_reports"][1]["gpu_calls"];
    // Stage I's measure; its step's wait is Stage II's.
    assert_eq!(calls["stage_one"]["host_waits"], 1, "{calls}");
    assert_eq!(calls["stage_two"]["host_waits"], 1, "{calls}");
    assert_eq!(report["keyframe_reports"].as_array().unwrap().len(), 8);
    assert!(report["kernels"].as_object().unwrap().len() > 10);
    // Paging per keyframe is the mean of every sync's figures.
    let keyframes = report["keyframe_reports"].as_array().unwrap();
    for field in ["bytes_up", "bytes_down", "blocks_in", "blocks_out"] {
        let sum: f64 = keyframes
            .iter()
            .flat_map(|k| k["paging"].as_array().unwrap())
            .map(|p| p[field].as_f64().unwrap())
            .sum();
        let mean = report["paging_per_keyframe"][field].as_f64().unwrap();
        assert!(
            (mean - sum / 8.0).abs() <= 1e-9 * sum.max(1.0),
            "{field}: {mean} vs {sum} / 8"
        );
    }

    // report.html: three plots over the keyframes and the kernel table,
    // with nothing fetched from elsewhere.
    let html = std::fs::read_to_string(run.join("report.html")).unwrap();
    assert_eq!(html.matches("<svg").count(), 3, "{html}");
    assert!(html.contains("Time per keyframe, by stage") && html.contains("Slowest kernels"));
    assert!(html.contains("raster_forward"));
    for fetch in ["src=", "href=", "@import", "url("] {
        assert!(!html.contains(fetch), "report.html fetches: {fetch}");
    }

    // config.toml: the effective configuration, overrides included.
    let cfg = MapperConfig::from_toml(&std::fs::read_to_string(run.join("config.toml")).unwrap())
        .unwrap();
    assert_eq!((cfg.replay, cfg.seed), (2, 5));

    // map.ply holds exactly the saved map's Gaussians.
    let ply = read_ply(&run.join("map.ply")).unwrap();
    assert_eq!(ply.gaussians.len(), gaussians);
    let ctx = Context::new(ContextOptions::default()).unwrap();
    let mut mapper = Mapper::load(&ctx, &run).unwrap();
    let map = mapper.snapshot().unwrap().to_gaussians();
    for (g, p) in map.iter().zip(&ply.gaussians) {
        assert_eq!((g.mean, g.log_scale), (p.mean, p.log_scale));
        assert_eq!(unit_quat(g.quat), p.quat);
        assert_eq!((g.opacity_logit, g.query), (p.opacity_logit, p.query));
        for c in 0..3 {
            assert!((g.color[c] - p.color[c]).abs() < 1e-5);
        }
    }

    // trajectory.txt: the keyframes' poses (every 4th frame of the log).
    let trajectory = read_tum(&run.join("trajectory.txt")).unwrap();
    let frames: Vec<_> = McapFrames::open(&log, AssemblyConfig::default())
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(trajectory.len(), 8);
    for (k, (stamp, pose)) in trajectory.iter().enumerate() {
        let f = &frames[4 * k];
        assert_eq!(*stamp, f.stamp_ns);
        assert!((pose.translation - f.pose.translation).length() < 1e-6);
        assert!(pose.rotation.dot(f.pose.rotation).abs() > 1.0 - 1e-9);
    }

    // trace.json: a Chrome trace of the mapping's kernels.
    let trace = json(&run.join("trace.json"));
    let events = trace["traceEvents"].as_array().unwrap();
    assert!(events.len() > 100);
    assert!(events.iter().all(|e| (e["ph"] == "X"
        && e["dur"].as_f64().unwrap() >= 0.0
        && e["tid"].is_u64())
        || e["ph"] == "M"));

    // query --embedding: the heat map's relevance is the cosine of each
    // Gaussian's decoded latent, decoded on the CPU from decoder.safetensors.
    let vocab = read_vocabulary(&log, "/vocabulary").unwrap().unwrap();
    let q = &vocab.vectors[..DIM];
    let npy = dir.join("q.npy");
    write_npy(&npy, q);
    let heat = dir.join("heat.ply");
    let stdout = ok(latentam()
        .arg("query")
        .arg(&run)
        .arg("--embedding")
        .arg(&npy)
        .arg("--out")
        .arg(&heat)
        .args(["--top", "3"])
        .output()
        .unwrap());
    assert!(stdout.contains("top 3"), "{stdout}");
    let heat_map = read_ply(&heat).unwrap();
    let (name, relevance) = &heat_map.extra[0];
    assert_eq!(name, "relevance");
    assert_eq!(relevance.len(), gaussians);
    let decoder = DecoderFile::read(&run.join("decoder.safetensors")).unwrap();
    assert_eq!(decoder.dim as usize, DIM);
    assert_eq!(decoder.model, vocab.model);
    assert!(decoder.atom_count() > 0);
    let step = (gaussians / 50).max(1);
    let sample: Vec<_> = ply
        .gaussians
        .iter()
        .step_by(step)
        .map(|g| g.query)
        .collect();
    let decoded = decoder.decode(&sample);
    for (i, e) in decoded.chunks_exact(DIM).enumerate() {
        let expected = cosine(e, q);
        let got = relevance[i * step] as f64;
        assert!(
            (got - expected).abs() < 2e-3,
            "Gaussian {}: {got} vs {expected}",
            i * step
        );
    }

    // query --name with a relevance image from the first keyframe's pose.
    let (_, p) = trajectory[0];
    let pose = format!(
        "{},{},{},{},{},{},{}",
        p.translation.x,
        p.translation.y,
        p.translation.z,
        p.rotation.x,
        p.rotation.y,
        p.rotation.z,
        p.rotation.w
    );
    let png = dir.join("view.png");
    ok(latentam()
        .arg("query")
        .arg(&run)
        .args(["--name", &vocab.names[0], "--vocabulary"])
        .arg(&log)
        .args(["--view", &pose, "--png"])
        .arg(&png)
        .output()
        .unwrap());
    let softmax = read_ply(&run.join("heatmap.ply")).unwrap();
    assert!(softmax.extra[0].1.iter().all(|&r| (0.0..=1.0).contains(&r)));
    let decoder_png =
        png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&png).unwrap()));
    let info = decoder_png.read_info().unwrap();
    assert_eq!((info.info().width, info.info().height), (120, 90));

    // export --foxglove: read back by the `mcap` package and checked
    // against Foxglove's published message types; the clouds are the map's
    // Gaussians and the relevance is what `query --name` gave.
    let fox = dir.join("fox.mcap");
    ok(latentam()
        .arg("export")
        .arg(&run)
        .arg("--foxglove")
        .arg(&fox)
        .arg("--vocabulary")
        .arg(&log)
        .output()
        .unwrap());
    let summary: serde_json::Value =
        serde_json::from_str(&run_python("foxglove_check.py", &[fox.as_os_str()])).unwrap();
    let topics = summary.as_object().unwrap();
    assert_eq!(topics.len(), 2 + vocab.names.len(), "{:?}", topics.keys());
    let points = |topic: &str| summary[topic]["points"].as_array().unwrap().clone();
    let map_points = points("/latentam/map");
    assert_eq!(map_points.len(), gaussians);
    for (g, p) in map.iter().zip(&map_points).step_by(97) {
        for (a, axis) in ["x", "y", "z"].iter().enumerate() {
            assert_eq!(p[axis].as_f64().unwrap() as f32, g.mean[a]);
        }
        let opacity = 1.0 / (1.0 + (-g.opacity_logit as f64).exp());
        assert!((p["opacity"].as_f64().unwrap() - opacity).abs() < 1e-6);
    }
    let word0 = vocab.names[0]
        .to_lowercase()
        .replace(|c: char| !c.is_ascii_alphanumeric(), "_");
    let cloud = points(&format!("/latentam/relevance/{word0}"));
    assert_eq!(
        summary[format!("/latentam/relevance/{word0}")]["frame_id"],
        "map"
    );
    for (p, r) in cloud.iter().zip(&softmax.extra[0].1) {
        assert!((p["relevance"].as_f64().unwrap() - *r as f64).abs() < 1e-4);
    }
    let poses = summary["/latentam/trajectory"]["poses"].as_array().unwrap();
    assert_eq!(poses.len(), trajectory.len());
    for (p, (_, t)) in poses.iter().zip(&trajectory) {
        assert!((p[0].as_f64().unwrap() - t.translation.x).abs() < 1e-6);
        assert!((p[6].as_f64().unwrap() - t.rotation.w).abs() < 1e-6);
    }

    // render --frame: the pictures are the engine's render of that frame's
    // camera, the frame's own image, and a relevance that is black where
    // the map covers too little.
    let prefix = dir.join("views").join("f6");
    let stdout = ok(latentam()
        .arg("render")
        .arg(&run)
        .arg(&log)
        .args(["--frame", "6", "--name", &vocab.names[0], "--out"])
        .arg(&prefix)
        .output()
        .unwrap());
    assert!(stdout.contains("f6-relevance.png"), "{stdout}");
    let picture = |suffix: &str| {
        let path = dir.join("views").join(format!("f6-{suffix}.png"));
        let mut d = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&path).unwrap()))
            .read_info()
            .unwrap();
        let mut buf = vec![0; d.output_buffer_size().unwrap()];
        let info = d.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb, "{suffix}");
        assert_eq!((info.width, info.height), (120, 90), "{suffix}");
        buf
    };
    let mut again = Mapper::load(&ctx, &run).unwrap();
    let (view, _) = again.render(&frames[6]).unwrap();
    let expected: Vec<u8> = view
        .rgbd
        .iter()
        .flat_map(|p| (0..3).map(move |c| (p[c].clamp(0.0, 1.0) * 255.0).round() as u8))
        .collect();
    let colour = picture("color");
    let off = colour
        .iter()
        .zip(&expected)
        .filter(|(a, b)| a.abs_diff(**b) > 1)
        .count();
    assert!(
        off * 1000 < colour.len(),
        "{off} colour values differ from the engine's render"
    );
    assert_eq!(picture("input"), frames[6].color.to_rgb8());
    let relevance = picture("relevance");
    for (i, &a) in view.alpha.iter().enumerate() {
        if a < 0.4 {
            assert_eq!(
                relevance[3 * i..3 * i + 3],
                [0, 0, 0],
                "pixel {i}, alpha {a}"
            );
        }
    }
    assert!(
        relevance.iter().any(|&v| v > 0),
        "the relevance picture is black"
    );
    for suffix in ["depth", "input-depth"] {
        assert!(picture(suffix).iter().any(|&v| v > 0), "{suffix} is black");
    }
    drop(again);

    // eval on every other frame: keyframes and views that never were,
    // reported apart.
    let eval = dir.join("eval.json");
    let stdout = ok(latentam()
        .arg("eval")
        .arg(&run)
        .arg(&log)
        .arg("--json")
        .arg(&eval)
        .args(["--every", "2", "--offset", "2"])
        .output()
        .unwrap());
    assert!(stdout.contains("novel views"), "{stdout}");
    let e = json(&eval);
    assert_eq!(e["frames_evaluated"], 15);
    let per_frame = e["per_frame"].as_array().unwrap();
    assert_eq!(per_frame.len(), 15);
    assert_eq!(per_frame[1]["frame"], 4);
    let keyframe_stamps: Vec<i64> = mapper
        .snapshot()
        .unwrap()
        .trajectory
        .iter()
        .map(|t| t.0)
        .collect();
    let mut novel = 0;
    for f in per_frame {
        let stamp = f["stamp_ns"].as_i64().unwrap();
        assert_eq!(f["keyframe"], keyframe_stamps.contains(&stamp), "{f}");
        novel += usize::from(f["keyframe"] == false);
    }
    assert_eq!(novel, 8, "frames 2, 6, …, 30 were never keyframes");
    assert_eq!(e["novel_views"]["frames"], 8);
    assert_eq!(e["keyframes"]["frames"], 7);
    for group in ["keyframes", "novel_views"] {
        let g = &e[group]["mean"];
        assert!(g["psnr"].as_f64().unwrap() > 12.0, "{group}: {g}");
        assert!(g["cosine_loss"].as_f64().unwrap() > 0.0, "{group}: {g}");
    }
    // The group means are those of their frames.
    let psnr_of = |keyframe: bool| {
        let v: Vec<f64> = per_frame
            .iter()
            .filter(|f| f["keyframe"] == keyframe)
            .map(|f| f["psnr"].as_f64().unwrap())
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    for (group, keyframe) in [("keyframes", true), ("novel_views", false)] {
        let want = psnr_of(keyframe);
        let got = e[group]["mean"]["psnr"].as_f64().unwrap();
        assert!((got - want).abs() < 1e-9, "{group}: {got} vs {want}");
    }
    let psnr = e["mean"]["psnr"].as_f64().unwrap();
    assert!(psnr > 12.0, "PSNR {psnr}");
    let cos = e["mean"]["cosine_loss"].as_f64().unwrap();
    assert!(cos > 0.0 && cos < 0.8, "cosine loss {cos}");
    let miou = e["mean"]["miou"].as_f64().unwrap();
    assert!(miou > 0.0 && miou <= 1.0, "mIoU {miou}");
    assert_eq!(e["segmentation"], "labels");
    assert!(e["run_fps"].as_f64().unwrap() > 0.0);

    // profile: the per-kernel table and a trace.
    let trace = dir.join("profile.json");
    let stdout = ok(latentam()
        .arg("profile")
        .arg(&log)
        .args(["--frames", "8", "--set", "replay=1", "--trace"])
        .arg(&trace)
        .output()
        .unwrap());
    assert!(
        stdout.contains("mean ± std ms") && stdout.contains("share"),
        "{stdout}"
    );
    assert!(stdout.contains("raster_forward"), "{stdout}");
    assert!(!json(&trace)["traceEvents"].as_array().unwrap().is_empty());

    drop(mapper);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn ctrl_c_writes_the_run_folder_and_resume_continues() {
    let dir = scratch("interrupt");
    let frames = 400;
    let log = gen_scene(&dir, frames);
    let run = dir.join("run");
    let mut child = latentam()
        .env_remove("LATENTAM_VALIDATION")
        .arg("map")
        .arg(&log)
        .arg("--out")
        .arg(&run)
        .stderr(Stdio::piped())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    // The first status line comes after the first keyframe.
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut line = String::new();
    while stderr.read_line(&mut line).unwrap() > 0 && !line.starts_with("mapping: ") {
        line.clear();
    }
    assert!(line.starts_with("mapping: "), "no progress line");
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let status = child.wait().unwrap();
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    assert_eq!(status.code(), Some(130), "{rest}");
    assert!(rest.contains("--resume"), "{rest}");
    let report = json(&run.join("report.json"));
    assert_eq!(report["ending"], "interrupted");
    let mapped = report["frames"].as_u64().unwrap();
    assert!(mapped >= 1 && mapped < frames as u64, "{mapped} frames");
    let first = read_ply(&run.join("map.ply")).unwrap().gaussians.len();
    assert_eq!(first as u64, report["gaussians"].as_u64().unwrap());

    // --resume skips what was mapped and goes on.
    let more = mapped + 8;
    ok(latentam()
        .arg("map")
        .arg(&log)
        .arg("--out")
        .arg(&run)
        .args(["--resume", "--frames", &more.to_string()])
        .output()
        .unwrap());
    let report = json(&run.join("report.json"));
    assert_eq!(report["ending"], "frame_limit");
    assert_eq!(report["frames_skipped_as_already_mapped"], mapped);
    assert_eq!(report["frames"], 8);
    let trajectory = read_tum(&run.join("trajectory.txt")).unwrap();
    assert_eq!(trajectory.len() as u64, mapped.div_ceil(4) + 2);
    assert!(read_ply(&run.join("map.ply")).unwrap().gaussians.len() >= first);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn configuration_is_documented_and_checked() {
    let defaults = ok(latentam()
        .args(["config", "--print-defaults"])
        .output()
        .unwrap());
    let parsed = MapperConfig::from_toml(&defaults).unwrap();
    assert_eq!(parsed.to_toml(), MapperConfig::default().to_toml());
    assert!(defaults.lines().filter(|l| l.starts_with('#')).count() > 20);
    let out = latentam()
        .args(["config", "--set", "keyframes.no_such_key=1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("no_such_key"));
    let out = latentam()
        .args(["map", "nowhere.mcap", "--out", "x", "--set", "replay=-1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("replay"));
}

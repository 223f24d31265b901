//! Converters, the demo scene and the MCAP reader end to end, on the real
//! test data in `../shared/data` and on generated folders.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use latentam_cli::convert::features::FeatureDir;
use latentam_cli::convert::oracle::Oracle;
use latentam_cli::convert::{
    convert, datasets, npy, ConvertOptions, EmbeddingSource, Registration,
};
use latentam_io::{
    codec, AssemblyConfig, Compression, DepthData, Dtype, EmbeddingLayout, Frame, McapFrames,
};
use latentam_tests::shared_data;

/// A directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static N: AtomicUsize = AtomicUsize::new(0);
        let p = std::env::temp_dir().join(format!(
            "latentam-it-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn options(kind: &str, embeddings: EmbeddingSource, max_frames: Option<usize>) -> ConvertOptions {
    ConvertOptions {
        embeddings,
        intrinsics: None,
        registration: Registration::Dataset,
        raw_depth: false,
        depth_units_per_metre: None,
        dtype: Dtype::F16,
        compression: Compression::Zstd,
        max_frames,
        kind: kind.into(),
        source: PathBuf::from("test"),
    }
}

/// The shared 7-Scenes frames converted into `out` with `options`.
fn convert_seven_scenes(
    out: &Path,
    options: ConvertOptions,
) -> latentam_cli::convert::ConvertSummary {
    let src = shared_data("7scenes-redkitchen");
    convert(
        datasets::seven_scenes(&src, 30.0).unwrap(),
        &options,
        out,
        |_, _| {},
    )
    .unwrap()
}

fn frames_of(path: &Path) -> (Vec<Frame>, latentam_io::IngestReport) {
    let mut it = McapFrames::open(path, AssemblyConfig::default()).unwrap();
    let frames: Vec<Frame> = (&mut it).map(|f| f.unwrap()).collect();
    (frames, it.report().clone())
}

fn depth_units(f: &Frame) -> &[u16] {
    match &f.depth.data {
        DepthData::Units { values, .. } => values,
        other => panic!("expected integer depth, got {other:?}"),
    }
}

#[test]
fn seven_scenes_frames_keep_their_pixels_depth_and_poses_unregistered() {
    let src = shared_data("7scenes-redkitchen");
    let dir = TempDir::new("7s");
    let out = dir.join("7s.mcap");
    let summary = convert(
        datasets::seven_scenes(&src, 30.0).unwrap(),
        &ConvertOptions {
            registration: Registration::Off,
            ..options("7scenes", EmbeddingSource::None, Some(8))
        },
        &out,
        |_, _| {},
    )
    .unwrap();
    assert_eq!(summary.frames, 8);
    let (frames, report) = frames_of(&out);
    assert_eq!(frames.len(), 8, "{report}");
    assert_eq!(report.total_skipped(), 0, "{report}");
    for (i, f) in frames.iter().enumerate() {
        let id = format!("frame-{i:06}");
        let jpeg = std::fs::read(src.join(format!("{id}.color.jpg"))).unwrap();
        assert_eq!(f.color, codec::decode_jpeg(&jpeg).unwrap(), "{id}: colour");
        let png = std::fs::read(src.join(format!("{id}.depth.png"))).unwrap();
        let (w, h, mm) = codec::decode_png_u16(&png).unwrap();
        assert_eq!((w, h), (640, 480));
        assert_eq!(
            depth_units(f),
            &mm[..],
            "{id}: depth must be unchanged millimetres"
        );
        assert_eq!(
            (f.intrinsics.fx, f.intrinsics.cx, f.intrinsics.cy),
            (585.0, 320.0, 240.0)
        );
        let text = std::fs::read_to_string(src.join(format!("{id}.pose.txt"))).unwrap();
        let m: Vec<f64> = text
            .split_whitespace()
            .map(|t| t.parse().unwrap())
            .collect();
        let want_t = DVec3::new(m[3], m[7], m[11]);
        assert!((f.pose.translation - want_t).length() < 1e-9, "{id}");
        // The rotation maps camera axes to the matrix's columns (KinectFusion
        // rotations are orthonormal to ~2e-4 only).
        for c in 0..3 {
            let col = DVec3::new(m[c], m[4 + c], m[8 + c]);
            let mut axis = DVec3::ZERO;
            axis[c] = 1.0;
            assert!(
                (f.pose.rotation * axis - col).length() < 5e-4,
                "{id} column {c}"
            );
        }
    }
}

/// How well frame `i`'s colours agree with frame `j`'s on the surfaces
/// both see (every 2nd pixel of `i` with depth, moved into `j` through
/// depth, intrinsics and poses, kept where `j`'s depth agrees within 3 cm):
/// PSNR on the 0-255 scale.
fn cross_view_psnr(a: &Frame, b: &Frame) -> f64 {
    let (da, db) = (depth_units(a), depth_units(b));
    let (ka, kb) = (&a.intrinsics, &b.intrinsics);
    let (w, h) = (kb.width as i64, kb.height as i64);
    let (mut sse, mut n) = (0.0, 0u64);
    for y in (0..ka.height).step_by(2) {
        for x in (0..ka.width).step_by(2) {
            let d = da[(y * ka.width + x) as usize];
            if d == 0 {
                continue;
            }
            let z = d as f64 / 1000.0;
            let local = DVec3::new(
                (x as f64 - ka.cx) / ka.fx * z,
                (y as f64 - ka.cy) / ka.fy * z,
                z,
            );
            let world = a.pose.rotation * local + a.pose.translation;
            let p = b.pose.rotation.inverse() * (world - b.pose.translation);
            if p.z <= 0.1 {
                continue;
            }
            let u = (kb.fx * p.x / p.z + kb.cx).round() as i64;
            let v = (kb.fy * p.y / p.z + kb.cy).round() as i64;
            if u < 0 || v < 0 || u >= w || v >= h {
                continue;
            }
            let seen = db[(v * w + u) as usize] as f64 / 1000.0;
            if seen == 0.0 || (seen - p.z).abs() > 0.03 {
                continue;
            }
            let (ca, cb) = (a.color.rgb(x, y), b.color.rgb(u as u32, v as u32));
            for c in 0..3 {
                sse += (ca[c] as f64 - cb[c] as f64).powi(2);
            }
            n += 3;
        }
    }
    assert!(n > 10_000, "{n} samples");
    10.0 * (255.0f64.powi(2) / (sse / n as f64)).log10()
}

/// 7-Scenes colour is not registered to depth: the converter re-projects
/// depth into the measured colour lens and moves the poses to it. The
/// same surface must then look alike from two frames, as it does not
/// unregistered (measured: 2.5-4.5 dB better, docs/quality.md "Map fidelity").
#[test]
fn seven_scenes_depth_is_registered_to_colour() {
    let dir = TempDir::new("7s-registered");
    let frames = |registration, name: &str| {
        let out = dir.join(name);
        let summary = convert_seven_scenes(
            &out,
            ConvertOptions {
                registration,
                ..options("7scenes", EmbeddingSource::None, Some(41))
            },
        );
        assert!(
            summary.notes.iter().any(|n| n.contains("registered")),
            "{:?}",
            summary.notes
        );
        let (frames, report) = frames_of(&out);
        assert_eq!(frames.len(), 41, "{report}");
        frames
    };
    let raw = frames(Registration::Off, "raw.mcap");
    let registered = frames(Registration::Dataset, "registered.mcap");
    let k = &registered[0].intrinsics;
    assert_eq!((k.width, k.height), (640, 480));
    assert!(
        (k.fx - 0.905 * 585.0).abs() < 1e-9 && k.cy == 239.0,
        "{k:?}"
    );
    // The colour lens sits 2.27 cm along the depth camera's x axis.
    for (r, g) in raw.iter().zip(&registered) {
        let moved = r.pose.rotation.inverse() * (g.pose.translation - r.pose.translation);
        assert!(
            (moved - DVec3::new(12.0 / 529.425, 0.0, 0.0)).length() < 1e-6,
            "{moved}"
        );
    }
    let mut gains = Vec::new();
    for (i, j) in [(0, 4), (10, 14), (0, 20), (20, 40)] {
        let before = cross_view_psnr(&raw[i], &raw[j]);
        let after = cross_view_psnr(&registered[i], &registered[j]);
        eprintln!("frames {i} -> {j}: {before:.2} dB unregistered, {after:.2} dB registered");
        gains.push(after - before);
    }
    let mean = gains.iter().sum::<f64>() / gains.len() as f64;
    assert!(mean > 1.5, "registration gained {gains:?} dB");
}

/// 7-Scenes written as a Kinect bag recorded without registration (raw
/// depth in its own optical frame, the depth lens's camera info, the
/// 2.27 cm between the lenses on `/tf_static`) reads as the same frames as
/// the log `convert` registered: the reader registers it from the bag
/// itself, sample for sample, so the two map alike.
#[test]
fn seven_scenes_as_a_raw_depth_bag_reads_as_the_registered_log() {
    let dir = TempDir::new("7s-raw-bag");
    let write = |raw_depth, name: &str| {
        let out = dir.join(name);
        convert_seven_scenes(
            &out,
            ConvertOptions {
                raw_depth,
                ..options("7scenes", EmbeddingSource::None, Some(12))
            },
        );
        out
    };
    let (registered, _) = frames_of(&write(false, "registered.mcap"));
    let bag = write(true, "raw.mcap");
    let (read, report) = frames_of(&bag);
    assert_eq!(read.len(), 12, "{report}");
    assert!(report.warnings.is_empty(), "{report}");
    assert!(
        report
            .notes
            .iter()
            .any(|n| n.contains("registered to the colour camera") && n.contains("2.27 cm")),
        "{report}"
    );
    for (a, b) in read.iter().zip(&registered) {
        assert_eq!((a.stamp_ns, a.intrinsics), (b.stamp_ns, b.intrinsics));
        assert_eq!(a.pose, b.pose);
        let (da, db) = (a.depth.to_metres(), b.depth.to_metres());
        let differ = da.iter().zip(&db).filter(|(x, y)| x != y).count();
        assert_eq!(
            (differ, a.depth.width, a.depth.height),
            (0, b.depth.width, b.depth.height),
            "frame at {} ns: depth samples that differ",
            a.stamp_ns
        );
    }
    // The bag's depth itself is the raw 640×480 image in its own frame.
    let log = latentam_io::McapLog::open(&bag).unwrap();
    let topics: Vec<String> = log.channels().iter().map(|c| c.topic.clone()).collect();
    for t in ["/camera/depth/camera_info", "/tf_static"] {
        assert!(topics.iter().any(|x| x == t), "{topics:?}");
    }
}

#[test]
fn replica_depth_is_rescaled_to_millimetres_and_oracle_labels_become_regions() {
    let src = shared_data("replica-office0-4frames");
    let dir = TempDir::new("replica");
    // Oracle labels: three classes in bands, class 0 (unlabelled) on top.
    let labels_dir = dir.join("labels");
    std::fs::create_dir(&labels_dir).unwrap();
    let (lw, lh) = (300u32, 170u32);
    for i in 0..4 {
        let classes: Vec<u8> = (0..lw * lh)
            .map(|p| ((p / lw * 4 / lh + i) % 4) as u8)
            .collect();
        let mut bytes = Vec::new();
        let mut enc = png::Encoder::new(&mut bytes, lw, lh);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header()
            .unwrap()
            .write_image_data(&classes)
            .unwrap();
        std::fs::write(labels_dir.join(format!("frame{i:06}.png")), bytes).unwrap();
    }
    let vectors: Vec<f32> = (0..4 * 8).map(|k| (k as f32 * 0.37).sin()).collect();
    let vec_bytes: Vec<u8> = vectors.iter().flat_map(|v| v.to_le_bytes()).collect();
    let vec_path = dir.join("classes.npy");
    std::fs::write(
        &vec_path,
        npy::write(npy::NpyType::F32, &[4, 8], &vec_bytes),
    )
    .unwrap();
    let oracle = Oracle::new(&labels_dir, &vec_path).unwrap();
    let out = dir.join("replica.mcap");
    let summary = convert(
        datasets::replica(&src, 30.0).unwrap(),
        &options("replica", EmbeddingSource::Oracle(oracle), None),
        &out,
        |_, _| {},
    )
    .unwrap();
    assert_eq!((summary.frames, summary.with_embeddings), (4, 4));
    let mut it = McapFrames::open(&out, AssemblyConfig::default()).unwrap();
    let frames: Vec<Frame> = (&mut it).map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 4, "{}", it.report());
    let vocab = it
        .vocabulary()
        .expect("oracle logs carry the class vectors")
        .clone();
    assert_eq!(vocab.names, ["class_1", "class_2", "class_3"]);
    assert_eq!(vocab.model, "oracle:class-vectors");
    for (i, f) in frames.iter().enumerate() {
        let png = std::fs::read(src.join(format!("results/depth{i:06}.png"))).unwrap();
        let (_, _, raw) = codec::decode_png_u16(&png).unwrap();
        for (k, &r) in raw.iter().enumerate().step_by(997) {
            let want = r as f64 / 6553.5;
            let got = f.depth.metres(k).map_or(0.0, |m| m as f64);
            assert!(
                (got - want).abs() <= 0.0005 + 1e-6,
                "frame {i} pixel {k}: {got} vs {want}"
            );
        }
        let e = f.embeddings.as_ref().unwrap();
        assert_eq!(e.count, 3, "classes 1..3 present");
        let EmbeddingLayout::Regions(labels) = &e.layout else {
            panic!("regions expected")
        };
        let semantic = f.semantic.as_ref().unwrap();
        let got = e.to_f32();
        for (p, &region) in labels.labels.iter().enumerate() {
            let class = semantic.labels[p] as usize;
            if class == 0 {
                assert_eq!(region, u16::MAX);
                continue;
            }
            let v = &got[region as usize * 8..region as usize * 8 + 8];
            for (a, b) in v.iter().zip(&vectors[class * 8..class * 8 + 8]) {
                assert!(
                    (a - b).abs() < 2e-3,
                    "region vector is its class vector (f16)"
                );
            }
        }
    }
}

fn write_safetensors(
    path: &Path,
    tensors: &[(&str, safetensors::Dtype, Vec<usize>, Vec<u8>)],
    model: &str,
) {
    let views: Vec<(String, safetensors::tensor::TensorView<'_>)> = tensors
        .iter()
        .map(|(n, d, s, b)| {
            (
                n.to_string(),
                safetensors::tensor::TensorView::new(*d, s.clone(), b).unwrap(),
            )
        })
        .collect();
    let meta = HashMap::from([("model".to_string(), model.to_string())]);
    std::fs::write(path, safetensors::serialize(views, Some(meta)).unwrap()).unwrap();
}

#[test]
fn feature_files_in_every_documented_layout_are_read_and_missing_ones_counted() {
    let src = shared_data("replica-office0-4frames");
    let dir = TempDir::new("features");
    let fdir = dir.join("features");
    std::fs::create_dir(&fdir).unwrap();
    let f16 = |v: &[f32]| -> Vec<u8> {
        v.iter()
            .flat_map(|x| half::f16::from_f32(*x).to_le_bytes())
            .collect()
    };
    let (w, h, d) = (40usize, 20usize, 6usize);
    // Frame 0: safetensors masks (I32 labels with -1 = none).
    let labels: Vec<i32> = (0..w * h)
        .map(|p| if p % 7 == 0 { -1 } else { (p % 3) as i32 })
        .collect();
    let feats: Vec<f32> = (0..3 * d).map(|k| k as f32 / 10.0).collect();
    write_safetensors(
        &fdir.join("frame000000.safetensors"),
        &[
            (
                "labels",
                safetensors::Dtype::I32,
                vec![h, w],
                labels.iter().flat_map(|l| l.to_le_bytes()).collect(),
            ),
            ("features", safetensors::Dtype::F16, vec![3, d], f16(&feats)),
        ],
        "clip-test",
    );
    // Frame 1: safetensors masks with U16 labels and F32 features.
    let l1: Vec<u8> = (0..w * h)
        .flat_map(|p| ((p % 4) as u16).to_le_bytes())
        .collect();
    let f1: Vec<u8> = feats
        .iter()
        .chain(&feats[..d])
        .flat_map(|x| x.to_le_bytes())
        .collect();
    write_safetensors(
        &fdir.join("frame000001.safetensors"),
        &[
            ("labels", safetensors::Dtype::U16, vec![h, w], l1),
            ("features", safetensors::Dtype::F32, vec![4, d], f1),
        ],
        "clip-test",
    );
    // Frame 2: .npy pair with the model from --model; frame 3: no file.
    let l16: Vec<u8> = (0..w * h)
        .flat_map(|p| ((p % 2) as u16).to_le_bytes())
        .collect();
    std::fs::write(
        fdir.join("frame000002.labels.npy"),
        npy::write(npy::NpyType::U16, &[h, w], &l16),
    )
    .unwrap();
    std::fs::write(
        fdir.join("frame000002.features.npy"),
        npy::write(npy::NpyType::F16, &[2, d], &f16(&feats[..2 * d])),
    )
    .unwrap();

    let out = dir.join("f.mcap");
    let features = FeatureDir::new(&fdir, Some("clip-test".into())).unwrap();
    let summary = convert(
        datasets::replica(&src, 30.0).unwrap(),
        &options("replica", EmbeddingSource::Features(features), None),
        &out,
        |_, _| {},
    )
    .unwrap();
    assert_eq!(
        (summary.with_embeddings, summary.without_embeddings),
        (3, 1)
    );
    let (frames, report) = frames_of(&out);
    assert_eq!(report.frames_with_embeddings, 3, "{report}");
    let e0 = frames[0].embeddings.as_ref().unwrap();
    let EmbeddingLayout::Regions(l0) = &e0.layout else {
        panic!()
    };
    assert_eq!(
        (l0.width, l0.height, l0.labels[0], l0.labels[1]),
        (40, 20, u16::MAX, 1)
    );
    assert!((e0.to_f32()[7] - 0.7).abs() < 1e-3);
    assert_eq!(frames[1].embeddings.as_ref().unwrap().count, 4);
    assert_eq!(frames[2].embeddings.as_ref().unwrap().count, 2);
    assert!(frames[3].embeddings.is_none());

    // A grid in another folder: FeatureGrid messages.
    let gdir = dir.join("grid");
    std::fs::create_dir(&gdir).unwrap();
    let grid: Vec<f32> = (0..2 * 3 * d).map(|k| 1.0 - k as f32 / 50.0).collect();
    write_safetensors(
        &gdir.join("frame000000.safetensors"),
        &[(
            "grid",
            safetensors::Dtype::F32,
            vec![2, 3, d],
            grid.iter().flat_map(|x| x.to_le_bytes()).collect(),
        )],
        "lseg-test",
    );
    let out = dir.join("g.mcap");
    let features = FeatureDir::new(&gdir, None).unwrap();
    convert(
        datasets::replica(&src, 30.0).unwrap(),
        &options("replica", EmbeddingSource::Features(features), None),
        &out,
        |_, _| {},
    )
    .unwrap();
    let (frames, _) = frames_of(&out);
    let e = frames[0].embeddings.as_ref().unwrap();
    assert_eq!(
        (e.layout.clone(), e.count, e.dim, e.model.as_str()),
        (
            EmbeddingLayout::Grid { rows: 2, cols: 3 },
            6,
            d as u32,
            "lseg-test"
        )
    );
    assert!((e.to_f32()[5] - 0.9).abs() < 1e-3);

    // Masks and grids cannot share a log.
    std::fs::copy(
        gdir.join("frame000000.safetensors"),
        fdir.join("frame000003.safetensors"),
    )
    .unwrap();
    let features = FeatureDir::new(&fdir, Some("clip-test".into())).unwrap();
    let err = convert(
        datasets::replica(&src, 30.0).unwrap(),
        &options("replica", EmbeddingSource::Features(features), None),
        &dir.join("mixed.mcap"),
        |_, _| {},
    )
    .unwrap_err();
    assert!(format!("{err:#}").contains("grid"), "{err:#}");
    std::fs::remove_file(fdir.join("frame000003.safetensors")).unwrap();

    // A label past the feature rows is refused at conversion, naming the file.
    let bad = fdir.join("frame000003.labels.npy");
    std::fs::write(
        &bad,
        npy::write(npy::NpyType::U16, &[h, w], &vec![9; w * h * 2]),
    )
    .unwrap();
    std::fs::write(
        fdir.join("frame000003.features.npy"),
        npy::write(npy::NpyType::F16, &[2, d], &f16(&feats[..2 * d])),
    )
    .unwrap();
    let features = FeatureDir::new(&fdir, Some("clip-test".into())).unwrap();
    let err = convert(
        datasets::replica(&src, 30.0).unwrap(),
        &options("replica", EmbeddingSource::Features(features), None),
        &dir.join("bad.mcap"),
        |_, _| {},
    )
    .unwrap_err();
    assert!(
        format!("{err:#}").contains("frame000003.labels.npy"),
        "{err:#}"
    );
    assert!(
        !dir.join("bad.mcap").exists(),
        "a failed conversion leaves no output"
    );
}

#[test]
fn tum_streams_are_paired_by_stamp_and_poses_interpolated() {
    let dir = TempDir::new("tum");
    let root = dir.join("rgbd_dataset_freiburg3_synthetic");
    std::fs::create_dir_all(root.join("rgb")).unwrap();
    std::fs::create_dir_all(root.join("depth")).unwrap();
    // The size of the TUM cameras the converter's intrinsics are for.
    let (w, h) = (640u32, 480u32);
    let mut rgb_txt = String::from("# color images\n");
    let mut depth_txt = String::from("# depth maps\n");
    let mut gt = String::from("# timestamp tx ty tz qx qy qz qw\n");
    let t0 = 1305031102.0f64;
    for i in 0..5 {
        let t = t0 + i as f64 / 30.0;
        let rgb: Vec<u8> = (0..w * h * 3).map(|k| (k as usize + i) as u8).collect();
        let mut bytes = Vec::new();
        let mut enc = png::Encoder::new(&mut bytes, w, h);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.write_header().unwrap().write_image_data(&rgb).unwrap();
        std::fs::write(root.join(format!("rgb/{t:.6}.png")), bytes).unwrap();
        rgb_txt += &format!("{t:.6} rgb/{t:.6}.png\n");
        // Depth 8 ms later, 5000 units per metre: 1.0 m + i cm.
        let td = t + 0.008;
        let d = vec![5000 + 50 * i as u16; (w * h) as usize];
        std::fs::write(
            root.join(format!("depth/{td:.6}.png")),
            codec::encode_png_u16(w, h, &d),
        )
        .unwrap();
        depth_txt += &format!("{td:.6} depth/{td:.6}.png\n");
    }
    for k in -10..30 {
        let t = t0 + k as f64 / 100.0;
        let q = DQuat::from_rotation_z(t - t0);
        gt += &format!("{t:.4} {} 0 1.5 {} {} {} {}\n", t - t0, q.x, q.y, q.z, q.w);
    }
    std::fs::write(root.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(root.join("depth.txt"), depth_txt).unwrap();
    std::fs::write(root.join("groundtruth.txt"), gt).unwrap();
    let out = dir.join("tum.mcap");
    convert(
        datasets::tum(&root).unwrap(),
        &options("tum", EmbeddingSource::None, None),
        &out,
        |_, _| {},
    )
    .unwrap();
    let (frames, report) = frames_of(&out);
    assert_eq!(frames.len(), 5, "{report}");
    for (i, f) in frames.iter().enumerate() {
        let s = i as f64 / 30.0;
        assert!(
            (f.pose.translation - DVec3::new(s, 0.0, 1.5)).length() < 1e-4,
            "{i}"
        );
        assert!(f.pose.rotation.angle_between(DQuat::from_rotation_z(s)) < 1e-4);
        assert!((f.depth.metres(0).unwrap() - (1.0 + 0.01 * i as f32)).abs() < 1e-6);
        assert_eq!(f.intrinsics.fx, 535.4);
        assert_eq!(
            f.color.rgb(1, 0),
            [(3 + i) as u8, (4 + i) as u8, (5 + i) as u8]
        );
    }
}

#[test]
fn the_demo_scene_reads_back_with_consistent_regions_and_classes() {
    use latentam_scene::{generate, SceneConfig};
    let dir = TempDir::new("scene");
    let out = dir.join("scene.mcap");
    let config = SceneConfig {
        frames: 12,
        width: 64,
        height: 48,
        dim: 32,
        ..SceneConfig::default()
    };
    let summary = generate(&config, &out, |_| {}).unwrap();
    assert_eq!(summary.objects, 14);
    let mut it = McapFrames::open(&out, AssemblyConfig::default()).unwrap();
    let frames: Vec<Frame> = (&mut it).map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 12, "{}", it.report());
    assert_eq!(it.report().total_skipped(), 0, "{}", it.report());
    let vocab = it.vocabulary().unwrap().clone();
    assert_eq!(vocab.names.len(), 11);
    for f in &frames {
        let e = f.embeddings.as_ref().unwrap();
        let EmbeddingLayout::Regions(labels) = &e.layout else {
            panic!()
        };
        let semantic = &f.semantic.as_ref().unwrap().labels;
        let vectors = e.to_f32();
        // A region is one instance, so one class, but for the pixels its
        // imperfect mask spills over a boundary.
        let mut counts = vec![std::collections::BTreeMap::<u16, usize>::new(); e.count as usize];
        for (p, &r) in labels.labels.iter().enumerate() {
            if r != u16::MAX {
                *counts[r as usize].entry(semantic[p]).or_default() += 1;
            }
        }
        let unit = |v: &[f32]| {
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.iter().map(|x| x / n).collect::<Vec<f32>>()
        };
        for (r, by_class) in counts.iter().enumerate() {
            let total: usize = by_class.values().sum();
            let (&c, &n) = by_class
                .iter()
                .max_by_key(|(_, &n)| n)
                .expect("every region has pixels");
            assert!(n * 2 > total, "region {r}: {by_class:?}");
            // Its embedding is nearer its class than any other class.
            let v = unit(&vectors[r * 32..r * 32 + 32]);
            let cos = |k: usize| -> f32 {
                unit(&vocab.vectors[k * 32..k * 32 + 32])
                    .iter()
                    .zip(&v)
                    .map(|(a, b)| a * b)
                    .sum()
            };
            let own = vocab
                .ids
                .iter()
                .position(|&id| id as u64 == c as u64)
                .unwrap();
            for k in 0..vocab.names.len() {
                if k != own {
                    assert!(
                        cos(own) > cos(k),
                        "region {r} of class {c}: {} vs {}",
                        cos(own),
                        cos(k)
                    );
                }
            }
        }
    }
    // Deterministic: the same seed writes the same messages.
    let again = dir.join("again.mcap");
    generate(&config, &again, |_| {}).unwrap();
    let (frames_again, _) = frames_of(&again);
    assert_eq!(frames_again, frames);
}

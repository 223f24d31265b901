//! Replica (depth rescaled, oracle labels as regions) and TUM (streams
//! paired by stamp, poses interpolated) converted.

use super::*;

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

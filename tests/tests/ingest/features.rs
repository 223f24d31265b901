//! Feature files in every documented layout, and missing ones counted.

use super::*;

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

//! The demo scene read back through the MCAP reader.

use super::*;

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

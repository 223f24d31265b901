//! The dictionary part: the head created from the first embeddings, their
//! model and dimension held to, and what it hands to the other parts.

use glam::DVec3;

use super::*;
use crate::mapper::tests::fixtures::keyframe;
use latentam_gpu::testing::with_context;

fn config() -> MapperConfig {
    MapperConfig {
        atoms: 16,
        max_regions: 64,
        ..MapperConfig::default()
    }
}

fn vocabulary(dim: u32, model: &str) -> Vocabulary {
    Vocabulary {
        names: vec!["wall".into()],
        ids: vec![0],
        dim,
        vectors: vec![1.0; dim as usize],
        model: model.into(),
    }
}

#[test]
fn the_first_embeddings_create_the_head_and_fix_model_and_dimension() {
    with_context(|ctx| {
        let mut dictionary = Dictionary::new(&config());
        // What a snapshot of a map with this dictionary checks.
        let check = |d: &Dictionary, v: &Vocabulary| match d.head() {
            None => Err(Error::NoEmbeddings),
            Some(head) => check_vocabulary(head.config().dim, d.model(), v),
        };
        let frame = keyframe(DVec3::ZERO);
        let record = KeyframeRecord::from_frame(&frame);
        // Nothing to decode or score with before.
        assert!(dictionary.decoder_file(ctx).unwrap().is_none());
        let regions = record.regions.as_ref().unwrap();
        assert!(dictionary
            .projected_queries(ctx, regions, None)
            .unwrap()
            .is_none());
        assert!(matches!(
            check(&dictionary, &vocabulary(32, "test")),
            Err(Error::NoEmbeddings)
        ));
        assert_eq!(dictionary.dim_for(&frame), Some(32));

        // Not waited for, as the mapper leaves it: the read-backs below
        // see the update through the queue's order alone.
        let _ = dictionary.update(ctx, &frame, &record).unwrap();
        let head = dictionary.head().expect("created by the first embeddings");
        assert_eq!(head.config().dim, 32);
        assert_eq!(head.config().atoms, 16);
        assert!(head.atom_count() >= 1);
        assert_eq!(dictionary.model(), Some("test"));

        let mut other_model = keyframe(DVec3::ZERO);
        other_model.embeddings.as_mut().unwrap().model = "another".into();
        assert!(matches!(
            dictionary.check_frame(&other_model),
            Err(Error::EmbeddingModel { .. })
        ));
        let mut other_dim = keyframe(DVec3::ZERO);
        let e = other_dim.embeddings.as_mut().unwrap();
        (e.dim, e.count) = (16, 4);
        assert!(matches!(
            dictionary.check_frame(&other_dim),
            Err(Error::EmbeddingDimension {
                map: 32,
                given: 16,
                ..
            })
        ));
        dictionary.check_frame(&frame).unwrap();
        let mut no_embeddings = keyframe(DVec3::ZERO);
        no_embeddings.embeddings = None;
        dictionary.check_frame(&no_embeddings).unwrap();

        check(&dictionary, &vocabulary(32, "oracle:test")).unwrap();
        assert!(matches!(
            check(&dictionary, &vocabulary(16, "test")),
            Err(Error::EmbeddingDimension { .. })
        ));
        assert!(matches!(
            check(&dictionary, &vocabulary(32, "another")),
            Err(Error::EmbeddingModel { .. })
        ));
    });
}

#[test]
fn the_head_hands_out_its_decoder_and_projected_queries() {
    with_context(|ctx| {
        let mut dictionary = Dictionary::new(&config());
        let frame = keyframe(DVec3::ZERO);
        let record = KeyframeRecord::from_frame(&frame);
        if let Some(s) = dictionary.update(ctx, &frame, &record).unwrap() {
            s.wait().unwrap();
        }
        let head = dictionary.head().unwrap();
        let file = dictionary.decoder_file(ctx).unwrap().unwrap();
        let atoms = head.atom_count() as usize;
        assert_eq!(file.dim, 32);
        assert_eq!(file.w.len(), QUERY_DIM * 32);
        assert_eq!(file.atoms.len(), atoms * 32);
        assert_eq!(file.atom_weights.len(), atoms);
        assert_eq!(file.model, "test");
        let w: Vec<f32> = ctx.download(head.w()).unwrap();
        assert_eq!(file.w, w[..QUERY_DIM * 32]);

        let regions = record.regions.as_ref().unwrap();
        let queries = dictionary
            .projected_queries(ctx, regions, None)
            .unwrap()
            .unwrap();
        // W read back beside another submission projects the same.
        let w = ctx.download::<f32>(dictionary.w_buffer().unwrap()).unwrap();
        let read = dictionary
            .projected_queries(ctx, regions, Some(&w))
            .unwrap()
            .unwrap();
        assert_eq!(read, queries);
        assert_eq!(queries.len(), regions.count as usize);
        assert!(queries
            .iter()
            .all(|q| q.is_some_and(|q| q.iter().all(|x| x.is_finite()))));
    });
}

#[test]
fn regions_without_an_embedding_do_not_reach_the_dictionary() {
    let regions = RegionTargets {
        width: 2,
        height: 1,
        labels: vec![0, 1],
        grid: false,
        count: 3,
        vectors: vec![1.0, 0.0, 0.0, 0.0, 0.0, 0.5],
        dim: 2,
    };
    assert_eq!(nonzero_rows(&regions), vec![1.0, 0.0, 0.0, 0.5]);
}

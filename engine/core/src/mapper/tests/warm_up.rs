//! A mapper builds every kernel it can dispatch before it is ready: none
//! is built (by the driver, inside a keyframe) while it maps, queries,
//! renders and evaluates, whatever its blending settings.

use glam::DVec3;

use super::fixtures::*;
use crate::latent::TextQuery;
use crate::mapper::*;
use crate::splat::BlendLayout;
use latentam_gpu::testing::with_context;

#[test]
fn a_warmed_up_mapper_builds_no_kernel_while_it_maps() {
    let configs = [
        ("the defaults", small_map_config()),
        (
            "query gradients reaching geometry",
            MapperConfig {
                attach_feature_gradients: true,
                ..small_map_config()
            },
        ),
        (
            "the pixel layout",
            MapperConfig {
                blend_layout: BlendLayout::Pixels,
                ..small_map_config()
            },
        ),
    ];
    for (name, cfg) in configs {
        with_context(|ctx| {
            let mut mapper = Mapper::with_context(ctx, cfg).unwrap();
            let ready = mapper.warm_up().unwrap();
            // Built means run once too (a driver may compile only then).
            let built: Vec<&str> = ctx.kernel_build_times().iter().map(|t| t.kernel).collect();
            assert_eq!(built.len(), ready, "{name}");
            let mut last = None;
            for i in 0..5 {
                let mut f = keyframe(DVec3::new(0.05 * i as f64, 0.0, 0.0));
                f.stamp_ns = i;
                mapper.integrate(&f).unwrap();
                last = Some(f);
            }
            let frame = last.unwrap();
            let mut word = vec![0.0f32; DIM];
            word[3] = 1.0;
            let query = TextQuery::embedding(word);
            mapper.relevance(&query, Scored::Gaussians).unwrap();
            let (view, _) = mapper.render(&frame).unwrap();
            mapper.relevance(&query, Scored::Pixels(&view)).unwrap();
            mapper.evaluate(&frame, None, 1).unwrap();
            mapper.snapshot().unwrap();
            let lazily: Vec<&str> = ctx
                .built_kernels()
                .into_iter()
                .filter(|k| !built.contains(k))
                .collect();
            assert!(lazily.is_empty(), "{name}: built while mapping: {lazily:?}");
        });
    }
}

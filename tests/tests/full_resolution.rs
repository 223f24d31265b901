//! Mapping at a robot camera's full resolution (lavapipe, with the
//! validation layer): a 1280×720 log with 512-d region embeddings and the
//! paper's B = 5 replayed keyframes maps within the default GPU budget, the
//! memory for images stays that of one view however many keyframes a batch
//! replays, and no per-pixel feature image is allocated.

use latentam_core::mapper::budget::pixel_bytes;
use latentam_core::mapper::{Integrated, Mapper, MapperConfig};
use latentam_gpu::{Context, ContextOptions, Validation};
use latentam_io::{AssemblyConfig, Frame, McapFrames};

const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;

fn frames(count: usize) -> Vec<Frame> {
    use latentam_scene::{generate, SceneConfig};
    let dir = std::env::temp_dir().join(format!("latentam-full-res-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scene.mcap");
    let config = SceneConfig {
        frames: count,
        width: WIDTH,
        height: HEIGHT,
        dim: 512,
        ..SceneConfig::default()
    };
    generate(&config, &path, |_| {}).unwrap();
    let frames = McapFrames::open(&path, AssemblyConfig::default())
        .unwrap()
        .map(|f| f.unwrap())
        .collect();
    std::fs::remove_dir_all(&dir).unwrap();
    frames
}

#[test]
fn a_1280x720_log_maps_with_five_replayed_keyframes_in_one_view_of_image_memory() {
    let ctx = Context::new(ContextOptions {
        validation: Validation::Required,
        ..ContextOptions::default()
    })
    .expect("a Vulkan device (lavapipe: apt install mesa-vulkan-drivers)");
    // Keyframes every 4th frame: 0, 4, 8, 12; B = 5 allows every earlier
    // one to be replayed.
    let frames = frames(13);
    let cfg = MapperConfig {
        seed: 5,
        ..MapperConfig::default()
    };
    assert_eq!(cfg.replay, 5, "the paper's B is the default");
    assert!(cfg.gpu_budget.is_none(), "the default budget");
    let mut mapper = Mapper::with_context(&ctx, cfg).unwrap();
    let mut widest_batch = 0;
    for f in &frames {
        if let Integrated::Keyframe(r) = mapper.integrate(f).unwrap() {
            assert!(
                r.stage_one.regions > 0,
                "keyframe {} trained no region",
                r.index
            );
            assert!(r.stage_one.image.total().is_finite());
            // Each 1280×720 view is a chunk of its own.
            widest_batch = widest_batch.max(r.stage_one.chunks);
        }
    }
    let stats = mapper.stats();
    assert_eq!(stats.keyframes, 4);
    // Replays are drawn among the keyframes near the camera: at least two
    // of the three earlier ones joined a batch.
    assert!(
        (3..=4).contains(&widest_batch),
        "widest batch {widest_batch} views"
    );
    let one_view = pixel_bytes(WIDTH as u64 * HEIGHT as u64, 1, false);
    let split = stats.gpu_peak_split;
    eprintln!(
        "peak GPU {} B: images {} B and features {} B (one view budgeted at {one_view} B), \
         head {} B, window {} B, staging {} B",
        stats.gpu_peak_bytes,
        split.images,
        split.features,
        split.latent_head,
        split.window,
        split.staging
    );
    // No per-pixel query image in mapping: the rasterizer pools queries
    // into region rows.
    assert_eq!(split.features, 0, "{split:?}");
    assert!(
        split.images > 0 && split.images <= one_view + one_view / 100,
        "{split:?}"
    );
    assert!(split.images <= 200_000_000, "{split:?}");
    let budget = stats.window.unwrap().budget;
    assert!(stats.gpu_peak_bytes <= budget);
}

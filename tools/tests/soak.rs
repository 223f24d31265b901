//! A short soak: the demo scene walked four times at low resolution with
//! the validation layer on. GPU memory must stay flat after the first lap,
//! the map must grow ever less on revisits, live Vulkan objects must come
//! back to the same counts at the end of every lap, and the validation
//! layer must stay silent (leaks are reported when the device goes).
//! `latentam bench soak` runs the same check for thousands of frames.

use latentam::config::KeyframePolicy;
use latentam::{Config as MapperConfig, Context, ContextOptions, Validation};
use latentam_cli::soak::{lap_table, run, SoakOptions};
use latentam_scene::SceneConfig;

#[test]
fn a_long_walk_keeps_gpu_memory_flat_leaks_nothing_and_grows_with_the_space_seen() {
    let ctx = Context::new(ContextOptions {
        validation: Validation::Required,
        ..ContextOptions::default()
    })
    .expect("a Vulkan device with the validation layer");
    let log = ctx.validation_log();
    let mut config = MapperConfig {
        replay: 2,
        atoms: 32,
        ..MapperConfig::default()
    };
    config.keyframes.policy = KeyframePolicy::Interval(8);
    let opts = SoakOptions {
        scene: SceneConfig {
            frames: 400,
            laps: 4,
            width: 48,
            height: 36,
            dim: 32,
            ..SceneConfig::default()
        },
        config,
    };
    let scratch = std::env::temp_dir().join(format!("latentam-soak-test-{}", std::process::id()));
    let r = run(&ctx, &opts, &scratch, |_| {}).unwrap();
    let _ = std::fs::remove_dir_all(&scratch);
    eprint!("{}", lap_table(&r));
    assert_eq!(r.laps_summary.len(), 4);
    assert!(
        r.gpu_growth_after_first_lap <= 1.01,
        "{}",
        r.gpu_growth_after_first_lap
    );
    assert!(r.objects_steady, "{:?}", r.laps_summary);
    assert_eq!(r.validation_messages, 0);
    // The first lap maps the building one way, the second sees the other
    // sides; after that revisits add little, and ever less.
    let g: Vec<f64> = r
        .laps_summary
        .iter()
        .map(|l| l.end_gaussians as f64)
        .collect();
    let added: Vec<f64> = g.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(added[2] < 0.5 * added[0], "Gaussians per lap {g:?}");
    assert!(added[2] < 0.2 * g[0], "Gaussians per lap {g:?}");
    let cpu: Vec<f64> = r
        .laps_summary
        .iter()
        .map(|l| l.end_cpu_bytes as f64)
        .collect();
    assert!(cpu[3] < 1.15 * cpu[2], "CPU bytes per lap {cpu:?}");
    // Paging against the map's size: the keyframes in tenths, in order,
    // their figures the means of the curve's.
    let tenths = &r.paging_by_map_size;
    assert_eq!(tenths.len(), 10, "{tenths:?}");
    assert_eq!(tenths[0].first_keyframe, r.curve[0].keyframe);
    assert!(tenths
        .windows(2)
        .all(|w| w[0].first_keyframe < w[1].first_keyframe));
    let per = r.curve.len().div_ceil(10);
    let mean_bytes = r.curve[..per]
        .iter()
        .map(|p| (p.paging_bytes_up + p.paging_bytes_down) as f64)
        .sum::<f64>()
        / per as f64;
    assert!((tenths[0].paging_bytes_per_keyframe - mean_bytes).abs() <= 1e-6 * mean_bytes.max(1.0));
    // Nothing spills under the default host budget (the disk tier's time
    // is its check alone).
    assert!(r.curve.iter().all(|p| p.spilled_gaussians == 0));
    drop(ctx);
    let errors = log.errors();
    assert!(errors.is_empty(), "{}", errors.join("\n"));
}

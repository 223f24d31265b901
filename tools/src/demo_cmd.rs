//! `latentam demo`: the built-in scene end to end — generate, map,
//! evaluate on keyframes and on views that were not keyframes, query one
//! class, and print a summary with where everything went.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use latentam::frames::{read_vocabulary, AssemblyConfig, McapFrames};
use latentam::runs::{RunFolder, Written};
use latentam::{Context, ContextOptions, Ending, Mapper};
use latentam_cli::progress::Progress;
use latentam_scene::{generate, SceneConfig};

use crate::config_args::ConfigArgs;
use crate::mapping::{map_log, summary, write_folder, RunOptions, RUN_FILES};
use crate::pictures::Picture;
use crate::query_args::{queryable_dim, QueryArgs};
use crate::render_cmd::{nth_frame, render_pictures, ViewSource};

#[derive(clap::Args)]
pub struct Args {
    /// Folder for the scene log, the run folder and the evaluation.
    #[arg(long, default_value = "latentam-demo")]
    out: PathBuf,
    /// Frames along the scene's trajectory (the path is the same; more
    /// frames, smaller steps and a longer run). With the default keyframe
    /// interval of 4, 120 frames give 30 keyframes.
    #[arg(long, default_value_t = 120, value_parser = clap::value_parser!(u64).range(8..))]
    frames: u64,
    /// Image width of the scene.
    #[arg(long, default_value_t = 160)]
    width: u32,
    /// Image height of the scene.
    #[arg(long, default_value_t = 120)]
    height: u32,
    #[command(flatten)]
    config: ConfigArgs,
    #[command(flatten)]
    live: crate::live_args::LiveViewArgs,
}

pub fn run(args: Args) -> Result<()> {
    let config = args.config.load()?;
    args.live.check()?;
    std::fs::create_dir_all(&args.out)?;
    let log = args.out.join("scene.mcap");
    let run_dir = args.out.join("run");
    let scene = SceneConfig {
        frames: args.frames as usize,
        width: args.width,
        height: args.height,
        ..SceneConfig::default()
    };
    println!(
        "1/4 generating the demo scene: two rooms and a corridor, {} frames of {}×{} with \
         synthetic {}-d region embeddings",
        scene.frames, scene.width, scene.height, scene.dim
    );
    let mut progress = Progress::new("scene", scene.frames);
    generate(&scene, &log, |d| progress.set(d))?;

    println!("2/4 mapping it (every kernel timed)");
    let folder = RunFolder::lock(&run_dir)?;
    let mut run = map_log(
        &RunOptions {
            log: log.clone(),
            assembly: AssemblyConfig::default(),
            config,
            max_frames: None,
            resume: None,
            profile: true,
            autosave_every: 0,
            continue_after_failed_autosave: false,
            live: Some(args.live.clone()).filter(|l| l.live.is_some()),
        },
        Some(&folder),
    )?;
    let report = match write_folder(&mut run, &folder)? {
        Written::Saved(report) => report,
        Written::Kept(why) => bail!("{}: {why}", run_dir.display()),
    };
    drop(folder);
    match &run.ending {
        Ending::Failed(e) => bail!("{e}"),
        Ending::Interrupted => bail!("interrupted; what was mapped is in {}", run_dir.display()),
        _ => {}
    }
    let profile = run.context().profiler_snapshot();
    drop(run);

    // Every 6th frame from 2: views that were never keyframes (2, 14, …)
    // alternate with keyframes (8, 20, …; every 4th frame is one).
    println!("3/4 evaluating on keyframes and on views that were not (frames 2, 8, 14, …)");
    let eval_json = args.out.join("eval.json");
    crate::eval_cmd::run(crate::eval_cmd::Args {
        dir: run_dir.clone(),
        log: log.clone(),
        json: Some(eval_json.clone()),
        every: 6,
        offset: 2,
        frames: None,
        pixel_stride: 1,
        input: Default::default(),
        quiet: true,
    })?;

    let class = query_first_class(&log, &run_dir)?;

    // One held-out view (frame 2 was not a keyframe) as pictures.
    let preview = args.out.join("preview.png");
    write_preview(&run_dir, &log, class.as_deref(), &preview)?;

    println!();
    println!("mapping:");
    for line in summary(&report).lines() {
        println!("  {line}");
    }
    println!("slowest kernels (share of the mapping wall time):");
    let table = profile.table_with_share_of(report.wall_s * 1e3);
    for line in table.lines().take(9) {
        println!("  {line}");
    }
    print_outputs(&log, &run_dir, &eval_json, &preview, class.as_deref());
    print_next_steps(&log, &run_dir, class.as_deref());
    Ok(())
}

/// Step 4: queries the map for the vocabulary's first class, which it
/// returns (`None` for a log without a vocabulary).
fn query_first_class(log: &Path, run_dir: &Path) -> Result<Option<String>> {
    let vocab = read_vocabulary(log, "/vocabulary")?;
    let class = vocab.as_ref().and_then(|v| v.names.first().cloned());
    if let Some(name) = &class {
        println!("4/4 querying the map for `{name}` and drawing a held-out view");
        crate::query_cmd::run(crate::query_cmd::Args {
            dir: run_dir.to_path_buf(),
            query: crate::query_args::QueryArgs {
                embedding: None,
                name: Some(name.clone()),
                vocabulary: Some(log.to_path_buf()),
                temperature: 0.1,
            },
            vocabulary_topic: "/vocabulary".into(),
            out: None,
            top: 5,
            view: None,
            png: None,
        })?;
    }
    Ok(class)
}

/// The files the demo wrote, each with what it is.
fn print_outputs(
    log: &Path,
    run_dir: &Path,
    eval_json: &Path,
    preview: &Path,
    class: Option<&str>,
) {
    println!("outputs:");
    println!("  {}  (the scene log)", log.display());
    for f in RUN_FILES.iter().chain(&["heatmap.ply"]) {
        let p = run_dir.join(f);
        if p.exists() {
            println!("  {}", p.display());
        }
    }
    println!("  {}  (evaluation)", eval_json.display());
    println!(
        "  {}  (held-out frame {PREVIEW_FRAME}: input, rendered map, {})",
        preview.display(),
        class.map_or_else(
            || "rendered depth".to_string(),
            |c| format!("relevance of `{c}`")
        )
    );
}

/// Commands to go on with, on the demo's own files.
fn print_next_steps(log: &Path, run_dir: &Path, class: Option<&str>) {
    println!("next:");
    if let Some(name) = class {
        println!(
            "  latentam query {} --name {name} --vocabulary {}",
            run_dir.display(),
            log.display()
        );
    }
    println!(
        "  latentam eval {} {} --every 2",
        run_dir.display(),
        log.display()
    );
    println!(
        "  latentam render {} {} --frame 10 --out views/f10",
        run_dir.display(),
        log.display()
    );
    println!("  latentam profile {} --frames 40", log.display());
    println!(
        "  open {} in a 3DGS viewer (e.g. SuperSplat)",
        run_dir.join("map.ply").display()
    );
}

/// The frame the preview shows: not a keyframe (every 4th frame is).
const PREVIEW_FRAME: u64 = 2;

/// `preview.png`: frame [`PREVIEW_FRAME`] of `log` as input, as rendered
/// from the map in `run_dir`, and as the relevance of `class` (else the
/// rendered depth), side by side.
fn write_preview(run_dir: &Path, log: &Path, class: Option<&str>, out: &Path) -> Result<()> {
    let ctx = Context::new(ContextOptions::default())?;
    let mut mapper = Mapper::load(&ctx, run_dir)?;
    ctx.set_memory_budget(None);
    let query = match class {
        Some(name) => {
            let dim = queryable_dim(&mapper, run_dir)?;
            let args = QueryArgs {
                name: Some(name.to_string()),
                temperature: 0.1,
                ..QueryArgs::default()
            };
            args.resolve(&mapper, dim, Some(log), "/vocabulary")?
        }
        None => None,
    };
    let frames = McapFrames::open(log, AssemblyConfig::default())?;
    let frame = nth_frame(frames, PREVIEW_FRAME, log)?;
    let p = render_pictures(&mut mapper, ViewSource::Frame(&frame), query.as_ref())?;
    let (input, _) = p.input.as_ref().expect("rendered from a frame");
    let third = p.relevance.as_ref().map_or(&p.depth, |(r, _)| r);
    Picture::side_by_side(&[input, &p.colour, third], 4).write_png(out)
}

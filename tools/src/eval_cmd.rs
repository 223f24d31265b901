//! `latentam eval`: re-renders a log's frames from a mapped run and scores
//! them as the paper does (Sec. IV-A): colour PSNR over all pixels,
//! depth L1 over valid ones, and per pixel the cosine loss and L2 of the
//! decoded embedding against its region's embedding and mIoU over the
//! vocabulary's classes (against the semantic labels when the log has
//! them, else the teacher/student variant). The region-pooled figures
//! follow on a line of their own. Frames the run mapped as keyframes and
//! views it never trained on are also reported apart.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use latentam::eval::{add_iou, mean_iou, RegionPooled};
use latentam::frames::{read_class_names, read_vocabulary, McapFrames, Vocabulary};
use latentam::runs::read_one_version;
use latentam::{Context, ContextOptions, Mapper, ViewMetrics};
use latentam_cli::progress::Stages;
use serde::Serialize;

#[derive(clap::Args)]
pub struct Args {
    /// Run folder written by `latentam map`.
    pub dir: PathBuf,
    /// Log whose frames are re-rendered and compared (the mapped log, or
    /// another one of the same place).
    pub log: PathBuf,
    /// Write the per-frame and mean metrics here as JSON.
    #[arg(long, value_name = "PATH")]
    pub json: Option<PathBuf>,
    /// Evaluate every N-th frame (with --offset: e.g. `--every 8 --offset 2`
    /// takes frames 2, 10, 18, …, views that were not keyframes when
    /// mapping kept every 4th).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    pub every: u64,
    /// Index of the first frame evaluated.
    #[arg(long, default_value_t = 0)]
    pub offset: u64,
    /// Evaluate at most this many frames.
    #[arg(long, value_name = "N")]
    pub frames: Option<usize>,
    /// Per-pixel metrics on every N-th pixel of every N-th row (1: all,
    /// the paper's protocol); a larger N divides the decoding time by
    /// about N² on slow devices. PSNR and depth always use every pixel.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..=64))]
    pub pixel_stride: u64,
    #[command(flatten)]
    pub input: crate::input_args::InputArgs,
    /// Only the summary, not a line per frame.
    #[arg(skip)]
    pub quiet: bool,
}

#[derive(Serialize)]
struct FrameRow {
    frame: u64,
    stamp_ns: i64,
    /// Whether the run mapped this frame as a keyframe (its stamp is on
    /// the run's trajectory); the others are views the map never trained on.
    keyframe: bool,
    #[serde(flatten)]
    metrics: ViewMetrics,
}

#[derive(Serialize)]
struct ClassRow {
    id: u16,
    /// From the vocabulary, else the log's class table, else `class N`.
    name: String,
    iou: f64,
    /// Evaluated pixels of the class (ground truth).
    pixels: u64,
}

#[derive(Serialize, Default)]
struct Means {
    psnr: f64,
    depth_l1: f64,
    coverage: f64,
    /// Per pixel, over every evaluated pixel with a target.
    cosine_loss: Option<f64>,
    l2: Option<f64>,
    /// Per pixel, over the vocabulary classes in the ground truth.
    miou: Option<f64>,
    /// Each region's mean query decoded once (debugging; more lenient).
    region_pooled: PooledMeans,
}

#[derive(Serialize, Default)]
struct PooledMeans {
    cosine_loss: Option<f64>,
    l2: Option<f64>,
    miou: Option<f64>,
}

/// The figures of one group of frames.
#[derive(Serialize)]
struct Group {
    frames: usize,
    mean: Means,
    /// Per vocabulary class of the group's ground truth.
    classes: Vec<ClassRow>,
}

#[derive(Serialize)]
struct EvalReport {
    run: String,
    log: String,
    frames_evaluated: usize,
    /// Over every evaluated frame.
    mean: Means,
    /// Over the frames the run mapped as keyframes (absent when none was
    /// evaluated).
    keyframes: Option<Group>,
    /// Over the frames that were never keyframes: views the map did not
    /// train on (absent when none was evaluated).
    novel_views: Option<Group>,
    /// `labels` or `teacher` (see `ViewMetrics::segmentation`).
    segmentation: Option<&'static str>,
    classes: Vec<ClassRow>,
    /// From the run's report.json: end-to-end frames per second of the
    /// mapping run and its peak GPU memory.
    run_fps: Option<f64>,
    run_peak_gpu_bytes: Option<u64>,
    /// Evaluation wall time per frame (render, read-back, metrics).
    eval_ms_per_frame: f64,
    /// Every N-th pixel and row were decoded.
    pixel_stride: u64,
    per_frame: Vec<FrameRow>,
}

/// The run folder's `report.json`, when it has one; one written by another
/// run than the state's is refused.
fn run_report_of(dir: &Path, state_run_id: Option<&str>) -> Result<Option<serde_json::Value>> {
    let Some(report) = crate::loaded_map::read_run_report(dir)? else {
        return Ok(None);
    };
    // A state with a run id was written with its report: a report without
    // one (or with one that is not a string) is not that run's either.
    if let Some(ours) = state_run_id {
        let theirs = match &report["run_id"] {
            serde_json::Value::String(s) => latentam::text::shown(s),
            serde_json::Value::Null => "no run id".to_string(),
            other => format!(
                "a run id that is not text, {}",
                latentam::text::shown(&other.to_string())
            ),
        };
        if report["run_id"].as_str() != Some(ours) {
            bail!(
                "{}: report.json was written by another run ({theirs}) than the state ({ours}); \
                 the folder mixes two runs",
                dir.display()
            );
        }
    }
    Ok(Some(report))
}

fn mean(v: impl Iterator<Item = f64>) -> Option<f64> {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    (n > 0).then(|| s / n as f64)
}

pub fn run(args: Args) -> Result<()> {
    let outputs: Vec<(&str, &Path)> = args.json.iter().map(|p| ("--json", p.as_path())).collect();
    crate::own_inputs::refuse_overwriting_inputs(
        &[
            crate::own_inputs::Input::RunFolder(&args.dir),
            crate::own_inputs::Input::File(&args.log),
        ],
        &outputs,
    )?;
    if !args.quiet {
        Stages::new("eval").start(format_args!("loading the map in {}", args.dir.display()));
    }
    let ctx = Context::new(ContextOptions::default())?;
    // The map and its report of one version, even while a writer swaps
    // the folder.
    let (mut mapper, run_report) = read_one_version(&args.dir, || {
        let mapper = Mapper::load(&ctx, &args.dir)?;
        let report = run_report_of(&args.dir, mapper.stats().run_id.as_deref()).map_err(|e| {
            latentam::Error::damaged(args.dir.join("report.json"), format!("{e:#}"))
        })?;
        Ok((mapper, report))
    })
    .with_context(|| format!("loading the map in {}", args.dir.display()))?;
    let assembly = args.input.assembly()?;
    let vocabulary = read_vocabulary(&args.log, &assembly.topics.vocabulary)?;
    if let Some(v) = &vocabulary {
        let stats = mapper.stats();
        if stats.embedding_dim.is_some() {
            stats.check_vocabulary(v).with_context(|| {
                format!(
                    "the vocabulary on {} in {}",
                    assembly.topics.vocabulary,
                    args.log.display()
                )
            })?;
        }
    }
    let class_table = read_class_names(&args.log)?;
    let frames = McapFrames::open(&args.log, assembly)
        .with_context(|| format!("opening {}", args.log.display()))?;
    let started = std::time::Instant::now();
    // Evaluation renders views of any size; the mapping budget is not
    // meant for it.
    ctx.set_memory_budget(None);
    let rows = evaluate_frames(&args, &mut mapper, frames, vocabulary.as_ref())?;
    if rows.is_empty() {
        bail!("no frame of {} could be evaluated", args.log.display());
    }
    let eval_ms_per_frame = started.elapsed().as_secs_f64() * 1e3 / rows.len() as f64;
    let report = eval_report(
        &args,
        rows,
        vocabulary.as_ref(),
        &class_table,
        run_report.as_ref(),
        eval_ms_per_frame,
    );
    print_summary(&report);
    if let Some(p) = &args.json {
        crate::mapping::write_text(p, &serde_json::to_string_pretty(&report)?)?;
    }
    Ok(())
}

/// Evaluates the frames `args` selects (`--every`, `--offset`,
/// `--frames`), printing a row per frame unless quiet; a frame the
/// evaluation refuses is skipped with a word.
fn evaluate_frames(
    args: &Args,
    mapper: &mut Mapper,
    frames: McapFrames,
    vocabulary: Option<&Vocabulary>,
) -> Result<Vec<FrameRow>> {
    let limit = args.frames.unwrap_or(usize::MAX);
    let keyframes: std::collections::HashSet<i64> = mapper
        .snapshot()?
        .trajectory
        .iter()
        .map(|&(stamp, _)| stamp)
        .collect();
    let mut rows = Vec::new();
    if !args.quiet {
        println!(
            "{:>6} {:>9} {:>10} {:>9} {:>9} {:>8}",
            "frame", "PSNR dB", "depth L1 m", "cos loss", "L2", "coverage"
        );
    }
    for (i, frame) in frames.enumerate() {
        let i = i as u64;
        if rows.len() >= limit {
            break;
        }
        if i < args.offset || !(i - args.offset).is_multiple_of(args.every) {
            continue;
        }
        let frame = frame.with_context(|| format!("reading {}", args.log.display()))?;
        let m = match mapper.evaluate(&frame, vocabulary, args.pixel_stride as usize) {
            Ok(m) => m,
            Err(e @ latentam::Error::BadInput { .. }) => {
                eprintln!("frame {i}: skipped ({e})");
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let opt = |x: Option<f64>| x.map_or("-".into(), |v| format!("{v:.4}"));
        if !args.quiet {
            println!(
                "{i:>6} {:>9.2} {:>10.4} {:>9} {:>9} {:>8.3}",
                m.psnr,
                m.depth_l1,
                opt(m.cosine_loss),
                opt(m.l2),
                m.coverage
            );
        }
        rows.push(FrameRow {
            frame: i,
            stamp_ns: frame.stamp_ns,
            keyframe: keyframes.contains(&frame.stamp_ns),
            metrics: m,
        });
    }
    Ok(rows)
}

/// The report of the evaluated `rows`: means over all, over keyframes
/// and over the views that were not, per class, and the run's own figures.
fn eval_report(
    args: &Args,
    rows: Vec<FrameRow>,
    vocabulary: Option<&Vocabulary>,
    class_table: &BTreeMap<u16, String>,
    run_report: Option<&serde_json::Value>,
    eval_ms_per_frame: f64,
) -> EvalReport {
    let all: Vec<&FrameRow> = rows.iter().collect();
    let (means, classes) = figures(&all, vocabulary, class_table);
    let group = |keyframe: bool| {
        let rows: Vec<&FrameRow> = rows.iter().filter(|r| r.keyframe == keyframe).collect();
        (!rows.is_empty()).then(|| {
            let (mean, classes) = figures(&rows, vocabulary, class_table);
            Group {
                frames: rows.len(),
                mean,
                classes,
            }
        })
    };
    EvalReport {
        run: args.dir.display().to_string(),
        log: args.log.display().to_string(),
        frames_evaluated: rows.len(),
        segmentation: rows.iter().find_map(|r| r.metrics.segmentation),
        mean: means,
        keyframes: group(true),
        novel_views: group(false),
        classes,
        run_fps: run_report.and_then(|r| r["fps"].as_f64()),
        run_peak_gpu_bytes: run_report.and_then(|r| r["peak_gpu_bytes"].as_u64()),
        eval_ms_per_frame,
        pixel_stride: args.pixel_stride,
        per_frame: rows,
    }
}

/// The mean figures of `rows` and their per-class IoU.
fn figures(
    rows: &[&FrameRow],
    vocabulary: Option<&Vocabulary>,
    class_table: &BTreeMap<u16, String>,
) -> (Means, Vec<ClassRow>) {
    let mut counts = BTreeMap::new();
    let mut pooled_counts = BTreeMap::new();
    for r in rows {
        add_iou(&mut counts, &r.metrics.class_iou);
        if let Some(p) = &r.metrics.region_pooled {
            add_iou(&mut pooled_counts, &p.class_iou);
        }
    }
    // Per-pixel means weigh every evaluated pixel alike, across frames.
    let per_pixel = |f: fn(&ViewMetrics) -> Option<f64>| {
        let (s, n) = rows.iter().fold((0.0, 0u64), |(s, n), r| {
            let k = r.metrics.cosine_pixels;
            match f(&r.metrics) {
                Some(v) if k > 0 => (s + v * k as f64, n + k),
                _ => (s, n),
            }
        });
        (n > 0).then(|| s / n as f64)
    };
    let pooled = |f: fn(&RegionPooled) -> Option<f64>| {
        mean(
            rows.iter()
                .filter_map(|r| r.metrics.region_pooled.as_ref().and_then(f)),
        )
    };
    let means = Means {
        psnr: mean(rows.iter().map(|r| r.metrics.psnr)).unwrap_or(0.0),
        depth_l1: mean(rows.iter().map(|r| r.metrics.depth_l1)).unwrap_or(0.0),
        coverage: mean(rows.iter().map(|r| r.metrics.coverage)).unwrap_or(0.0),
        cosine_loss: per_pixel(|m| m.cosine_loss),
        l2: per_pixel(|m| m.l2),
        miou: mean_iou(&counts),
        region_pooled: PooledMeans {
            cosine_loss: pooled(|p| p.cosine_loss),
            l2: pooled(|p| p.l2),
            miou: mean_iou(&pooled_counts),
        },
    };
    let name_of = |id: u16| {
        vocabulary
            .and_then(|v| {
                v.ids
                    .iter()
                    .position(|&x| x == id)
                    .map(|i| v.names[i].clone())
            })
            .or_else(|| class_table.get(&id).cloned())
            .unwrap_or_else(|| format!("class {id}"))
    };
    let classes: Vec<ClassRow> = counts
        .iter()
        .filter(|(_, c)| c.truth > 0)
        .map(|(&id, c)| ClassRow {
            id,
            name: name_of(id),
            iou: c.iou(),
            pixels: c.truth,
        })
        .collect();
    (means, classes)
}

fn print_summary(r: &EvalReport) {
    let m = &r.mean;
    let opt = |x: Option<f64>| x.map_or("n/a".into(), |v| format!("{v:.4}"));
    println!("mean over {} frames:", r.frames_evaluated);
    println!("  PSNR          {:.2} dB", m.psnr);
    println!("  depth L1      {:.4} m", m.depth_l1);
    println!("  coverage      {:.3}", m.coverage);
    println!("  cosine loss   {}", opt(m.cosine_loss));
    println!("  L2            {}", opt(m.l2));
    match r.segmentation {
        Some(s) => println!("  mIoU          {} ({s})", opt(m.miou)),
        None => println!("  mIoU          n/a (no vocabulary in the log)"),
    }
    for c in &r.classes {
        let name = latentam::text::shown(&c.name);
        println!("    {name:<16} {:.3}  ({} pixels)", c.iou, c.pixels);
    }
    if let (Some(k), Some(n)) = (&r.keyframes, &r.novel_views) {
        print_split(k, n);
    }
    let p = &m.region_pooled;
    println!(
        "  region-pooled: cosine loss {}, L2 {}, mIoU {}",
        opt(p.cosine_loss),
        opt(p.l2),
        opt(p.miou)
    );
    let stride = match r.pixel_stride {
        1 => "every pixel".to_string(),
        n => format!("every {} pixel and row", ordinal(n)),
    };
    println!(
        "protocol: per pixel ({stride}); {:.0} ms per frame",
        r.eval_ms_per_frame
    );
    if let (Some(fps), Some(gpu)) = (r.run_fps, r.run_peak_gpu_bytes) {
        println!(
            "mapping run: {fps:.2} frames/s end to end, peak GPU {:.1} MB",
            gpu as f64 / 1e6
        );
    }
}

/// The figures of keyframes beside those of views the map never trained on.
fn print_split(k: &Group, n: &Group) {
    let opt = |x: Option<f64>| x.map_or("n/a".into(), |v| format!("{v:.4}"));
    println!("  {:<14} {:>12} {:>12}", "", "keyframes", "novel views");
    println!("  {:<14} {:>12} {:>12}", "frames", k.frames, n.frames);
    println!(
        "  {:<14} {:>12.2} {:>12.2}",
        "PSNR dB", k.mean.psnr, n.mean.psnr
    );
    println!(
        "  {:<14} {:>12.4} {:>12.4}",
        "depth L1 m", k.mean.depth_l1, n.mean.depth_l1
    );
    for (name, a, b) in [
        ("cosine loss", k.mean.cosine_loss, n.mean.cosine_loss),
        ("L2", k.mean.l2, n.mean.l2),
        ("mIoU", k.mean.miou, n.mean.miou),
    ] {
        println!("  {name:<14} {:>12} {:>12}", opt(a), opt(b));
    }
}

/// `n` as an English ordinal: 2nd, 3rd, 4th, 11th, 21st.
fn ordinal(n: u64) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

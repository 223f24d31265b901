//! `latentam bench live`: the live handle under load. A generated scene
//! (640×480 by default) goes through it three times: its first 48 frames
//! twice with nothing dropped (`submit_waiting`), alone and with a thread
//! asking relevance queries at 2 Hz (every other one on the live map and
//! on a large synthetic snapshot of the sizes a long run reaches: 100 000
//! Gaussians, K = 2000 atoms, d_f = 768), so both map the same keyframes;
//! then all of it at the scene's frame rate with `submit`, a thread
//! rendering a view every 3 s, and an abort at the end. Measured: `submit`
//! latency, query and render latency while keyframes run, mapping time per
//! keyframe with and without queries, frames dropped, time to ready on a
//! new machine (the driver's shader cache and the engine's pipeline cache
//! in empty folders) and again with the caches that start filled, the
//! first keyframe against the next five, and how long `abort` takes.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _, Result};
use latentam_base::HostGaussians;
use latentam_core::latent::TextQuery;
use latentam_core::live::{IndexSettings, LiveMapper, LiveOptions, MapSnapshot};
use latentam_core::mapper::{
    camera_of, first_keyframe_over_median, DecoderFile, Integrated, Mapper, MapperConfig,
    MapperStats,
};
use latentam_gpu::{Context, ContextOptions};
use latentam_io::{AssemblyConfig, Frame, McapFrames, Vocabulary};
use rand::{Rng, SeedableRng};

use super::common::write_json;

mod report;
use report::{FirstKeyframe, LargeSnapshot, Latencies, Pass, Ready, Report};

#[derive(clap::Args)]
pub struct Args {
    /// Frames of the generated scene (at least 40).
    #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(40..=100_000))]
    frames: u64,
    /// Image width.
    #[arg(long, default_value_t = 640, value_parser = clap::value_parser!(u32).range(16..=4096))]
    width: u32,
    /// Image height.
    #[arg(long, default_value_t = 480, value_parser = clap::value_parser!(u32).range(16..=4096))]
    height: u32,
    /// Embedding dimension of the scene.
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u64).range(1..=8192))]
    dim: u64,
    /// Frames per second the scene is submitted at.
    #[arg(long, default_value_t = 30.0)]
    rate: f64,
    /// Relevance queries per second while mapping, in the second run.
    #[arg(long, default_value_t = 2.0)]
    query_hz: f64,
    /// Gaussians of the large synthetic snapshot queried beside the map.
    #[arg(long, default_value_t = 100_000, value_parser = clap::value_parser!(u64).range(1..=10_000_000))]
    query_gaussians: u64,
    /// Atoms (K) of the large snapshot's dictionary.
    #[arg(long, default_value_t = 2000, value_parser = clap::value_parser!(u64).range(1..=65_536))]
    query_atoms: u64,
    /// Embedding dimension of the large snapshot.
    #[arg(long, default_value_t = 768, value_parser = clap::value_parser!(u64).range(1..=8192))]
    query_dim: u64,
    /// Frames of the scene mapped without drops, alone and with queries,
    /// for the throughput comparison (the same keyframes both times).
    #[arg(long, default_value_t = 48, value_parser = clap::value_parser!(u64).range(8..=100_000))]
    lossless_frames: u64,
    /// Frames the live queue holds.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    queue: u64,
    /// Write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn run(args: Args) -> Result<()> {
    let scratch = std::env::temp_dir().join(format!("latentam-bench-live-{}", std::process::id()));
    std::fs::create_dir_all(&scratch)?;
    // A new machine's start: the driver's own shader cache (Mesa's, and
    // NVIDIA's) in an empty folder of the scratch space, set before any
    // device is opened, while this process has no other thread.
    let driver_cache = scratch.join("driver-cache");
    std::fs::create_dir_all(&driver_cache)?;
    for var in ["MESA_SHADER_CACHE_DIR", "__GL_SHADER_DISK_CACHE_PATH"] {
        std::env::set_var(var, &driver_cache);
    }
    let result = bench(&args, &scratch);
    let _ = std::fs::remove_dir_all(&scratch);
    result
}

fn bench(args: &Args, scratch: &Path) -> Result<()> {
    let log = scratch.join("scene.mcap");
    let scene = latentam_scene::SceneConfig {
        frames: args.frames as usize,
        width: args.width,
        height: args.height,
        dim: args.dim as usize,
        fps: args.rate,
        ..latentam_scene::SceneConfig::default()
    };
    let mut progress = latentam_cli::progress::Progress::new("generating scene", scene.frames);
    latentam_scene::generate(&scene, &log, |d| progress.set(d))?;
    drop(progress);
    let mut reader = McapFrames::open(&log, AssemblyConfig::default())
        .with_context(|| format!("opening {}", log.display()))?;
    let frames: Vec<Frame> = (&mut reader).collect::<Result<_, _>>()?;
    let vocabulary = reader
        .vocabulary()
        .cloned()
        .context("the generated scene has a vocabulary")?;
    if frames.len() < 40 {
        bail!("the scene gave {} frames", frames.len());
    }

    let caches = scratch.join("pipelines");
    let (cold_ms, _, first_cold) = open_and_map(&caches, &frames)?;
    let (warm_ms, ctx, first_warm) = open_and_map(&caches, &frames)?;
    let ready = Ready {
        cold_ms,
        warm_ms,
        warm_cache_bytes: ctx.info().pipeline_cache_loaded_bytes,
        cold_builds: first_cold.builds.clone(),
        warm_builds: first_warm.builds.clone(),
    };
    let (first_cold, first_warm) = (first_cold.first, first_warm.first);
    println!(
        "time to ready: {cold_ms:.0} ms cold ({} kernels, {:.1} s of building), {warm_ms:.0} ms \
         warm; the first keyframe over the median of the next five: {:.2} cold, {:.2} warm \
         (Stage I: {:.2}, {:.2})",
        ready.cold_builds.kernels,
        ready.cold_builds.work_ms / 1e3,
        first_cold.total_first_over_median_of_later,
        first_warm.total_first_over_median_of_later,
        first_cold.first_over_median_of_later,
        first_warm.first_over_median_of_later
    );

    let (large, large_snapshot) = large_snapshot(args);
    println!(
        "large snapshot: {} Gaussians, K = {}, d_f = {}: index built in {:.0} ms, {:.1} MB",
        args.query_gaussians,
        args.query_atoms,
        args.query_dim,
        large_snapshot.index_build_ms,
        large_snapshot.index_bytes as f64 / 1e6
    );
    let large = Arc::new(large);

    let probes = Arc::new(Probes {
        large: large.clone(),
        vocabulary,
        camera_frame: frames[frames.len() / 2].clone(),
    });
    // Throughput with and without queries on the same keyframes; then the
    // camera's rate, with renders.
    let same = frames[..frames.len().min(args.lossless_frames as usize)].to_vec();
    let lossless = |probe| (Feed::Lossless, probe);
    let (alone, _) = pass(
        args,
        &ctx,
        same.clone(),
        lossless(Probe::Nothing),
        &probes,
        false,
    )?;
    print_pass(&alone);
    let (with, _) = pass(args, &ctx, same, lossless(Probe::Queries), &probes, false)?;
    print_pass(&with);
    let camera = (Feed::CameraRate, Probe::Renders);
    let (rendering, abort_ms) = pass(args, &ctx, frames, camera, &probes, true)?;
    print_pass(&rendering);
    let abort_ms = abort_ms.unwrap_or(f64::NAN);
    println!("abort while a keyframe ran: {abort_ms:.0} ms");
    let throughput = with.keyframes_per_mapping_s / alone.keyframes_per_mapping_s;
    println!(
        "mapping throughput with queries: {:.1} % of without",
        throughput * 100.0
    );

    let report = Report {
        device: ctx.info().name.clone(),
        cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
        frames: args.frames,
        width: args.width,
        height: args.height,
        dim: args.dim,
        rate_hz: args.rate,
        query_hz: args.query_hz,
        queue_frames: args.queue,
        ready,
        first_keyframe_cold: first_cold,
        first_keyframe_warm: first_warm,
        large_snapshot,
        passes: vec![alone, with, rendering],
        throughput_with_queries: throughput,
        abort_ms,
    };
    write_json(args.json.as_deref(), &report)
}

/// A start and its first keyframes.
struct Start {
    builds: latentam_core::mapper::KernelBuilds,
    first: FirstKeyframe,
}

/// Opens a context with its pipeline cache in `caches`, builds the
/// mapper's kernels (the time to ready), and maps the first six keyframes
/// synchronously for their times.
fn open_and_map(caches: &Path, frames: &[Frame]) -> Result<(f64, Context, Start)> {
    let start = Instant::now();
    let ctx = Context::new(ContextOptions {
        pipeline_cache_dir: Some(caches.to_path_buf()),
        ..ContextOptions::default()
    })?;
    let mut mapper = Mapper::with_context(&ctx, MapperConfig::default())?;
    mapper.warm_up()?;
    let ready_ms = start.elapsed().as_secs_f64() * 1e3;
    let (mut stage_one_ms, mut total_ms) = (Vec::new(), Vec::new());
    for f in frames {
        if let Integrated::Keyframe(k) = mapper.integrate(f)? {
            stage_one_ms.push(k.timings.stage_one_ms);
            total_ms.push(k.timings.total_ms);
            if stage_one_ms.len() == 6 {
                break;
            }
        }
    }
    let over = |ms: &[f64]| first_keyframe_over_median(ms).unwrap_or(f64::NAN);
    let first = FirstKeyframe {
        first_over_median_of_later: over(&stage_one_ms),
        total_first_over_median_of_later: over(&total_ms),
        stage_one_ms,
        total_ms,
    };
    let builds = latentam_core::mapper::KernelBuilds::of(&ctx.kernel_build_times());
    Ok((ready_ms, ctx, Start { builds, first }))
}

/// A snapshot of random Gaussians and a random decoder at the sizes asked
/// for, its index built.
fn large_snapshot(args: &Args) -> (MapSnapshot, LargeSnapshot) {
    let mut r = rand::rngs::StdRng::seed_from_u64(7);
    let n = args.query_gaussians as usize;
    let (k, d) = (args.query_atoms as usize, args.query_dim as usize);
    let mut g = HostGaussians::zeros(n);
    for q in &mut g.queries {
        q.iter_mut().for_each(|x| *x = r.random_range(-1.0..1.0));
    }
    let decoder = DecoderFile {
        dim: d as u32,
        w: (0..32 * d).map(|_| r.random_range(-1.0..1.0)).collect(),
        atoms: (0..k * d).map(|_| r.random_range(-1.0..1.0)).collect(),
        anchors: Vec::new(),
        atom_weights: vec![1.0; k],
        temperature: 0.05,
        eps: 1e-6,
        model: "synthetic".into(),
        run_id: None,
    };
    let stats = MapperStats {
        gaussians: n,
        ..MapperStats::default()
    };
    let snapshot = MapSnapshot::new(
        g,
        Some(decoder),
        Vec::new(),
        stats,
        IndexSettings::default(),
    );
    let index = snapshot
        .relevance_index()
        .expect("a decoder with atoms indexes");
    let summary = LargeSnapshot {
        gaussians: args.query_gaussians,
        atoms: args.query_atoms,
        dim: args.query_dim,
        index_build_ms: index.build_ms(),
        index_bytes: index.bytes(),
        mean_atoms_per_gaussian: index.mean_atoms(),
    };
    (snapshot, summary)
}

/// What a prober thread asks while the scene is submitted.
#[derive(Clone, Copy, PartialEq)]
enum Probe {
    Nothing,
    /// Relevance queries at `query_hz`, every other one on the live map
    /// (whose snapshots the indexer then indexes as they come) and on the
    /// large snapshot.
    Queries,
    /// A render of a view of the scene every three seconds.
    Renders,
}

/// What the prober needs.
struct Probes {
    large: Arc<MapSnapshot>,
    vocabulary: Vocabulary,
    camera_frame: Frame,
}

/// Submits `frames` at the scene's rate; returns the submit latencies.
fn submit_at_rate(live: &LiveMapper, frames: Vec<Frame>, rate: f64) -> Result<Vec<f64>> {
    let start = Instant::now();
    let mut submit_ms = Vec::with_capacity(frames.len());
    for (i, f) in frames.into_iter().enumerate() {
        let due = start + Duration::from_secs_f64(i as f64 / rate);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let t = Instant::now();
        live.submit(f)?;
        submit_ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(submit_ms)
}

/// Submits every frame, waiting for room; no latencies.
fn submit_all(live: &LiveMapper, frames: Vec<Frame>) -> Result<Vec<f64>> {
    for f in frames {
        if live.submit_waiting(f, Duration::from_secs(3600))?.is_some() {
            bail!("the queue stayed full for an hour");
        }
    }
    Ok(Vec::new())
}

fn start_live(args: &Args, ctx: &Context) -> Result<LiveMapper> {
    let mapper = Mapper::with_context(ctx, MapperConfig::default())?;
    Ok(LiveMapper::start(
        mapper,
        LiveOptions {
            queue_frames: args.queue as usize,
            ..LiveOptions::default()
        },
    )?)
}

/// How a pass feeds the handle.
#[derive(Clone, Copy, PartialEq)]
enum Feed {
    /// At the scene's frame rate with `submit`: frames drop by policy.
    CameraRate,
    /// As fast as the handle takes them with `submit_waiting`: every frame
    /// is mapped, so two passes map the same keyframes.
    Lossless,
}

/// One pass of `frames` fed as `feed` says with `probe` asking beside
/// it; the abort latency, measured at its end, when `measure_abort`.
fn pass(
    args: &Args,
    ctx: &Context,
    frames: Vec<Frame>,
    (feed, probe): (Feed, Probe),
    probes: &Arc<Probes>,
    measure_abort: bool,
) -> Result<(Pass, Option<f64>)> {
    let tail: Vec<Frame> = frames[frames.len() - 8..].to_vec();
    let live = Arc::new(start_live(args, ctx)?);
    let done = Arc::new(AtomicBool::new(false));
    let prober = {
        let (live, done, probes) = (live.clone(), done.clone(), probes.clone());
        let period = match probe {
            Probe::Renders => Duration::from_secs(3),
            _ => Duration::from_secs_f64(1.0 / args.query_hz.max(1e-3)),
        };
        std::thread::spawn(move || ask(&live, &done, &probes, probe, period))
    };
    let start = Instant::now();
    let submitted = match feed {
        Feed::CameraRate => submit_at_rate(&live, frames, args.rate),
        Feed::Lossless => submit_all(&live, frames),
    };
    live.wait_idle(Duration::from_secs(24 * 3600));
    let wall_s = start.elapsed().as_secs_f64();
    done.store(true, Ordering::SeqCst);
    let asked = prober.join().expect("the prober thread");
    let submit_ms = submitted?;
    let (live_ms, large_ms, render_ms) = asked?;
    let status = live.status();
    let stats = live.snapshot().stats.clone();
    let live = Arc::into_inner(live).expect("the prober is done");
    let latencies = [
        Latencies::of(&live_ms),
        Latencies::of(&large_ms),
        Latencies::of(&render_ms),
    ];
    let summary = summarise(
        (feed, probe),
        wall_s,
        &status,
        &stats,
        &submit_ms,
        latencies,
    );
    if !measure_abort {
        live.finish()?;
        return Ok((summary, None));
    }
    // Abort while a keyframe of eight more frames runs.
    for (i, mut f) in tail.into_iter().enumerate() {
        f.stamp_ns += 1_000_000_000 * (i as i64 + 1) + 60_000_000_000;
        live.submit(f)?;
    }
    let t = Instant::now();
    while !live.status().mapping && t.elapsed() < Duration::from_secs(60) {
        std::thread::sleep(Duration::from_millis(1));
    }
    std::thread::sleep(Duration::from_millis(300));
    let t = Instant::now();
    live.abort()?;
    Ok((summary, Some(t.elapsed().as_secs_f64() * 1e3)))
}

/// The prober: at each period, what `probe` asks.
#[allow(clippy::type_complexity)]
fn ask(
    live: &LiveMapper,
    done: &AtomicBool,
    probes: &Probes,
    probe: Probe,
    period: Duration,
) -> Result<(Vec<f64>, Vec<f64>, Vec<f64>)> {
    let word = probes
        .vocabulary
        .names
        .first()
        .context("an empty vocabulary")?;
    let query = TextQuery::vocabulary_word(&probes.vocabulary, word, 0.1)?;
    let mut r = rand::rngs::StdRng::seed_from_u64(11);
    let dim = probes.large.decoder.as_ref().map_or(0, |d| d.dim as usize);
    let text = TextQuery::embedding((0..dim).map(|_| r.random_range(-1.0..1.0)).collect());
    let camera = camera_of(&probes.camera_frame);
    let (mut live_ms, mut large_ms, mut render_ms) = (Vec::new(), Vec::new(), Vec::new());
    let mut tick = 0u64;
    while !done.load(Ordering::SeqCst) && probe != Probe::Nothing {
        let next = Instant::now() + period;
        tick += 1;
        if probe == Probe::Queries && tick.is_multiple_of(2) {
            let t = Instant::now();
            match live.relevance(&query) {
                Ok(_) => live_ms.push(t.elapsed().as_secs_f64() * 1e3),
                Err(latentam::Error::NoEmbeddings) => {}
                Err(e) => return Err(e.into()),
            }
        } else if probe == Probe::Queries {
            let t = Instant::now();
            probes.large.relevance(&text)?;
            large_ms.push(t.elapsed().as_secs_f64() * 1e3);
        } else if live.status().gaussians > 0 {
            let t = Instant::now();
            live.render(&camera)?;
            render_ms.push(t.elapsed().as_secs_f64() * 1e3);
        }
        while Instant::now() < next && !done.load(Ordering::SeqCst) {
            std::thread::sleep(Duration::from_millis(5));
        }
    }
    Ok((live_ms, large_ms, render_ms))
}

fn summarise(
    (feed, probe): (Feed, Probe),
    wall_s: f64,
    status: &latentam_core::live::LiveStatus,
    stats: &MapperStats,
    submit_ms: &[f64],
    probes: [Option<Latencies>; 3],
) -> Pass {
    let keyframes = stats.keyframes.max(1);
    let ms = stats.timings.total_ms / keyframes as f64;
    Pass {
        fed: match feed {
            Feed::CameraRate => "at the camera's rate",
            Feed::Lossless => "every frame, waiting for room",
        },
        probing: match probe {
            Probe::Nothing => "nothing",
            Probe::Queries => "relevance queries",
            Probe::Renders => "renders",
        },
        submitted: status.submitted,
        keyframes: stats.keyframes,
        dropped: status.dropped,
        wall_s,
        mapping_ms_per_keyframe: ms,
        keyframes_per_mapping_s: 1e3 / ms.max(1e-9),
        submit: Latencies::of(submit_ms),
        live_map_queries: probes[0],
        large_snapshot_queries: probes[1],
        renders: probes[2],
        last_keyframe_latency_ms: status.last_keyframe_latency_ms,
        gaussians: stats.gaussians,
    }
}

fn print_pass(p: &Pass) {
    let line = |name: &str, l: &Option<Latencies>| {
        if let Some(l) = l {
            println!(
                "  {name:<24} n={:<5} p50 {:>9.3} ms  p99 {:>9.3} ms  max {:>9.3} ms",
                l.count, l.p50_ms, l.p99_ms, l.max_ms
            );
        }
    };
    println!(
        "{}, probing {}: {} frames submitted, {} keyframes, {} dropped ({} not keyframes, {} superseded), \
         {:.0} ms mapping per keyframe, {} Gaussians",
        p.fed,
        p.probing,
        p.submitted,
        p.keyframes,
        p.dropped.total(),
        p.dropped.not_keyframe,
        p.dropped.superseded,
        p.mapping_ms_per_keyframe,
        p.gaussians
    );
    line("submit", &p.submit);
    line("live map relevance", &p.live_map_queries);
    line("large snapshot relevance", &p.large_snapshot_queries);
    line("render", &p.renders);
}

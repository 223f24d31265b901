//! Long-run soak of the mapper on the demo scene (or a building of rooms)
//! walked lap after lap: per keyframe the GPU bytes, CPU bytes, Gaussians,
//! kept keyframes, live Vulkan objects, validation messages, paging and
//! the disk tier, and a verdict per lap. Shared by
//! `latentam bench soak` and the test suite's short soak.
//!
//! What a bounded run looks like: after the first lap (every room seen)
//! GPU bytes stop growing, CPU bytes grow only where new surface is seen
//! (little), live objects come back to the same counts at the end of every
//! lap, and the validation layer stays silent.

use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context as _, Result};
use latentam::frames::{AssemblyConfig, McapFrames};
use latentam::{Config as MapperConfig, Context, Integrated, LiveObjects, Mapper};
use serde::Serialize;

use latentam_scene::{generate, SceneConfig};

/// One keyframe of the soak.
#[derive(Clone, Debug, Serialize)]
pub struct SoakPoint {
    pub keyframe: u64,
    pub frame: u64,
    pub lap: usize,
    pub gaussians: usize,
    /// Gaussians seeded and pruned at this keyframe.
    pub added: usize,
    pub pruned: usize,
    pub resident: usize,
    pub kept_keyframes: usize,
    pub gpu_bytes: u64,
    pub cpu_bytes: u64,
    pub objects: LiveObjects,
    pub validation_messages: usize,
    pub ms: f64,
    /// Paging of this keyframe: bytes up and down, host time.
    pub paging_bytes_up: u64,
    pub paging_bytes_down: u64,
    pub paging_cpu_ms: f64,
    /// Gaussians on disk afterwards, and the disk tier's time this
    /// keyframe (see `host_budget`).
    pub spilled_gaussians: usize,
    pub disk_ms: f64,
}

/// Per lap: the largest values seen and the state at its end.
#[derive(Clone, Debug, Serialize)]
pub struct LapSummary {
    pub lap: usize,
    pub keyframes: usize,
    pub max_gpu_bytes: u64,
    pub end_cpu_bytes: u64,
    pub end_gaussians: usize,
    pub end_kept_keyframes: usize,
    pub end_objects: LiveObjects,
    pub ms_per_keyframe: f64,
    /// Means over the lap's keyframes.
    pub paging_bytes_per_keyframe: f64,
    pub paging_cpu_ms_per_keyframe: f64,
    pub disk_ms_per_keyframe: f64,
    pub end_spilled_gaussians: usize,
}

/// Paging per keyframe against the map's size: the keyframes in order,
/// cut into tenths, each with its mean map size and paging. Flat paging
/// while the map grows is what paging by block promises.
#[derive(Clone, Debug, Serialize)]
pub struct PagingByMapSize {
    pub first_keyframe: u64,
    pub gaussians: f64,
    pub paging_bytes_per_keyframe: f64,
    pub paging_cpu_ms_per_keyframe: f64,
    pub disk_ms_per_keyframe: f64,
}

/// The soak's result.
#[derive(Clone, Debug, Serialize)]
pub struct SoakReport {
    pub frames: usize,
    pub laps: usize,
    pub width: u32,
    pub height: u32,
    pub device: String,
    pub wall_s: f64,
    pub curve: Vec<SoakPoint>,
    pub laps_summary: Vec<LapSummary>,
    pub paging_by_map_size: Vec<PagingByMapSize>,
    /// Largest GPU bytes after the first lap over the first lap's largest
    /// (1.0 = flat).
    pub gpu_growth_after_first_lap: f64,
    /// CPU bytes at the end over those at the end of the first lap.
    pub cpu_growth_after_first_lap: f64,
    /// Gaussians at the end over those at the end of the first lap.
    pub gaussian_growth_after_first_lap: f64,
    /// Live objects at the end of every lap after the first equal those at
    /// the end of the first.
    pub objects_steady: bool,
    pub validation_messages: usize,
}

/// What to soak.
#[derive(Clone, Debug)]
pub struct SoakOptions {
    pub scene: SceneConfig,
    pub config: MapperConfig,
}

/// Generates the scene into `scratch` and maps it on `ctx`, reporting
/// through `progress(frames done)`.
pub fn run(
    ctx: &Context,
    opts: &SoakOptions,
    scratch: &Path,
    mut progress: impl FnMut(usize),
) -> Result<SoakReport> {
    if opts.scene.laps < 2 {
        bail!("a soak needs at least 2 laps (one to warm up, one to compare)");
    }
    std::fs::create_dir_all(scratch)?;
    let log = scratch.join("soak.mcap");
    generate(&opts.scene, &log, |_| {})?;
    let frames = McapFrames::open(&log, AssemblyConfig::default())
        .with_context(|| format!("opening {}", log.display()))?;
    let mut mapper = Mapper::with_context(ctx, opts.config.clone())?;
    // Every pipeline up front, so the object counts compare like with like.
    mapper.warm_up()?;
    let validation = ctx.validation_log();
    let per_lap = opts.scene.frames as f64 / opts.scene.laps as f64;
    let mut curve = Vec::new();
    let start = Instant::now();
    for (i, frame) in frames.enumerate() {
        let frame = frame?;
        let t = Instant::now();
        if let Integrated::Keyframe(k) = mapper.integrate(&frame)? {
            curve.push(SoakPoint {
                keyframe: k.index,
                frame: i as u64,
                lap: ((i as f64 / per_lap) as usize).min(opts.scene.laps - 1),
                gaussians: k.gaussians,
                added: k.added,
                pruned: k.pruned,
                resident: k.resident,
                kept_keyframes: mapper.stats().kept_keyframes,
                gpu_bytes: k.gpu_bytes,
                cpu_bytes: k.cpu_bytes,
                objects: ctx.live_objects(),
                validation_messages: validation.errors().len(),
                ms: t.elapsed().as_secs_f64() * 1e3,
                paging_bytes_up: k.paging.iter().map(|p| p.bytes_up).sum(),
                paging_bytes_down: k.paging.iter().map(|p| p.bytes_down).sum(),
                paging_cpu_ms: k.timings.paging_cpu_ms,
                spilled_gaussians: k.disk.spilled_gaussians,
                disk_ms: k.timings.disk_ms,
            });
        }
        progress(i + 1);
    }
    let wall_s = start.elapsed().as_secs_f64();
    let mean = |pts: &[&SoakPoint], f: &dyn Fn(&SoakPoint) -> f64| {
        pts.iter().map(|p| f(p)).sum::<f64>() / pts.len().max(1) as f64
    };
    let paging_bytes = |p: &SoakPoint| (p.paging_bytes_up + p.paging_bytes_down) as f64;
    let laps_summary: Vec<LapSummary> = (0..opts.scene.laps)
        .filter_map(|lap| {
            let pts: Vec<&SoakPoint> = curve.iter().filter(|p| p.lap == lap).collect();
            let end = pts.last()?;
            Some(LapSummary {
                lap,
                keyframes: pts.len(),
                max_gpu_bytes: pts.iter().map(|p| p.gpu_bytes).max().unwrap_or(0),
                end_cpu_bytes: end.cpu_bytes,
                end_gaussians: end.gaussians,
                end_kept_keyframes: end.kept_keyframes,
                end_objects: end.objects,
                ms_per_keyframe: pts.iter().map(|p| p.ms).sum::<f64>() / pts.len() as f64,
                paging_bytes_per_keyframe: mean(&pts, &paging_bytes),
                paging_cpu_ms_per_keyframe: mean(&pts, &|p| p.paging_cpu_ms),
                disk_ms_per_keyframe: mean(&pts, &|p| p.disk_ms),
                end_spilled_gaussians: end.spilled_gaussians,
            })
        })
        .collect();
    let all: Vec<&SoakPoint> = curve.iter().collect();
    let tenth = all.len().div_ceil(10).max(1);
    let paging_by_map_size = all
        .chunks(tenth)
        .map(|pts| PagingByMapSize {
            first_keyframe: pts[0].keyframe,
            gaussians: mean(pts, &|p| p.gaussians as f64),
            paging_bytes_per_keyframe: mean(pts, &paging_bytes),
            paging_cpu_ms_per_keyframe: mean(pts, &|p| p.paging_cpu_ms),
            disk_ms_per_keyframe: mean(pts, &|p| p.disk_ms),
        })
        .collect();
    let Some(first) = laps_summary.first() else {
        bail!("no keyframes: the scene gave no usable frames");
    };
    let later = &laps_summary[1..];
    let last = laps_summary.last().expect("non-empty");
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { f64::NAN };
    Ok(SoakReport {
        frames: opts.scene.frames,
        laps: opts.scene.laps,
        width: opts.scene.width,
        height: opts.scene.height,
        device: ctx.info().name.clone(),
        wall_s,
        gpu_growth_after_first_lap: ratio(
            later.iter().map(|l| l.max_gpu_bytes).max().unwrap_or(0) as f64,
            first.max_gpu_bytes as f64,
        ),
        cpu_growth_after_first_lap: ratio(last.end_cpu_bytes as f64, first.end_cpu_bytes as f64),
        gaussian_growth_after_first_lap: ratio(
            last.end_gaussians as f64,
            first.end_gaussians as f64,
        ),
        objects_steady: later.iter().all(|l| l.end_objects == first.end_objects),
        validation_messages: validation.errors().len(),
        curve,
        laps_summary,
        paging_by_map_size,
    })
}

/// A table of the laps, then paging against the map's size.
pub fn lap_table(r: &SoakReport) -> String {
    let mut s = format!(
        "{:>4} {:>9} {:>12} {:>12} {:>10} {:>9} {:>8} {:>8} {:>10} {:>12} {:>11} {:>9}\n",
        "lap",
        "keyframes",
        "max GPU MB",
        "end CPU MB",
        "Gaussians",
        "kept kf",
        "buffers",
        "pools",
        "ms per kf",
        "paging kB/kf",
        "paging ms/kf",
        "disk ms/kf"
    );
    for l in &r.laps_summary {
        let o = &l.end_objects;
        s += &format!(
            "{:>4} {:>9} {:>12.1} {:>12.2} {:>10} {:>9} {:>8} {:>8} {:>10.0} {:>12.1} {:>11.2} {:>9.2}\n",
            l.lap,
            l.keyframes,
            l.max_gpu_bytes as f64 / 1e6,
            l.end_cpu_bytes as f64 / 1e6,
            l.end_gaussians,
            l.end_kept_keyframes,
            o.buffers,
            o.command_pools + o.descriptor_pools + o.query_pools,
            l.ms_per_keyframe,
            l.paging_bytes_per_keyframe / 1e3,
            l.paging_cpu_ms_per_keyframe,
            l.disk_ms_per_keyframe
        );
    }
    s += &format!(
        "\n{:>14} {:>12} {:>12} {:>11} {:>9}\n",
        "from keyframe", "Gaussians", "paging kB/kf", "paging ms/kf", "disk ms/kf"
    );
    for t in &r.paging_by_map_size {
        s += &format!(
            "{:>14} {:>12.0} {:>12.1} {:>11.2} {:>9.2}\n",
            t.first_keyframe,
            t.gaussians,
            t.paging_bytes_per_keyframe / 1e3,
            t.paging_cpu_ms_per_keyframe,
            t.disk_ms_per_keyframe
        );
    }
    s
}

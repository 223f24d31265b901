//! `latentam bench map`: the online mapper end to end on the generated
//! scene (or any log): keyframes per second, milliseconds per keyframe by
//! stage, paging and how much of it Stage II hid, peak GPU and CPU bytes,
//! and per keyframe the curves of GPU bytes, CPU bytes and Gaussians. At
//! the end, the PSNR of re-rendered keyframes.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context as _, Result};
use latentam_core::mapper::budget::MemorySplit;
use latentam_core::mapper::eval::{add_iou, mean_iou};
use latentam_core::mapper::GpuWorkReport;
use latentam_core::mapper::{
    Integrated, KeyframeGpuCalls, KeyframeReport, KeyframeTimings, Mapper, MapperConfig,
};
use latentam_gpu::{Context, ContextOptions, GpuCalls, GpuModel};
use latentam_io::{read_vocabulary, AssemblyConfig, Frame, McapFrames};
use serde::Serialize;

pub struct MapBench {
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub dim: usize,
    pub log: Option<PathBuf>,
    pub config: Option<PathBuf>,
    pub budget: Option<u64>,
    pub eval_keyframes: usize,
    pub json: Option<PathBuf>,
    /// A GPU to state the floor on besides the presets.
    pub gpu: Option<GpuModel>,
}

/// A GPU given by its peak rate and bandwidth, with a discrete GPU's
/// launch and round-trip costs.
pub fn custom_gpu(tflops: f64, gbs: f64) -> GpuModel {
    GpuModel {
        name: format!("a GPU of {tflops} TFLOPS and {gbs} GB/s"),
        fp32_tflops: tflops,
        memory_gbs: gbs,
        link_gbs: gbs,
        ..GpuModel::rtx_4090()
    }
}

#[derive(Serialize)]
struct CurvePoint {
    keyframe: u64,
    frame: u64,
    gaussians: usize,
    resident: usize,
    gpu_bytes: u64,
    cpu_bytes: u64,
    total_ms: f64,
    kmeans_ms: f64,
    stage_one_ms: f64,
    stage_two_ms: f64,
    /// Dictionary atoms after the keyframe.
    atoms: u32,
    /// Host waits in Stage I and Stage II.
    stage_one_and_two_waits: u64,
    /// Host waits of the whole keyframe.
    host_waits: u64,
    /// Bytes the keyframe uploaded and downloaded in all (images and
    /// embeddings included).
    uploaded_bytes: u64,
    downloaded_bytes: u64,
    /// Paging alone: bytes up and down, blocks in and out, host
    /// milliseconds (planning and recording; waits included).
    paging_bytes_up: u64,
    paging_bytes_down: u64,
    paging_blocks_in: usize,
    paging_blocks_out: usize,
    paging_cpu_ms: f64,
    /// GPU calls and host-link bytes by step.
    #[serde(skip)]
    calls: KeyframeGpuCalls,
}

/// What one step of a keyframe asked of the GPU, per keyframe: megabytes
/// across the host link each way, host waits and dispatches.
#[derive(Serialize)]
struct StepCalls {
    up_mb: f64,
    down_mb: f64,
    host_waits: f64,
    dispatches: f64,
}

/// Paging per keyframe, mean over the keyframes after the first five
/// (which build the window up rather than page it).
#[derive(Serialize)]
struct PagingPerKeyframe {
    /// Keyframes averaged over.
    keyframes: usize,
    bytes_up: f64,
    bytes_down: f64,
    blocks_in: f64,
    blocks_out: f64,
    cpu_ms: f64,
    /// Host waits of the whole keyframe.
    host_waits: f64,
    /// Every byte across the host link, host wait and dispatch per
    /// keyframe, by the step that recorded it (paging's own syncs under
    /// `insertion` when new Gaussians re-centred the window before
    /// Stage I, under `paging` beside Stage II).
    by_step: BTreeMap<&'static str, StepCalls>,
}

impl PagingPerKeyframe {
    const SKIP: usize = 5;

    fn of(curve: &[CurvePoint]) -> Option<Self> {
        let points = curve.get(Self::SKIP..).filter(|p| !p.is_empty())?;
        let n = points.len() as f64;
        let mean = |f: &dyn Fn(&CurvePoint) -> f64| points.iter().map(f).sum::<f64>() / n;
        Some(PagingPerKeyframe {
            keyframes: points.len(),
            bytes_up: mean(&|p| p.paging_bytes_up as f64),
            bytes_down: mean(&|p| p.paging_bytes_down as f64),
            blocks_in: mean(&|p| p.paging_blocks_in as f64),
            blocks_out: mean(&|p| p.paging_blocks_out as f64),
            cpu_ms: mean(&|p| p.paging_cpu_ms),
            host_waits: mean(&|p| p.host_waits as f64),
            by_step: [
                (
                    "dictionary",
                    (|c| c.dictionary) as fn(&KeyframeGpuCalls) -> GpuCalls,
                ),
                ("insertion", |c| c.insertion),
                ("stage_one", |c| c.stage_one),
                ("stage_two", |c| c.stage_two),
                ("paging", |c| c.paging),
                ("prune", |c| c.prune),
            ]
            .into_iter()
            .map(|(name, step)| {
                let calls = StepCalls {
                    up_mb: mean(&|p| step(&p.calls).uploaded_bytes as f64) / 1e6,
                    down_mb: mean(&|p| step(&p.calls).downloaded_bytes as f64) / 1e6,
                    host_waits: mean(&|p| step(&p.calls).host_waits as f64),
                    dispatches: mean(&|p| step(&p.calls).dispatches as f64),
                };
                (name, calls)
            })
            .collect(),
        })
    }
}

/// Mean milliseconds per keyframe of one phase of the run: while the
/// dictionary fills, or once it holds every atom it may.
#[derive(Serialize)]
struct Phase {
    keyframes: usize,
    total_ms: f64,
    kmeans_ms: f64,
    stage_one_ms: f64,
    stage_two_ms: f64,
    /// Gaussians on the GPU after the keyframe: Stage I grows with them.
    resident: f64,
}

impl Phase {
    /// The stages whose work grows with the dictionary.
    fn dictionary_ms(&self) -> f64 {
        self.kmeans_ms + self.stage_two_ms
    }

    fn of(points: &[&CurvePoint]) -> Option<Phase> {
        let n = points.len();
        let mean = |f: fn(&CurvePoint) -> f64| points.iter().map(|p| f(p)).sum::<f64>() / n as f64;
        (n > 0).then(|| Phase {
            keyframes: n,
            total_ms: mean(|p| p.total_ms),
            kmeans_ms: mean(|p| p.kmeans_ms),
            stage_one_ms: mean(|p| p.stage_one_ms),
            stage_two_ms: mean(|p| p.stage_two_ms),
            resident: mean(|p| p.resident as f64),
        })
    }
}

#[derive(Serialize)]
struct Report {
    device: String,
    source: String,
    frames: u64,
    width: u32,
    height: u32,
    keyframes: u64,
    wall_s: f64,
    keyframes_per_s: f64,
    ms_per_keyframe: KeyframeTimings,
    /// Host waits, submissions and dispatches per keyframe.
    gpu_calls_per_keyframe: latentam_core::mapper::HostWaits,
    /// The work per keyframe counted from the kernels' launch sizes, per
    /// kernel, and the floor it puts on the time per keyframe on GPU
    /// models.
    gpu_work: GpuWorkReport,
    /// The dictionary's capacity, and the time per keyframe while it
    /// filled and once it was full (the first keyframe, which creates
    /// every workspace, is left out of both).
    atoms: u32,
    while_filling: Option<Phase>,
    once_full: Option<Phase>,
    paging_gpu_ms_total: Option<f64>,
    paging_hidden_ms_total: Option<f64>,
    paging_hidden_share: Option<f64>,
    /// Paging per keyframe after the first five.
    paging_per_keyframe: Option<PagingPerKeyframe>,
    dedicated_transfer_queue: bool,
    gpu_budget: u64,
    window_capacity: u64,
    peak_gpu_bytes: u64,
    /// Peak GPU bytes by part (images, latent head, window, staging).
    peak_gpu_split: MemorySplit,
    peak_cpu_bytes: u64,
    /// Peak resident memory of the process, as the OS measured it.
    peak_rss_bytes: Option<u64>,
    gaussians: usize,
    evicted: u64,
    fetched: u64,
    psnr_keyframes: Option<f64>,
    /// Per pixel (the paper's protocol) over the same keyframes, when the
    /// log has embeddings and a vocabulary: cosine loss and mIoU.
    cosine_loss_keyframes: Option<f64>,
    miou_keyframes: Option<f64>,
    keyframes_evaluated: usize,
    curve: Vec<CurvePoint>,
}

pub fn run(b: MapBench) -> Result<()> {
    let mut cfg = match &b.config {
        Some(p) => MapperConfig::from_toml(
            &latentam_io::read_input_to_string(p)
                .with_context(|| format!("reading {}", p.display()))?,
        )?,
        None => MapperConfig::default(),
    };
    if b.budget.is_some() {
        cfg.gpu_budget = b.budget;
    }
    let scratch = std::env::temp_dir().join(format!("latentam-bench-map-{}", std::process::id()));
    let (path, source) = match &b.log {
        Some(p) => (p.clone(), p.display().to_string()),
        None => {
            use latentam_scene::{generate, SceneConfig};
            std::fs::create_dir_all(&scratch)?;
            let p = scratch.join("scene.mcap");
            let sc = SceneConfig {
                frames: b.frames,
                width: b.width,
                height: b.height,
                dim: b.dim,
                ..SceneConfig::default()
            };
            let mut progress = latentam_cli::progress::Progress::new("generating scene", b.frames);
            generate(&sc, &p, |d| progress.set(d))?;
            (p, format!("generated scene, {} frames", b.frames))
        }
    };
    let result = map(&b, cfg, &path, source);
    let _ = std::fs::remove_dir_all(&scratch);
    result
}

fn map(b: &MapBench, cfg: MapperConfig, path: &std::path::Path, source: String) -> Result<()> {
    let ctx = Context::new(ContextOptions {
        profiling: true,
        ..ContextOptions::default()
    })?;
    let atoms = cfg.atoms;
    let mut mapper = Mapper::with_context(&ctx, cfg)?;
    // The kernels of this configuration (its blending layout), not the
    // defaults', so no keyframe builds one.
    mapper.warm_up()?;
    let mut gpu_calls = Vec::new();
    let frames = McapFrames::open(path, AssemblyConfig::default())
        .with_context(|| format!("opening {}", path.display()))?;
    let limit = if b.log.is_some() {
        b.frames
    } else {
        usize::MAX
    };
    let mut progress = latentam_cli::progress::Progress::new("mapping", b.frames);
    let mut curve = Vec::new();
    let mut kept: Vec<Frame> = Vec::new();
    let (mut width, mut height, mut n) = (0, 0, 0u64);
    let start = Instant::now();
    for (i, frame) in frames.take(limit).enumerate() {
        let frame = frame?;
        (width, height) = (frame.color.width, frame.color.height);
        n += 1;
        if let Integrated::Keyframe(k) = mapper.integrate(&frame)? {
            curve.push(CurvePoint::of(&k));
            gpu_calls.push(k.gpu_calls);
            kept.push(frame);
        }
        progress.set(i + 1);
    }
    let wall = start.elapsed().as_secs_f64();
    drop(progress);
    if curve.is_empty() {
        bail!("no keyframes: the log has no usable frames");
    }
    let stats = mapper.stats();
    let keyframes = stats.keyframes;

    if b.eval_keyframes > 0 {
        ctx.set_memory_budget(None);
    }
    let quality = keyframe_quality(&mut mapper, &kept, b.eval_keyframes, path)?;
    let mut models = GpuModel::presets();
    models.extend(b.gpu.clone());
    let t = &stats.timings;
    let hidden_share = match (t.paging_gpu_ms, t.paging_hidden_ms) {
        (Some(g), Some(h)) if g > 0.0 => Some(h / g),
        _ => None,
    };
    let report = Report {
        device: ctx.info().name.clone(),
        source,
        frames: n,
        width,
        height,
        keyframes,
        wall_s: wall,
        keyframes_per_s: keyframes as f64 / wall,
        ms_per_keyframe: t.per_keyframe(keyframes),
        gpu_calls_per_keyframe: latentam_core::mapper::HostWaits::of(&gpu_calls),
        gpu_work: GpuWorkReport::of(&stats.gpu_work, &gpu_calls, &models),
        atoms,
        while_filling: phase(&curve, atoms, false),
        once_full: phase(&curve, atoms, true),
        paging_gpu_ms_total: t.paging_gpu_ms,
        paging_hidden_ms_total: t.paging_hidden_ms,
        paging_hidden_share: hidden_share,
        paging_per_keyframe: PagingPerKeyframe::of(&curve),
        dedicated_transfer_queue: ctx.info().dedicated_transfer_queue,
        gpu_budget: stats.window.map_or(0, |w| w.budget),
        window_capacity: stats.window.map_or(0, |w| w.capacity),
        peak_gpu_bytes: stats.gpu_peak_bytes,
        peak_gpu_split: stats.gpu_peak_split,
        peak_cpu_bytes: stats.cpu_peak_bytes,
        peak_rss_bytes: latentam_base::process::peak_rss_bytes(),
        gaussians: stats.gaussians,
        evicted: stats.evicted,
        fetched: stats.fetched,
        psnr_keyframes: quality.psnr,
        cosine_loss_keyframes: quality.cosine_loss,
        miou_keyframes: quality.miou,
        keyframes_evaluated: quality.evaluated,
        curve,
    };
    print_report(&report);
    if let Some(p) = &b.json {
        std::fs::write(p, serde_json::to_string_pretty(&report)?)
            .with_context(|| format!("writing {}", p.display()))?;
    }
    Ok(())
}

/// The keyframes after the first while the dictionary of `atoms` fills
/// (`full` false) or once it is full; none without embeddings, which have
/// no dictionary to fill.
fn phase(curve: &[CurvePoint], atoms: u32, full: bool) -> Option<Phase> {
    if !curve.iter().any(|p| p.atoms > 0) {
        return None;
    }
    let points: Vec<&CurvePoint> = curve
        .iter()
        .skip(1)
        .filter(|p| (p.atoms >= atoms) == full)
        .collect();
    Phase::of(&points)
}

impl CurvePoint {
    fn of(k: &KeyframeReport) -> Self {
        CurvePoint {
            keyframe: k.index,
            frame: k.frame,
            gaussians: k.gaussians,
            resident: k.resident,
            gpu_bytes: k.gpu_bytes,
            cpu_bytes: k.cpu_bytes,
            total_ms: k.timings.total_ms,
            kmeans_ms: k.timings.kmeans_ms,
            stage_one_ms: k.timings.stage_one_ms,
            stage_two_ms: k.timings.stage_two_ms,
            atoms: k.atoms,
            stage_one_and_two_waits: k.gpu_calls.training().host_waits,
            host_waits: k.gpu_calls.total().host_waits,
            uploaded_bytes: k.gpu_work.uploaded_bytes,
            downloaded_bytes: k.gpu_work.downloaded_bytes,
            paging_bytes_up: k.paging.iter().map(|p| p.bytes_up).sum(),
            paging_bytes_down: k.paging.iter().map(|p| p.bytes_down).sum(),
            paging_blocks_in: k.paging.iter().map(|p| p.blocks_in).sum(),
            paging_blocks_out: k.paging.iter().map(|p| p.blocks_out).sum(),
            paging_cpu_ms: k.timings.paging_cpu_ms,
            calls: k.gpu_calls,
        }
    }
}

/// Quality of re-rendered keyframes.
struct Quality {
    psnr: Option<f64>,
    /// Per pixel, over every evaluated pixel.
    cosine_loss: Option<f64>,
    miou: Option<f64>,
    evaluated: usize,
}

/// PSNR, cosine loss and mIoU of `count` of the `kept` keyframes, spread
/// over the run, rendered from the map as it ends.
fn keyframe_quality(
    mapper: &mut Mapper,
    kept: &[Frame],
    count: usize,
    path: &std::path::Path,
) -> Result<Quality> {
    let every = (kept.len() / count.max(1)).max(1);
    let mut psnr = Vec::new();
    let vocabulary = read_vocabulary(path, &AssemblyConfig::default().topics.vocabulary)?;
    let (mut cos, mut cos_pixels) = (0.0, 0u64);
    let mut classes = std::collections::BTreeMap::new();
    for f in kept.iter().step_by(every).take(count) {
        let m = mapper.evaluate(f, vocabulary.as_ref(), 1)?;
        psnr.push(m.psnr);
        if let Some(c) = m.cosine_loss {
            cos += c * m.cosine_pixels as f64;
            cos_pixels += m.cosine_pixels;
        }
        add_iou(&mut classes, &m.class_iou);
    }
    Ok(Quality {
        psnr: (!psnr.is_empty()).then(|| psnr.iter().sum::<f64>() / psnr.len() as f64),
        cosine_loss: (cos_pixels > 0).then(|| cos / cos_pixels as f64),
        miou: mean_iou(&classes),
        evaluated: psnr.len(),
    })
}

fn print_report(r: &Report) {
    let m = &r.ms_per_keyframe;
    let opt = |x: Option<f64>| x.map_or("n/a".to_string(), |v| format!("{v:.1}"));
    println!("device: {}   source: {}", r.device, r.source);
    println!(
        "{} frames ({}×{}), {} keyframes in {:.1} s: {:.3} keyframes/s",
        r.frames, r.width, r.height, r.keyframes, r.wall_s, r.keyframes_per_s
    );
    println!("ms per keyframe (wall):");
    println!("  k-means           {:>10.1}", m.kmeans_ms);
    println!("  insertion         {:>10.1}", m.insertion_ms);
    println!("  Stage I           {:>10.1}", m.stage_one_ms);
    println!("  Stage II + paging {:>10.1}", m.stage_two_ms);
    println!("  paging (host)     {:>10.1}", m.paging_cpu_ms);
    println!("  paging (GPU)      {:>10}", opt(m.paging_gpu_ms));
    println!("  paging hidden     {:>10}", opt(m.paging_hidden_ms));
    println!("  pruning           {:>10.1}", m.prune_ms);
    println!("  total             {:>10.1}", m.total_ms);
    println!("{}", r.gpu_calls_per_keyframe.summary());
    print_work(&r.gpu_work);
    let last_atoms = r.curve.last().map_or(0, |p| p.atoms);
    if last_atoms > 0 {
        println!("dictionary: {last_atoms} of {} atoms at the end", r.atoms);
    }
    for (name, phase) in [
        ("while filling", &r.while_filling),
        ("once full", &r.once_full),
    ] {
        if let Some(p) = phase {
            println!(
                "  {name:<14} {:>4} keyframes: {:.1} ms per keyframe (k-means {:.1}, Stage I {:.1}, \
                 Stage II {:.1}), {:.0} Gaussians resident",
                p.keyframes, p.total_ms, p.kmeans_ms, p.stage_one_ms, p.stage_two_ms, p.resident
            );
        }
    }
    if let (Some(a), Some(b)) = (&r.while_filling, &r.once_full) {
        println!(
            "  once full / while filling: {:.2}x in all, {:.2}x in k-means + Stage II (Stage I \
             grows with the Gaussians resident, not the dictionary)",
            b.total_ms / a.total_ms,
            b.dictionary_ms() / a.dictionary_ms()
        );
    }
    if let Some(p) = &r.paging_per_keyframe {
        println!(
            "paging per keyframe (keyframes {} on): {:.2} MB up, {:.2} MB down, {:.1} blocks in, \
             {:.1} out, {:.1} ms of host time; {:.1} host waits per keyframe in all",
            PagingPerKeyframe::SKIP,
            p.bytes_up / 1e6,
            p.bytes_down / 1e6,
            p.blocks_in,
            p.blocks_out,
            p.cpu_ms,
            p.host_waits
        );
        println!("per keyframe by step: MB up, MB down, host waits, dispatches");
        for (name, c) in &p.by_step {
            println!(
                "  {name:<10} {:>8.2} {:>8.2} {:>6.2} {:>7.1}",
                c.up_mb, c.down_mb, c.host_waits, c.dispatches
            );
        }
    }
    println!(
        "paging hidden behind Stage II: {} (dedicated transfer queue: {})",
        r.paging_hidden_share
            .map_or("n/a".into(), |s| format!("{:.0} %", s * 100.0)),
        r.dedicated_transfer_queue
    );
    println!(
        "GPU budget {} B, window {} Gaussians; peak GPU {} B, peak CPU {} B, peak RSS {}",
        r.gpu_budget,
        r.window_capacity,
        r.peak_gpu_bytes,
        r.peak_cpu_bytes,
        r.peak_rss_bytes.map_or("n/a".into(), |b| format!("{b} B"))
    );
    let sp = &r.peak_gpu_split;
    println!(
        "peak GPU by part: images {:.1} MB, features {:.1} MB, latent head {:.1} MB, window {:.1} MB, \
         staging {:.1} MB",
        sp.images as f64 / 1e6,
        sp.features as f64 / 1e6,
        sp.latent_head as f64 / 1e6,
        sp.window as f64 / 1e6,
        sp.staging as f64 / 1e6
    );
    println!(
        "Gaussians {} (evicted {}, fetched {} over the run)",
        r.gaussians, r.evicted, r.fetched
    );
    if let Some(p) = r.psnr_keyframes {
        println!(
            "PSNR of {} re-rendered keyframes: {p:.2} dB",
            r.keyframes_evaluated
        );
    }
    if let (Some(c), Some(m)) = (r.cosine_loss_keyframes, r.miou_keyframes) {
        println!("per pixel on the same keyframes: cosine loss {c:.4}, mIoU {m:.4}");
    }
}

/// The work per keyframe, the kernels that weigh most in the first GPU
/// model's floor, and each model's floor by term.
fn print_work(w: &GpuWorkReport) {
    println!(
        "GPU work per keyframe (counted from launch sizes): {:.2} GFLOP, {:.1} MB of GPU memory \
         traffic, {:.1} MB uploaded, {:.1} MB downloaded, {:.0} dispatches ({:.1} uncounted)",
        w.gflop_per_keyframe,
        w.mb_per_keyframe,
        w.uploaded_mb_per_keyframe,
        w.downloaded_mb_per_keyframe,
        w.dispatches_per_keyframe,
        w.uncounted_dispatches_per_keyframe
    );
    let Some(first) = GpuModel::presets().into_iter().next() else {
        return;
    };
    let ms = |k: &latentam_core::mapper::KernelWorkPerKeyframe| {
        first.kernel_ms(k.gflop * 1e9, k.mb * 1e6)
    };
    let mut kernels: Vec<_> = w.kernels.iter().collect();
    kernels.sort_by(|a, b| ms(b.1).total_cmp(&ms(a.1)));
    println!(
        "  the kernels that weigh most in the floor on {}:",
        first.name
    );
    println!(
        "  {:<34} {:>10} {:>10} {:>10} {:>12}",
        "kernel", "dispatches", "GFLOP", "MB", "floor ms"
    );
    for (name, k) in kernels.iter().take(10) {
        println!(
            "  {name:<34} {:>10.1} {:>10.3} {:>10.1} {:>12.4}",
            k.dispatches,
            k.gflop,
            k.mb,
            ms(k)
        );
    }
    for f in &w.floors {
        println!(
            "  floor on {}: {:.2} ms per keyframe (kernels {:.2}, of which compute-bound {:.2}; \
             dispatches {:.2}; host waits {:.2}; host link {:.2})",
            f.gpu,
            f.total_ms,
            f.kernels_ms,
            f.compute_bound_ms,
            f.dispatch_ms,
            f.host_wait_ms,
            f.link_ms
        );
    }
}

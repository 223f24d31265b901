//! `latentam query`: open-vocabulary relevance of every Gaussian of a
//! mapped run, a heat-map PLY, a top-k summary and, from a pose, a
//! relevance image.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use glam::{DAffine3, DQuat, DVec3};
use latentam::gpu::{Context, ContextOptions};
use latentam::io::{read_vocabulary, write_ply};
use latentam::latent::RelevanceScorer;
use latentam::mapper::eval::Evaluator;
use latentam::mapper::Mapper;
use latentam::splat::QUERY_DIM;
use latentam_cli::convert::features::read_vector;
use latentam_cli::progress::Stages;

#[derive(clap::Args)]
pub struct Args {
    /// Run folder written by `latentam map`.
    pub dir: PathBuf,
    /// The query: one embedding from your vision-language model's text
    /// encoder, as `.npy` (F16/F32, shape [D] or [1, D]) or `.safetensors`.
    /// Relevance is the cosine similarity with each Gaussian's decoded
    /// embedding.
    #[arg(long, value_name = "FILE", required_unless_present = "name")]
    pub embedding: Option<PathBuf>,
    /// The query as an entry of a vocabulary (with --vocabulary).
    /// Relevance is the softmax over the whole vocabulary, at
    /// --temperature, of cosine similarities: the probability that a
    /// Gaussian is this class rather than another.
    #[arg(long, conflicts_with = "embedding", requires = "vocabulary")]
    pub name: Option<String>,
    /// Log holding the vocabulary (a `TextEmbeddings` message), e.g. the
    /// mapped log itself.
    #[arg(long, value_name = "LOG")]
    pub vocabulary: Option<PathBuf>,
    /// Topic of the vocabulary in that log.
    #[arg(long, default_value = "/vocabulary")]
    pub vocabulary_topic: String,
    /// Softmax temperature over the vocabulary (--name).
    #[arg(long, default_value_t = 0.1)]
    pub temperature: f32,
    /// Heat-map PLY (3DGS layout, colour = relevance, plus a `relevance`
    /// property); default DIR/heatmap.ply.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// How many of the most relevant Gaussians to list.
    #[arg(long, default_value_t = 10)]
    pub top: usize,
    /// Also render a relevance image from this camera pose,
    /// `tx,ty,tz,qx,qy,qz,qw` (camera-to-world, as in trajectory.txt),
    /// with the intrinsics of the map's last keyframe.
    #[arg(long, requires = "png", allow_hyphen_values = true)]
    pub view: Option<String>,
    /// PNG for the relevance image (with --view).
    #[arg(long, requires = "view")]
    pub png: Option<PathBuf>,
}

/// How scores against the query texts become one relevance per row.
enum Relevance {
    /// Cosine with the one text.
    Cosine,
    /// Softmax over the texts at a temperature; the value for `index`.
    Softmax { index: usize, temperature: f32 },
}

impl Relevance {
    fn of(&self, scores: &[f32], texts: usize) -> Vec<f32> {
        match *self {
            Relevance::Cosine => scores.to_vec(),
            Relevance::Softmax { index, temperature } => scores
                .chunks_exact(texts)
                .map(|row| {
                    let max = row.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
                    let e: Vec<f32> = row
                        .iter()
                        .map(|s| ((s - max) / temperature).exp())
                        .collect();
                    e[index] / e.iter().sum::<f32>()
                })
                .collect(),
        }
    }
}

/// Colour of a relevance in 0..1: a ramp dark blue → cyan → green →
/// yellow → red, so low and high read apart at a glance.
pub fn heat(t: f32) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.05, 0.05, 0.45],
        [0.0, 0.75, 0.9],
        [0.1, 0.8, 0.2],
        [0.95, 0.85, 0.1],
        [0.85, 0.1, 0.05],
    ];
    let x = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    std::array::from_fn(|c| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f)
}

fn parse_pose(s: &str) -> Result<DAffine3> {
    let v: Vec<f64> = s
        .split(|c: char| c == ',' || c.is_whitespace())
        .filter(|p| !p.is_empty())
        .map(|p| p.parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--view {s:?}: not numbers"))?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        bail!("--view {s:?}: expected 7 finite numbers tx,ty,tz,qx,qy,qz,qw");
    }
    let q = DQuat::from_xyzw(v[3], v[4], v[5], v[6]);
    if (q.length() - 1.0).abs() > 1e-3 {
        bail!(
            "--view {s:?}: the quaternion has norm {:.4}, not 1",
            q.length()
        );
    }
    Ok(DAffine3::from_rotation_translation(
        q.normalize(),
        DVec3::new(v[0], v[1], v[2]),
    ))
}

pub fn run(args: Args) -> Result<()> {
    let pose = args.view.as_deref().map(parse_pose).transpose()?;
    let stages = Stages::new("query");
    stages.start(format_args!("loading the map in {}", args.dir.display()));
    let ctx = Context::new(ContextOptions::default())?;
    let mut mapper = Mapper::load(&ctx, &args.dir)
        .with_context(|| format!("loading the map in {}", args.dir.display()))?;
    // A head's dim is at least 1 (`LatentHead::new` refuses 0).
    let Some(dim) = mapper.online_ref().head().map(|h| h.config().dim as usize) else {
        if mapper.stats().keyframes == 0 {
            bail!(
                "{} holds no keyframe: there is nothing to query",
                args.dir.display()
            );
        }
        bail!(
            "{} was mapped without embeddings: there is nothing to query",
            args.dir.display()
        );
    };
    if mapper.global().is_empty() {
        bail!(
            "the map in {} holds no Gaussians: there is nothing to score",
            args.dir.display()
        );
    }
    let (texts, relevance, what) = match (&args.embedding, &args.name) {
        (Some(path), _) => {
            let v = read_vector(path)?;
            if v.len() != dim {
                bail!(
                    "{}: the query has {} values; the map's embeddings are {dim}-d",
                    path.display(),
                    v.len()
                );
            }
            (v, Relevance::Cosine, path.display().to_string())
        }
        (None, Some(name)) => {
            // clap: --name requires --vocabulary.
            let log = args.vocabulary.as_ref().expect("clap requires it");
            let vocab = read_vocabulary(log, &args.vocabulary_topic)?.with_context(|| {
                format!(
                    "{} has no vocabulary on {}",
                    log.display(),
                    args.vocabulary_topic
                )
            })?;
            let Some(index) = vocab.names.iter().position(|n| n == name) else {
                bail!(
                    "`{name}` is not in the vocabulary; it has: {}",
                    vocab.names.join(", ")
                );
            };
            mapper
                .online_ref()
                .check_vocabulary(&vocab)
                .with_context(|| format!("the vocabulary in {}", log.display()))?;
            if !(args.temperature > 0.0 && args.temperature.is_finite()) {
                bail!("--temperature must be positive");
            }
            let relevance = Relevance::Softmax {
                index,
                temperature: args.temperature,
            };
            (vocab.vectors, relevance, format!("`{name}`"))
        }
        // clap: --embedding is required unless --name is given.
        (None, None) => unreachable!("clap requires one"),
    };
    // One text of `dim` values, or the vocabulary's `names × dim` (its size
    // checked on reading), so `index < count` for the softmax.
    let count = texts.len() / dim;
    stages.start(format_args!(
        "scoring {} Gaussians against {what}",
        mapper.global().len()
    ));
    let scores = mapper.query_many(&texts)?;
    let rel = relevance.of(&scores, count);
    let mut gaussians: Vec<_> = mapper.global().iter().map(|(_, g)| *g).collect();

    // Heat map: colour spans the scores' range (cosine) or 0..1 (softmax).
    let (lo, hi) = match relevance {
        Relevance::Cosine => rel
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            }),
        Relevance::Softmax { .. } => (0.0, 1.0),
    };
    let span = (hi - lo).max(1e-6);
    for (g, &r) in gaussians.iter_mut().zip(&rel) {
        g.color = heat((r - lo) / span);
    }
    let out = args.out.unwrap_or_else(|| args.dir.join("heatmap.ply"));
    write_ply(&out, &gaussians, &[("relevance", &rel)])?;

    let mut order: Vec<usize> = (0..rel.len()).collect();
    order.sort_by(|&a, &b| rel[b].total_cmp(&rel[a]));
    // `rel` has one value per Gaussian, and the map has some (checked
    // above); `p` is in 0..=1, so the index is within `order`.
    let pct = |p: f64| rel[order[((1.0 - p) * (rel.len() - 1) as f64).round() as usize]];
    println!(
        "{} Gaussians scored against {what}: max {:.3}, 90th percentile {:.3}, median {:.3}, min {:.3}",
        rel.len(),
        pct(1.0),
        pct(0.9),
        pct(0.5),
        pct(0.0)
    );
    if matches!(relevance, Relevance::Softmax { .. }) {
        let likely = rel.iter().filter(|&&r| r >= 0.5).count();
        println!("{likely} Gaussians are more likely this class than all others together (≥ 0.5)");
    }
    println!("top {}:", args.top.min(rel.len()));
    println!("  rank  relevance          x          y          z");
    for (rank, &i) in order.iter().take(args.top).enumerate() {
        let m = gaussians[i].mean;
        println!(
            "  {:>4}  {:>9.4} {:>10.3} {:>10.3} {:>10.3}",
            rank + 1,
            rel[i],
            m[0],
            m[1],
            m[2]
        );
    }
    println!("heat map: {}", out.display());

    if let (Some(pose), Some(png)) = (pose, &args.png) {
        stages.start("rendering the relevance image");
        render_relevance(&ctx, &mut mapper, pose, &texts, count, &relevance, png)?;
        println!("relevance image: {}", png.display());
    }
    Ok(())
}

/// Renders the map's queries from `pose`, decodes and scores every pixel,
/// and writes the relevance as a colour PNG (pixels the map does not
/// cover are black).
fn render_relevance(
    ctx: &Context,
    mapper: &mut Mapper,
    pose: DAffine3,
    texts: &[f32],
    count: usize,
    relevance: &Relevance,
    png: &Path,
) -> Result<()> {
    let online = mapper.online();
    let history = online.history();
    let Some(last) = history.len().checked_sub(1).and_then(|i| history.get(i)) else {
        bail!("the map has no keyframe to take intrinsics from");
    };
    let mut camera = last.camera;
    camera.cam_to_world = pose;
    let mut ev = Evaluator::new(ctx);
    let (view, _) = ev.render(online, &camera)?;
    let head = online.head().expect("checked by the caller");
    let mut scorer = None;
    let scorer = RelevanceScorer::ensure(&mut scorer, ctx, head, count as u32)?;
    let queries: Vec<[f32; QUERY_DIM]> = view.query.clone();
    let rel = relevance.of(&scorer.score(ctx, head, &queries, texts)?, count);
    let covered: Vec<f32> = rel
        .iter()
        .zip(&view.alpha)
        .filter(|(_, &a)| a > 0.5)
        .map(|(&r, _)| r)
        .collect();
    let (lo, hi) = match relevance {
        Relevance::Cosine => covered
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| {
                (a.min(x), b.max(x))
            }),
        Relevance::Softmax { .. } => (0.0, 1.0),
    };
    let span = (hi - lo).max(1e-6);
    let rgb: Vec<u8> = rel
        .iter()
        .zip(&view.alpha)
        .flat_map(|(&r, &a)| {
            let c = if a > 0.5 {
                heat((r - lo) / span)
            } else {
                [0.0; 3]
            };
            c.map(|x| (x * 255.0).round() as u8)
        })
        .collect();
    crate::png_out::write_rgb(png, view.width, view.height, &rgb)
}

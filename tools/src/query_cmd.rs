//! `latentam query`: open-vocabulary relevance of every Gaussian of a
//! mapped run, a heat-map PLY, a top-k summary and, from a pose, a
//! relevance image.

use std::path::PathBuf;

use anyhow::{bail, Context as _, Result};
use latentam::interchange::write_ply;
use latentam::{Context, ContextOptions, Mapper, Scored, Scoring, Viewpoint};
use latentam_cli::progress::Stages;

use crate::own_inputs::{refuse_overwriting_inputs, Input};
use crate::pictures::heat;
use crate::query_args::{queryable_dim, QueryArgs};
use crate::render_cmd::{parse_pose, relevance_picture};

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["embedding", "name"])))]
#[command(group(clap::ArgGroup::new("named").args(["name"]).requires("vocabulary")))]
pub struct Args {
    /// Run folder written by `latentam map`.
    pub dir: PathBuf,
    #[command(flatten)]
    pub query: QueryArgs,
    /// Topic of the vocabulary in the --vocabulary log.
    #[arg(long, default_value = "/vocabulary")]
    pub vocabulary_topic: String,
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

pub fn run(args: Args) -> Result<()> {
    let pose = args.view.as_deref().map(parse_pose).transpose()?;
    let mut inputs = vec![Input::RunFolder(&args.dir)];
    inputs.extend(args.query.embedding.as_deref().map(Input::File));
    inputs.extend(args.query.vocabulary.as_deref().map(Input::File));
    let mut outputs = Vec::new();
    outputs.extend(args.out.as_deref().map(|p| ("--out", p)));
    outputs.extend(args.png.as_deref().map(|p| ("--png", p)));
    refuse_overwriting_inputs(&inputs, &outputs)?;
    let stages = Stages::new("query");
    stages.start(format_args!("loading the map in {}", args.dir.display()));
    let ctx = Context::new(ContextOptions::default())?;
    let mut mapper = Mapper::load(&ctx, &args.dir)
        .with_context(|| format!("loading the map in {}", args.dir.display()))?;
    let dim = queryable_dim(&mapper, &args.dir)?;
    if mapper.stats().gaussians == 0 {
        bail!(
            "the map in {} holds no Gaussians: there is nothing to score",
            args.dir.display()
        );
    }
    let query = args
        .query
        .resolve(&mapper, dim, None, &args.vocabulary_topic)?
        .expect("clap requires --embedding or --name");
    stages.start(format_args!(
        "scoring {} Gaussians against {}",
        mapper.stats().gaussians,
        query.what
    ));
    let rel = mapper.relevance(&query.text, Scored::Gaussians)?;
    let mut gaussians = mapper.snapshot()?.to_gaussians();

    // Heat map: colour spans the scores' range (cosine) or 0..1 (softmax).
    let (lo, hi) = query.colour_range(&rel, |_| true);
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
        "{} Gaussians scored against {}: max {:.3}, 90th percentile {:.3}, median {:.3}, min {:.3}",
        rel.len(),
        query.what,
        pct(1.0),
        pct(0.9),
        pct(0.5),
        pct(0.0)
    );
    if matches!(query.text.relevance, Scoring::Softmax { .. }) {
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
        let (view, _) = mapper.render(Viewpoint::Pose(pose))?;
        relevance_picture(&mut mapper, &query, &view)?
            .0
            .write_png(png)?;
        println!("relevance image: {}", png.display());
    }
    Ok(())
}

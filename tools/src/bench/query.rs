//! `latentam bench query`: relevance of every Gaussian of a saved map to
//! an embedding, timed query after query, with the map loaded under a
//! host budget: the latency a user sees on a map larger than memory (the
//! first query builds the relevance index, reading spilled blocks from
//! disk one at a time; the others read the index), and the process's peak
//! RSS while it answers.
//!
//! The embeddings are random unit vectors (seeded): the time does not
//! depend on what a query asks, only on the map's size and the latent
//! head's (atoms × dimension).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, Context as _, Result};
use latentam_core::latent::TextQuery;
use latentam_core::mapper::{Mapper, Scored};
use latentam_gpu::{Context, ContextOptions};
use rand::{Rng, SeedableRng};
use serde::Serialize;

use super::common::write_json;

/// Settings of `latentam bench query`.
#[derive(clap::Args)]
pub struct Args {
    /// Run folder of the map (`latentam map --out`).
    dir: PathBuf,
    /// Queries timed, each with another embedding; at least 5.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(5..))]
    runs: u32,
    /// Host memory of the map's blocks while it is loaded and queried,
    /// bytes (the `host_budget` setting; 0: no bound).
    #[arg(long, default_value_t = 64_000_000)]
    host_budget: u64,
    /// Folder of the scratch file for blocks past the budget (the
    /// `spill_dir` setting; default: the map's own).
    #[arg(long)]
    spill_dir: Option<String>,
    /// Write the results as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Serialize)]
struct Report {
    dir: String,
    device: String,
    gaussians: u64,
    spilled_gaussians: u64,
    host_budget: u64,
    embedding_dim: u32,
    load_s: f64,
    /// The first query: the relevance index built (every block read, in
    /// memory or from disk), then scored.
    first_query_ms: f64,
    runs: usize,
    query_ms: Vec<f64>,
    p50_ms: f64,
    p99_ms: f64,
    max_ms: f64,
    peak_rss_bytes: Option<u64>,
}

/// The `q`-quantile of `v` (nearest rank).
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = ((q * s.len() as f64).ceil() as usize).clamp(1, s.len());
    s[rank - 1]
}

pub fn run(args: Args) -> Result<()> {
    let ctx = Context::new(ContextOptions::default())?;
    let start = Instant::now();
    let (budget, spill_dir) = (args.host_budget, args.spill_dir.clone());
    let mut mapper = Mapper::load_with(&ctx, &args.dir, &|c| {
        let mut c = c.clone();
        c.host_budget = budget;
        if let Some(d) = &spill_dir {
            c.spill_dir = Some(d.clone());
        }
        Ok(c)
    })
    .with_context(|| format!("loading the map in {}", args.dir.display()))?;
    let load_s = start.elapsed().as_secs_f64();
    let stats = mapper.stats();
    let Some(dim) = stats.embedding_dim else {
        bail!("{} has no embeddings to query", args.dir.display());
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x9e7);
    let mut times = Vec::new();
    let mut first_query_ms = 0.0;
    // One more query than timed: the first builds the relevance index.
    for i in 0..=args.runs {
        let mut e: Vec<f32> = (0..dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        let norm = e.iter().map(|x| x * x).sum::<f32>().sqrt().max(1e-12);
        e.iter_mut().for_each(|x| *x /= norm);
        let query = TextQuery::embedding(e);
        let t = Instant::now();
        let scores = mapper.relevance(&query, Scored::Gaussians)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        if scores.len() != stats.gaussians {
            bail!("{} scores for {} Gaussians", scores.len(), stats.gaussians);
        }
        if i > 0 {
            times.push(ms);
        } else {
            first_query_ms = ms;
        }
    }
    let after = mapper.stats();
    let report = Report {
        dir: args.dir.display().to_string(),
        device: ctx.info().name.clone(),
        gaussians: stats.gaussians as u64,
        spilled_gaussians: after.disk.spilled_gaussians as u64,
        host_budget: budget,
        embedding_dim: dim,
        load_s,
        first_query_ms,
        runs: times.len(),
        p50_ms: quantile(&times, 0.5),
        p99_ms: quantile(&times, 0.99),
        max_ms: quantile(&times, 1.0),
        query_ms: times,
        peak_rss_bytes: latentam_base::process::peak_rss_bytes(),
    };
    println!(
        "{} Gaussians ({} spilled, host budget {} MB), {}-d, on {}: loaded in {:.1} s, first \
         query (the index built) {:.1} s",
        report.gaussians,
        report.spilled_gaussians,
        budget / 1_000_000,
        dim,
        report.device,
        load_s,
        first_query_ms / 1e3
    );
    println!(
        "relevance of every Gaussian: p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms over {} queries; \
         peak RSS {}",
        report.p50_ms,
        report.p99_ms,
        report.max_ms,
        report.runs,
        report
            .peak_rss_bytes
            .map_or("unknown".into(), |b| format!("{:.2} GB", b as f64 / 1e9))
    );
    write_json(args.json.as_deref(), &report)
}

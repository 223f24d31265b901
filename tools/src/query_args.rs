//! What to score a map against, as `query` and `render` take it: one text
//! embedding (cosine) or an entry of a vocabulary (softmax over the
//! vocabulary), and how scores become relevance.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use latentam::gpu::Context;
use latentam::io::read_vocabulary;
use latentam::latent::RelevanceScorer;
use latentam::mapper::Mapper;
use latentam::splat::RenderedView;
use latentam_cli::convert::features::read_vector;

#[derive(clap::Args, Clone, Debug, Default)]
pub struct QueryArgs {
    /// The query: one embedding from your vision-language model's text
    /// encoder, as `.npy` (F16/F32, shape [D] or [1, D]) or `.safetensors`.
    /// Relevance is the cosine similarity with each Gaussian's decoded
    /// embedding.
    #[arg(long, value_name = "FILE")]
    pub embedding: Option<PathBuf>,
    /// The query as an entry of a vocabulary (with --vocabulary).
    /// Relevance is the softmax over the whole vocabulary, at
    /// --temperature, of cosine similarities: the probability that a
    /// Gaussian is this class rather than another.
    #[arg(long, conflicts_with = "embedding")]
    pub name: Option<String>,
    /// Log holding the vocabulary (a `TextEmbeddings` message), e.g. the
    /// mapped log itself.
    #[arg(long, value_name = "LOG")]
    pub vocabulary: Option<PathBuf>,
    /// Softmax temperature over the vocabulary (--name).
    #[arg(long, default_value_t = 0.1)]
    pub temperature: f32,
}

/// How scores against the query texts become one relevance per row.
pub enum Relevance {
    /// Cosine with the one text.
    Cosine,
    /// Softmax over the texts at a temperature; the value for `index`.
    Softmax { index: usize, temperature: f32 },
}

/// Each `count`-wide row of `scores` through a softmax at `temperature`.
pub fn softmax_rows(scores: &[f32], count: usize, temperature: f32) -> Vec<f32> {
    let mut out = Vec::with_capacity(scores.len());
    for row in scores.chunks_exact(count) {
        let max = row.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let start = out.len();
        out.extend(row.iter().map(|s| ((s - max) / temperature).exp()));
        let sum: f32 = out[start..].iter().sum();
        out[start..].iter_mut().for_each(|e| *e /= sum);
    }
    out
}

/// A resolved query: the texts to score against and how.
pub struct Query {
    /// `count × dim` text embeddings.
    pub texts: Vec<f32>,
    pub count: usize,
    pub relevance: Relevance,
    /// The query in words, for messages.
    pub what: String,
}

/// The embedding dimension of the map loaded from `dir`, or why it cannot
/// be queried.
pub fn queryable_dim(mapper: &Mapper, dir: &Path) -> Result<usize> {
    // A head's dim is at least 1 (`LatentHead::new` refuses 0).
    let Some(dim) = mapper.head().map(|h| h.config().dim as usize) else {
        if mapper.stats().keyframes == 0 {
            bail!(
                "{} holds no keyframe: there is nothing to query",
                dir.display()
            );
        }
        bail!(
            "{} was mapped without embeddings: there is nothing to query",
            dir.display()
        );
    };
    Ok(dim)
}

impl QueryArgs {
    /// Whether a query was given.
    pub fn given(&self) -> bool {
        self.embedding.is_some() || self.name.is_some()
    }

    /// The query against `mapper`'s `dim`-d embeddings; `None` when none was
    /// given. A vocabulary is read from `--vocabulary`, else from
    /// `default_log`, on `topic`.
    pub fn resolve(
        &self,
        mapper: &Mapper,
        dim: usize,
        default_log: Option<&Path>,
        topic: &str,
    ) -> Result<Option<Query>> {
        match (&self.embedding, &self.name) {
            (Some(path), _) => {
                let v = read_vector(path)?;
                if v.len() != dim {
                    bail!(
                        "{}: the query has {} values; the map's embeddings are {dim}-d",
                        path.display(),
                        v.len()
                    );
                }
                Ok(Some(Query {
                    texts: v,
                    count: 1,
                    relevance: Relevance::Cosine,
                    what: path.display().to_string(),
                }))
            }
            (None, Some(name)) => {
                let Some(log) = self.vocabulary.as_deref().or(default_log) else {
                    bail!("--name needs --vocabulary LOG, the log holding the vocabulary");
                };
                let vocab = read_vocabulary(log, topic)?
                    .with_context(|| format!("{} has no vocabulary on {topic}", log.display()))?;
                let Some(index) = vocab.names.iter().position(|n| n == name) else {
                    bail!(
                        "`{name}` is not in the vocabulary; it has: {}",
                        vocab.names.join(", ")
                    );
                };
                mapper
                    .check_vocabulary(&vocab)
                    .with_context(|| format!("the vocabulary in {}", log.display()))?;
                if !(self.temperature > 0.0 && self.temperature.is_finite()) {
                    bail!("--temperature must be positive");
                }
                // The vocabulary's `names × dim` values (its size checked on
                // reading), so `index < count`.
                Ok(Some(Query {
                    count: vocab.vectors.len() / dim,
                    texts: vocab.vectors,
                    relevance: Relevance::Softmax {
                        index,
                        temperature: self.temperature,
                    },
                    what: format!("`{name}`"),
                }))
            }
            (None, None) => Ok(None),
        }
    }
}

impl Query {
    /// One relevance per row of `scores` (`rows × count` cosines).
    pub fn relevance_of(&self, scores: &[f32]) -> Vec<f32> {
        match self.relevance {
            Relevance::Cosine => scores.to_vec(),
            Relevance::Softmax { index, temperature } => {
                softmax_rows(scores, self.count, temperature)
                    .chunks_exact(self.count)
                    .map(|row| row[index])
                    .collect()
            }
        }
    }

    /// The values the colour ramp spans: the range of the relevances kept
    /// (cosine), or 0..1 (softmax, a probability).
    pub fn colour_range(&self, relevance: &[f32], keep: impl Fn(usize) -> bool) -> (f32, f32) {
        match self.relevance {
            Relevance::Cosine => crate::pictures::range_of(relevance, keep).unwrap_or((0.0, 1.0)),
            Relevance::Softmax { .. } => (0.0, 1.0),
        }
    }

    /// The relevance of every pixel of `view` (decoded from its rendered
    /// queries).
    pub fn score_view(
        &self,
        ctx: &Context,
        mapper: &Mapper,
        view: &RenderedView,
    ) -> Result<Vec<f32>> {
        let head = mapper
            .head()
            .context("the map has no latent head to decode with")?;
        let mut scorer = None;
        let scorer = RelevanceScorer::ensure(&mut scorer, ctx, head, self.count as u32)?;
        Ok(self.relevance_of(&scorer.score(ctx, head, &view.query, &self.texts)?))
    }
}

//! What to score a map against, as `query` and `render` take it: one text
//! embedding (cosine) or an entry of a vocabulary (softmax over the
//! vocabulary), and how scores become relevance.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context as _, Result};
use latentam::embedding_files::read_vector;
use latentam::frames::read_vocabulary;
use latentam::{Mapper, RenderedView, Scored, Scoring, TextQuery};

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

/// A resolved query: what to score against and how (the library's
/// [`TextQuery`]), and its words for messages.
pub struct Query {
    pub text: TextQuery,
    /// The query in words, for messages.
    pub what: String,
}

/// The embedding dimension of the map loaded from `dir`, or why it cannot
/// be queried.
pub fn queryable_dim(mapper: &Mapper, dir: &Path) -> Result<usize> {
    // A head's dim is at least 1 (`LatentHead::new` refuses 0).
    let Some(dim) = mapper.stats().embedding_dim.map(|d| d as usize) else {
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
                let v = match read_vector(path) {
                    Ok(v) => v,
                    // The reason names the file.
                    Err(
                        e @ (latentam::Error::BadInput { .. } | latentam::Error::Damaged { .. }),
                    ) => {
                        bail!("{e}")
                    }
                    Err(latentam::Error::Io { path, source }) => {
                        return Err(anyhow::Error::new(source)
                            .context(format!("reading {}", path.display())))
                    }
                    Err(e) => return Err(e.into()),
                };
                if v.len() != dim {
                    bail!(
                        "{}: the query has {} values; the map's embeddings are {dim}-d",
                        path.display(),
                        v.len()
                    );
                }
                Ok(Some(Query {
                    text: TextQuery::embedding(v),
                    what: latentam::text::shown_path(path),
                }))
            }
            (None, Some(name)) => {
                let Some(log) = self.vocabulary.as_deref().or(default_log) else {
                    bail!("--name needs --vocabulary LOG, the log holding the vocabulary");
                };
                let vocab = read_vocabulary(log, topic)?
                    .with_context(|| format!("{} has no vocabulary on {topic}", log.display()))?;
                mapper
                    .stats()
                    .check_vocabulary(&vocab)
                    .with_context(|| format!("the vocabulary in {}", log.display()))?;
                TextQuery::check_temperature(self.temperature)
                    .map_err(latentam_args::flag_error("--temperature"))?;
                let text = match TextQuery::vocabulary_word(&vocab, name, self.temperature) {
                    Ok(t) => t,
                    Err(e @ latentam::Error::BadInput { .. }) => bail!("{e}"),
                    Err(e) => return Err(e.into()),
                };
                Ok(Some(Query {
                    text,
                    what: format!("`{}`", latentam::text::shown(name)),
                }))
            }
            (None, None) => Ok(None),
        }
    }
}

impl Query {
    /// The values the colour ramp spans: the range of the relevances kept
    /// (cosine), or 0..1 (softmax, a probability).
    pub fn colour_range(&self, relevance: &[f32], keep: impl Fn(usize) -> bool) -> (f32, f32) {
        match self.text.relevance {
            Scoring::Cosine => crate::pictures::range_of(relevance, keep).unwrap_or((0.0, 1.0)),
            Scoring::Softmax { .. } => (0.0, 1.0),
        }
    }

    /// The relevance of every pixel of `view` (decoded from its rendered
    /// queries).
    pub fn score_view(&self, mapper: &mut Mapper, view: &RenderedView) -> Result<Vec<f32>> {
        Ok(mapper.relevance(&self.text, Scored::Pixels(view))?)
    }
}

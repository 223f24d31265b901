//! Open-vocabulary scoring: decode latent queries into the embedding space
//! through the head's attention decoder and compare them with text (or any
//! other) embeddings by cosine similarity. Used to score every Gaussian of
//! a map, or every pixel of a rendered query image. CPU reference: the
//! decoder's forward pass in `latentam_reference::decoder` followed by a
//! cosine.

use crate::latent::{DecoderParams, LatentHead};
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::ops::{normalize_rows, Gemm, Transpose};
use latentam_gpu::{Buffer, Context};

/// What a query scores against, and how scores become one relevance.
///
/// ```
/// use latentam_core::latent::TextQuery;
///
/// let q = TextQuery::embedding(vec![1.0, 0.0]);
/// assert_eq!(q.relevance_of(&[0.3, -0.2]), vec![0.3, -0.2]); // cosines as they are
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct TextQuery {
    /// `texts() × d_f` embeddings, back to back.
    pub embeddings: Vec<f32>,
    /// Texts among `embeddings`.
    pub texts: usize,
    /// How the scores against them become one relevance.
    pub relevance: Relevance,
}

/// How scores against a query's texts become one relevance per row.
///
/// ```
/// use latentam_core::latent::{Relevance, TextQuery};
///
/// // Two texts ("mug", "table"); each row of scores is one Gaussian's cosines with them.
/// let query = TextQuery {
///     embeddings: vec![1.0, 0.0, 0.0, 1.0],
///     texts: 2,
///     relevance: Relevance::Softmax { index: 0, temperature: 0.1 },
/// };
/// let p_mug = query.relevance_of(&[0.9, 0.2, 0.1, 0.8]);
/// assert!(p_mug[0] > 0.99 && p_mug[1] < 0.01);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Relevance {
    /// The cosine with the one text.
    Cosine,
    /// The softmax over all texts at `temperature`, taken at `index`: the
    /// probability that the row shows that text rather than any other of
    /// the vocabulary (how open-vocabulary segmentation labels pixels).
    Softmax {
        /// The text asked about.
        index: usize,
        /// Softmax temperature.
        temperature: f32,
    },
}

/// Smallest softmax temperature, of the decoder's attention and of a
/// vocabulary's relevance: scores are cosines divided by it, so at most
/// 1024 here, which keeps every exponential, sum and gradient finite in
/// f32 (at 1e-45 the division overflows and scores turn to NaN). A power
/// of two, so the bound reads the same in f32, f64 and decimal text.
pub const MIN_TEMPERATURE: f32 = 1.0 / 1024.0;
/// Largest softmax temperature: beyond it every score is about the same.
pub const MAX_TEMPERATURE: f32 = 10.0;

impl TextQuery {
    /// Refuses a softmax temperature outside
    /// [`MIN_TEMPERATURE`]..=[`MAX_TEMPERATURE`] (NaN included).
    pub fn check_temperature(temperature: f32) -> Result<()> {
        if (MIN_TEMPERATURE..=MAX_TEMPERATURE).contains(&temperature) {
            return Ok(());
        }
        Err(Error::bad_input(
            "temperature",
            format!(
                "softmax temperature {temperature} is outside {MIN_TEMPERATURE}..={MAX_TEMPERATURE}"
            ),
        ))
    }

    /// Cosine relevance to one embedding.
    pub fn embedding(embedding: Vec<f32>) -> Self {
        TextQuery {
            embeddings: embedding,
            texts: 1,
            relevance: Relevance::Cosine,
        }
    }

    /// Relevance to the vocabulary word `name` against all the others,
    /// through a softmax at `temperature` (errors for an unknown word or a
    /// temperature outside [`MIN_TEMPERATURE`]..=[`MAX_TEMPERATURE`]).
    pub fn vocabulary_word(
        vocabulary: &latentam_io::Vocabulary,
        name: &str,
        temperature: f32,
    ) -> Result<Self> {
        let Some(index) = vocabulary.names.iter().position(|n| n == name) else {
            return Err(Error::bad_input(
                "word",
                format!(
                    "`{name}` is not in the vocabulary; it has: {}",
                    vocabulary.names.join(", ")
                ),
            ));
        };
        Self::check_temperature(temperature)?;
        Ok(TextQuery {
            embeddings: vocabulary.vectors.clone(),
            texts: vocabulary.names.len(),
            relevance: Relevance::Softmax { index, temperature },
        })
    }

    /// One relevance per row of `scores` (`rows × texts` cosines).
    pub fn relevance_of(&self, scores: &[f32]) -> Vec<f32> {
        match self.relevance {
            Relevance::Cosine => scores.to_vec(),
            Relevance::Softmax { index, temperature } => {
                softmax_rows(scores, self.texts, temperature)
                    .chunks_exact(self.texts)
                    .map(|row| row[index])
                    .collect()
            }
        }
    }
}

/// Each `texts`-wide row of `scores` through a softmax at `temperature`.
pub fn softmax_rows(scores: &[f32], texts: usize, temperature: f32) -> Vec<f32> {
    let mut out = Vec::with_capacity(scores.len());
    for row in scores.chunks_exact(texts.max(1)) {
        let max = row.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let start = out.len();
        out.extend(row.iter().map(|s| ((s - max) / temperature).exp()));
        let sum: f32 = out[start..].iter().sum();
        out[start..].iter_mut().for_each(|e| *e /= sum);
    }
    out
}

/// Workspace for scoring queries against up to `max_texts` embeddings.
///
/// ```no_run
/// # use latentam_gpu::*;
/// # use latentam_core::latent::*;
/// # let ctx = Context::new(ContextOptions::default())?;
/// # let head = LatentHead::new(&ctx, LatentHeadConfig { dim: 64, atoms: 16, ..Default::default() })?;
/// let scorer = RelevanceScorer::new(&ctx, &head, 4)?;
/// let queries = vec![[0.1f32; 32]; 1000];           // e.g. every Gaussian's query
/// let text = vec![0.125f32; 64];                     // one 64-d text embedding
/// let scores = scorer.score(&ctx, &head, &queries, &text)?;  // 1000 cosines
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct RelevanceScorer {
    rows: u32,
    dim: u32,
    max_texts: u32,
    queries: Buffer,
    unit: Buffer,
    norms: Buffer,
    texts: Buffer,
    scores: Buffer,
}

impl RelevanceScorer {
    /// A scorer for `head` (it decodes as many queries per batch as the
    /// head's decoder holds regions).
    pub fn new(ctx: &Context, head: &LatentHead, max_texts: u32) -> Result<Self> {
        let rows = head.config().max_regions;
        let dim = head.config().dim;
        if max_texts == 0 {
            return Err(Error::bad_input(
                "max_texts",
                "a relevance scorer needs room for at least one text",
            ));
        }
        let buf = |name: &str, bytes: u64| Buffer::device(ctx, &format!("relevance/{name}"), bytes);
        Ok(RelevanceScorer {
            rows,
            dim,
            max_texts,
            queries: buf("queries", rows as u64 * QUERY_DIM as u64 * 4)?,
            unit: buf("unit", rows as u64 * dim as u64 * 4)?,
            norms: buf("norms", rows as u64 * 4)?,
            texts: buf("texts", max_texts as u64 * dim as u64 * 4)?,
            scores: buf("scores", rows as u64 * max_texts as u64 * 4)?,
        })
    }

    /// The scorer in `slot`, (re)built when missing, too small for
    /// `texts` embeddings, or made for another head's sizes.
    pub fn ensure<'s>(
        slot: &'s mut Option<Self>,
        ctx: &Context,
        head: &LatentHead,
        texts: u32,
    ) -> Result<&'s Self> {
        let fits = slot.as_ref().is_some_and(|s| {
            s.max_texts >= texts
                && s.dim == head.config().dim
                && s.rows == head.config().max_regions
        });
        if !fits {
            *slot = None;
            *slot = Some(RelevanceScorer::new(ctx, head, texts.max(16))?);
        }
        Ok(slot.as_ref().expect("built above"))
    }

    /// Cosine similarity between each decoded query and each row of
    /// `texts` (`m` × d_f, any norm; zero rows score 0). Returns
    /// `queries.len()` × m scores, row-major. Errors when the head has no
    /// atoms yet or the sizes disagree.
    pub fn score(
        &self,
        ctx: &Context,
        head: &LatentHead,
        queries: &[[f32; QUERY_DIM]],
        texts: &[f32],
    ) -> Result<Vec<f32>> {
        let d = self.dim as usize;
        if head.config().dim != self.dim || head.config().max_regions != self.rows {
            return Err(Error::bad_input(
                "latent head",
                "the relevance scorer was built for another latent head",
            ));
        }
        if texts.is_empty() || !texts.len().is_multiple_of(d) {
            return Err(Error::bad_input(
                "text embeddings",
                format!("{} text values are not whole {d}-d embeddings", texts.len()),
            ));
        }
        let m = texts.len() / d;
        if m > self.max_texts as usize {
            return Err(Error::bad_input(
                "text embeddings",
                format!("{m} texts; the scorer holds {}", self.max_texts),
            ));
        }
        if head.atom_count() == 0 {
            return Err(Error::NoEmbeddings);
        }
        if texts.iter().any(|x| !x.is_finite()) {
            return Err(Error::bad_input(
                "text embeddings",
                "a text embedding has non-finite values",
            ));
        }
        let mut unit_texts = Vec::with_capacity(texts.len());
        for t in texts.chunks(d) {
            let n = t.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
            let s = if n > 0.0 { 1.0 / n } else { 0.0 };
            unit_texts.extend(t.iter().map(|&x| (x as f64 * s) as f32));
        }
        ctx.upload(&self.texts, 0, &unit_texts)?;
        let params = DecoderParams {
            w: head.w(),
            atoms: head.atoms(),
            atom_count: head.atom_count(),
        };
        let mut out = Vec::with_capacity(queries.len() * m);
        for chunk in queries.chunks(self.rows as usize) {
            let n = chunk.len() as u32;
            let mut rec = ctx.recorder()?;
            rec.upload(&self.queries, 0, chunk)?;
            head.decoder()
                .record_forward(&mut rec, params, &self.queries, n)?;
            normalize_rows(
                &mut rec,
                head.decoder().output(),
                &self.unit,
                &self.norms,
                n,
                self.dim,
                1e-12,
            )?;
            Gemm {
                transpose: Transpose::B,
                m: n,
                n: m as u32,
                k: self.dim,
                alpha: 1.0,
                beta: 0.0,
            }
            .record(&mut rec, &self.unit, &self.texts, &self.scores)?;
            let rb = rec.download(&self.scores, 0, n as u64 * m as u64 * 4)?;
            rec.submit()?.wait()?;
            out.extend(rb.read::<f32>()?);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn vocabulary_softmax_matches_its_definition() {
        let vocabulary = latentam_io::Vocabulary {
            names: vec!["wall".into(), "chair".into(), "door".into()],
            ids: vec![1, 2, 3],
            dim: 1,
            vectors: vec![1.0, 2.0, 3.0],
            model: "m".into(),
        };
        let q = super::TextQuery::vocabulary_word(&vocabulary, "chair", 0.5).unwrap();
        let scores = [0.2f32, 0.9, -0.1, 0.0, 0.0, 0.0];
        let got = q.relevance_of(&scores);
        let e = |x: f64| (x / 0.5).exp();
        let want = e(0.9) / (e(0.2) + e(0.9) + e(-0.1));
        assert!((got[0] as f64 - want).abs() < 1e-6, "{got:?}");
        assert!((got[1] - 1.0 / 3.0).abs() < 1e-6);
        assert!(super::TextQuery::vocabulary_word(&vocabulary, "sofa", 0.5).is_err());
        assert!(super::TextQuery::vocabulary_word(&vocabulary, "door", 0.0).is_err());
    }

    use rand::Rng;

    use super::*;
    use crate::latent::LatentHeadConfig;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::decoder::{forward, DecoderShape};

    #[test]
    fn scores_match_the_reference_decoder_and_cosine() {
        with_context(|ctx| {
            let mut r = rng("relevance");
            let (dim, atoms, rows) = (24usize, 6u32, 16u32);
            let head = LatentHead::new(
                ctx,
                LatentHeadConfig {
                    dim: dim as u32,
                    atoms,
                    max_regions: rows,
                    temperature: 0.2,
                    ..Default::default()
                },
            )
            .unwrap();
            let scorer = RelevanceScorer::new(ctx, &head, 3).unwrap();
            // Queries before any atom exist are refused.
            assert!(scorer
                .score(ctx, &head, &[[0.0; QUERY_DIM]], &vec![1.0; dim])
                .is_err());
            let feats: Vec<f32> = (0..rows as usize * dim)
                .map(|_| r.random_range(-1.0..1.0))
                .collect();
            let feats_buf = ctx.upload_new("test/features", &feats).unwrap();
            let mut rec = ctx.recorder().unwrap();
            head.record_dictionary_update(&mut rec, &feats_buf, None, rows)
                .unwrap();
            rec.submit().unwrap().wait().unwrap();
            let k = head.atom_count() as usize;
            assert!(k >= 2);
            let w: Vec<f32> = ctx.download(head.w()).unwrap();
            let d: Vec<f32> = ctx.download(head.atoms()).unwrap();

            // 40 queries: three batches of the decoder's 16 rows.
            let queries: Vec<[f32; QUERY_DIM]> = (0..40)
                .map(|_| std::array::from_fn(|_| r.random_range(-1.0..1.0)))
                .collect();
            let mut texts: Vec<f32> = (0..2 * dim).map(|_| r.random_range(-2.0..2.0)).collect();
            texts.extend(std::iter::repeat_n(0.0, dim)); // a zero text scores 0
            let got = scorer.score(ctx, &head, &queries, &texts).unwrap();
            assert_eq!(got.len(), 40 * 3);

            let flat: Vec<f32> = queries.iter().flatten().copied().collect();
            let shape = DecoderShape {
                n: 40,
                query_dim: QUERY_DIM,
                dim,
                atoms: k,
                tau: 0.2,
                eps: 1e-6,
            };
            let f = forward(&shape, &flat, &w, &d[..k * dim]);
            for i in 0..40 {
                let out = &f.output[i * dim..(i + 1) * dim];
                let on = out.iter().map(|x| x * x).sum::<f64>().sqrt();
                for t in 0..3 {
                    let tv = &texts[t * dim..(t + 1) * dim];
                    let tn = tv.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
                    let dot: f64 = out.iter().zip(tv).map(|(a, &b)| a * b as f64).sum();
                    let want = if tn > 0.0 { dot / (on * tn) } else { 0.0 };
                    let g = got[i * 3 + t] as f64;
                    assert!((g - want).abs() < 2e-4, "query {i} text {t}: {g} vs {want}");
                }
            }
            // Bad input.
            assert!(scorer
                .score(ctx, &head, &queries, &texts[..dim - 1])
                .is_err());
            assert!(scorer
                .score(ctx, &head, &queries, &vec![0.5; 4 * dim])
                .is_err());
            let mut nan = texts[..dim].to_vec();
            nan[3] = f32::NAN;
            assert!(scorer.score(ctx, &head, &queries, &nan).is_err());
        });
    }
}

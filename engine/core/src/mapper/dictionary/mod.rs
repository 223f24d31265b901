//! The dictionary part of the mapper: the latent head (the projection W and
//! the dictionary D of paper §III-B, Eq. 4) created from the first region
//! embeddings, its streaming k-means update per keyframe (§III-C), and the
//! embedding model the map's embeddings come from, which every later frame
//! and every query vocabulary must share.

use crate::latent::{projected_queries, KMeansConfig, LatentHead, LatentHeadConfig};
use crate::mapper::config::MapperConfig;
use crate::mapper::export::DecoderFile;
use crate::mapper::history::{KeyframeRecord, RegionTargets};
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Submission};
use latentam_io::{embedding_space, Frame, Vocabulary};

#[cfg(test)]
mod tests;

/// The latent head, once embeddings were seen, and their model.
pub(crate) struct Dictionary {
    /// The head's settings but its dimension, which the first embeddings
    /// give.
    settings: LatentHeadConfig,
    head: Option<LatentHead>,
    /// The embedding model of the map's region embeddings (first seen).
    model: Option<String>,
}

impl Dictionary {
    /// No head yet: it is created at the first keyframe with embeddings.
    pub(crate) fn new(cfg: &MapperConfig) -> Self {
        Dictionary {
            settings: LatentHeadConfig {
                dim: 0,
                atoms: cfg.atoms,
                max_regions: cfg.max_regions,
                temperature: cfg.temperature,
                lr_w: cfg.latent_lr,
                lr_d: cfg.latent_lr,
                weights: cfg.weights,
                seed: cfg.seed,
                kmeans: KMeansConfig {
                    // A dictionary smaller than m takes it whole at once.
                    micro_clusters: cfg.micro_clusters.min(cfg.atoms),
                    ..Default::default()
                },
            },
            head: None,
            model: None,
        }
    }

    /// A fresh head of dimension `dim` with this map's settings (also
    /// what a loaded state uploads its saved head into).
    pub(crate) fn make_head(&self, ctx: &Context, dim: u32) -> Result<LatentHead> {
        LatentHead::new(
            ctx,
            LatentHeadConfig {
                dim,
                ..self.settings
            },
        )
    }

    /// The head, once a keyframe with embeddings was mapped.
    pub(crate) fn head(&self) -> Option<&LatentHead> {
        self.head.as_ref()
    }

    /// Puts a head in place (a loaded state's).
    pub(crate) fn restore(&mut self, head: LatentHead) {
        self.head = Some(head);
    }

    /// Sets the map's embedding model (a loaded state's, which may have
    /// one before any head).
    pub(crate) fn restore_model(&mut self, model: Option<String>) {
        self.model = model;
    }

    /// The embedding dimension: the head's, or else that of `frame`'s
    /// embeddings (what the head will have).
    pub(crate) fn dim_for(&self, frame: &Frame) -> Option<u32> {
        self.head
            .as_ref()
            .map(|h| h.config().dim)
            .or(frame.embeddings.as_ref().map(|e| e.dim))
    }

    /// The model id of the region embeddings mapped so far.
    pub(crate) fn model(&self) -> Option<&str> {
        self.model.as_deref()
    }

    /// Refuses a frame whose embeddings do not suit the map (model or
    /// dimension), before anything changes.
    pub(crate) fn check_frame(&self, frame: &Frame) -> Result<()> {
        let Some(e) = &frame.embeddings else {
            return Ok(());
        };
        // The caller knows which frame it offered.
        if let Some(m) = &self.model {
            if embedding_space(m) != embedding_space(&e.model) {
                return Err(Error::EmbeddingModel {
                    map: m.clone(),
                    given: e.model.clone(),
                    context: None,
                });
            }
        }
        if let Some(head) = &self.head {
            if head.config().dim != e.dim {
                return Err(Error::EmbeddingDimension {
                    map: head.config().dim,
                    given: e.dim,
                    context: None,
                });
            }
        }
        Ok(())
    }

    /// Folds a keyframe's region embeddings into the dictionary by
    /// streaming k-means, creating the head (and taking the model as the
    /// map's) at the first keyframe with embeddings. Returns the update's
    /// submission without waiting for it: the keyframe's next host wait
    /// (seeding's render) covers it, and its timestamps are collected
    /// then ([`Submission::finished_span`]); the atom count it reports is
    /// the host's own.
    pub(crate) fn update(
        &mut self,
        ctx: &Context,
        frame: &Frame,
        record: &KeyframeRecord,
    ) -> Result<Option<Submission>> {
        if let Some(e) = &frame.embeddings {
            // `check_frame` refused any other model before anything changed.
            self.model.get_or_insert_with(|| e.model.clone());
        }
        let Some(r) = &record.regions else {
            return Ok(None);
        };
        if self.head.is_none() {
            self.head = Some(self.make_head(ctx, r.dim)?);
        }
        // `check_frame` refused another dimension before anything changed.
        let head = self.head.as_ref().expect("created above");
        let rows = nonzero_rows(r);
        if rows.is_empty() {
            return Ok(None);
        }
        let mut rec = ctx.recorder()?;
        head.record_keyframe_update(&mut rec, &rows)?;
        Ok(Some(rec.submit()?))
    }

    /// The decoder's W, for a read-back riding along another submission
    /// (`None` before there is a head).
    pub(crate) fn w_buffer(&self) -> Option<&Buffer> {
        self.head.as_ref().map(|h| h.w())
    }

    /// Each region's embedding projected through W into a query
    /// (Eq. 4 read backwards), where new Gaussians of that region start;
    /// `None` before there is a head. W (32 × d_f) is `read` when a
    /// read-back of it came along another submission, else read back
    /// here (a host wait).
    pub(crate) fn projected_queries(
        &self,
        ctx: &Context,
        regions: &RegionTargets,
        read: Option<&[f32]>,
    ) -> Result<Option<Vec<Option<[f32; QUERY_DIM]>>>> {
        let Some(head) = &self.head else {
            return Ok(None);
        };
        let w: std::borrow::Cow<'_, [f32]> = match read {
            Some(w) => w.into(),
            None => ctx.download::<f32>(head.w())?.into(),
        };
        let dim = regions.dim as usize;
        Ok(Some(projected_queries(
            w.get(..QUERY_DIM * dim).unwrap_or(&[]),
            dim,
            &regions.vectors,
        )))
    }

    /// The decoder as it stands (`None` before the first keyframe with
    /// embeddings).
    pub(crate) fn decoder_file(&self, ctx: &Context) -> Result<Option<DecoderFile>> {
        let Some(head) = &self.head else {
            return Ok(None);
        };
        let d = head.config().dim as usize;
        let k = head.atom_count() as usize;
        let w: Vec<f32> = ctx.download(head.w())?;
        let mut atoms: Vec<f32> = ctx.download(head.atoms())?;
        atoms.truncate(k * d);
        let mut anchors: Vec<f32> = ctx.download(head.anchor())?;
        anchors.truncate(k * d);
        let mut atom_weights: Vec<f32> = ctx.download(head.kmeans().weights())?;
        atom_weights.truncate(k);
        Ok(Some(DecoderFile {
            dim: d as u32,
            w: w[..QUERY_DIM * d].to_vec(),
            atoms,
            anchors,
            atom_weights,
            temperature: head.decoder().config().temperature,
            eps: head.decoder().config().eps,
            model: self.model.clone().unwrap_or_default(),
            run_id: None,
        }))
    }
}

/// The region embeddings that are not all zero (a region without an
/// embedding is stored as zeros), back to back.
fn nonzero_rows(r: &RegionTargets) -> Vec<f32> {
    r.vectors
        .chunks(r.dim as usize)
        .filter(|row| row.iter().any(|&x| x != 0.0))
        .flatten()
        .copied()
        .collect()
}

/// Whether vocabulary `v` suits a map of `dim`-d embeddings of `model`
/// (when known): the same dimension and the same embedding space.
pub(crate) fn check_vocabulary(dim: u32, model: Option<&str>, v: &Vocabulary) -> Result<()> {
    if v.dim != dim {
        return Err(Error::EmbeddingDimension {
            map: dim,
            given: v.dim,
            context: Some(format!("the vocabulary's, of `{}`", v.model)),
        });
    }
    if let Some(m) = model {
        if embedding_space(m) != embedding_space(&v.model) {
            return Err(Error::EmbeddingModel {
                map: m.to_string(),
                given: v.model.clone(),
                context: Some("the vocabulary's".into()),
            });
        }
    }
    Ok(())
}

//! What a map shows: relevance of its Gaussians and of rendered pixels to
//! a text embedding, views rendered from any camera, the metrics of a view
//! against a frame, and the map and decoder written out. Each reads the
//! global map with the GPU window written back first.

use std::path::Path;

use super::eval::{Evaluator, MapParts, ViewMetrics};
use super::export::DecoderFile;
use super::facade::Mapper;
use crate::latent::{DevicePixelDecoder, TextQuery};
use crate::map::{write_ply, write_ply_without_latents};
use crate::splat::{Camera, RenderedView};
use latentam_base::{Error, Result};
use latentam_io::{Frame, Vocabulary};

impl Mapper {
    /// Relevance of every Gaussian to `text_embedding` (cosine similarity
    /// of its decoded embedding), in the order of
    /// [`GlobalMap::iter`](crate::map::GlobalMap::iter) on [`Mapper::global`].
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// let text_embedding = vec![0.0f32; 512]; // from the map's embedding model
    /// let scores = mapper.query(&text_embedding)?;
    /// let best = scores.iter().cloned().fold(f32::MIN, f32::max);
    /// println!("best match {best:.3} over {} Gaussians", scores.len());
    /// # Ok(())
    /// # }
    /// ```
    pub fn query(&mut self, text_embedding: &[f32]) -> Result<Vec<f32>> {
        self.query_many(text_embedding)
    }

    /// Relevance of every Gaussian to each of several embeddings given
    /// back to back: Gaussians × embeddings scores, row-major.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// let (a, b) = (vec![0.0f32; 512], vec![1.0f32; 512]);
    /// let scores = mapper.query_many(&[a, b].concat())?;
    /// let first_gaussian = &scores[0..2]; // its score for a, then for b
    /// # Ok(())
    /// # }
    /// ```
    pub fn query_many(&mut self, embeddings: &[f32]) -> Result<Vec<f32>> {
        let head = self.dictionary.head().ok_or(Error::NoEmbeddings)?;
        let dim = head.config().dim as usize;
        if embeddings.is_empty() || !embeddings.len().is_multiple_of(dim) {
            return Err(Error::EmbeddingDimension {
                map: dim as u32,
                given: embeddings.len() as u32,
                context: Some("a query, or several back to back".into()),
            });
        }
        self.flush()?;
        let head = self.dictionary.head().expect("checked above");
        // Made per call, not kept: its batch buffers would otherwise hold
        // tens of MB of the mapping budget between queries.
        let mut decoder = DevicePixelDecoder::from_head(&self.ctx, head)?;
        let queries: Vec<_> = self.pager.global().iter().map(|(_, g)| g.query).collect();
        decoder.cosines(&self.ctx, &queries, embeddings)
    }

    /// Relevance of every Gaussian to `query` (cosine, or the softmax over
    /// a vocabulary), in the order of [`GlobalMap::iter`](crate::map::GlobalMap::iter).
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, vocabulary: &latentam_io::Vocabulary) -> latentam_core::Result<()> {
    /// use latentam_core::latent::TextQuery;
    /// let chair = TextQuery::vocabulary_word(vocabulary, "chair", 0.1)?;
    /// let p: Vec<f32> = mapper.relevance(&chair)?; // per Gaussian, 0..1
    /// # Ok(())
    /// # }
    /// ```
    pub fn relevance(&mut self, query: &TextQuery) -> Result<Vec<f32>> {
        Ok(query.relevance_of(&self.query_many(&query.embeddings)?))
    }

    /// Relevance of every pixel of a rendered view to `query`, from its
    /// rendered queries (see [`Mapper::render`]).
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame, vocabulary: &latentam_io::Vocabulary) -> latentam_core::Result<()> {
    /// use latentam_core::latent::TextQuery;
    /// let (view, _) = mapper.render_frame(frame)?;
    /// let chair = TextQuery::vocabulary_word(vocabulary, "chair", 0.1)?;
    /// let heat: Vec<f32> = mapper.view_relevance(&view, &chair)?; // per pixel
    /// # Ok(())
    /// # }
    /// ```
    pub fn view_relevance(&mut self, view: &RenderedView, query: &TextQuery) -> Result<Vec<f32>> {
        let head = self.dictionary.head().ok_or(Error::NoEmbeddings)?;
        let mut decoder = DevicePixelDecoder::from_head(&self.ctx, head)?;
        Ok(query.relevance_of(&decoder.cosines(&self.ctx, &view.query, &query.embeddings)?))
    }

    /// Renders colour, depth and queries of the map from `camera`, with
    /// the Gaussians of the global map near it (those paged out included),
    /// and says how many Gaussians it drew.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, camera: &latentam_core::splat::Camera) -> latentam_core::Result<()> {
    /// let (view, drawn) = mapper.render(camera)?;
    /// println!("{} pixels rendered", view.rgbd.len());
    /// # Ok(())
    /// # }
    /// ```
    pub fn render(&mut self, camera: &Camera) -> Result<(RenderedView, usize)> {
        let (ev, map) = self.evaluator()?;
        ev.render(map, camera)
    }

    /// [`Mapper::render`] at a frame's pose and with its camera, at the
    /// camera's exposure of the frame's time (interpolated between the
    /// keyframes around it; see `exposure_compensation`).
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame) -> latentam_core::Result<()> {
    /// let (view, drawn) = mapper.render_frame(frame)?;
    /// println!("{drawn} Gaussians drawn, {} pixels", view.rgbd.len());
    /// # Ok(())
    /// # }
    /// ```
    pub fn render_frame(&mut self, frame: &Frame) -> Result<(RenderedView, usize)> {
        let (ev, map) = self.evaluator()?;
        ev.render_frame(map, frame)
    }

    /// Measures the map on a frame it did not necessarily see (the paper's
    /// protocol, Sec. IV-A): PSNR and depth error, and with embeddings the
    /// per-pixel cosine loss and, given a vocabulary, the class IoUs.
    /// `pixel_stride` decodes every N-th pixel and row (1: all).
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame) -> latentam_core::Result<()> {
    /// let m = mapper.evaluate(frame, None, 1)?;
    /// println!("PSNR {:.2} dB", m.psnr);
    /// # Ok(())
    /// # }
    /// ```
    pub fn evaluate(
        &mut self,
        frame: &Frame,
        vocabulary: Option<&Vocabulary>,
        pixel_stride: usize,
    ) -> Result<ViewMetrics> {
        let (ev, map) = self.evaluator()?;
        ev.pixel_stride = pixel_stride.max(1);
        ev.evaluate(map, frame, vocabulary)
    }

    /// Writes the map as a 3D Gaussian splatting PLY file (positions,
    /// scales, rotations, opacities, colours as degree-0 SH, and with
    /// embeddings the 32 `latent_*` query channels), atomically. The
    /// queries decode to embeddings with [`Mapper::decoder`].
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// mapper.export_ply("kitchen.ply".as_ref())?; // opens in 3DGS viewers
    /// # Ok(())
    /// # }
    /// ```
    pub fn export_ply(&mut self, path: &Path) -> Result<()> {
        self.flush()?;
        let gaussians: Vec<_> = self.pager.global().iter().map(|(_, g)| *g).collect();
        // A map without embeddings has no meaningful queries to write.
        if self.dictionary.head().is_some() {
            write_ply(path, &gaussians, &[])
        } else {
            write_ply_without_latents(path, &gaussians, &[])
        }
    }

    /// The decoder as it stands (W, the dictionary and the temperature),
    /// to turn the map's queries into embeddings elsewhere; `None` before
    /// the first keyframe with embeddings.
    ///
    /// ```no_run
    /// # fn f(mapper: &latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// if let Some(decoder) = mapper.decoder()? {
    ///     decoder.write("decoder.safetensors".as_ref())?;
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn decoder(&self) -> Result<Option<DecoderFile>> {
        self.dictionary.decoder_file(&self.ctx)
    }

    /// The view renderer (made on first use) and the parts of the map it
    /// renders, the window written back first.
    fn evaluator(&mut self) -> Result<(&mut Evaluator, MapParts<'_>)> {
        self.flush()?;
        let layout = self.cfg.blend_layout;
        let ctx = &self.ctx;
        let ev = self
            .evaluator
            .get_or_insert_with(|| Evaluator::with_layout(ctx, layout));
        let map = MapParts {
            global: self.pager.global(),
            exposure: &self.exposure,
            head: self.dictionary.head(),
        };
        Ok((ev, map))
    }
}

//! What a map shows: relevance of its Gaussians and of rendered pixels to
//! a text embedding, views rendered from any camera, the metrics of a view
//! against a frame, and the map and decoder written out. Each reads the
//! global map with the GPU window written back first.

use std::path::Path;

use glam::DAffine3;

use super::eval::{Evaluator, MapParts, ViewMetrics};
use super::export::DecoderFile;
use super::facade::Mapper;
use super::relevance_index::{DecoderView, IndexSettings, RelevanceIndex};
use super::snapshot::MapSnapshot;
use crate::latent::{DevicePixelDecoder, TextQuery};
use crate::map::write_map_ply_streamed;
use crate::splat::{Camera, RenderedView};
use latentam_base::{Error, Result};
use latentam_io::{Frame, Vocabulary};

/// What [`Mapper::relevance`] scores.
#[derive(Clone, Copy, Debug)]
pub enum Scored<'a> {
    /// Every Gaussian of the map.
    Gaussians,
    /// Every pixel of a view rendered from the map.
    Pixels(&'a RenderedView),
}

/// Where [`Mapper::render`] renders from: a camera of your choosing, or
/// a recorded frame, whose pose and intrinsics give the camera, whose
/// time gives the exposure (interpolated between the keyframes around
/// it; see `exposure_compensation`) and whose depth says how far the
/// view reaches.
#[derive(Clone, Copy, Debug)]
pub enum Viewpoint<'a> {
    /// A camera: pose and intrinsics.
    Camera(&'a Camera),
    /// A recorded frame.
    Frame(&'a Frame),
    /// A camera-to-world pose, with the intrinsics of the last keyframe
    /// kept for replay (the map's own camera).
    Pose(DAffine3),
}

impl<'a> From<&'a Camera> for Viewpoint<'a> {
    fn from(camera: &'a Camera) -> Self {
        Viewpoint::Camera(camera)
    }
}

impl<'a> From<&'a Frame> for Viewpoint<'a> {
    fn from(frame: &'a Frame) -> Self {
        Viewpoint::Frame(frame)
    }
}

impl Mapper {
    /// The cosine of every Gaussian's decoded embedding with each of
    /// several embeddings given back to back (Gaussians × embeddings,
    /// row-major), in the order of the global map's `iter` (the window
    /// written back first).
    pub(crate) fn cosines(&mut self, embeddings: &[f32]) -> Result<Vec<f32>> {
        self.check_query_dim(embeddings)?;
        if self.relevance_index.is_none() {
            self.flush()?;
            let decoder = self.decoder()?.ok_or(Error::NoEmbeddings)?;
            let view = DecoderView::of(&decoder);
            // Block by block into batches of at most this many queries
            // (16 MiB): a map spilled to disk is read one block at a time.
            const BATCH: usize = 1 << 17;
            let global = self.pager.global();
            let index =
                RelevanceIndex::build_streamed(&view, IndexSettings::default(), None, |add| {
                    let mut queries = Vec::with_capacity(BATCH.min(global.len()));
                    global.for_each_block(|_, _, gaussians| {
                        if queries.len() + gaussians.len() > BATCH && !queries.is_empty() {
                            add(&queries)?;
                            queries.clear();
                        }
                        queries.extend(gaussians.iter().map(|g| g.query));
                        Ok(())
                    })?;
                    add(&queries)
                })?;
            self.relevance_index = Some(index);
        }
        let index = self.relevance_index.as_ref().expect("built above");
        index.cosines(embeddings)
    }

    /// Refuses `embeddings` that are not whole vectors of the map's
    /// embedding dimension.
    fn check_query_dim(&self, embeddings: &[f32]) -> Result<()> {
        let head = self.dictionary.head().ok_or(Error::NoEmbeddings)?;
        let dim = head.config().dim as usize;
        if embeddings.is_empty() || !embeddings.len().is_multiple_of(dim) {
            return Err(Error::EmbeddingDimension {
                map: dim as u32,
                given: embeddings.len() as u32,
                context: Some("a query, or several back to back".into()),
            });
        }
        Ok(())
    }

    /// [`Mapper::relevance`] of every Gaussian decoded in full on the GPU
    /// (paper Eq. 5), not through the relevance index: the reference the
    /// index is tested against. Unstable: for the engine's tests.
    #[cfg(any(test, feature = "testing"))]
    #[doc(hidden)]
    pub fn relevance_decoded(&mut self, query: &TextQuery) -> Result<Vec<f32>> {
        self.check_query_dim(&query.embeddings)?;
        self.flush()?;
        let head = self.dictionary.head().ok_or(Error::NoEmbeddings)?;
        let mut decoder = DevicePixelDecoder::from_head(&self.ctx, head)?;
        let mut queries = Vec::with_capacity(self.pager.global().len());
        self.pager.global().for_each_block(|_, _, gaussians| {
            queries.extend(gaussians.iter().map(|g| g.query));
            Ok(())
        })?;
        let cosines = decoder.cosines(&self.ctx, &queries, &query.embeddings)?;
        Ok(query.relevance_of(&cosines))
    }

    /// Relevance to `query` (the cosine with one embedding, the cosines
    /// with several, or the softmax over a vocabulary at one word; see
    /// [`TextQuery`]) of every Gaussian, in the order of
    /// [`Mapper::snapshot`]'s, or of every pixel of a view rendered with
    /// [`Mapper::render`]. With several embeddings and
    /// [`Relevance::Cosine`](crate::latent::Relevance::Cosine) the result
    /// holds one row of cosines per Gaussian or pixel.
    ///
    /// Gaussians are scored through an index of each one's attention over
    /// the atoms ([`RelevanceIndex`]: paper Eq. 5 factorised, the smallest
    /// 10⁻³ of each Gaussian's attention left out), built on the first
    /// query after a keyframe by reading the map block by block (spilled
    /// blocks from disk): later queries cost a few multiply-adds a
    /// Gaussian. Pixels are decoded in full on the GPU.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, frame: &latentam_io::Frame, vocabulary: &latentam_io::Vocabulary) -> latentam_core::Result<()> {
    /// use latentam_core::latent::TextQuery;
    /// use latentam_core::mapper::Scored;
    /// let chair = TextQuery::vocabulary_word(vocabulary, "chair", 0.1)?;
    /// let per_gaussian: Vec<f32> = mapper.relevance(&chair, Scored::Gaussians)?; // 0..1
    /// let (view, _) = mapper.render(frame)?;
    /// let per_pixel: Vec<f32> = mapper.relevance(&chair, Scored::Pixels(&view))?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn relevance(&mut self, query: &TextQuery, of: Scored<'_>) -> Result<Vec<f32>> {
        let cosines = match of {
            Scored::Gaussians => self.cosines(&query.embeddings)?,
            Scored::Pixels(view) => {
                let head = self.dictionary.head().ok_or(Error::NoEmbeddings)?;
                let mut decoder = DevicePixelDecoder::from_head(&self.ctx, head)?;
                decoder.cosines(&self.ctx, &view.query, &query.embeddings)?
            }
        };
        Ok(query.relevance_of(&cosines))
    }

    /// Renders colour, depth and queries of the map from a camera or a
    /// recorded frame ([`Viewpoint`]), with the Gaussians of the global map
    /// near it (those paged out included), and says how many Gaussians it
    /// drew.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper, camera: &latentam_core::splat::Camera) -> latentam_core::Result<()> {
    /// let (view, drawn) = mapper.render(camera)?;
    /// println!("{} pixels rendered", view.rgbd.len());
    /// # Ok(())
    /// # }
    /// ```
    pub fn render<'a>(&mut self, at: impl Into<Viewpoint<'a>>) -> Result<(RenderedView, usize)> {
        match at.into() {
            Viewpoint::Camera(camera) => {
                let (ev, map) = self.evaluator()?;
                ev.render(map, camera)
            }
            Viewpoint::Frame(frame) => self.render_frame(frame),
            Viewpoint::Pose(pose) => {
                let Some(record) = self.history.last() else {
                    return Err(Error::bad_input(
                        "a view at a pose",
                        "the map has no keyframe to take the camera's intrinsics from",
                    ));
                };
                let mut camera = record.camera;
                camera.cam_to_world = pose;
                let (ev, map) = self.evaluator()?;
                ev.render(map, &camera)
            }
        }
    }

    /// The map as it stands, as a [`MapSnapshot`] of its own: every
    /// Gaussian (in the order [`Mapper::relevance`] scores them), the
    /// decoder, the trajectory, the last keyframe's camera and the
    /// statistics. The GPU window is written back first.
    ///
    /// ```no_run
    /// # fn f(mapper: &mut latentam_core::mapper::Mapper) -> latentam_core::Result<()> {
    /// let map = mapper.snapshot()?;
    /// println!("{} Gaussians, {} keyframes", map.len(), map.trajectory.len());
    /// map.export_ply("kitchen.ply".as_ref())?; // opens in 3DGS viewers
    /// if let Some(decoder) = &map.decoder {
    ///     decoder.write("decoder.safetensors".as_ref())?;
    /// }
    /// # Ok(())
    /// # }
    /// ```
    pub fn snapshot(&mut self) -> Result<MapSnapshot> {
        self.flush()?;
        MapSnapshot::of(self, IndexSettings::default())
    }

    /// [`Mapper::render`] at a frame's pose and with its camera, at the
    /// camera's exposure of the frame's time (interpolated between the
    /// keyframes around it; see `exposure_compensation`).
    pub(crate) fn render_frame(&mut self, frame: &Frame) -> Result<(RenderedView, usize)> {
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
    /// queries decode to embeddings with the decoder.
    pub(crate) fn export_ply(&mut self, path: &Path) -> Result<()> {
        self.flush()?;
        let global = self.pager.global();
        let latents = self.dictionary.head().is_some();
        // Block by block: spilled blocks are read from disk one at a time.
        write_map_ply_streamed(path, global.len(), latents, |put| {
            global.for_each_block(|_, _, gaussians| put(gaussians))
        })
    }

    /// The decoder as it stands (W, the dictionary and the temperature),
    /// to turn the map's queries into embeddings elsewhere; `None` before
    /// the first keyframe with embeddings.
    pub(crate) fn decoder(&self) -> Result<Option<DecoderFile>> {
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

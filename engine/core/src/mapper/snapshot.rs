//! What a reader sees of a live map: an immutable copy taken between
//! keyframes, shared behind an `Arc`, so reading it never waits for
//! mapping once taken.

use std::sync::atomic::AtomicBool;
use std::sync::{Mutex, OnceLock};

use latentam_base::{Error, HostGaussians, Result};
use latentam_io::CameraPose;

use super::relevance_index::{DecoderView, IndexSettings, RelevanceIndex};
use super::{DecoderFile, Mapper, MapperStats};
use crate::latent::TextQuery;
use crate::map::{gaussian_at, write_map_ply, Gaussian};
use crate::splat::Camera;
use std::path::Path;

/// The map as it stood after a keyframe: every Gaussian (positions,
/// colours, opacities, scales, rotations, latent queries), the decoder
/// that turns queries into embeddings, the keyframe trajectory and the
/// mapper's statistics, all of the same moment. Relevance queries on it
/// use an index built on first use and kept with it (see
/// [`RelevanceIndex`]).
///
/// ```no_run
/// # fn f(live: &latentam_core::live::LiveMapper, text_embedding: Vec<f32>) -> latentam_core::Result<()> {
/// use latentam_core::latent::TextQuery;
/// let snapshot = live.snapshot(); // the map as of the last keyframe
/// let scores = snapshot.relevance(&TextQuery::embedding(text_embedding))?;
/// let best = (0..scores.len()).max_by(|&a, &b| scores[a].total_cmp(&scores[b]));
/// if let Some(i) = best {
///     println!("best match at {:?}", snapshot.gaussians.means[i]);
/// }
/// # Ok(())
/// # }
/// ```
pub struct MapSnapshot {
    /// Keyframes mapped when it was taken.
    pub keyframes: u64,
    /// Every Gaussian of the map; `stats.gaussians` of them.
    pub gaussians: HostGaussians,
    /// The decoder (W, the dictionary, the temperature), once a keyframe
    /// with embeddings has been mapped.
    pub decoder: Option<DecoderFile>,
    /// Every keyframe's stamp (ns) and camera-to-world pose, in order.
    pub trajectory: Vec<(i64, CameraPose)>,
    /// The mapper's counts, memory and timings at that moment.
    pub stats: MapperStats,
    /// The camera (pose and intrinsics) of the last keyframe kept for
    /// replay, to render the map as the camera saw it.
    pub camera: Option<Camera>,
    settings: IndexSettings,
    index: OnceLock<RelevanceIndex>,
    /// Held while the index is built, so it is built once.
    building: Mutex<()>,
}

impl MapSnapshot {
    /// A snapshot of parts (the live handle takes its own; this is for
    /// programs that assemble one from a saved map, and for benchmarks).
    pub fn new(
        gaussians: HostGaussians,
        decoder: Option<DecoderFile>,
        trajectory: Vec<(i64, CameraPose)>,
        stats: MapperStats,
        settings: IndexSettings,
    ) -> Self {
        MapSnapshot {
            keyframes: stats.keyframes,
            gaussians,
            decoder,
            trajectory,
            stats,
            camera: None,
            settings,
            index: OnceLock::new(),
            building: Mutex::new(()),
        }
    }

    /// The map of `mapper` as it stands, without writing its GPU window
    /// back (so taking it between keyframes leaves mapping as it was).
    pub(crate) fn of(mapper: &Mapper, settings: IndexSettings) -> Result<Self> {
        let mut snapshot = MapSnapshot::new(
            mapper.gaussians_now()?,
            mapper.decoder()?,
            mapper.trajectory().to_vec(),
            mapper.stats(),
            settings,
        );
        snapshot.camera = mapper.history().last().map(|k| k.camera);
        Ok(snapshot)
    }

    /// Gaussian `i`, as the map stores it.
    ///
    /// # Panics
    /// If `i` is not below [`MapSnapshot::len`].
    pub fn gaussian(&self, i: usize) -> Gaussian {
        gaussian_at(&self.gaussians, i)
    }

    /// Every Gaussian, as the map stores them (positions, scales,
    /// rotations, colours, opacity logits, queries), in order.
    pub fn to_gaussians(&self) -> Vec<Gaussian> {
        (0..self.len()).map(|i| self.gaussian(i)).collect()
    }

    /// Writes the map as a 3D Gaussian splatting PLY file (positions,
    /// scales, rotations, opacities, colours as degree-0 SH, and with
    /// embeddings the 32 `latent_*` query channels), atomically. The
    /// queries decode to embeddings with [`MapSnapshot::decoder`].
    pub fn export_ply(&self, path: &Path) -> Result<()> {
        write_map_ply(path, &self.to_gaussians(), self.decoder.is_some())
    }

    /// Gaussians in it.
    pub fn len(&self) -> usize {
        self.gaussians.opacity_logits.len()
    }

    /// Whether it holds no Gaussian (before the first keyframe).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The relevance index, built on the first call (on the calling
    /// thread; concurrent callers wait for that one build).
    pub fn relevance_index(&self) -> Result<&RelevanceIndex> {
        self.index_cancellable(None)
    }

    /// [`MapSnapshot::relevance_index`], giving up soon after `cancel` is
    /// set (a closing handle's indexer).
    pub(crate) fn index_cancellable(&self, cancel: Option<&AtomicBool>) -> Result<&RelevanceIndex> {
        if let Some(index) = self.index.get() {
            return Ok(index);
        }
        let Some(decoder) = &self.decoder else {
            return Err(Error::NoEmbeddings);
        };
        let _one_build = self.building.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(index) = self.index.get() {
            return Ok(index);
        }
        let view = DecoderView::of(decoder);
        let built = RelevanceIndex::build(&self.gaussians.queries, &view, self.settings, cancel)?;
        Ok(self.index.get_or_init(|| built))
    }

    /// Whether the relevance index has been built.
    pub fn is_indexed(&self) -> bool {
        self.index.get().is_some()
    }

    /// Cosine similarity of every Gaussian's decoded embedding with each
    /// embedding of `texts` (m × d_f back to back): Gaussians × m,
    /// row-major, in the order of [`MapSnapshot::gaussians`].
    pub fn cosines(&self, texts: &[f32]) -> Result<Vec<f32>> {
        self.relevance_index()?.cosines(texts)
    }

    /// Relevance of every Gaussian to `query` (the cosine with one
    /// embedding, or the softmax over a vocabulary at one word; see
    /// [`TextQuery`]), in the order of [`MapSnapshot::gaussians`].
    pub fn relevance(&self, query: &TextQuery) -> Result<Vec<f32>> {
        Ok(query.relevance_of(&self.cosines(&query.embeddings)?))
    }
}

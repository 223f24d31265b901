//! The decoder as a file of its own (`decoder.safetensors` in a run
//! folder): with the `latent_*` properties of an exported PLY it turns any
//! Gaussian's 32-d query back into a full embedding without the engine or
//! a GPU, e.g. in a Python viewer.
//!
//! Tensors: `W` (32 × d_f), `D` and `D0` (K × d_f, the atoms in use and
//! their trust-region anchors), `atom_weights` (K, the streaming k-means
//! counts), `tau` (1). Metadata: `format` = `latentam-decoder`, `version`,
//! `model` (the embedding model id), `dim` (d_f), `query_dim`, `atoms`,
//! `eps`. Decoding (paper Eq. 5): `E = qW`, cosine similarity of `E` with
//! every atom, softmax at temperature `tau`, weighted sum of the atoms.

use std::borrow::Cow;
use std::path::Path;

use super::archive::{Archive, ArchiveWriter};
use crate::latent::HostDecoder;
use crate::splat::QUERY_DIM;
use latentam_base::Result;

/// File name of the decoder in a run folder.
pub const DECODER_FILE: &str = "decoder.safetensors";
/// Format name of decoder files.
pub const DECODER_FORMAT: &str = "latentam-decoder";
/// Version this build writes (with a `crc32` checksum, which it must
/// carry); version 1 files, from before the checksum was required, are
/// read too.
pub const DECODER_VERSION: u32 = 2;

/// A map's decoder, on the host.
///
/// ```no_run
/// use latentam_core::mapper::DecoderFile;
///
/// let decoder = DecoderFile::read("run/decoder.safetensors".as_ref())?;
/// let query = [0.1f32; 32]; // a Gaussian's latent_0..31 from map.ply
/// let embedding = decoder.decode(&[query]); // d_f values
/// assert_eq!(embedding.len(), decoder.dim as usize);
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct DecoderFile {
    /// Embedding dimension d_f.
    pub dim: u32,
    /// Projection, `QUERY_DIM × dim`, row-major.
    pub w: Vec<f32>,
    /// Atoms in use, `atoms × dim`.
    pub atoms: Vec<f32>,
    /// Trust-region anchors of the atoms, `atoms × dim`.
    pub anchors: Vec<f32>,
    /// Streaming k-means weight of each atom.
    pub atom_weights: Vec<f32>,
    /// Softmax temperature.
    pub temperature: f32,
    /// Added to norms before dividing.
    pub eps: f32,
    /// Embedding model id of the map's region embeddings.
    pub model: String,
    /// The id of the run folder version it was written with, shared with
    /// the state beside it (see [`super::RunFolder`]).
    pub run_id: Option<String>,
}

impl DecoderFile {
    /// Number of atoms.
    pub fn atom_count(&self) -> usize {
        self.atom_weights.len()
    }

    /// Decodes queries to embeddings (`queries.len() × dim`, row-major),
    /// in f64 on the CPU.
    pub fn decode(&self, queries: &[[f32; QUERY_DIM]]) -> Vec<f32> {
        HostDecoder {
            dim: self.dim as usize,
            w: &self.w,
            atoms: &self.atoms,
            temperature: self.temperature,
            eps: self.eps,
        }
        .decode(queries)
    }

    /// Writes the decoder to `path` atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        latentam_base::files::write_bytes_atomically(path, &self.to_bytes()?)
    }

    /// The file [`DecoderFile::write`] writes.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let (d, k) = (self.dim as usize, self.atom_count());
        let mut a = ArchiveWriter::with_format(DECODER_FORMAT, DECODER_VERSION);
        a.meta("model", &self.model);
        a.meta("dim", d);
        a.meta("query_dim", QUERY_DIM);
        a.meta("atoms", k);
        a.meta("eps", self.eps);
        if let Some(id) = &self.run_id {
            a.meta("run_id", id);
        }
        a.tensor("W", &[QUERY_DIM, d], &self.w);
        a.tensor("D", &[k, d], &self.atoms);
        a.tensor("D0", &[k, d], &self.anchors);
        a.tensor("atom_weights", &[k], &self.atom_weights);
        a.tensor("tau", &[1], &[self.temperature]);
        a.into_bytes()
    }

    /// Reads a decoder written by [`DecoderFile::write`].
    pub fn read(path: &Path) -> Result<Self> {
        let a = Archive::open_as(path, DECODER_FORMAT, DECODER_VERSION, "decoder")?;
        Self::from_archive(&a)
    }

    /// Reads a decoder from `bytes`, the contents of `origin` (which only
    /// names it in errors), like [`DecoderFile::read`]. Any bytes are
    /// accepted: malformed ones are an error, never a panic.
    pub fn parse(bytes: &[u8], origin: &Path) -> Result<Self> {
        let a = Archive::parse_as(
            Cow::Borrowed(bytes),
            origin,
            DECODER_FORMAT,
            DECODER_VERSION,
            "decoder",
        )?;
        Self::from_archive(&a)
    }

    fn from_archive(a: &Archive<'_>) -> Result<Self> {
        let dim: u32 = a.meta_parse("dim")?;
        let k: usize = a.meta_parse("atoms")?;
        let query_dim: usize = a.meta_parse("query_dim")?;
        if query_dim != QUERY_DIM || dim == 0 {
            return Err(a.corrupt(format!(
                "a decoder of {query_dim}-d queries to {dim}-d embeddings; this build \
                 decodes {QUERY_DIM}-d queries"
            )));
        }
        let d = dim as usize;
        let temperature = a.exact::<f32>("tau", &[1])?[0];
        let eps: f32 = a.meta_parse("eps")?;
        if !(temperature.is_finite() && temperature > 0.0 && eps.is_finite() && eps >= 0.0) {
            return Err(a.corrupt(format!(
                "temperature {temperature} must be positive and eps {eps} not negative"
            )));
        }
        let file = DecoderFile {
            dim,
            w: a.exact("W", &[QUERY_DIM, d])?,
            atoms: a.exact("D", &[k, d])?,
            anchors: a.exact("D0", &[k, d])?,
            atom_weights: a.exact("atom_weights", &[k])?,
            temperature,
            eps,
            model: a.meta("model")?.to_string(),
            // A decoder written on its own (a snapshot's) has none.
            run_id: a.run_id()?,
        };
        for (name, values) in [
            ("W", &file.w),
            ("D", &file.atoms),
            ("D0", &file.anchors),
            ("atom_weights", &file.atom_weights),
        ] {
            if values.iter().any(|x| !x.is_finite()) {
                return Err(a.corrupt(format!("tensor `{name}` holds non-finite values")));
            }
        }
        Ok(file)
    }
}

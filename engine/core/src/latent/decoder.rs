//! The dictionary attention decoder: rendered 32-d region queries back to full
//! embeddings (paper Eq. 5). Forward and backward are GEMMs ([`Gemm`]) around
//! row normalisation ([`normalize_rows`] and its backward) and the row
//! softmax ([`row_softmax`] and its backward). CPU reference:
//! `latentam_reference::decoder`.

use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::ops::{
    normalize_rows, normalize_rows_backward, row_softmax, row_softmax_backward, Gemm, Transpose,
};
use latentam_gpu::{Buffer, Context, Recorder};

/// Sizes and constants of a decoder; the workspace is allocated for the
/// largest batch once.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::latent::{AttentionDecoder, DecoderConfig};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// // Up to 256 queries a call, against up to 1000 atoms of 512-d embeddings.
/// let cfg = DecoderConfig { max_regions: 256, max_atoms: 1000, dim: 512, ..Default::default() };
/// let decoder = AttentionDecoder::new(&ctx, cfg)?;
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecoderConfig {
    /// Most regions decoded in one call (n).
    pub max_regions: u32,
    /// Dictionary capacity (K).
    pub max_atoms: u32,
    /// Embedding dimension d_f (e.g. 768 for CLIP ViT-B/16).
    pub dim: u32,
    /// Softmax temperature τ over cosine similarities (M3's 0.05).
    pub temperature: f32,
    /// Added to each norm before dividing (M3's 1e-6).
    pub eps: f32,
}

impl Default for DecoderConfig {
    fn default() -> Self {
        Self {
            max_regions: 2000,
            max_atoms: 2000,
            dim: 768,
            temperature: 0.05,
            eps: 1e-6,
        }
    }
}

/// The learned parameters a decode reads: the projection W (32 × d_f,
/// row-major) and the dictionary D (`atom_count` × d_f rows in use).
///
/// ```no_run
/// use latentam_core::latent::{AttentionDecoder, DecoderParams, LatentHead};
/// # fn f(ctx: &latentam_gpu::Context, head: &LatentHead, decoder: &AttentionDecoder, queries: &latentam_gpu::Buffer) -> latentam_core::Result<()> {
/// // Decode 10 queries with the head's current W and dictionary.
/// let params = DecoderParams { w: head.w(), atoms: head.atoms(), atom_count: head.atom_count() };
/// let mut rec = ctx.recorder()?;
/// decoder.record_forward(&mut rec, params, queries, 10)?;
/// rec.submit()?.wait()?;
/// let embeddings: Vec<f32> = ctx.download(decoder.output())?; // 10 × d_f
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Copy)]
pub struct DecoderParams<'a> {
    /// Projection W.
    pub w: &'a Buffer,
    /// Dictionary D (capacity rows; the first `atom_count` are used).
    pub atoms: &'a Buffer,
    /// Atoms in use (1 ..= `max_atoms`).
    pub atom_count: u32,
}

/// Where [`AttentionDecoder::record_backward`] writes gradients (each is
/// overwritten, not accumulated).
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context};
/// use latentam_core::latent::{AttentionDecoder, DecoderGrads, DecoderParams};
/// # fn f(ctx: &Context, decoder: &AttentionDecoder, params: DecoderParams<'_>, queries: &Buffer, grad_output: &Buffer) -> latentam_core::Result<()> {
/// let (n, d) = (10, decoder.config().dim as u64);
/// let grad_q = Buffer::device(ctx, "dQ", n as u64 * 32 * 4)?;
/// let grad_w = Buffer::device(ctx, "dW", 32 * d * 4)?;
/// let grad_d = Buffer::device(ctx, "dD", params.atom_count as u64 * d * 4)?;
/// let grads = DecoderGrads { queries: Some(&grad_q), w: &grad_w, atoms: &grad_d };
/// let mut rec = ctx.recorder()?;
/// decoder.record_forward(&mut rec, params, queries, n)?;
/// decoder.record_backward(&mut rec, params, queries, n, grad_output, grads)?;
/// rec.submit()?.wait()?;
/// # Ok(())
/// # }
/// ```
pub struct DecoderGrads<'a> {
    /// ∂L/∂Q, n × 32; `None` when the queries are frozen (Stage II).
    pub queries: Option<&'a Buffer>,
    /// ∂L/∂W, 32 × d_f.
    pub w: &'a Buffer,
    /// ∂L/∂D, `atom_count` × d_f.
    pub atoms: &'a Buffer,
}

/// Decodes region queries by attention over a dictionary, and
/// back-propagates through it.
///
/// ```no_run
/// use latentam_gpu::{Buffer, Context, ContextOptions};
/// use latentam_core::latent::{AttentionDecoder, DecoderConfig, DecoderGrads, DecoderParams};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let cfg = DecoderConfig { max_regions: 4, max_atoms: 8, dim: 64, ..Default::default() };
/// let dec = AttentionDecoder::new(&ctx, cfg)?;
/// let q = ctx.upload_new("q", &vec![0.1f32; 4 * 32])?;
/// let w = ctx.upload_new("w", &vec![0.01f32; 32 * 64])?;
/// let d = ctx.upload_new("d", &vec![0.5f32; 8 * 64])?;
/// let params = DecoderParams { w: &w, atoms: &d, atom_count: 8 };
/// let target_grad = ctx.upload_new("dF", &vec![1.0f32; 4 * 64])?;
/// let (gw, gd) = (Buffer::device(&ctx, "dW", 32 * 64 * 4)?, Buffer::device(&ctx, "dD", 8 * 64 * 4)?);
/// let mut rec = ctx.recorder()?;
/// dec.record_forward(&mut rec, params, &q, 4)?;
/// dec.record_backward(&mut rec, params, &q, 4, &target_grad,
///     DecoderGrads { queries: None, w: &gw, atoms: &gd })?;
/// rec.submit()?.wait()?;
/// let decoded: Vec<f32> = ctx.download(dec.output())?; // 4 × 64
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct AttentionDecoder {
    cfg: DecoderConfig,
    e: Buffer,
    e_norm: Buffer,
    e_hat: Buffer,
    d_norm: Buffer,
    d_hat: Buffer,
    attention: Buffer,
    output: Buffer,
    d_attention: Buffer,
    d_e_hat: Buffer,
    d_e: Buffer,
    d_d_hat: Buffer,
}

impl AttentionDecoder {
    /// Allocates the workspace for `cfg`.
    pub fn new(ctx: &Context, cfg: DecoderConfig) -> Result<Self> {
        if cfg.max_regions == 0 || cfg.max_atoms == 0 || cfg.dim == 0 {
            return Err(Error::bad_input(
                "decoder sizes",
                format!("must be positive: {cfg:?}"),
            ));
        }
        let valid = cfg.temperature > 0.0 && cfg.temperature.is_finite() && cfg.eps >= 0.0;
        if !valid {
            return Err(Error::bad_input(
                "decoder temperature and eps",
                format!("the temperature must be positive and eps non-negative: {cfg:?}"),
            ));
        }
        let (n, k, d) = (cfg.max_regions as u64, cfg.max_atoms as u64, cfg.dim as u64);
        let buf =
            |name: &str, elems: u64| Buffer::device(ctx, &format!("decoder/{name}"), elems * 4);
        Ok(Self {
            cfg,
            e: buf("e", n * d)?,
            e_norm: buf("e_norm", n)?,
            e_hat: buf("e_hat", n * d)?,
            d_norm: buf("d_norm", k)?,
            d_hat: buf("d_hat", k * d)?,
            attention: buf("attention", n * k)?,
            output: buf("output", n * d)?,
            d_attention: buf("d_attention", n * k)?,
            d_e_hat: buf("d_e_hat", n * d)?,
            d_e: buf("d_e", n * d)?,
            d_d_hat: buf("d_d_hat", k * d)?,
        })
    }

    /// The configuration it was built with.
    pub fn config(&self) -> &DecoderConfig {
        &self.cfg
    }

    /// Decoded embeddings F̂ of the last forward pass (n × d_f, row-major).
    pub fn output(&self) -> &Buffer {
        &self.output
    }

    /// Attention A of the last forward pass (n × atom_count, row-major).
    pub fn attention(&self) -> &Buffer {
        &self.attention
    }

    fn check(&self, p: &DecoderParams, n: u32) -> Result<()> {
        if n > self.cfg.max_regions {
            return Err(Error::bad_input(
                "regions to decode",
                format!(
                    "decoding {n} regions, the decoder was sized for {}",
                    self.cfg.max_regions
                ),
            ));
        }
        if p.atom_count == 0 || p.atom_count > self.cfg.max_atoms {
            return Err(Error::bad_input(
                "atom count",
                format!(
                    "decoding with {} atoms; the dictionary holds 1 ..= {}",
                    p.atom_count, self.cfg.max_atoms
                ),
            ));
        }
        Ok(())
    }

    fn gemm(&self, transpose: Transpose, m: u32, n: u32, k: u32, alpha: f32, beta: f32) -> Gemm {
        Gemm {
            transpose,
            m,
            n,
            k,
            alpha,
            beta,
        }
    }

    fn normalize<'a>(
        &self,
        rec: &mut Recorder<'a>,
        x: &'a Buffer,
        y: &'a Buffer,
        norm: &'a Buffer,
        rows: u32,
    ) -> Result<()> {
        normalize_rows(rec, x, y, norm, rows, self.cfg.dim, self.cfg.eps)
    }

    /// Records the forward pass for `n` regions whose queries are the first
    /// n rows of `queries` (n × 32). The result is in [`Self::output`].
    pub fn record_forward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        p: DecoderParams<'a>,
        queries: &'a Buffer,
        n: u32,
    ) -> Result<()> {
        self.check(&p, n)?;
        let (d, k, s) = (self.cfg.dim, p.atom_count, QUERY_DIM as u32);
        self.normalize(rec, p.atoms, &self.d_hat, &self.d_norm, k)?;
        if n == 0 {
            return Ok(());
        }
        self.gemm(Transpose::None, n, d, s, 1.0, 0.0)
            .record(rec, queries, p.w, &self.e)?;
        self.normalize(rec, &self.e, &self.e_hat, &self.e_norm, n)?;
        self.gemm(Transpose::B, n, k, d, 1.0, 0.0).record(
            rec,
            &self.e_hat,
            &self.d_hat,
            &self.attention,
        )?;
        row_softmax(
            rec,
            &self.attention,
            &self.attention,
            n,
            k,
            1.0 / self.cfg.temperature,
        )?;
        self.gemm(Transpose::None, n, d, k, 1.0, 0.0).record(
            rec,
            &self.attention,
            p.atoms,
            &self.output,
        )
    }

    /// Records the backward pass for ∂L/∂F̂ = `grad_output` (n × d_f). The
    /// forward pass with the same parameters and queries must have been
    /// recorded before (it keeps what the backward reads). With n = 0 the
    /// W and D gradients are written as zeros.
    pub fn record_backward<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        p: DecoderParams<'a>,
        queries: &'a Buffer,
        n: u32,
        grad_output: &'a Buffer,
        grads: DecoderGrads<'a>,
    ) -> Result<()> {
        self.check(&p, n)?;
        let (d, k, s) = (self.cfg.dim, p.atom_count, QUERY_DIM as u32);
        if n == 0 {
            rec.fill_u32(grads.w, 0);
            rec.fill_u32(grads.atoms, 0);
            return Ok(());
        }
        // Direct path of F̂ = A·D.
        self.gemm(Transpose::A, k, d, n, 1.0, 0.0).record(
            rec,
            &self.attention,
            grad_output,
            grads.atoms,
        )?;
        self.gemm(Transpose::B, n, k, d, 1.0, 0.0).record(
            rec,
            grad_output,
            p.atoms,
            &self.d_attention,
        )?;
        let inv_tau = 1.0 / self.cfg.temperature;
        row_softmax_backward(rec, &self.attention, &self.d_attention, n, k, inv_tau)?;
        // Through the cosine similarities into both normalisations.
        self.gemm(Transpose::None, n, d, k, 1.0, 0.0).record(
            rec,
            &self.d_attention,
            &self.d_hat,
            &self.d_e_hat,
        )?;
        self.gemm(Transpose::A, k, d, n, 1.0, 0.0).record(
            rec,
            &self.d_attention,
            &self.e_hat,
            &self.d_d_hat,
        )?;
        let (dim, eps) = (self.cfg.dim, self.cfg.eps);
        let (d_hat, d_norm, d_d_hat) = (&self.d_hat, &self.d_norm, &self.d_d_hat);
        normalize_rows_backward(rec, d_hat, d_norm, d_d_hat, grads.atoms, k, dim, eps, 1.0)?;
        let (e_hat, e_norm, d_e_hat) = (&self.e_hat, &self.e_norm, &self.d_e_hat);
        normalize_rows_backward(rec, e_hat, e_norm, d_e_hat, &self.d_e, n, dim, eps, 0.0)?;
        self.gemm(Transpose::A, s, d, n, 1.0, 0.0)
            .record(rec, queries, &self.d_e, grads.w)?;
        if let Some(gq) = grads.queries {
            self.gemm(Transpose::B, n, s, d, 1.0, 0.0)
                .record(rec, &self.d_e, p.w, gq)?;
        }
        Ok(())
    }
}

#[cfg(test)]
#[path = "decoder_tests.rs"]
mod tests;

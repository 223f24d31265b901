//! Per-pixel decoding on the device: what evaluation and relevance images
//! need of every pixel's decoded embedding (paper Eq. 5), in batches of
//! pixels sized to the device's buffer limits.
//!
//! Per batch of n pixels (kernels in `glsl/pixel_decode.comp`):
//! 1. logits L = Q M, a GEMM of n × QUERY_DIM by QUERY_DIM × K, with
//!    M = W D̂ᵀ computed once per map (D̂: the atoms scaled to unit length,
//!    with the decoder's ε);
//! 2. `pixel_attention`: a = softmax(L / (τ (‖qW‖ + ε))), ‖qW‖² = q G qᵀ
//!    with G = W Wᵀ;
//! 3. the embeddings E = A D, a GEMM of n × K by K × d_f;
//! 4. `pixel_norms`: ‖e‖ and ⟨e, t̂⟩ for the pixel's region target;
//! 5. with texts, ⟨e, t̂_c⟩ for every text, a GEMM of n × d_f by d_f × m,
//!    and, when only the best text is wanted, its index (`argmax_rows`).
//!
//! A pixel costs QUERY_DIM·K + K·d_f + (m + 2)·d_f multiply-adds, against
//! QUERY_DIM·d_f + 2·K·d_f for decoding it as training does (Ê = qW
//! normalised, then its logits against D̂ in d_f dimensions). The K·d_f
//! of E is what the norm needs: the attention over real region embeddings
//! is not sparse enough at τ = 0.05 to leave atoms out (atoms are alike,
//! so a pixel's weights spread over most of them).
//!
//! References: [`super::FactorisedDecoder`] (the same quantities,
//! factorised, on the CPU) and `latentam_reference::decoder::forward`
//! (explicit, f64).

use crate::latent::{LatentHead, NO_REGION};
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};
use latentam_gpu::ops::{normalize_rows, Gemm, Transpose};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::{bind, push, ARGMAX_ROWS, PIXEL_ATTENTION, PIXEL_NORMS};

mod pixels;
#[cfg(test)]
mod tests;

use pixels::check_pixels;
pub(crate) use pixels::unit_rows;
pub use pixels::{DecodedPixels, PixelsToDecode, TextOutput};

/// Device memory one batch of pixels may take (bytes); the binding limit
/// can make batches smaller.
const BATCH_BYTES: u64 = 64 << 20;

/// The device buffers of one batch of pixels.
struct Batch {
    rows: u32,
    queries: Buffer,
    region: Buffer,
    weights: Buffer,
    embeddings: Buffer,
    norm: Buffer,
    target_dot: Buffer,
}

/// Decodes rendered queries per pixel on the device, factorised as
/// [`super::FactorisedDecoder`] does on the CPU.
///
/// ```
/// # let ctx = latentam_gpu::Context::new(Default::default())?;
/// use latentam_core::latent::{DevicePixelDecoder, PixelsToDecode, TextOutput};
///
/// // 2 atoms in 3 dimensions; W maps query channel 0 to atom 0.
/// let mut w = vec![0.0f32; 32 * 3];
/// w[0] = 1.0;
/// let w = ctx.upload_new("w", &w)?;
/// let atoms = ctx.upload_new("atoms", &[1.0f32, 0.0, 0.0, 0.0, 1.0, 0.0])?;
/// let mut dec = DevicePixelDecoder::new(&ctx, &w, &atoms, 2, 3, 0.05, 1e-6)?;
/// let mut q = [0.0f32; 32];
/// q[0] = 2.0;
/// let out = dec.decode(&ctx, &PixelsToDecode {
///     queries: &[q],
///     region: &[0],
///     targets: &[2.0, 0.0, 0.0],
///     texts: &[0.0, 1.0, 0.0, 1.0, 0.0, 0.0],
///     text_output: TextOutput::Best,
/// })?;
/// assert!((out.target_dot[0] / out.norm[0] - 1.0).abs() < 1e-3); // e ≈ atom 0
/// assert_eq!(out.best_text, vec![1]);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct DevicePixelDecoder {
    atoms: u32,
    /// K rounded up to a multiple of 4: the row length of M and A and the
    /// rows of D, zero past K.
    stride: u32,
    dim: u32,
    inv_tau: f32,
    eps: f32,
    /// W D̂ᵀ, QUERY_DIM × stride.
    m: Buffer,
    /// W Wᵀ, QUERY_DIM × QUERY_DIM.
    g: Buffer,
    /// D, stride × d_f.
    d: Buffer,
    batch: Batch,
}

impl DevicePixelDecoder {
    /// From W (`QUERY_DIM` × d_f, row-major) and the first `atom_count`
    /// rows of `atoms` (K × d_f) on the device, the softmax temperature τ
    /// and the norm's ε.
    pub fn new(
        ctx: &Context,
        w: &Buffer,
        atoms: &Buffer,
        atom_count: u32,
        dim: u32,
        temperature: f32,
        eps: f32,
    ) -> Result<Self> {
        if atom_count == 0 || dim == 0 {
            return Err(Error::bad_input(
                "pixel decoder sizes",
                format!("{atom_count} atoms in {dim} dimensions (both must be positive)"),
            ));
        }
        let finite = temperature.is_finite() && eps.is_finite();
        if !(finite && temperature > 0.0 && eps >= 0.0) {
            return Err(Error::bad_input(
                "decoder temperature and eps",
                format!("temperature {temperature} must be finite and positive, eps {eps} finite and non-negative"),
            ));
        }
        let stride = atom_count.next_multiple_of(4);
        let (k, d64) = (stride as u64, dim as u64);
        let buf =
            |name: &str, bytes: u64| Buffer::device(ctx, &format!("pixel_decoder/{name}"), bytes);
        let batch = Batch::new(ctx, Self::batch_rows(ctx, stride, dim)?, stride, dim)?;
        let mut dec = DevicePixelDecoder {
            atoms: atom_count,
            stride,
            dim,
            inv_tau: 1.0 / temperature,
            eps,
            m: buf("m", QUERY_DIM as u64 * k * 4)?,
            g: buf("g", (QUERY_DIM * QUERY_DIM) as u64 * 4)?,
            d: buf("atoms", k * d64 * 4)?,
            batch,
        };
        dec.load(ctx, w, atoms)?;
        Ok(dec)
    }

    /// Computes M, G and the copy of D from W and the first K atoms.
    fn load(&mut self, ctx: &Context, w: &Buffer, atoms: &Buffer) -> Result<()> {
        let (k, d64) = (self.atoms as u64, self.dim as u64);
        w.ensure_bytes(QUERY_DIM as u64 * d64 * 4, "pixel decoder W")?;
        atoms.ensure_bytes(k * d64 * 4, "pixel decoder atoms")?;
        let padded = self.stride as u64 * d64 * 4;
        let d_hat = Buffer::device(ctx, "pixel_decoder/unit_atoms", padded)?;
        let atom_norms = Buffer::device(ctx, "pixel_decoder/atom_norms", self.stride as u64 * 4)?;
        let mut rec = ctx.recorder()?;
        // The rows past K stay zero: their logits are never read, and 0 × D
        // must not be 0 × NaN in E = A D.
        rec.fill_u32(&self.d, 0);
        rec.copy(atoms, 0, &self.d, 0, k * d64 * 4)?;
        normalize_rows(
            &mut rec,
            &self.d,
            &d_hat,
            &atom_norms,
            self.stride,
            self.dim,
            self.eps,
        )?;
        Gemm {
            transpose: Transpose::B,
            m: QUERY_DIM as u32,
            n: self.stride,
            k: self.dim,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(&mut rec, w, &d_hat, &self.m)?;
        Gemm {
            transpose: Transpose::B,
            m: QUERY_DIM as u32,
            n: QUERY_DIM as u32,
            k: self.dim,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(&mut rec, w, w, &self.g)?;
        rec.submit()?.wait()
    }

    /// The decoder in `slot` updated to `head`'s current W and atoms:
    /// rebuilt when the head's sizes or settings changed, otherwise its
    /// buffers are reused.
    pub fn ensure<'s>(
        slot: &'s mut Option<Self>,
        ctx: &Context,
        head: &LatentHead,
    ) -> Result<&'s mut Self> {
        let cfg = head.config();
        let same = slot.as_ref().is_some_and(|d| {
            d.atoms == head.atom_count()
                && d.dim == cfg.dim
                && d.inv_tau == 1.0 / cfg.temperature
                && d.eps == head.decoder().config().eps
        });
        match slot {
            Some(dec) if same => dec.load(ctx, head.w(), head.atoms())?,
            _ => {
                *slot = None;
                *slot = Some(Self::from_head(ctx, head)?);
            }
        }
        Ok(slot.as_mut().expect("set above"))
    }

    /// The head's current W and atoms.
    pub fn from_head(ctx: &Context, head: &LatentHead) -> Result<Self> {
        if head.atom_count() == 0 {
            return Err(Error::NoEmbeddings);
        }
        let cfg = head.config();
        Self::new(
            ctx,
            head.w(),
            head.atoms(),
            head.atom_count(),
            cfg.dim,
            cfg.temperature,
            head.decoder().config().eps,
        )
    }

    /// Atoms K.
    pub fn atoms(&self) -> u32 {
        self.atoms
    }

    /// Embedding dimension d_f.
    pub fn dim(&self) -> u32 {
        self.dim
    }

    /// Pixels decoded per batch: as many as 64 MiB of batch buffers hold, with
    /// no buffer past the device's binding limit.
    pub fn batch_pixels(&self) -> u32 {
        self.batch.rows
    }

    fn batch_rows(ctx: &Context, atoms: u32, dim: u32) -> Result<u32> {
        Self::batch_rows_within(ctx.info().max_buffer_bytes(), atoms, dim)
    }

    /// Pixels a batch holds with buffers of at most `limit` bytes, for
    /// `atoms` (K rounded up to 4) and `dim`.
    pub(crate) fn batch_rows_within(limit: u64, atoms: u32, dim: u32) -> Result<u32> {
        let widest = 4 * (atoms.max(dim) as u64).max(QUERY_DIM as u64);
        // Weights, embedding, query and a few scalars a row.
        let per_row = 4 * (atoms as u64 + dim as u64 + QUERY_DIM as u64 + 8);
        let rows = (limit / widest)
            .min(BATCH_BYTES / per_row)
            .min(u32::MAX as u64);
        if rows == 0 {
            return Err(Error::Unsupported(format!(
                "one pixel's {atoms} attention weights do not fit the device's \
                 {limit}-byte buffers"
            )));
        }
        Ok(rows as u32)
    }

    /// Decodes `pixels` (see [`PixelsToDecode`]) in batches.
    pub fn decode(&mut self, ctx: &Context, pixels: &PixelsToDecode) -> Result<DecodedPixels> {
        let dim = self.dim as usize;
        let regions = check_pixels(pixels, dim)?;
        // A table of one zero row stands for "no targets" (never read).
        let (mut unit_targets, _) = unit_rows(pixels.targets, dim);
        if unit_targets.is_empty() {
            unit_targets = vec![0.0; dim];
        }
        let targets = ctx.upload_new("pixel_decoder/targets", &unit_targets)?;
        let texts = pixels.texts.len() / dim;
        // The texts' scores of a batch must fit one buffer too.
        let limit = ctx.info().max_buffer_bytes();
        let batch = (self.batch.rows as u64).min(limit / (4 * texts.max(1) as u64)) as usize;
        if batch == 0 {
            return Err(Error::Unsupported(format!(
                "one pixel's scores against {texts} texts do not fit the device's \
                 {limit}-byte buffers"
            )));
        }
        let text_buffers = if texts > 0 {
            let rows = batch as u64;
            Some(TextScores {
                unit_texts: ctx
                    .upload_new("pixel_decoder/texts", &unit_rows(pixels.texts, dim).0)?,
                dots: Buffer::device(ctx, "pixel_decoder/text_dots", rows * texts as u64 * 4)?,
                best_value: Buffer::device(ctx, "pixel_decoder/best_value", rows * 4)?,
                best_index: Buffer::device(ctx, "pixel_decoder/best_text", rows * 4)?,
                texts: texts as u32,
                dim: self.dim,
            })
        } else {
            None
        };
        let mut out = DecodedPixels::default();
        let no_regions = vec![NO_REGION; batch];
        for (i, queries) in pixels.queries.chunks(batch).enumerate() {
            let rows = queries.len() as u32;
            let region = match pixels.region {
                [] => &no_regions[..queries.len()],
                all => &all[i * batch..i * batch + queries.len()],
            };
            let mut rec = ctx.recorder()?;
            self.record_batch(&mut rec, queries, region, &targets, regions as u32)?;
            let b = &self.batch;
            let norm = rec.download(&b.norm, 0, rows as u64 * 4)?;
            let dot = rec.download(&b.target_dot, 0, rows as u64 * 4)?;
            let text_read = match &text_buffers {
                Some(t) => Some(t.record(&mut rec, &b.embeddings, rows, pixels.text_output)?),
                None => None,
            };
            rec.submit()?.wait()?;
            out.norm.extend(norm.read::<f32>()?);
            out.target_dot.extend(dot.read::<f32>()?);
            match (text_read, pixels.text_output) {
                (Some(r), TextOutput::All) => out.text_dots.extend(r.read::<f32>()?),
                (Some(r), TextOutput::Best) => out.best_text.extend(r.read::<u32>()?),
                (None, _) => {}
            }
        }
        Ok(out)
    }

    /// The cosine between each decoded query and each of `texts` (m ×
    /// d_f, any length; zero rows score 0): `queries.len()` × m, row-major.
    /// What relevance images and heat maps are made of.
    pub fn cosines(
        &mut self,
        ctx: &Context,
        queries: &[[f32; QUERY_DIM]],
        texts: &[f32],
    ) -> Result<Vec<f32>> {
        if texts.is_empty() {
            return Err(Error::bad_input("texts", "no text to score against"));
        }
        let out = self.decode(
            ctx,
            &PixelsToDecode {
                queries,
                region: &[],
                targets: &[],
                texts,
                text_output: TextOutput::All,
            },
        )?;
        let m = texts.len() / self.dim as usize;
        let mut cos = out.text_dots;
        for (row, &norm) in cos.chunks_exact_mut(m).zip(&out.norm) {
            let inv = if norm > 0.0 { 1.0 / norm } else { 0.0 };
            row.iter_mut()
                .for_each(|c| *c = (*c * inv).clamp(-1.0, 1.0));
        }
        Ok(cos)
    }

    /// Records steps 1–4 of the module doc for one batch.
    fn record_batch<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        queries: &[[f32; QUERY_DIM]],
        region: &[u32],
        targets: &'a Buffer,
        regions: u32,
    ) -> Result<()> {
        let b = &self.batch;
        let rows = queries.len() as u32;
        rec.upload(&b.queries, 0, queries)?;
        rec.upload(&b.region, 0, region)?;
        Gemm {
            transpose: Transpose::None,
            m: rows,
            n: self.stride,
            k: QUERY_DIM as u32,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(rec, &b.queries, &self.m, &b.weights)?;
        rec.dispatch_linear(
            &PIXEL_ATTENTION,
            rows,
            bind::PixelAttentionBuffers {
                weights: &b.weights,
                queries: &b.queries,
                query_gram: &self.g,
            },
            &push::PixelAttention {
                rows,
                atoms: self.atoms,
                stride: self.stride,
                inv_tau: self.inv_tau,
                eps: self.eps,
            },
        )?;
        Gemm {
            transpose: Transpose::None,
            m: rows,
            n: self.dim,
            k: self.stride,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(rec, &b.weights, &self.d, &b.embeddings)?;
        rec.dispatch_linear(
            &PIXEL_NORMS,
            rows,
            bind::PixelNormsBuffers {
                embeddings: &b.embeddings,
                region: &b.region,
                targets,
                norm: &b.norm,
                target_dot: &b.target_dot,
            },
            &push::PixelNorms {
                rows,
                dim: self.dim,
                regions,
            },
        )
    }
}

impl Batch {
    fn new(ctx: &Context, rows: u32, atoms: u32, dim: u32) -> Result<Self> {
        let r = rows as u64;
        let buf = |name: &str, per_row: u64| {
            Buffer::device(ctx, &format!("pixel_decoder/{name}"), r * per_row * 4)
        };
        Ok(Batch {
            rows,
            queries: buf("queries", QUERY_DIM as u64)?,
            region: buf("region", 1)?,
            weights: buf("weights", atoms as u64)?,
            embeddings: buf("embeddings", dim as u64)?,
            norm: buf("norm", 1)?,
            target_dot: buf("target_dot", 1)?,
        })
    }
}

/// The texts' buffers of a decode: their unit rows, and each batch's
/// scores against them (all of them, or the best per pixel).
struct TextScores {
    unit_texts: Buffer,
    dots: Buffer,
    best_value: Buffer,
    best_index: Buffer,
    texts: u32,
    dim: u32,
}

impl TextScores {
    /// Records the scores of `rows` decoded `embeddings` and their
    /// download: every text's (`TextOutput::All`) or the best text's index.
    fn record<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        embeddings: &'a Buffer,
        rows: u32,
        output: TextOutput,
    ) -> Result<latentam_gpu::Readback> {
        Gemm {
            transpose: Transpose::B,
            m: rows,
            n: self.texts,
            k: self.dim,
            alpha: 1.0,
            beta: 0.0,
        }
        .record(rec, embeddings, &self.unit_texts, &self.dots)?;
        match output {
            TextOutput::All => rec.download(&self.dots, 0, rows as u64 * self.texts as u64 * 4),
            TextOutput::Best => {
                rec.dispatch_linear(
                    &ARGMAX_ROWS,
                    rows,
                    bind::ArgmaxRowsBuffers {
                        m: &self.dots,
                        best_value: &self.best_value,
                        best_index: &self.best_index,
                    },
                    &push::ArgmaxRows {
                        rows,
                        cols: self.texts,
                        exclude_diagonal: 0,
                    },
                )?;
                rec.download(&self.best_index, 0, rows as u64 * 4)
            }
        }
    }
}

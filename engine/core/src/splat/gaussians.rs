//! Gaussian parameters, on the host and on the GPU, in the same
//! structure-of-arrays layout.

use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};

use super::{HostGaussians, QUERY_DIM};

/// The fields of [`HostGaussians`] as GPU buffers, for a fixed capacity.
/// Used both for parameters and for their gradients.
///
/// ```no_run
/// use latentam_gpu::{Context, ContextOptions};
/// use latentam_core::splat::{GaussianBuffers, HostGaussians};
///
/// let ctx = Context::new(ContextOptions::default())?;
/// let params = GaussianBuffers::new(&ctx, "gaussians", 10_000)?;
/// let grads = GaussianBuffers::new(&ctx, "grads", params.capacity())?;
/// params.upload(&ctx, 0, &HostGaussians::zeros(100))?;
/// assert_eq!(params.download(&ctx, 100)?.len()?, 100);
/// # Ok::<(), latentam_core::Error>(())
/// ```
pub struct GaussianBuffers {
    capacity: u64,
    /// 3 floats per Gaussian.
    pub means: Buffer,
    /// 3 floats per Gaussian.
    pub log_scales: Buffer,
    /// 4 floats per Gaussian.
    pub quats: Buffer,
    /// 3 floats per Gaussian.
    pub colors: Buffer,
    /// 1 float per Gaussian.
    pub opacity_logits: Buffer,
    /// [`QUERY_DIM`] floats per Gaussian.
    pub queries: Buffer,
}

/// Floats per Gaussian in each field, in field order.
/// Floats per Gaussian in each field buffer, in [`GaussianBuffers::fields`]
/// order.
pub const FIELD_WIDTHS: [u64; 6] = [3, 3, 4, 3, 1, QUERY_DIM as u64];

/// Bytes of GPU memory one Gaussian's parameters take.
pub const GAUSSIAN_BYTES: u64 = (3 + 3 + 4 + 3 + 1 + QUERY_DIM as u64) * 4;

impl GaussianBuffers {
    /// Allocates room for `capacity` Gaussians; buffer names are
    /// `{prefix}/means` etc. (the prefix is the memory-report category).
    pub fn new(ctx: &Context, prefix: &str, capacity: u64) -> Result<Self> {
        let c = capacity.max(1);
        let mk = |field: &str, w: u64| Buffer::device(ctx, &format!("{prefix}/{field}"), c * w * 4);
        Ok(Self {
            capacity,
            means: mk("means", 3)?,
            log_scales: mk("log_scales", 3)?,
            quats: mk("quats", 4)?,
            colors: mk("colors", 3)?,
            opacity_logits: mk("opacity_logits", 1)?,
            queries: mk("queries", QUERY_DIM as u64)?,
        })
    }

    /// How many Gaussians fit.
    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// The six buffers, in field order.
    pub fn fields(&self) -> [&Buffer; 6] {
        [
            &self.means,
            &self.log_scales,
            &self.quats,
            &self.colors,
            &self.opacity_logits,
            &self.queries,
        ]
    }

    /// Records a fill of every field with the bit pattern `bits` (0 zeroes
    /// them; tests poison outputs with a NaN pattern).
    pub fn record_fill<'a>(&'a self, rec: &mut Recorder<'a>, bits: u32) {
        for b in self.fields() {
            rec.fill_u32(b, bits);
        }
    }

    /// Uploads `host` to slots `first..first + host.len()` and waits.
    pub fn upload(&self, ctx: &Context, first: u64, host: &HostGaussians) -> Result<()> {
        let mut rec = ctx.recorder()?;
        self.record_upload(&mut rec, first, host)?;
        rec.submit()?.wait()
    }

    /// Records an upload of `host` to slots `first..first + host.len()`
    /// (through staging buffers, on whichever queue `rec` records for).
    pub fn record_upload<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        first: u64,
        host: &HostGaussians,
    ) -> Result<()> {
        let n = host.len()? as u64;
        if first + n > self.capacity {
            return Err(Error::bad_input(
                "Gaussians to upload",
                format!(
                    "uploading {n} Gaussians at slot {first} exceeds the capacity {}",
                    self.capacity
                ),
            ));
        }
        let data: [&[f32]; 6] = [
            bytemuck::cast_slice(&host.means),
            bytemuck::cast_slice(&host.log_scales),
            bytemuck::cast_slice(&host.quats),
            bytemuck::cast_slice(&host.colors),
            &host.opacity_logits,
            bytemuck::cast_slice(&host.queries),
        ];
        for ((buf, w), d) in self.fields().into_iter().zip(FIELD_WIDTHS).zip(data) {
            if !d.is_empty() {
                rec.upload(buf, first * w * 4, d)?;
            }
        }
        Ok(())
    }

    /// Downloads slots `0..count` and waits.
    pub fn download(&self, ctx: &Context, count: u64) -> Result<HostGaussians> {
        let mut rec = ctx.recorder()?;
        let pending = self.record_download(&mut rec, count)?;
        rec.submit()?.wait()?;
        pending.read()
    }

    /// Records a download of slots `0..count`; read it with
    /// [`GaussianReadback::read`] once the submission has completed.
    pub fn record_download<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        count: u64,
    ) -> Result<GaussianReadback> {
        if count > self.capacity {
            return Err(Error::bad_input(
                "Gaussians to download",
                format!(
                    "downloading {count} Gaussians from buffers of capacity {}",
                    self.capacity
                ),
            ));
        }
        let mut reads = Vec::new();
        if count > 0 {
            for (buf, w) in self.fields().into_iter().zip(FIELD_WIDTHS) {
                reads.push(rec.download(buf, 0, count * w * 4)?);
            }
        }
        Ok(GaussianReadback { reads })
    }
}

/// A recorded download of Gaussians (see
/// [`GaussianBuffers::record_download`]).
///
/// ```no_run
/// # fn f(ctx: &latentam_gpu::Context, params: &latentam_core::splat::GaussianBuffers) -> latentam_core::Result<()> {
/// let mut rec = ctx.recorder()?;
/// let pending = params.record_download(&mut rec, 100)?;
/// rec.submit()?.wait()?;
/// let host = pending.read()?;
/// assert_eq!(host.means.len(), 100);
/// # Ok(())
/// # }
/// ```
pub struct GaussianReadback {
    reads: Vec<latentam_gpu::Readback>,
}

impl GaussianReadback {
    /// The downloaded Gaussians; errors if the submission has not completed.
    pub fn read(&self) -> Result<HostGaussians> {
        if self.reads.is_empty() {
            return Ok(HostGaussians::default());
        }
        // One copy per field, straight out of the mapped staging memory.
        Ok(HostGaussians {
            means: self.reads[0].read()?,
            log_scales: self.reads[1].read()?,
            quats: self.reads[2].read()?,
            colors: self.reads[3].read()?,
            opacity_logits: self.reads[4].read()?,
            queries: self.reads[5].read()?,
        })
    }
}

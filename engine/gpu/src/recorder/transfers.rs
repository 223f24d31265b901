//! Copies, fills, uploads and downloads recorded beside the kernels, with
//! the same hazard tracking.

use super::*;

impl<'a> Recorder<'a> {
    pub(super) fn copy_raw(&mut self, src: &Buffer, dst: &Buffer, region: vk::BufferCopy) {
        self.copy_raw_regions(src, dst, &[region]);
    }

    pub(super) fn copy_raw_regions(
        &mut self,
        src: &Buffer,
        dst: &Buffer,
        regions: &[vk::BufferCopy],
    ) {
        self.count_copy(src, dst, regions.iter().map(|r| r.size).sum());
        let (src, dst) = (src.raw, dst.raw);
        self.track(&[src], &[dst]);
        let start = self.timestamp(vk::PipelineStageFlags::TRANSFER);
        // SAFETY: recording a copy between live buffers with checked ranges.
        unsafe { self.dev.raw.cmd_copy_buffer(self.cmd, src, dst, regions) };
        let end = self.timestamp(vk::PipelineStageFlags::TRANSFER);
        if let (Some(s), Some(e)) = (start, end) {
            self.labels.push(("copy", s, e));
        }
    }

    /// Counts a copy in [`Context::gpu_work`]: between device buffers it
    /// reads and writes device memory; to or from staging it crosses
    /// between host and device.
    fn count_copy(&mut self, src: &Buffer, dst: &Buffer, bytes: u64) {
        let work = &self.dev.work;
        match (
            src.kind() == BufferKind::Device,
            dst.kind() == BufferKind::Device,
        ) {
            (true, true) => work.recorded(
                "copy",
                Some(latentam_shaders::Work {
                    flops: 0.0,
                    bytes: 2.0 * bytes as f64,
                }),
            ),
            (false, true) => {
                work.uploaded(bytes);
                self.dev.calls.uploaded(bytes);
            }
            (true, false) => {
                work.downloaded(bytes);
                self.dev.calls.downloaded(bytes);
            }
            (false, false) => {}
        }
    }

    fn count_fill(&mut self, bytes: u64) {
        let written = latentam_shaders::Work {
            flops: 0.0,
            bytes: bytes as f64,
        };
        self.dev.work.recorded("fill", Some(written));
    }

    /// Copies `bytes` bytes between device buffers.
    pub fn copy(
        &mut self,
        src: &'a Buffer,
        src_offset: u64,
        dst: &'a Buffer,
        dst_offset: u64,
        bytes: u64,
    ) -> Result<()> {
        if src_offset + bytes > src.bytes() || dst_offset + bytes > dst.bytes() {
            return Err(Error::bad_input(
                "copy",
                format!(
                    "{bytes} bytes from `{}`+{src_offset} to `{}`+{dst_offset} is out of range",
                    src.name(),
                    dst.name()
                ),
            ));
        }
        if bytes == 0 {
            return Ok(());
        }
        self.copy_raw(
            src,
            dst,
            vk::BufferCopy {
                src_offset,
                dst_offset,
                size: bytes,
            },
        );
        Ok(())
    }

    /// Copies many `(src_offset, dst_offset, bytes)` regions from `src` to
    /// `dst` in one command: they run in no particular order, so no
    /// destination may overlap another region (checked, since Vulkan
    /// leaves it undefined).
    pub fn copy_regions(
        &mut self,
        src: &'a Buffer,
        dst: &'a Buffer,
        regions: &[(u64, u64, u64)],
    ) -> Result<()> {
        let mut spans: Vec<(u64, u64, bool)> = Vec::with_capacity(regions.len() * 2);
        for &(s, d, n) in regions {
            if s + n > src.bytes() || d + n > dst.bytes() {
                return Err(Error::bad_input(
                    "copy region",
                    format!(
                        "{n} bytes from `{}`+{s} to `{}`+{d} is out of range",
                        src.name(),
                        dst.name()
                    ),
                ));
            }
            spans.push((d, d + n, true));
            if src.raw == dst.raw {
                spans.push((s, s + n, false));
            }
        }
        spans.sort_unstable();
        for w in spans.windows(2) {
            if w[1].0 < w[0].1 && (w[0].2 || w[1].2) {
                return Err(Error::bad_input(
                    "copy regions",
                    format!(
                        "those into `{}` overlap (bytes {}..{} and {}..{})",
                        dst.name(),
                        w[0].0,
                        w[0].1,
                        w[1].0,
                        w[1].1
                    ),
                ));
            }
        }
        let regions: Vec<vk::BufferCopy> = regions
            .iter()
            .filter(|r| r.2 > 0)
            .map(|&(src_offset, dst_offset, size)| vk::BufferCopy {
                src_offset,
                dst_offset,
                size,
            })
            .collect();
        if !regions.is_empty() {
            self.copy_raw_regions(src, dst, &regions);
        }
        Ok(())
    }

    /// Fills a device buffer with a repeated 32-bit pattern (e.g. to poison
    /// outputs before a test dispatch, or to zero accumulators).
    pub fn fill_u32(&mut self, buf: &'a Buffer, value: u32) {
        self.count_fill(buf.bytes());
        self.track(&[], &[buf.raw]);
        // SAFETY: whole-buffer fill of a live buffer.
        unsafe {
            self.dev
                .raw
                .cmd_fill_buffer(self.cmd, buf.raw, 0, vk::WHOLE_SIZE, value)
        };
    }

    /// Fills `bytes` bytes of `buf` from byte `offset` with `value` (both
    /// multiples of 4; allowed on the transfer queue).
    pub fn fill_range_u32(
        &mut self,
        buf: &'a Buffer,
        offset: u64,
        bytes: u64,
        value: u32,
    ) -> Result<()> {
        if !offset.is_multiple_of(4) || !bytes.is_multiple_of(4) || offset + bytes > buf.bytes() {
            return Err(Error::bad_input(
                "fill",
                format!(
                    "{bytes} bytes at {offset} in a {}-byte buffer (multiples of 4 within it)",
                    buf.bytes()
                ),
            ));
        }
        if bytes == 0 {
            return Ok(());
        }
        self.count_fill(bytes);
        self.track(&[], &[buf.raw]);
        // SAFETY: range checked against the live buffer above.
        unsafe {
            self.dev
                .raw
                .cmd_fill_buffer(self.cmd, buf.raw, offset, bytes, value)
        };
        Ok(())
    }

    /// Records an upload of `data` to byte `offset` of `dst` through a fresh
    /// staging buffer.
    pub fn upload<T: bytemuck::Pod>(
        &mut self,
        dst: &'a Buffer,
        offset: u64,
        data: &[T],
    ) -> Result<()> {
        let bytes = bytemuck::cast_slice::<T, u8>(data);
        if offset + bytes.len() as u64 > dst.bytes() {
            return Err(Error::bad_input(
                "upload",
                format!(
                    "{} bytes at offset {offset} overflow `{}` ({} bytes)",
                    bytes.len(),
                    dst.name(),
                    dst.bytes()
                ),
            ));
        }
        if bytes.is_empty() {
            return Ok(());
        }
        let ctx = Context {
            dev: self.dev.clone(),
        };
        let mut staging = Buffer::new(
            &ctx,
            &format!("staging/{}", dst.name()),
            bytes.len() as u64,
            BufferKind::Upload,
        )?;
        staging.mapped_mut().copy_from_slice(bytes);
        self.copy_raw(
            &staging,
            dst,
            vk::BufferCopy {
                src_offset: 0,
                dst_offset: offset,
                size: bytes.len() as u64,
            },
        );
        self.keep.push(Arc::new(staging));
        Ok(())
    }

    /// Records an upload of several parts, each `(destination, byte
    /// offset, bytes)`, through one staging buffer that packs them one
    /// after another: one contiguous range crosses the host link, then a
    /// copy per part. Each part's length must be a multiple of 4 (the
    /// parts stay 4-byte aligned in staging).
    ///
    /// ```no_run
    /// # use latentam_gpu::*;
    /// # fn f(ctx: &Context, means: &Buffer, colors: &Buffer) -> latentam_gpu::Result<()> {
    /// let (xyz, rgb) = ([0.0f32; 6], [1.0f32; 6]); // two rows of each
    /// let mut rec = ctx.recorder()?;
    /// rec.upload_packed(&[
    ///     (means, 0, bytemuck::cast_slice(&xyz)),
    ///     (colors, 0, bytemuck::cast_slice(&rgb)),
    /// ])?;
    /// rec.submit()?.wait()?;
    /// # Ok(())
    /// # }
    /// ```
    pub fn upload_packed(&mut self, parts: &[(&'a Buffer, u64, &[u8])]) -> Result<()> {
        let mut total = 0u64;
        for (dst, offset, bytes) in parts {
            let n = bytes.len() as u64;
            if offset + n > dst.bytes() || !n.is_multiple_of(4) {
                return Err(Error::bad_input(
                    "upload",
                    format!(
                        "{n} bytes at offset {offset} into `{}` ({} bytes): past its end, \
                         or not whole 32-bit words",
                        dst.name(),
                        dst.bytes()
                    ),
                ));
            }
            total += n;
        }
        if total == 0 {
            return Ok(());
        }
        let ctx = Context {
            dev: self.dev.clone(),
        };
        let mut staging = Buffer::new(&ctx, "staging/packed", total, BufferKind::Upload)?;
        let mut at = 0u64;
        let mapped = staging.mapped_mut();
        for (_, _, bytes) in parts {
            mapped[at as usize..at as usize + bytes.len()].copy_from_slice(bytes);
            at += bytes.len() as u64;
        }
        let mut at = 0u64;
        for (dst, offset, bytes) in parts {
            let size = bytes.len() as u64;
            if size > 0 {
                self.copy_raw(
                    &staging,
                    dst,
                    vk::BufferCopy {
                        src_offset: at,
                        dst_offset: *offset,
                        size,
                    },
                );
            }
            at += size;
        }
        self.keep.push(Arc::new(staging));
        Ok(())
    }

    /// Records a copy of `bytes` bytes at `offset` of `src` into a staging
    /// buffer; read it with [`Readback::read`] after the submission completes.
    pub fn download(&mut self, src: &'a Buffer, offset: u64, bytes: u64) -> Result<Readback> {
        if offset + bytes > src.bytes() {
            return Err(Error::bad_input(
                "download",
                format!(
                    "{bytes} bytes at offset {offset} overflow `{}` ({} bytes)",
                    src.name(),
                    src.bytes()
                ),
            ));
        }
        let ctx = Context {
            dev: self.dev.clone(),
        };
        let staging = Arc::new(Buffer::new(
            &ctx,
            &format!("staging/{}", src.name()),
            bytes,
            BufferKind::Readback,
        )?);
        if bytes > 0 {
            self.copy_raw(
                src,
                &staging,
                vk::BufferCopy {
                    src_offset: offset,
                    dst_offset: 0,
                    size: bytes,
                },
            );
        }
        self.keep.push(staging.clone());
        self.host_reads = true;
        // Not readable until the submission sets the value it signals.
        let after = Arc::new(AtomicU64::new(u64::MAX));
        self.readbacks.push(after.clone());
        Ok(Readback {
            staging,
            transfer: self.transfer,
            after,
        })
    }
}

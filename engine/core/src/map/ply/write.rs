//! Writing a map as a PLY file.

use std::collections::HashSet;
use std::io::Write;
use std::path::Path;

use super::format::*;
use crate::map::Gaussian;
use crate::splat::QUERY_DIM;
use latentam_base::files::{write_atomically, write_atomically_with};
use latentam_base::{Error, Result};

/// Writes `gaussians` to `path` as a binary little-endian PLY in the Inria
/// 3DGS layout (see the module documentation), followed by the `extra`
/// per-Gaussian float properties in the order given.
///
/// Each extra slice must have one value per Gaussian, and its name must be
/// a plain token (ASCII graphic characters, no spaces), distinct from the
/// other extras and from the standard property names; otherwise
/// [`Error::BadInput`] is returned before any file is touched.
///
/// The write is atomic: the data goes to `<path>.partial` next to `path`,
/// is flushed and synced, and is then renamed over `path`, so a reader
/// never sees half a map, and a crash leaves any previous file intact.
pub fn write_ply(path: &Path, gaussians: &[Gaussian], extra: &[(&str, &[f32])]) -> Result<()> {
    write_ply_as(path, gaussians, extra, true)
}

/// [`write_ply`] without the `latent_*` properties: for a map built
/// without embeddings, whose queries mean nothing.
pub fn write_ply_without_latents(
    path: &Path,
    gaussians: &[Gaussian],
    extra: &[(&str, &[f32])],
) -> Result<()> {
    write_ply_as(path, gaussians, extra, false)
}

/// The map's PLY as the engine exports it: [`write_ply`] when the map has
/// embeddings, [`write_ply_without_latents`] when it has none (its
/// queries mean nothing then).
pub fn write_map_ply(path: &Path, gaussians: &[Gaussian], has_embeddings: bool) -> Result<()> {
    write_ply_as(path, gaussians, &[], has_embeddings)
}

/// [`write_map_ply`] of a map of `count` Gaussians that `visit` hands
/// over a chunk at a time (a map larger than memory, read from disk as it
/// is written). Handing over another number of Gaussians than `count`, or
/// an error from `visit`, leaves no file and `path` as it was.
pub fn write_map_ply_streamed(
    path: &Path,
    count: usize,
    has_embeddings: bool,
    visit: impl FnOnce(&mut dyn FnMut(&[Gaussian]) -> Result<()>) -> Result<()>,
) -> Result<()> {
    let header = header_text(count, has_embeddings, std::iter::empty());
    write_atomically_with(path, |out| {
        let io = |source| Error::Io {
            path: path.to_path_buf(),
            source,
        };
        out.write_all(header.as_bytes()).map_err(io)?;
        let mut rows: Vec<f32> = Vec::new();
        let mut seen = 0usize;
        visit(&mut |gaussians| {
            seen += gaussians.len();
            for chunk in gaussians.chunks(ROWS_PER_CHUNK) {
                rows.clear();
                for g in chunk {
                    push_row(&mut rows, g, has_embeddings);
                }
                write_rows(out, &mut rows).map_err(io)?;
            }
            Ok(())
        })?;
        if seen != count {
            return Err(Error::bad_input(
                path.display().to_string(),
                format!("{seen} Gaussians written for a header of {count}"),
            ));
        }
        Ok(())
    })
}

/// Writes `rows` (f32 values) as little-endian bytes, swapping them in
/// place first on a big-endian machine.
fn write_rows(out: &mut impl Write, rows: &mut [f32]) -> std::io::Result<()> {
    if cfg!(target_endian = "big") {
        for v in rows.iter_mut() {
            *v = f32::from_bits(v.to_bits().swap_bytes());
        }
    }
    out.write_all(bytemuck::cast_slice(rows))
}

/// A quaternion scaled to unit length (computed in f64); the identity for
/// one of zero or non-finite length.
pub fn unit_quat(q: [f32; 4]) -> [f32; 4] {
    let n = q.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>().sqrt();
    if n > 0.0 && n.is_finite() {
        q.map(|v| (f64::from(v) / n) as f32)
    } else {
        [1.0, 0.0, 0.0, 0.0]
    }
}

pub(super) fn write_ply_as(
    path: &Path,
    gaussians: &[Gaussian],
    extra: &[(&str, &[f32])],
    latents: bool,
) -> Result<()> {
    validate_extra(gaussians.len(), extra)?;
    let header = header_text(
        gaussians.len(),
        latents,
        extra.iter().map(|(name, _)| *name),
    );
    write_atomically(path, |out| {
        out.write_all(header.as_bytes())?;
        let row_floats = BASE_PROPERTIES.len() + if latents { QUERY_DIM } else { 0 } + extra.len();
        let mut rows: Vec<f32> = Vec::with_capacity(ROWS_PER_CHUNK * row_floats);
        for (chunk_index, chunk) in gaussians.chunks(ROWS_PER_CHUNK).enumerate() {
            rows.clear();
            let first = chunk_index * ROWS_PER_CHUNK;
            for (i, g) in chunk.iter().enumerate() {
                push_row(&mut rows, g, latents);
                rows.extend(extra.iter().map(|(_, values)| values[first + i]));
            }
            write_rows(out, &mut rows)?;
        }
        Ok(())
    })
}

pub(super) fn validate_extra(count: usize, extra: &[(&str, &[f32])]) -> Result<()> {
    let mut seen = HashSet::new();
    for (name, values) in extra {
        if name.is_empty() || !name.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(Error::bad_input(
                format!("PLY property name {name:?}"),
                "must be non-empty ASCII without spaces",
            ));
        }
        if is_reserved(name) {
            return Err(Error::bad_input(
                format!("PLY property name {name:?}"),
                "clashes with a standard property (or the reserved latent_* names)",
            ));
        }
        if !seen.insert(*name) {
            return Err(Error::bad_input(
                format!("PLY property name {name:?}"),
                "given twice",
            ));
        }
        if values.len() != count {
            return Err(Error::bad_input(
                format!("PLY property {name:?}"),
                format!("{} values for {count} Gaussians", values.len()),
            ));
        }
    }
    Ok(())
}

pub(super) fn header_text<'a>(
    count: usize,
    latents: bool,
    extra: impl Iterator<Item = &'a str>,
) -> String {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\n");
    h += &format!(
        "comment written by latentam {}\n",
        env!("CARGO_PKG_VERSION")
    );
    if latents {
        h += &format!("comment latent_dim {QUERY_DIM}\n");
    }
    h += &format!("element vertex {count}\n");
    let latents = (0..if latents { QUERY_DIM } else { 0 }).map(|i| format!("latent_{i}"));
    let names = BASE_PROPERTIES
        .iter()
        .map(|s| s.to_string())
        .chain(latents)
        .chain(extra.map(str::to_owned));
    for name in names {
        h += &format!("property float {name}\n");
    }
    h += "end_header\n";
    h
}

pub(super) fn push_row(rows: &mut Vec<f32>, g: &Gaussian, latents: bool) {
    let dc = g.color.map(|c| ((f64::from(c) - 0.5) / SH_C0) as f32);
    rows.extend_from_slice(&g.mean);
    rows.extend_from_slice(&[0.0; 3]);
    rows.extend_from_slice(&dc);
    rows.push(g.opacity_logit);
    rows.extend_from_slice(&g.log_scale);
    rows.extend_from_slice(&unit_quat(g.quat));
    if latents {
        rows.extend_from_slice(&g.query);
    }
}

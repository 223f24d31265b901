//! Reading a PLY file by property name.

use std::collections::HashSet;
use std::io::{BufReader, Read};
use std::path::Path;

use bytemuck::Zeroable;

use super::format::*;
use super::header::*;
use crate::map::Gaussian;
use crate::splat::QUERY_DIM;
use latentam_base::{Error, Result};

/// A Gaussian map read from a PLY file.
///
/// ```no_run
/// use latentam_core::map::read_ply;
///
/// let map = read_ply("runs/kitchen/map.ply".as_ref())?;
/// let opaque = map.gaussians.iter().filter(|g| g.opacity_logit > 0.0).count();
/// println!("{} Gaussians, {opaque} more than half opaque", map.gaussians.len());
/// for (name, values) in &map.extra {
///     println!("extra property {name}: {} values", values.len());
/// }
/// # Ok::<(), latentam_core::Error>(())
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PlyMap {
    /// The Gaussians, in file order.
    pub gaussians: Vec<Gaussian>,
    /// Every vertex property that is not one of the standard ones, by
    /// name, in file order, one value per Gaussian.
    pub extra: Vec<(String, Vec<f32>)>,
}

/// Reads a Gaussian map from a binary little-endian PLY file with one
/// `vertex` element, matching properties by name (see the module
/// documentation for the conventions).
///
/// `x y z`, `f_dc_0..2`, `opacity`, `scale_0..2` and `rot_0..3` are
/// required; `latent_*`, when present, must be exactly
/// `latent_0..latent_31` (absent, the queries are zero); `nx ny nz` are
/// ignored; every other property is returned in [`PlyMap::extra`]. Any
/// numeric scalar type is accepted and converted to `f32`.
///
/// Errors: [`Error::Io`] when the file cannot be read,
/// [`Error::Damaged`] (naming the file) when it is not a PLY file this
/// reader supports or is damaged.
pub fn read_ply(path: &Path) -> Result<PlyMap> {
    let io_err = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let bad = |message: String| Error::damaged(path, message);

    let file = latentam_io::open_input(path).map_err(io_err)?;
    let file_len = file.metadata().map_err(io_err)?.len();
    let mut reader = BufReader::with_capacity(1 << 20, file);
    let (header, header_len) = read_header(&mut reader).map_err(|e| match e {
        HeaderError::Io(source) => io_err(source),
        HeaderError::Format(message) => bad(message),
    })?;
    let layout = Layout::new(&header).map_err(bad)?;

    let count = header.count;
    let body_len = file_len.saturating_sub(header_len);
    let expected = count.checked_mul(layout.row_bytes as u64);
    match expected {
        Some(expected) if expected == body_len => {}
        Some(expected) if expected > body_len => {
            return Err(bad(format!(
                "truncated: {count} vertices of {} bytes need {expected} bytes after the \
                 header, the file has {body_len}",
                layout.row_bytes
            )))
        }
        Some(expected) => {
            return Err(bad(format!(
                "{} bytes after the {count} vertices the header declares",
                body_len - expected
            )))
        }
        None => return Err(bad(format!("vertex count {count} is impossibly large"))),
    }
    // The body length matches the file, so the count is bounded by what the
    // file can hold and allocating for it is safe.
    let count = count as usize;

    let mut gaussians = vec![Gaussian::zeroed(); count];
    let mut extra: Vec<(String, Vec<f32>)> = layout
        .extra_names
        .iter()
        .map(|name| (name.clone(), vec![0.0; count]))
        .collect();
    let mut buf = vec![0u8; ROWS_PER_CHUNK.min(count.max(1)) * layout.row_bytes];
    let mut done = 0;
    while done < count {
        let rows = (count - done).min(ROWS_PER_CHUNK);
        let bytes = &mut buf[..rows * layout.row_bytes];
        reader.read_exact(bytes).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                bad("truncated while reading vertices (was the file changed?)".to_owned())
            } else {
                io_err(e)
            }
        })?;
        for (r, row) in bytes.chunks_exact(layout.row_bytes).enumerate() {
            let g = &mut gaussians[done + r];
            for field in &layout.fields {
                let v = field.ty.read(&row[field.offset..]);
                match field.target {
                    Target::Mean(i) => g.mean[i] = v,
                    Target::Dc(i) => g.color[i] = (0.5 + SH_C0 * f64::from(v)) as f32,
                    Target::Opacity => g.opacity_logit = v,
                    Target::Scale(i) => g.log_scale[i] = v,
                    Target::Rot(i) => g.quat[i] = v,
                    Target::Latent(i) => g.query[i] = v,
                    Target::Extra(i) => extra[i].1[done + r] = v,
                    Target::Ignored => {}
                }
            }
        }
        done += rows;
    }
    Ok(PlyMap { gaussians, extra })
}

/// Where a property's value goes.
#[derive(Clone, Copy, Debug)]
pub(super) enum Target {
    Mean(usize),
    Dc(usize),
    Opacity,
    Scale(usize),
    Rot(usize),
    Latent(usize),
    Extra(usize),
    Ignored,
}

pub(super) struct Field {
    pub(super) offset: usize,
    pub(super) ty: ScalarType,
    pub(super) target: Target,
}

/// How to decode one vertex row.
pub(super) struct Layout {
    pub(super) row_bytes: usize,
    pub(super) fields: Vec<Field>,
    pub(super) extra_names: Vec<String>,
}

impl Layout {
    pub(super) fn new(header: &Header) -> std::result::Result<Self, String> {
        let mut fields = Vec::with_capacity(header.properties.len());
        let mut extra_names = Vec::new();
        let mut seen = HashSet::new();
        let mut latents = 0;
        let mut offset = 0;
        for (ty, name) in &header.properties {
            if !seen.insert(name.as_str()) {
                return Err(format!("vertex property `{name}` appears twice"));
            }
            let target = match name.as_str() {
                "x" => Target::Mean(0),
                "y" => Target::Mean(1),
                "z" => Target::Mean(2),
                "nx" | "ny" | "nz" => Target::Ignored,
                "f_dc_0" => Target::Dc(0),
                "f_dc_1" => Target::Dc(1),
                "f_dc_2" => Target::Dc(2),
                "opacity" => Target::Opacity,
                "scale_0" => Target::Scale(0),
                "scale_1" => Target::Scale(1),
                "scale_2" => Target::Scale(2),
                "rot_0" => Target::Rot(0),
                "rot_1" => Target::Rot(1),
                "rot_2" => Target::Rot(2),
                "rot_3" => Target::Rot(3),
                _ if name.starts_with("latent_") => match latent_index(name) {
                    Some(i) if i < QUERY_DIM => {
                        latents += 1;
                        Target::Latent(i)
                    }
                    _ => {
                        return Err(format!(
                            "vertex property `{name}`: latent properties must be exactly \
                             latent_0..latent_{}",
                            QUERY_DIM - 1
                        ))
                    }
                },
                _ => {
                    extra_names.push(name.clone());
                    Target::Extra(extra_names.len() - 1)
                }
            };
            fields.push(Field {
                offset,
                ty: *ty,
                target,
            });
            offset += ty.size();
        }
        let missing: Vec<&str> = BASE_PROPERTIES
            .iter()
            .copied()
            .filter(|name| !matches!(*name, "nx" | "ny" | "nz") && !seen.contains(name))
            .collect();
        if !missing.is_empty() {
            return Err(format!(
                "missing vertex properties: {}; not a 3D Gaussian splat file?",
                missing.join(" ")
            ));
        }
        if latents != 0 && latents != QUERY_DIM {
            return Err(format!(
                "{latents} latent properties; expected none or latent_0..latent_{}",
                QUERY_DIM - 1
            ));
        }
        Ok(Layout {
            row_bytes: offset,
            fields,
            extra_names,
        })
    }
}

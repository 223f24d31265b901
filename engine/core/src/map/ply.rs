//! Gaussian maps as PLY files in the layout of the Inria 3D Gaussian
//! Splatting reference code, so the map opens in common splat viewers
//! (SuperSplat, the Inria viewer, …) as it is.
//!
//! The file is `binary_little_endian 1.0` with one `vertex` element and one
//! `float` property per parameter, in this order:
//!
//! | property | value | why |
//! |---|---|---|
//! | `x y z` | [`Gaussian::mean`] | |
//! | `nx ny nz` | 0 | the Inria layout has them; viewers expect the names |
//! | `f_dc_0..2` | `(color − 0.5) / C0` | degree-0 spherical harmonics, which viewers turn back into `0.5 + C0 · f_dc`, so they show the engine's view-independent colour; `C0 = 1 / (2√π)` |
//! | `opacity` | [`Gaussian::opacity_logit`] | viewers apply the sigmoid |
//! | `scale_0..2` | [`Gaussian::log_scale`] | viewers apply `exp` |
//! | `rot_0..3` | [`Gaussian::quat`] normalised ([`unit_quat`]), as `w, x, y, z` | the Inria order; the engine keeps its quaternions unnormalised (it normalises when rendering), tools expect unit ones |
//! | `latent_0..31` | [`Gaussian::query`] | the engine's own; viewers ignore unknown properties; left out by [`write_ply_without_latents`] for maps without embeddings |
//!
//! followed by any extra per-Gaussian properties the caller names (a
//! relevance score, say), also `float`. Every value except the colour and
//! the rotation's length is stored bit for bit, so a map written and read
//! back renders and decodes exactly as before.
//!
//! The reader goes by property name, so it also takes files from other
//! tools: any property order, any numeric property type, unknown properties
//! kept in [`PlyMap::extra`], `latent_*` optional. What it does not take
//! (ASCII or big-endian bodies, list properties, elements other than
//! `vertex`) is rejected with an error naming the file and the problem;
//! damaged files are errors, never panics or huge allocations.

use std::collections::HashSet;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;

use bytemuck::Zeroable;

use super::Gaussian;
use crate::splat::QUERY_DIM;
use latentam_base::files::write_atomically;
use latentam_base::{Error, Result};

/// The degree-0 spherical-harmonic basis constant, `1 / (2√π)`.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;

/// Properties every Gaussian has, before the latent query.
const BASE_PROPERTIES: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Floats per Gaussian before any extra property (latents written).
#[cfg(test)]
const STANDARD_FLOATS: usize = BASE_PROPERTIES.len() + QUERY_DIM;

/// The longest header the reader accepts: far more than any real property
/// list, and a bound on how much of a non-PLY file is scanned for
/// `end_header`.
const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Rows converted per write or read call: large enough to amortise the
/// call, small enough to keep the staging buffer in cache-friendly sizes.
const ROWS_PER_CHUNK: usize = 4096;

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

/// Writes `gaussians` to `path` as a binary little-endian PLY in the Inria
/// 3DGS layout (see the module documentation), followed by the `extra`
/// per-Gaussian float properties in the order given.
///
/// Each extra slice must have one value per Gaussian, and its name must be
/// a plain token (ASCII graphic characters, no spaces), distinct from the
/// other extras and from the standard property names; otherwise
/// [`Error::InvalidArgument`] is returned before any file is touched.
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

fn write_ply_as(
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
            if cfg!(target_endian = "big") {
                for v in &mut rows {
                    *v = f32::from_bits(v.to_bits().swap_bytes());
                }
            }
            out.write_all(bytemuck::cast_slice(&rows))?;
        }
        Ok(())
    })
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
/// [`Error::InvalidArgument`] (with the path in the message) when it is not
/// a PLY file this reader supports or is damaged.
pub fn read_ply(path: &Path) -> Result<PlyMap> {
    let io_err = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let bad = |message: String| Error::InvalidArgument(format!("{}: {message}", path.display()));

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

fn validate_extra(count: usize, extra: &[(&str, &[f32])]) -> Result<()> {
    let mut seen = HashSet::new();
    for (name, values) in extra {
        if name.is_empty() || !name.bytes().all(|b| b.is_ascii_graphic()) {
            return Err(Error::InvalidArgument(format!(
                "PLY property name {name:?} must be non-empty ASCII without spaces"
            )));
        }
        if is_reserved(name) {
            return Err(Error::InvalidArgument(format!(
                "PLY property name {name:?} clashes with a standard property (or the \
                 reserved latent_* names)"
            )));
        }
        if !seen.insert(*name) {
            return Err(Error::InvalidArgument(format!(
                "PLY property name {name:?} given twice"
            )));
        }
        if values.len() != count {
            return Err(Error::InvalidArgument(format!(
                "PLY property {name:?} has {} values for {count} Gaussians",
                values.len()
            )));
        }
    }
    Ok(())
}

/// Names an extra property may not have: the standard ones, and every
/// `latent_*`, which the reader takes as part of the latent query.
fn is_reserved(name: &str) -> bool {
    BASE_PROPERTIES.contains(&name) || name.starts_with("latent_")
}

/// `Some(i)` for `latent_<i>` with a canonical decimal `i`.
fn latent_index(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("latent_")?;
    let canonical = !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit())
        && (digits == "0" || !digits.starts_with('0'));
    if !canonical {
        return None;
    }
    digits.parse().ok()
}

fn header_text<'a>(count: usize, latents: bool, extra: impl Iterator<Item = &'a str>) -> String {
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

fn push_row(rows: &mut Vec<f32>, g: &Gaussian, latents: bool) {
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

/// The parts of a header the reader uses.
struct Header {
    count: u64,
    properties: Vec<(ScalarType, String)>,
}

enum HeaderError {
    Io(std::io::Error),
    Format(String),
}

impl From<std::io::Error> for HeaderError {
    fn from(e: std::io::Error) -> Self {
        HeaderError::Io(e)
    }
}

/// Reads the header up to and including `end_header`; returns it and its
/// length in bytes.
fn read_header(reader: &mut impl BufRead) -> std::result::Result<(Header, u64), HeaderError> {
    let fail = |m: String| Err(HeaderError::Format(m));
    let mut limited = reader.take(MAX_HEADER_BYTES);
    let mut consumed = 0u64;
    let mut line = Vec::new();
    let mut format_seen = false;
    let mut vertex: Option<Header> = None;
    let mut line_no = 0;
    loop {
        line_no += 1;
        line.clear();
        let n = limited.read_until(b'\n', &mut line)?;
        consumed += n as u64;
        if line_no == 1 {
            if n == 0 {
                return fail("empty file, not a PLY file".to_owned());
            }
            if !matches!(line.as_slice(), b"ply\n" | b"ply\r\n") {
                return fail("does not start with the `ply` magic line".to_owned());
            }
            continue;
        }
        if line.last() != Some(&b'\n') {
            return fail(if consumed >= MAX_HEADER_BYTES {
                format!("no end_header in the first {MAX_HEADER_BYTES} bytes")
            } else {
                "no end_header before the end of the file".to_owned()
            });
        }
        let Ok(text) = std::str::from_utf8(&line) else {
            return fail(format!(
                "header line {line_no} is not text; not a PLY file?"
            ));
        };
        let text = text.trim_end_matches(['\n', '\r']);
        let mut words = text.split_ascii_whitespace();
        let keyword = words.next().unwrap_or("");
        let rest: Vec<&str> = words.collect();
        match keyword {
            "format" => {
                match rest.as_slice() {
                    ["binary_little_endian", "1.0"] => {}
                    [format @ ("ascii" | "binary_big_endian"), _] => {
                        return fail(format!(
                            "PLY format `{format}` is not supported; only \
                             binary_little_endian 1.0 is"
                        ))
                    }
                    _ => {
                        return fail(format!(
                            "header line {line_no}: unknown format line `{text}`; only \
                             `format binary_little_endian 1.0` is supported"
                        ))
                    }
                }
                format_seen = true;
            }
            "comment" | "obj_info" => {}
            "element" => {
                if !format_seen {
                    return fail(format!("header line {line_no}: element before format"));
                }
                let [name, count] = rest.as_slice() else {
                    return fail(format!("header line {line_no}: malformed `{text}`"));
                };
                if *name != "vertex" {
                    return fail(format!(
                        "element `{name}` is not supported; only a single `vertex` element is"
                    ));
                }
                if vertex.is_some() {
                    return fail("more than one vertex element".to_owned());
                }
                let Ok(count) = count.parse::<u64>() else {
                    return fail(format!("header line {line_no}: bad vertex count `{count}`"));
                };
                vertex = Some(Header {
                    count,
                    properties: Vec::new(),
                });
            }
            "property" => {
                let Some(element) = vertex.as_mut() else {
                    return fail(format!(
                        "header line {line_no}: property outside an element"
                    ));
                };
                match rest.as_slice() {
                    ["list", ..] => {
                        return fail(format!(
                            "header line {line_no}: list properties are not supported in \
                             vertices"
                        ))
                    }
                    [ty, name] => {
                        let Some(ty) = ScalarType::parse(ty) else {
                            return fail(format!(
                                "header line {line_no}: unknown property type `{ty}`"
                            ));
                        };
                        element.properties.push((ty, (*name).to_owned()));
                    }
                    _ => return fail(format!("header line {line_no}: malformed `{text}`")),
                }
            }
            "end_header" if rest.is_empty() => {
                if !format_seen {
                    return fail("no format line".to_owned());
                }
                let Some(vertex) = vertex else {
                    return fail("no vertex element".to_owned());
                };
                return Ok((vertex, consumed));
            }
            _ => {
                return fail(format!(
                    "header line {line_no}: unknown line `{}`",
                    text.chars().take(80).collect::<String>()
                ))
            }
        }
    }
}

/// A PLY scalar property type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// The little-endian value at the start of `b`, as `f32`.
    fn read(self, b: &[u8]) -> f32 {
        // `b` starts at the property's offset within a row, and
        // `Layout::new` makes the row long enough for every property's
        // size, so the first `N` bytes are there.
        fn arr<const N: usize>(b: &[u8]) -> [u8; N] {
            b[..N].try_into().expect("slice of N bytes")
        }
        match self {
            Self::I8 => f32::from(b[0] as i8),
            Self::U8 => f32::from(b[0]),
            Self::I16 => f32::from(i16::from_le_bytes(arr(b))),
            Self::U16 => f32::from(u16::from_le_bytes(arr(b))),
            Self::I32 => i32::from_le_bytes(arr(b)) as f32,
            Self::U32 => u32::from_le_bytes(arr(b)) as f32,
            Self::F32 => f32::from_le_bytes(arr(b)),
            Self::F64 => f64::from_le_bytes(arr(b)) as f32,
        }
    }
}

/// Where a property's value goes.
#[derive(Clone, Copy, Debug)]
enum Target {
    Mean(usize),
    Dc(usize),
    Opacity,
    Scale(usize),
    Rot(usize),
    Latent(usize),
    Extra(usize),
    Ignored,
}

struct Field {
    offset: usize,
    ty: ScalarType,
    target: Target,
}

/// How to decode one vertex row.
struct Layout {
    row_bytes: usize,
    fields: Vec<Field>,
    extra_names: Vec<String>,
}

impl Layout {
    fn new(header: &Header) -> std::result::Result<Self, String> {
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

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use latentam_base::files::partial_path;
    use latentam_base::files::testing::TempDir;

    fn random_gaussians(n: usize, seed: u64) -> Vec<Gaussian> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let mut g = Gaussian::zeroed();
                g.mean = std::array::from_fn(|_| rng.random_range(-10.0..10.0));
                g.log_scale = std::array::from_fn(|_| rng.random_range(-6.0..0.0));
                g.quat = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
                g.color = std::array::from_fn(|_| rng.random_range(0.0..1.0));
                g.opacity_logit = rng.random_range(-5.0..5.0);
                g.query = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
                g
            })
            .collect()
    }

    fn assert_same(a: &Gaussian, b: &Gaussian) {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&a.mean), bits(&b.mean));
        assert_eq!(bits(&a.log_scale), bits(&b.log_scale));
        assert_eq!(bits(&unit_quat(a.quat)), bits(&b.quat));
        assert_eq!(a.opacity_logit.to_bits(), b.opacity_logit.to_bits());
        assert_eq!(bits(&a.query), bits(&b.query));
        for (x, y) in a.color.iter().zip(&b.color) {
            assert!((x - y).abs() <= 1e-6, "colour {x} vs {y}");
        }
    }

    /// A header followed by `body`, written by hand.
    fn write_raw(path: &Path, header: &str, body: &[u8]) {
        let mut bytes = header.as_bytes().to_vec();
        bytes.extend_from_slice(body);
        std::fs::write(path, bytes).unwrap();
    }

    fn expect_error(path: &Path, needle: &str) {
        match read_ply(path) {
            Err(Error::InvalidArgument(m)) => {
                assert!(m.contains(&path.display().to_string()), "{m}");
                assert!(m.contains(needle), "{m:?} should mention {needle:?}");
            }
            other => panic!("expected a format error mentioning {needle:?}, got {other:?}"),
        }
    }

    #[test]
    fn round_trip_is_bit_exact_except_colour() {
        let dir = TempDir::new("ply");
        let path = dir.path().join("map.ply");
        // More than one chunk, and not a multiple of it.
        let gaussians = random_gaussians(ROWS_PER_CHUNK + 123, 1);
        let relevance: Vec<f32> = (0..gaussians.len()).map(|i| i as f32 * 0.25).collect();
        write_ply(&path, &gaussians, &[("relevance", &relevance)]).unwrap();
        assert!(!partial_path(&path).unwrap().exists());

        let map = read_ply(&path).unwrap();
        assert_eq!(map.gaussians.len(), gaussians.len());
        for (a, b) in gaussians.iter().zip(&map.gaussians) {
            assert_same(a, b);
        }
        assert_eq!(map.extra, vec![("relevance".to_owned(), relevance)]);

        // Overwriting replaces the file.
        write_ply(&path, &gaussians[..3], &[]).unwrap();
        let map = read_ply(&path).unwrap();
        assert_eq!(map.gaussians.len(), 3);
        assert!(map.extra.is_empty());
    }

    #[test]
    fn empty_map_round_trips() {
        let dir = TempDir::new("ply");
        let path = dir.path().join("empty.ply");
        write_ply(&path, &[], &[("score", &[])]).unwrap();
        let map = read_ply(&path).unwrap();
        assert!(map.gaussians.is_empty());
        assert_eq!(map.extra, vec![("score".to_owned(), vec![])]);
    }

    #[test]
    fn header_is_exact() {
        let dir = TempDir::new("ply");
        let path = dir.path().join("one.ply");
        let mut g = Gaussian::zeroed();
        g.color = [0.5, 0.5 + SH_C0 as f32, 0.5];
        g.quat = [1.0, 0.0, 0.0, 0.0];
        write_ply(&path, &[g], &[("relevance", &[0.75])]).unwrap();
        let bytes = std::fs::read(&path).unwrap();

        let mut expected = format!(
            "ply\nformat binary_little_endian 1.0\ncomment written by latentam {}\n\
             comment latent_dim 32\nelement vertex 1\n",
            env!("CARGO_PKG_VERSION")
        );
        for name in [
            "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
            "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ] {
            expected += &format!("property float {name}\n");
        }
        for i in 0..32 {
            expected += &format!("property float latent_{i}\n");
        }
        expected += "property float relevance\nend_header\n";
        assert_eq!(
            std::str::from_utf8(&bytes[..expected.len()]).unwrap(),
            expected
        );

        let body: &[u8] = &bytes[expected.len()..];
        assert_eq!(body.len(), (STANDARD_FLOATS + 1) * 4);
        let floats: Vec<f32> = body
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(floats[6], 0.0, "grey is f_dc 0");
        assert!((floats[7] - 1.0).abs() < 1e-6, "0.5 + C0 is f_dc 1");
        assert_eq!(floats[13..17], [1.0, 0.0, 0.0, 0.0], "rot is w x y z");
        assert_eq!(floats[STANDARD_FLOATS], 0.75);
    }

    #[test]
    fn rotations_are_written_unit_length_and_latents_only_when_asked() {
        let dir = TempDir::new("ply");
        let mut gs = random_gaussians(300, 9);
        gs[0].quat = [0.0; 4];
        gs[1].quat = [f32::NAN, 0.0, 0.0, 1.0];
        gs[2].quat = [3.0, 0.0, 4.0, 0.0];
        let path = dir.path().join("map.ply");
        write_ply(&path, &gs, &[]).unwrap();
        let back = read_ply(&path).unwrap().gaussians;
        for (g, b) in gs.iter().zip(&back) {
            let n: f64 = b
                .quat
                .iter()
                .map(|&v| f64::from(v).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!((n - 1.0).abs() < 1e-6, "{:?} -> {:?}", g.quat, b.quat);
        }
        assert_eq!(back[0].quat, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(back[1].quat, [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(back[2].quat, [0.6, 0.0, 0.8, 0.0]);
        // The same rotation: a direction rotated by either agrees.
        let rot =
            |q: [f32; 4]| glam::Quat::from_xyzw(q[1], q[2], q[3], q[0]).normalize() * glam::Vec3::X;
        for (g, b) in gs.iter().zip(&back).skip(3) {
            assert!((rot(g.quat) - rot(b.quat)).length() < 1e-5);
        }

        // Without latents: no latent_* property, queries read back as 0,
        // everything else as before.
        let path = dir.path().join("geometry.ply");
        write_ply_without_latents(&path, &gs, &[("score", &vec![0.5; 300])]).unwrap();
        let text = std::fs::read(&path).unwrap();
        let header = String::from_utf8_lossy(&text[..2048]);
        assert!(!header.contains("latent_"), "{header}");
        let map = read_ply(&path).unwrap();
        assert_eq!(map.extra[0].1, vec![0.5; 300]);
        for (g, b) in gs.iter().zip(&map.gaussians).skip(3) {
            assert_eq!(b.query, [0.0; QUERY_DIM]);
            assert_eq!((g.mean, g.log_scale), (b.mean, b.log_scale));
        }
    }

    #[test]
    fn reads_by_name_in_any_order_and_type() {
        let dir = TempDir::new("ply");
        let path = dir.path().join("shuffled.ply");
        let header = "ply\r\nformat binary_little_endian 1.0\r\ncomment by hand\r\n\
            obj_info nothing\r\nelement vertex 2\r\n\
            property float rot_3\r\nproperty float32 opacity\r\nproperty double x\r\n\
            property float confidence\r\nproperty float f_dc_2\r\nproperty float y\r\n\
            property float scale_2\r\nproperty float rot_0\r\nproperty float f_dc_0\r\n\
            property float scale_0\r\nproperty float z\r\nproperty float rot_1\r\n\
            property uchar label\r\nproperty float f_dc_1\r\nproperty float scale_1\r\n\
            property float rot_2\r\nend_header\r\n";
        let mut body = Vec::new();
        for v in 0..2u8 {
            let k = f32::from(v) + 1.0;
            let f = |body: &mut Vec<u8>, x: f32| body.extend_from_slice(&x.to_le_bytes());
            f(&mut body, 0.4 * k); // rot_3
            f(&mut body, -2.0 * k); // opacity
            body.extend_from_slice(&(1.5f64 * f64::from(k)).to_le_bytes()); // x
            f(&mut body, 0.9 * k); // confidence
            f(&mut body, 0.0); // f_dc_2
            f(&mut body, 2.5 * k); // y
            f(&mut body, -3.0 * k); // scale_2
            f(&mut body, 0.1 * k); // rot_0
            f(&mut body, 1.0); // f_dc_0
            f(&mut body, -k); // scale_0
            f(&mut body, 3.5 * k); // z
            f(&mut body, 0.2 * k); // rot_1
            body.push(7 + v); // label
            f(&mut body, -1.0); // f_dc_1
            f(&mut body, -2.0 * k); // scale_1
            f(&mut body, 0.3 * k); // rot_2
        }
        write_raw(&path, header, &body);

        let map = read_ply(&path).unwrap();
        assert_eq!(map.gaussians.len(), 2);
        for (v, g) in map.gaussians.iter().enumerate() {
            let k = v as f32 + 1.0;
            assert_eq!(g.mean, [1.5 * k, 2.5 * k, 3.5 * k]);
            assert_eq!(g.log_scale, [-k, -2.0 * k, -3.0 * k]);
            assert_eq!(g.quat, [0.1 * k, 0.2 * k, 0.3 * k, 0.4 * k]);
            assert_eq!(g.opacity_logit, -2.0 * k);
            let c0 = SH_C0 as f32;
            for (c, want) in g.color.iter().zip([0.5 + c0, 0.5 - c0, 0.5]) {
                assert!((c - want).abs() < 1e-6);
            }
            assert_eq!(g.query, [0.0; QUERY_DIM], "no latents: zero query");
        }
        assert_eq!(
            map.extra,
            vec![
                ("confidence".to_owned(), vec![0.9, 1.8]),
                ("label".to_owned(), vec![7.0, 8.0]),
            ]
        );
    }

    #[test]
    fn bad_files_are_errors() {
        let dir = TempDir::new("ply");
        let good = dir.path().join("good.ply");
        write_ply(&good, &random_gaussians(3, 2), &[]).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let header_len = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let header = std::str::from_utf8(&bytes[..header_len]).unwrap();
        let body = &bytes[header_len..];
        let path = dir.path().join("bad.ply");

        write_raw(&path, header, &body[..body.len() - 1]);
        expect_error(&path, "truncated");

        write_raw(&path, header, &[body, &[0]].concat());
        expect_error(&path, "1 bytes after");

        write_raw(
            &path,
            &header.replace("vertex 3\n", "vertex 1000000000000\n"),
            body,
        );
        expect_error(&path, "truncated");

        write_raw(
            &path,
            &header.replace("vertex 3\n", "vertex 18446744073709551615\n"),
            body,
        );
        expect_error(&path, "impossibly large");

        write_raw(&path, &header.replace("vertex 3", "vertex -3"), body);
        expect_error(&path, "bad vertex count");

        write_raw(
            &path,
            &header.replace("binary_little_endian", "ascii"),
            body,
        );
        expect_error(&path, "only binary_little_endian 1.0");

        write_raw(
            &path,
            &header.replace("binary_little_endian", "binary_big_endian"),
            body,
        );
        expect_error(&path, "not supported");

        write_raw(&path, &header.replace("endian 1.0", "endian 2.0"), body);
        expect_error(&path, "unknown format line");

        write_raw(&path, &header.replace("property float opacity\n", ""), body);
        expect_error(&path, "missing vertex properties: opacity");

        write_raw(&path, &header.replace("float rot_1", "float x"), body);
        expect_error(&path, "appears twice");

        write_raw(&path, &header.replace("latent_31", "latent_32"), body);
        expect_error(&path, "latent_0..latent_31");

        write_raw(
            &path,
            &header.replace("property float latent_31\n", ""),
            body,
        );
        expect_error(&path, "31 latent properties");

        write_raw(
            &path,
            &header.replace("float rot_1", "float64x rot_1"),
            body,
        );
        expect_error(&path, "unknown property type");

        write_raw(
            &path,
            &header.replace("float rot_1", "list uchar int rot_1"),
            body,
        );
        expect_error(&path, "list properties");

        let face = header.replace(
            "end_header",
            "element face 0\nproperty list uchar int i\nend_header",
        );
        write_raw(&path, &face, body);
        expect_error(&path, "element `face`");

        write_raw(&path, &header.replace("end_header\n", ""), &[]);
        expect_error(&path, "no end_header before the end");

        write_raw(&path, &header.replace("end_header\n", ""), body);
        expect_error(&path, "");

        write_raw(&path, &header.replace("end_header\n", "end_header"), &[]);
        expect_error(&path, "no end_header");

        write_raw(&path, &header.replace("comment", "remark"), body);
        expect_error(&path, "unknown line `remark");

        write_raw(&path, "", &[]);
        expect_error(&path, "empty file");

        write_raw(&path, "PK\u{3}\u{4}", &[0xff; 64]);
        expect_error(&path, "magic");

        write_raw(&path, "ply\n", &[0xff, 0xfe, b'\n']);
        expect_error(&path, "not text");

        write_raw(&path, "ply\n", &[b'x'; 1 << 21]);
        expect_error(&path, "no end_header in the first");

        write_raw(&path, "ply\nend_header\n", &[]);
        expect_error(&path, "no format line");

        write_raw(
            &path,
            "ply\nformat binary_little_endian 1.0\nend_header\n",
            &[],
        );
        expect_error(&path, "no vertex element");

        write_raw(
            &path,
            "ply\nformat binary_little_endian 1.0\nproperty float x\n",
            &[],
        );
        expect_error(&path, "property outside an element");

        assert!(matches!(
            read_ply(&dir.path().join("missing.ply")),
            Err(Error::Io { .. })
        ));
    }

    #[test]
    fn bad_extras_are_rejected_before_writing() {
        let dir = TempDir::new("ply");
        let path = dir.path().join("map.ply");
        let gaussians = random_gaussians(2, 3);
        let two = [1.0f32, 2.0];
        for extra in [
            vec![("relevance", &two[..1])],
            vec![("relevance", &two[..]), ("relevance", &two[..])],
            vec![("opacity", &two[..])],
            vec![("latent_3", &two[..])],
            vec![("latent_32", &two[..])],
            vec![("nx", &two[..])],
            vec![("has space", &two[..])],
            vec![("", &two[..])],
        ] {
            let result = write_ply(&path, &gaussians, &extra);
            assert!(
                matches!(result, Err(Error::InvalidArgument(_))),
                "{extra:?}"
            );
        }
        assert!(!path.exists() && !partial_path(&path).unwrap().exists());
    }

    #[test]
    fn failed_write_leaves_no_partial_file() {
        let dir = TempDir::new("ply");
        // The target is a directory, so the rename fails after the partial
        // file was written.
        let path = dir.path().join("taken");
        std::fs::create_dir(&path).unwrap();
        std::fs::write(path.join("keep"), b"x").unwrap();
        assert!(matches!(
            write_ply(&path, &random_gaussians(1, 4), &[]),
            Err(Error::Io { .. })
        ));
        assert!(!partial_path(&path).unwrap().exists());
        // Nor does a write into a missing directory leave anything behind.
        let nowhere = dir.path().join("no/such/dir/map.ply");
        assert!(matches!(
            write_ply(&nowhere, &[], &[]),
            Err(Error::Io { .. })
        ));
    }
}

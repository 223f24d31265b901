//! What the PLY layout fixes: property names, sizes and limits.

#[cfg(test)]
use crate::splat::QUERY_DIM;

/// The degree-0 spherical-harmonic basis constant, `1 / (2√π)`.
pub const SH_C0: f64 = 0.282_094_791_773_878_14;

/// Properties every Gaussian has, before the latent query.
pub(super) const BASE_PROPERTIES: [&str; 17] = [
    "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
    "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
];

/// Floats per Gaussian before any extra property (latents written).
#[cfg(test)]
pub(super) const STANDARD_FLOATS: usize = BASE_PROPERTIES.len() + QUERY_DIM;

/// The longest header the reader accepts: far more than any real property
/// list, and a bound on how much of a non-PLY file is scanned for
/// `end_header`.
pub(super) const MAX_HEADER_BYTES: u64 = 1 << 20;

/// Rows converted per write or read call: large enough to amortise the
/// call, small enough to keep the staging buffer in cache-friendly sizes.
pub(super) const ROWS_PER_CHUNK: usize = 4096;

/// Names an extra property may not have: the standard ones, and every
/// `latent_*`, which the reader takes as part of the latent query.
pub(super) fn is_reserved(name: &str) -> bool {
    BASE_PROPERTIES.contains(&name) || name.starts_with("latent_")
}

/// `Some(i)` for `latent_<i>` with a canonical decimal `i`.
pub(super) fn latent_index(name: &str) -> Option<usize> {
    let digits = name.strip_prefix("latent_")?;
    let canonical = !digits.is_empty()
        && digits.bytes().all(|b| b.is_ascii_digit())
        && (digits == "0" || !digits.starts_with('0'));
    if !canonical {
        return None;
    }
    digits.parse().ok()
}

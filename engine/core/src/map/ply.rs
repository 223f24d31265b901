//! Gaussian maps as PLY files in the layout of the Inria 3D Gaussian
//! Splatting reference code, so the map opens in common splat viewers
//! (SuperSplat, the Inria viewer, …) as it is.
//!
//! The file is `binary_little_endian 1.0` with one `vertex` element and one
//! `float` property per parameter, in this order:
//!
//! | property | value | why |
//! |---|---|---|
//! | `x y z` | [`Gaussian::mean`](crate::map::Gaussian::mean) | |
//! | `nx ny nz` | 0 | the Inria layout has them; viewers expect the names |
//! | `f_dc_0..2` | `(color − 0.5) / C0` | degree-0 spherical harmonics, which viewers turn back into `0.5 + C0 · f_dc`, so they show the engine's view-independent colour; `C0 = 1 / (2√π)` |
//! | `opacity` | [`Gaussian::opacity_logit`](crate::map::Gaussian::opacity_logit) | viewers apply the sigmoid |
//! | `scale_0..2` | [`Gaussian::log_scale`](crate::map::Gaussian::log_scale) | viewers apply `exp` |
//! | `rot_0..3` | [`Gaussian::quat`](crate::map::Gaussian::quat) normalised ([`unit_quat`]), as `w, x, y, z` | the Inria order; the engine keeps its quaternions unnormalised (it normalises when rendering), tools expect unit ones |
//! | `latent_0..31` | [`Gaussian::query`](crate::map::Gaussian::query) | the engine's own; viewers ignore unknown properties; left out by [`write_ply_without_latents`] for maps without embeddings |
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

mod format;
mod header;
mod read;
#[cfg(test)]
mod tests;
mod write;

pub use format::SH_C0;
pub use read::{read_ply, PlyMap};
pub use write::{
    unit_quat, write_map_ply, write_map_ply_streamed, write_ply, write_ply_without_latents,
};

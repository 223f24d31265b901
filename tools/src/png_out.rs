//! Writing 8-bit RGB PNG images (relevance renders).

use std::path::Path;

use anyhow::{Context as _, Result};

/// Writes a `width × height` RGB8 image, whole or not at all.
pub fn write_rgb(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let mut bytes = Vec::new();
    let mut enc = png::Encoder::new(&mut bytes, width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc
        .write_header()
        .with_context(|| format!("encoding {}", path.display()))?;
    w.write_image_data(rgb)
        .with_context(|| format!("encoding {}", path.display()))?;
    w.finish()
        .with_context(|| format!("encoding {}", path.display()))?;
    Ok(latentam::files::write_bytes_atomically(path, &bytes)?)
}

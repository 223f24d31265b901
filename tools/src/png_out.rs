//! Writing 8-bit RGB PNG images (relevance renders).

use std::path::Path;

use anyhow::{Context as _, Result};
use latentam_cli::partial::PartialFile;

/// Writes a `width × height` RGB8 image, whole or not at all.
pub fn write_rgb(path: &Path, width: u32, height: u32, rgb: &[u8]) -> Result<()> {
    let out = PartialFile::new(path);
    let file = std::fs::File::create(out.path())
        .with_context(|| format!("creating {}", out.path().display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc
        .write_header()
        .with_context(|| format!("writing {}", path.display()))?;
    w.write_image_data(rgb)
        .with_context(|| format!("writing {}", path.display()))?;
    w.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    out.commit()
}

//! Output files that appear whole or not at all.

use std::path::{Path, PathBuf};

use anyhow::Context;

/// A file written under `NAME.partial`: [`PartialFile::commit`] renames it
/// to its final name; dropping it uncommitted (an error on the way)
/// removes it, so a failed command leaves no half-written output behind.
pub struct PartialFile {
    tmp: PathBuf,
    out: PathBuf,
    committed: bool,
}

impl PartialFile {
    /// Reserves `out`; write to [`PartialFile::path`].
    pub fn new(out: &Path) -> Self {
        let mut name = out.file_name().unwrap_or_default().to_os_string();
        name.push(".partial");
        PartialFile {
            tmp: out.with_file_name(name),
            out: out.to_path_buf(),
            committed: false,
        }
    }

    /// Where to write.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// Moves the finished file to its final name.
    pub fn commit(mut self) -> anyhow::Result<()> {
        std::fs::rename(&self.tmp, &self.out)
            .with_context(|| format!("moving {} to {}", self.tmp.display(), self.out.display()))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for PartialFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

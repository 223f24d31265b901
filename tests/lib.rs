//! Cross-crate integration tests for latentam; the tests live in `tests/`.
//! What several of them share is here.

use std::path::{Path, PathBuf};

/// A data set of `../shared/data` (beside the repository), which the
/// tests read and never copy.
pub fn shared_data(name: &str) -> PathBuf {
    let p = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data")
        .join(name);
    assert!(
        p.is_dir(),
        "test data {} is missing (../shared must sit beside the repository)",
        p.display()
    );
    p
}

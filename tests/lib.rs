//! Cross-crate integration tests for latentam; the tests live in `tests/`.

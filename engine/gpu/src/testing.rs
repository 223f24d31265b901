//! Test support: a context with the validation layer required, checked for
//! validation errors (including leaks reported at device destruction) when the
//! test body returns.

use super::{Context, ContextOptions, FloatAtomics, Validation};

pub mod devices;

/// Runs `f` on a fresh validated context; fails the test on any validation
/// error. A missing driver or layer fails too, with install instructions.
pub fn with_context(f: impl FnOnce(&Context)) {
    with_options(ContextOptions::default(), f)
}

/// Like [`with_context`], forcing the compare-and-swap float-atomic path.
pub fn with_cas_atomics(f: impl FnOnce(&Context)) {
    let o = ContextOptions {
        float_atomics: FloatAtomics::CompareAndSwap,
        ..ContextOptions::default()
    };
    with_options(o, f)
}

pub fn with_options(mut o: ContextOptions, f: impl FnOnce(&Context)) {
    o.validation = Validation::Required;
    let ctx = match Context::new(o) {
        Ok(c) => c,
        Err(e) => panic!("cannot open a Vulkan device for the test: {e}"),
    };
    let log = ctx.validation_log();
    f(&ctx);
    drop(ctx);
    let errors = log.errors();
    assert!(
        errors.is_empty(),
        "Vulkan validation errors:\n{}",
        errors.join("\n")
    );
}

/// A random generator with a fresh seed per run (or `LATENTAM_TEST_SEED`),
/// printed so a failure can be replayed.
pub fn rng(test: &str) -> rand_chacha::ChaCha8Rng {
    use rand::SeedableRng;
    let seed = std::env::var("LATENTAM_TEST_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos() as u64)
                .unwrap_or(1)
        });
    eprintln!("{test}: LATENTAM_TEST_SEED={seed}");
    rand_chacha::ChaCha8Rng::seed_from_u64(seed)
}

//! Every kernel of the generated table builds a pipeline on the device with
//! the validation layer silent (catches SPIR-V a driver rejects), and the
//! table agrees with what the engine dispatches.

use latentam_gpu::{Context, ContextOptions, Validation};

#[test]
fn every_kernel_builds_a_valid_pipeline() {
    let ctx = Context::new(ContextOptions {
        validation: Validation::Required,
        ..ContextOptions::default()
    })
    .unwrap_or_else(|e| panic!("cannot open a Vulkan device: {e}"));
    let log = ctx.validation_log();
    let n = ctx.warm_up().expect("pipeline creation");
    let expected = latentam_shaders::ALL.len() - usize::from(!ctx.info().native_float_atomics);
    assert_eq!(n, expected);
    drop(ctx);
    let errors = log.errors();
    assert!(
        errors.is_empty(),
        "validation errors:\n{}",
        errors.join("\n")
    );
}

#[test]
fn every_kernel_names_its_source_file() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for k in latentam_shaders::ALL {
        assert!(
            root.join(k.source).is_file(),
            "{}: {} missing",
            k.name,
            k.source
        );
    }
}

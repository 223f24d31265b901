//! Argument checks, device choice and the pipeline cache.

use super::*;

/// Compiled pipelines outlive the process: the first context writes its
/// device's cache file when it closes, the next one opens with it; a
/// damaged file is ignored and replaced.
#[test]
fn compiled_pipelines_are_kept_between_contexts() {
    let dir = std::env::temp_dir().join(format!("latentam-pipelines-{}", std::process::id()));
    let opts = || ContextOptions {
        pipeline_cache_dir: Some(dir.clone()),
        ..ContextOptions::default()
    };
    let mut file = None;
    with_options(opts(), |ctx| {
        assert_eq!(ctx.info().pipeline_cache_loaded_bytes, 0, "a cold start");
        file = ctx.info().pipeline_cache_file.clone();
        ctx.warm_up_only(|k| k.name.starts_with("scan")).unwrap();
    });
    let file = file.expect("a cache file");
    let saved = std::fs::read(&file).expect("written when the context closed");
    assert!(saved.len() > 20, "{} bytes", saved.len());
    with_options(opts(), |ctx| {
        assert_eq!(ctx.info().pipeline_cache_loaded_bytes, saved.len() - 20);
        ctx.warm_up_only(|k| k.name.starts_with("scan")).unwrap();
    });
    std::fs::write(&file, b"not a pipeline cache").unwrap();
    with_options(opts(), |ctx| {
        assert_eq!(
            ctx.info().pipeline_cache_loaded_bytes,
            0,
            "a damaged file is ignored"
        );
    });
    assert!(
        std::fs::read(&file).unwrap().starts_with(b"LTAMPC"),
        "and replaced"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn dispatch_checks_its_arguments() {
    with_context(|ctx| {
        let a = Buffer::device(ctx, "args/a", 64).unwrap();
        let counts = Buffer::device(ctx, "args/counts", 16).unwrap();
        let mut rec = ctx.recorder().unwrap();
        let too_many = ctx.info().max_workgroup_count[0] + 1;
        let err = rec
            .dispatch(
                &SCAN_BLOCKS,
                [too_many, 1, 1],
                bind::ScanBuffers { data: &a, sums: &a },
                &push::Scan { n: 4 },
            )
            .unwrap_err();
        assert!(err.to_string().contains("exceed"), "{err}");
        let err = rec
            .dispatch_indirect(
                &SCAN_BLOCKS,
                &a,
                0,
                bind::ScanBuffers {
                    data: &a,
                    sums: &counts,
                },
                &push::Scan { n: 4 },
            )
            .unwrap_err();
        assert!(
            err.to_string().contains("its own workgroup counts"),
            "{err}"
        );
        let err = rec
            .dispatch_indirect(
                &SCAN_BLOCKS,
                &counts,
                8,
                bind::ScanBuffers { data: &a, sums: &a },
                &push::Scan { n: 4 },
            )
            .unwrap_err();
        assert!(err.to_string().contains("needs 20"), "{err}");
        assert!(rec.upload(&a, 60, &[1u32, 2]).is_err());
        assert!(rec.download(&a, 0, 65).is_err());
        assert!(rec.copy(&a, 0, &a, 32, 64).is_err());
        let mut t = ctx.transfer_recorder().unwrap();
        if ctx.info().dedicated_transfer_queue || ctx.info().transfer_rehearsal {
            assert!(t
                .dispatch(
                    &SCAN_BLOCKS,
                    [1, 1, 1],
                    bind::ScanBuffers { data: &a, sums: &a },
                    &push::Scan { n: 4 }
                )
                .is_err());
        }
        t.fill_u32(&a, 0);
    });
}

#[test]
fn an_unknown_device_name_is_an_error_listing_the_devices() {
    let err = Context::new(ContextOptions {
        device: Some("no-such-device-xyz".into()),
        ..ContextOptions::default()
    })
    .unwrap_err();
    let msg = err.to_string();
    assert!(
        msg.contains("matches no device") && msg.contains("0: "),
        "{msg}"
    );
}

#[test]
fn buffers_larger_than_a_binding_are_refused() {
    with_context(|ctx| {
        let limit = ctx.info().max_storage_buffer_range;
        let err = Buffer::device(ctx, "big/x", limit + 4).unwrap_err();
        assert!(matches!(err, crate::Error::Unsupported(_)), "{err}");
    });
}

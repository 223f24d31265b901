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

/// A warm-up builds each chosen kernel once (on worker threads, each then
/// run once empty), reports progress after each, logs what each cost,
/// leaves out a kernel the driver rejects without failing, and costs
/// nothing for kernels it built before.
#[test]
fn warm_up_builds_each_chosen_kernel_once() {
    let o = ContextOptions {
        rejected_kernels: vec!["scan_add".into()],
        ..ContextOptions::default()
    };
    with_options(o, |ctx| {
        let chosen = |k: &latentam_shaders::Kernel| {
            k.name.starts_with("scan") || k.name.starts_with("reduce")
        };
        let mut expected: Vec<&str> = latentam_shaders::ALL
            .iter()
            .filter(|k| chosen(k) && ctx.info().can_run(k))
            .map(|k| k.name)
            .collect();
        assert!(expected.len() >= 4 && expected.contains(&"scan_add"));
        // A pipeline created but never dispatched is not built yet.
        let scan_blocks = latentam_shaders::ALL
            .iter()
            .find(|k| k.name == "scan_blocks")
            .unwrap();
        assert!(ctx.kernel_builds(scan_blocks).unwrap());
        let n = expected.len();
        let mut calls = Vec::new();
        let ready = ctx
            .warm_up_reporting(chosen, |built, of| calls.push((built, of)))
            .unwrap();
        assert_eq!(ready, n - 1, "all but the rejected kernel");
        assert_eq!(calls, (1..=n).map(|b| (b, n)).collect::<Vec<_>>());
        let times = ctx.kernel_build_times();
        let mut built: Vec<&str> = times.iter().map(|t| t.kernel).collect();
        built.sort();
        expected.retain(|k| *k != "scan_add");
        expected.sort();
        assert_eq!(built, expected);
        assert!(times
            .iter()
            .all(|t| t.create_ms > 0.0 && t.first_dispatch_ms > 0.0));
        let failed: Vec<&str> = ctx.kernel_build_failures().iter().map(|f| f.0).collect();
        assert_eq!(failed, ["scan_add"]);
        assert!(ctx.time_to_ready_ms().is_some());

        // Again: only the rejected kernel is tried (and refused at once).
        let pipelines = ctx.live_objects().pipelines;
        let mut again = Vec::new();
        let ready = ctx
            .warm_up_reporting(chosen, |built, of| again.push((built, of)))
            .unwrap();
        assert_eq!((ready, again), (n - 1, vec![(1, 1)]));
        assert_eq!(ctx.kernel_build_times().len(), times.len());
        assert_eq!(ctx.live_objects().pipelines, pipelines);
    });
}

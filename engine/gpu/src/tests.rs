//! Tests of the Vulkan layer itself: lifetimes, accounting, profiling,
//! synchronisation and argument checks.

use latentam_shaders::{push, SCAN_BLOCKS};

use super::testing::{with_context, with_options};
use super::*;
use crate::ops::PrefixScan;
use latentam_shaders::bind;

#[test]
fn buffers_dropped_while_in_flight_are_freed_after_the_gpu_is_done() {
    with_context(|ctx| {
        let data: Vec<u32> = (0..1_000_000).collect();
        let sub = {
            let buf = ctx.upload_new("inflight/data", &data).unwrap();
            let scan = PrefixScan::new(ctx, data.len() as u64).unwrap();
            let mut rec = ctx.recorder().unwrap();
            scan.record(&mut rec, &buf, data.len() as u64).unwrap();
            rec.submit().unwrap()
            // `buf` and `scan` drop here, before the GPU finishes.
        };
        sub.wait().unwrap();
        ctx.collect_garbage();
        let m = ctx.memory_report();
        assert_eq!(m.by_category["inflight"].current, 0, "{m:?}");
        assert_eq!(m.by_category["scan"].current, 0, "{m:?}");
        assert!(m.by_category["inflight"].peak >= 4_000_000);
    });
}

#[test]
fn a_readback_dropped_before_submission_keeps_its_staging_alive() {
    with_context(|ctx| {
        let staging = |ctx: &Context| {
            ctx.memory_report()
                .by_category
                .get("staging")
                .map_or(0, |c| c.current)
        };
        let src = ctx.upload_new("test/src", &vec![7u32; 1 << 20]).unwrap();
        let base = staging(ctx);
        let mut rec = ctx.recorder().unwrap();
        drop(rec.download(&src, 0, src.bytes()).unwrap());
        ctx.collect_garbage();
        // The recorded copy still writes into it: it must not be freed yet.
        assert!(
            staging(ctx) >= base + src.bytes(),
            "staging freed before submission"
        );
        let kept = rec.download(&src, 0, 16).unwrap();
        rec.submit().unwrap().wait().unwrap();
        assert_eq!(kept.read::<u32>().unwrap(), vec![7; 4]);
        drop(kept);
        ctx.collect_garbage();
        assert_eq!(staging(ctx), base, "and freed once the GPU is done");
    });
}

#[test]
fn memory_is_accounted_per_category_and_the_budget_is_enforced() {
    with_context(|ctx| {
        let a = Buffer::device(ctx, "gaussians/means", 1 << 20).unwrap();
        let b = Buffer::device(ctx, "gaussians/colours", 1 << 20).unwrap();
        let c = Buffer::device(ctx, "decoder/w", 4096).unwrap();
        let m = ctx.memory_report();
        assert!(m.by_category["gaussians"].current >= 2 << 20);
        assert!(m.by_category["decoder"].current >= 4096);
        assert_eq!(
            m.total.current,
            m.by_category.values().map(|c| c.current).sum::<u64>()
        );
        ctx.set_memory_budget(Some(m.total.current + (1 << 20)));
        let err = Buffer::device(ctx, "gaussians/more", 2 << 20).unwrap_err();
        assert!(matches!(err, crate::Error::OutOfMemory(_)), "{err}");
        assert!(err.to_string().contains("budget"), "{err}");
        // A refused allocation leaves the accounting unchanged.
        assert_eq!(ctx.memory_report().total.current, m.total.current);
        drop((a, b, c));
        ctx.wait_idle().unwrap();
        assert_eq!(ctx.memory_report().total.current, 0);
    });
}

#[test]
fn profiler_times_every_dispatch_and_writes_a_chrome_trace() {
    let opts = ContextOptions {
        profiling: true,
        ..ContextOptions::default()
    };
    with_options(opts, |ctx| {
        assert!(ctx.profiling(), "lavapipe and desktop GPUs have timestamps");
        let data: Vec<u32> = vec![1; 5000];
        let buf = ctx.upload_new("prof/data", &data).unwrap();
        ctx.profiler_reset();
        let scan = PrefixScan::new(ctx, 5000).unwrap();
        let mut rec = ctx.recorder().unwrap();
        scan.record(&mut rec, &buf, 5000).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let p = ctx.profiler_snapshot();
        let stats = p.stats();
        // 5000 elements: blocks at level 0, one block at level 1, then add.
        assert_eq!(stats["scan_blocks"].count, 2);
        assert_eq!(stats["scan_add"].count, 1);
        for s in stats.values() {
            assert!(s.min_ms >= 0.0 && s.min_ms <= s.mean_ms && s.mean_ms <= s.max_ms);
        }
        assert!(p.table().contains("scan_blocks"));
        let path = std::env::temp_dir().join(format!("latentam-trace-{}.json", std::process::id()));
        p.write_chrome_trace(&path).unwrap();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let events = v["traceEvents"].as_array().unwrap();
        let (meta, spans): (Vec<_>, Vec<_>) = events.iter().partition(|e| e["ph"] == "M");
        // Three GPU commands, and the host's wait for them.
        assert_eq!(spans.iter().filter(|e| e["pid"] == 1).count(), 3);
        assert_eq!(spans.iter().filter(|e| e["name"] == HOST_WAIT).count(), 1);
        assert!(spans
            .iter()
            .all(|e| e["ph"] == "X" && e["dur"].as_f64().unwrap() >= 0.0 && e["tid"].is_u64()));
        // The process and every thread the spans use are named.
        assert!(meta.iter().any(|e| e["name"] == "process_name"));
        for s in &spans {
            assert!(meta.iter().any(|m| m["name"] == "thread_name"
                && m["tid"] == s["tid"]
                && m["pid"] == s["pid"]));
        }
        std::fs::remove_file(&path).ok();
    });
}

/// Host spans and waits reach the trace, as a second process with a track
/// for the thread, beside the GPU's commands, after a clock calibration.
/// (Where they land on the device clock is checked on synthetic clocks in
/// the profiler's own tests: a CPU driver's stamps under load are no
/// reference.)
#[test]
fn host_spans_and_waits_are_traced_beside_the_gpu() {
    let opts = ContextOptions {
        profiling: true,
        ..ContextOptions::default()
    };
    with_options(opts, |ctx| {
        let clock = ctx.profiler_snapshot().clock().expect("a calibrated clock");
        assert!(clock.error_ns >= 0.0 && clock.error_ns < 1e9, "{clock:?}");
        let bytes = 4u64 << 20;
        let a = Buffer::device(ctx, "host_span/a", bytes).unwrap();
        let b = Buffer::device(ctx, "host_span/b", bytes).unwrap();
        ctx.profiler_reset();
        {
            let _stage = ctx.host_span("stage");
            for _ in 0..3 {
                let mut rec = ctx.recorder().unwrap();
                rec.copy(&a, 0, &b, 0, bytes).unwrap();
                rec.submit().unwrap().wait().unwrap();
            }
        }
        let p = ctx.profiler_snapshot();
        let names: Vec<&str> = p.host_samples().iter().map(|s| s.name).collect();
        assert_eq!(names, [HOST_WAIT, HOST_WAIT, HOST_WAIT, "stage"]);
        let stage = &p.host_samples()[3];
        for w in &p.host_samples()[..3] {
            assert!(
                w.start_ns >= stage.start_ns
                    && w.start_ns + w.duration_ns <= stage.start_ns + stage.duration_ns
            );
        }
        let path =
            std::env::temp_dir().join(format!("latentam-hosttrace-{}.json", std::process::id()));
        p.write_chrome_trace(&path).unwrap();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        std::fs::remove_file(&path).ok();
        let events = v["traceEvents"].as_array().unwrap();
        let host: Vec<_> = events
            .iter()
            .filter(|e| e["pid"] == 2 && e["ph"] == "X")
            .collect();
        assert_eq!(host.len(), 4);
        assert!(events
            .iter()
            .any(|e| e["pid"] == 2 && e["name"] == "process_name"));
        assert_eq!(
            events
                .iter()
                .filter(|e| e["pid"] == 1 && e["name"] == "copy")
                .count(),
            3
        );
        assert!(v["otherData"]["host_clock_calibrations"].as_u64().unwrap() >= 1);
    });
}

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
fn transfer_work_waits_on_compute_through_the_timeline() {
    with_context(|ctx| {
        let n = 300_000u64;
        let data = vec![1u32; n as usize];
        let buf = ctx.upload_new("sync/data", &data).unwrap();
        let out = Buffer::device(ctx, "sync/out", n * 4).unwrap();
        let scan = PrefixScan::new(ctx, n).unwrap();
        let mut rec = ctx.recorder().unwrap();
        scan.record(&mut rec, &buf, n).unwrap();
        let compute = rec.submit().unwrap();
        let mut copy = ctx.transfer_recorder().unwrap();
        copy.wait_for(compute.sync_point());
        copy.copy(&buf, 0, &out, 0, n * 4).unwrap();
        let rb = copy.download(&out, 0, n * 4).unwrap();
        let done = copy.submit().unwrap();
        assert!(rb.read::<u32>().is_err() || done.is_done());
        done.wait().unwrap();
        compute.wait().unwrap();
        let got = rb.read::<u32>().unwrap();
        assert!(got.iter().enumerate().all(|(i, &v)| v == i as u32));
    });
}

/// The dedicated-transfer-queue path rehearsed on the compute family
/// (lavapipe has no transfer family): transfer-only recording (its
/// barriers are checked by the validation layer), the implicit waits
/// between the two timelines in both directions, a batch that opts out of
/// them, and a timed transfer batch.
#[test]
fn the_transfer_path_rehearsed_on_the_compute_family_orders_both_ways() {
    let options = ContextOptions {
        transfer_queue: TransferQueue::SameFamily,
        profiling: true,
        ..ContextOptions::default()
    };
    with_options(options, |ctx| {
        assert!(ctx.info().transfer_rehearsal && !ctx.info().dedicated_transfer_queue);
        let n = 200_000u64;
        let buf = ctx
            .upload_new("rehearse/data", &vec![1u32; n as usize])
            .unwrap();
        let copy_of = Buffer::device(ctx, "rehearse/copy", n * 4).unwrap();
        let back = Buffer::device(ctx, "rehearse/back", n * 4).unwrap();
        let scan = PrefixScan::new(ctx, n).unwrap();
        // Compute writes; the transfer batch submitted after it waits for
        // it without being told, copies (a hazard inside the batch: the
        // recorder's transfer-only barrier) and copies the copy back.
        let mut rec = ctx.recorder().unwrap();
        scan.record(&mut rec, &buf, n).unwrap();
        let first = rec.submit().unwrap();
        let mut t = ctx.transfer_recorder().unwrap();
        t.start_span();
        t.copy(&buf, 0, &copy_of, 0, n * 4).unwrap();
        t.copy(&copy_of, 0, &back, 0, n * 4).unwrap();
        let paging = t.submit().unwrap();
        // A batch that overlaps the transfer queue does not wait for it...
        let other = Buffer::device(ctx, "rehearse/other", 64).unwrap();
        let mut beside = ctx.recorder().unwrap();
        beside.overlap_other_queue();
        beside.fill_u32(&other, 7);
        beside.submit().unwrap().wait().unwrap();
        // ...while an ordinary compute batch does: it reads the copy back.
        let mut after = ctx.recorder().unwrap();
        scan.record(&mut after, &back, n).unwrap();
        after.submit().unwrap().wait().unwrap();
        let span = paging.wait_span().unwrap();
        assert_eq!(span.is_some(), ctx.info().transfer_timestamps);
        assert!(first.is_done());
        // The copy holds the first scan; the copied-back buffer, scanned
        // again after the transfer batch, its exclusive prefix sums.
        let first: Vec<u32> = (0..n as u32).collect();
        let second: Vec<u32> = first
            .iter()
            .scan(0u32, |acc, &i| {
                let v = *acc;
                *acc = acc.wrapping_add(i);
                Some(v)
            })
            .collect();
        assert_eq!(ctx.download::<u32>(&copy_of).unwrap(), first);
        assert_eq!(ctx.download::<u32>(&back).unwrap(), second);
        assert_eq!(ctx.download::<u32>(&other).unwrap(), vec![7u32; 16]);
    });
}

/// A context under validation with `checks`, for the tests that expect its
/// errors (`testing::with_options` fails on any).
fn checked_context(checks: ValidationChecks) -> Context {
    Context::new(ContextOptions {
        validation: Validation::Required,
        validation_checks: checks,
        ..ContextOptions::default()
    })
    .unwrap()
}

/// Synchronization validation is on when asked for, and sees a hazard the
/// recorder would have barred: the suite runs under it
/// (`LATENTAM_VALIDATION_CHECKS=sync`), so a missing barrier fails a test
/// even on a driver that runs one command after another.
#[test]
fn synchronization_validation_reports_a_planted_hazard() {
    let ctx = checked_context(ValidationChecks {
        synchronization: true,
        ..ValidationChecks::default()
    });
    let log = ctx.validation_log();
    let n = 4096u32;
    let data = ctx
        .upload_new("hazard/data", &vec![1u32; n as usize])
        .unwrap();
    let sums = Buffer::device(&ctx, "hazard/sums", 64 * 4).unwrap();
    let targets = ctx
        .upload_new("hazard/targets", &vec![0u32; n as usize])
        .unwrap();
    let acc = Buffer::device(&ctx, "hazard/acc", 4).unwrap();
    let mut rec = ctx.recorder().unwrap();
    // The scan writes `data`; the scatter-add then reads it, with the
    // barrier between them forgotten: a read after write.
    rec.dispatch(
        &SCAN_BLOCKS,
        [1, 1, 1],
        bind::ScanBuffers {
            data: &data,
            sums: &sums,
        },
        &push::Scan { n },
    )
    .unwrap();
    rec.forget_hazards();
    rec.dispatch_linear(
        &latentam_shaders::ATOMIC_ADD_F32_CAS,
        n,
        bind::ScatterAddBuffers {
            values: &data,
            targets: &targets,
            acc: &acc,
        },
        &push::ScatterAdd { n },
    )
    .unwrap();
    rec.submit().unwrap().wait().unwrap();
    drop(ctx);
    let errors = log.errors();
    assert!(
        errors.iter().any(|e| e.contains("SYNC-HAZARD")),
        "no hazard reported: {errors:?}"
    );
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

#[test]
fn live_objects_return_to_their_count_once_work_is_dropped_and_done() {
    let opts = ContextOptions {
        profiling: true,
        ..ContextOptions::default()
    };
    with_options(opts, |ctx| {
        let data: Vec<u32> = vec![1; 5000];
        let work = |ctx: &Context| {
            let buf = ctx.upload_new("objects/data", &data).unwrap();
            let scan = PrefixScan::new(ctx, 5000).unwrap();
            let mut rec = ctx.recorder().unwrap();
            scan.record(&mut rec, &buf, 5000).unwrap();
            let back = rec.download(&buf, 0, 4).unwrap();
            rec.submit().unwrap().wait().unwrap();
            back.read::<u32>().unwrap()
        };
        // The first run creates the pipelines, which stay.
        work(ctx);
        ctx.wait_idle().unwrap();
        let before = ctx.live_objects();
        let during = {
            let _held = ctx.upload_new("objects/held", &data).unwrap();
            ctx.live_objects()
        };
        assert_eq!(during.buffers, before.buffers + 1, "{during:?}");
        for _ in 0..3 {
            assert_eq!(work(ctx), vec![0]);
        }
        ctx.wait_idle().unwrap();
        let after = ctx.live_objects();
        assert_eq!(after, before);
        assert_eq!(after.awaiting_destruction, 0);
        assert!(after.pipelines >= 2, "{after:?}");
    });
}

#[test]
fn every_host_wait_is_counted() {
    with_context(|ctx| {
        let buf = ctx.upload_new("waits/data", &[1u32; 64]).unwrap();
        let before = ctx.host_waits();
        let calls = ctx.gpu_calls();
        // An upload and a download each submit and wait once.
        ctx.upload(&buf, 0, &[2u32; 64]).unwrap();
        let back: Vec<u32> = ctx.download(&buf).unwrap();
        assert_eq!(back[0], 2);
        assert_eq!(ctx.host_waits() - before, 2);
        // A submission not waited on is not a wait.
        let mut rec = ctx.recorder().unwrap();
        rec.upload(&buf, 0, &[3u32; 64]).unwrap();
        let s = rec.submit().unwrap();
        assert_eq!(ctx.host_waits() - before, 2);
        s.wait().unwrap();
        ctx.wait_idle().unwrap();
        assert_eq!(ctx.host_waits() - before, 4);
        let calls = ctx.gpu_calls() - calls;
        assert_eq!(
            (calls.submissions, calls.host_waits, calls.dispatches),
            (3, 4, 0)
        );
    });
}

/// GPU-assisted validation is on when asked for, and sees a kernel read
/// and write past the end of its buffer (a scan told the array is 64
/// times longer than it is): the kernel tests run under it
/// (`LATENTAM_VALIDATION_CHECKS=gpu-assisted`, in `tools/run test`).
#[test]
fn gpu_assisted_validation_reports_a_planted_out_of_bounds_access() {
    let ctx = checked_context(ValidationChecks {
        gpu_assisted: true,
        ..ValidationChecks::default()
    });
    let log = ctx.validation_log();
    let data = ctx.upload_new("oob/data", &vec![1u32; 64]).unwrap();
    let sums = Buffer::device(&ctx, "oob/sums", 64 * 4).unwrap();
    let mut rec = ctx.recorder().unwrap();
    rec.dispatch(
        &SCAN_BLOCKS,
        [4, 1, 1],
        bind::ScanBuffers {
            data: &data,
            sums: &sums,
        },
        &push::Scan { n: 4096 },
    )
    .unwrap();
    rec.submit().unwrap().wait().unwrap();
    drop(ctx);
    let errors = log.errors();
    assert!(
        errors.iter().any(|e| e.contains("out of bounds")),
        "no out-of-bounds access reported: {errors:?}"
    );
}

/// What a dispatch counts in `Context::gpu_work`: its `@cost` line from
/// the launch, or what the caller stated; a dispatch of zero workgroups
/// counts nothing; an upload counts its bytes.
#[test]
fn dispatches_count_their_work() {
    use crate::ops::{Gemm, Transpose};
    with_context(|ctx| {
        let gemm = Gemm {
            transpose: Transpose::None,
            m: 40,
            n: 24,
            k: 36,
            alpha: 1.0,
            beta: 0.0,
        };
        let a = Buffer::device(ctx, "work/a", 40 * 36 * 4).unwrap();
        let b = Buffer::device(ctx, "work/b", 36 * 24 * 4).unwrap();
        let c = Buffer::device(ctx, "work/c", 40 * 24 * 4).unwrap();
        let before = ctx.gpu_work();
        let mut rec = ctx.recorder().unwrap();
        gemm.record(&mut rec, &a, &b, &c).unwrap();
        let stated = latentam_shaders::Work {
            flops: 5.0,
            bytes: 7.0,
        };
        rec.work_of_next(stated);
        gemm.record(&mut rec, &a, &b, &c).unwrap();
        let empty = Gemm { m: 0, ..gemm };
        empty.record(&mut rec, &a, &b, &c).unwrap();
        rec.upload(&a, 0, &[0f32; 16]).unwrap();
        rec.submit().unwrap().wait().unwrap();
        let work = ctx.gpu_work() - before;
        let kernels: Vec<_> = work
            .kernels
            .iter()
            .filter(|(n, _)| n.starts_with("gemm"))
            .collect();
        assert_eq!(kernels.len(), 1, "{work:?}");
        let w = kernels[0].1;
        assert_eq!((w.dispatches, w.uncounted), (2, 0));
        assert_eq!(w.flops, gemm.flops() + stated.flops);
        assert_eq!(
            w.bytes,
            4.0 * (40.0 * 36.0 + 36.0 * 24.0 + 40.0 * 24.0) + stated.bytes
        );
        assert_eq!(work.uploaded_bytes, 64);
        assert_eq!(work.downloaded_bytes, 0);
    });
}

//! The profiler: every dispatch timed, host spans traced, work counted.

use super::*;

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

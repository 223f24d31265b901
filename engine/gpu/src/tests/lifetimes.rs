//! Lifetimes and accounting: buffers freed after the GPU is done, staging
//! kept alive, memory per category, live objects and host waits counted.

use super::*;

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

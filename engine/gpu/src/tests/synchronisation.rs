//! Transfer work ordered against compute through the timeline, and the
//! validation layers' reports of planted hazards and out-of-bounds access.

use super::*;

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

/// A detached transfer batch (the next window sync's arrivals, uploaded
/// while Stage I trains) makes no later compute batch wait for it, while an
/// attached one does; the batch that uses its data waits for it by name and
/// sees it. Run on the rehearsed transfer path, so that there are two
/// timelines on any device, under the suite's synchronization validation.
#[test]
fn a_detached_batch_is_waited_for_only_by_name() {
    let options = ContextOptions {
        transfer_queue: TransferQueue::SameFamily,
        ..ContextOptions::default()
    };
    with_options(options, |ctx| {
        let n = 100_000u64;
        let data: Vec<u32> = (0..n as u32)
            .map(|i| i.wrapping_mul(2_654_435_761))
            .collect();
        let inbox = Buffer::device(ctx, "detach/inbox", n * 4).unwrap();
        let rows = Buffer::device(ctx, "detach/rows", n * 4).unwrap();
        let other = Buffer::device(ctx, "detach/other", 64).unwrap();

        let mut attached = ctx.transfer_recorder().unwrap();
        attached.fill_u32(&other, 1);
        let attached = attached.submit().unwrap();
        let mut upload = ctx.transfer_recorder().unwrap();
        upload.detach();
        assert_eq!(
            upload.implicit_wait(),
            None,
            "it waits for no compute batch"
        );
        upload.upload(&inbox, 0, &data).unwrap();
        let uploaded = upload.submit().unwrap();
        // A compute batch waits for the attached batch, not the detached one.
        let mut beside = ctx.recorder().unwrap();
        assert_eq!(beside.implicit_wait(), Some(attached.sync_point()));
        beside.fill_u32(&other, 7);
        beside.submit().unwrap().wait().unwrap();
        // The batch that reads the upload names it.
        let mut rec = ctx.recorder().unwrap();
        rec.wait_for(uploaded.sync_point());
        rec.copy(&inbox, 0, &rows, 0, n * 4).unwrap();
        rec.submit().unwrap().wait().unwrap();
        assert!(uploaded.is_done());
        uploaded.wait().unwrap();
        attached.wait().unwrap();
        assert_eq!(ctx.download::<u32>(&rows).unwrap(), data);
        // An attached transfer batch again makes compute wait for it.
        let mut again = ctx.transfer_recorder().unwrap();
        again.fill_u32(&other, 3);
        let again = again.submit().unwrap();
        assert_eq!(
            ctx.recorder().unwrap().implicit_wait(),
            Some(again.sync_point())
        );
        again.wait().unwrap();
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

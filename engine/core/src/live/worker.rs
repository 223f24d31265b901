//! The worker thread: it owns the mapper, maps queued frames one after
//! another, serves loans of the mapper between them, and takes snapshots
//! between them when a reader wants one (or every few keyframes, when the
//! options ask for that).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::Ordering;
use std::sync::{mpsc, Arc};
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use latentam_base::Error;

use super::keyframe_image::KeyframeImage;
use super::queue::Queued;
use super::shared::{Close, Lent, Outcome, Shared};
use crate::mapper::MapSnapshot;
use crate::mapper::{camera_of, Integrated, Mapper};

/// What the worker does next.
enum Job {
    Lend(mpsc::Sender<Lent>),
    /// A snapshot of the map as it stands after this many keyframes.
    Publish(u64),
    Frame(Box<Queued>),
    Exit,
}

/// Runs until the handle closes; gives the mapper back (none if a loan
/// never returned it).
pub(super) fn run(mut mapper: Mapper, shared: Arc<Shared>) -> Option<Mapper> {
    // A panic outside a frame (frames catch their own) still ends the
    // worker as a failure, so that no caller waits for it forever.
    let _exit_on_panic = ExitOnPanic(&shared);
    loop {
        match next_job(&shared) {
            Job::Exit => break,
            Job::Lend(to) => match lend(mapper, to) {
                Some(m) => mapper = m,
                None => {
                    shared.fail(
                        Error::Panicked("a loan of the mapper never gave it back".into()),
                        true,
                    );
                    shared.exit();
                    return None;
                }
            },
            Job::Publish(keyframes) => publish(&mapper, &shared, keyframes, true),
            Job::Frame(q) => map_one(&mut mapper, *q, &shared),
        }
    }
    // A reader that outlives a finished handle reads the final map.
    let last = {
        let st = shared.lock();
        let outlived = shared.readers.load(Ordering::SeqCst) > 1;
        let finished = st.close == Some(Close::Finish);
        (outlived && finished && !st.snapshot_current() && !st.fatal).then_some(st.keyframes)
    };
    if let Some(keyframes) = last {
        // The map itself is fine whatever becomes of this copy: a failure
        // is reported, and `finish` still gives the mapper back.
        publish(&mapper, &shared, keyframes, false);
    }
    // Whatever asked to hurry is answered: the mapper maps normally again.
    mapper.stop_flag().store(false, Ordering::SeqCst);
    shared.exit();
    Some(mapper)
}

fn next_job(shared: &Shared) -> Job {
    let mut st = shared.lock();
    let job = loop {
        if let Some(to) = st.lends.pop_front() {
            break Job::Lend(to);
        }
        if st.close == Some(Close::Abort) {
            let n = st.queue.clear();
            st.dropped.aborted += n;
            break Job::Exit;
        }
        // Before the next frame: a reader waits for it.
        if st.snapshot_due() {
            break Job::Publish(st.keyframes);
        }
        if st.stopped.is_none() {
            if let Some(q) = st.queue.pop() {
                st.busy = true;
                break Job::Frame(Box::new(q));
            }
        } else {
            let n = st.queue.clear();
            st.dropped.aborted += n;
        }
        if st.close == Some(Close::Finish) {
            break Job::Exit;
        }
        st = shared.work.wait(st).unwrap_or_else(|e| e.into_inner());
    };
    drop(st);
    // A frame left the queue: there is room for a waiting submitter.
    shared.room.notify_all();
    job
}

/// Hands the mapper to the caller that asked, and takes it back.
fn lend(mapper: Mapper, to: mpsc::Sender<Lent>) -> Option<Mapper> {
    let (back, returned) = mpsc::channel();
    // A caller that gave up drops the loan unopened, which sends the
    // mapper straight back.
    let _ = to.send(Lent {
        mapper: Some(mapper),
        back,
    });
    returned.recv().ok()
}

fn map_one(mapper: &mut Mapper, q: Queued, shared: &Shared) {
    if q.dropped_before > 0 {
        mapper.count_unseen_frames(q.dropped_before);
    }
    let started = Instant::now();
    // `submit` checked the frame.
    let result = catch_unwind(AssertUnwindSafe(|| mapper.integrate_checked(&q.frame)));
    let mut keyframe = false;
    let mut snapshot = None;
    let outcome = match result {
        Ok(Ok(integrated)) => {
            if let Integrated::Keyframe(report) = &integrated {
                keyframe = true;
                // Taken before the keyframe is counted, so that a reader
                // woken by the count finds it. An aborting handle has no
                // reader left to take one for.
                let every = shared.options.snapshot_every;
                // After every `every`-th keyframe (the report counts from 0).
                let due =
                    (every > 0 && (report.index + 1) % every == 0) || shared.lock().snapshot_wanted;
                if due && !shared.stop.load(Ordering::SeqCst) {
                    snapshot = Some(take_snapshot(mapper, shared, true));
                }
                keep_image(&q.frame, report.index, shared);
            }
            Ok(integrated)
        }
        Ok(Err(e)) => {
            let fatal = mapper.is_broken();
            let e = Arc::new(e);
            if fatal || shared.options.stop_on_rejected {
                shared.fail_shared(e.clone(), fatal);
            }
            Err(e)
        }
        Err(panic) => {
            let e = Arc::new(Error::Panicked(panic_message(&*panic)));
            shared.fail_shared(e.clone(), true);
            Err(e)
        }
    };
    let mut st = shared.lock();
    st.busy = false;
    st.integrated += 1;
    match &outcome {
        Err(e) => {
            if !matches!(**e, Error::Panicked(_)) && !mapper.is_broken() {
                st.dropped.rejected += 1;
            }
            st.last_error = Some(e.clone());
        }
        Ok(integrated) if keyframe => {
            let now = Instant::now();
            st.keyframes += 1;
            if let Integrated::Keyframe(report) = integrated {
                st.gaussians = report.gaussians;
                st.gpu_bytes = report.gpu_bytes;
            }
            if let Some(taken) = snapshot {
                let keyframes = st.keyframes;
                st.record_snapshot(taken, keyframes);
            }
            st.last_latency_ms = Some((now - q.submitted).as_secs_f64() * 1e3);
            st.last_stamp_latency_ms = stamp_latency_ms(q.frame.stamp_ns);
            st.last_keyframe_ms = Some((now - started).as_secs_f64() * 1e3);
            st.recent.push_back(now);
            if st.recent.len() > 11 {
                st.recent.pop_front();
            }
        }
        Ok(_) => {}
    }
    if let (Some(reports), Ok(Integrated::Keyframe(k))) = (&mut st.keyframe_reports, &outcome) {
        reports.push((**k).clone());
    }
    if let Some(outcomes) = &mut st.outcomes {
        outcomes.push(Outcome {
            frame: q.frame,
            result: outcome,
            stats: mapper.stats(),
        });
    }
    drop(st);
    shared.room.notify_all();
}

/// The time from a frame's stamp to now, when the stamp is wall-clock
/// time (within a day of now): a live camera's, not a log's.
fn stamp_latency_ms(stamp_ns: i64) -> Option<f64> {
    let now = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .ok()?
        .as_nanos() as i64;
    let ms = (now - stamp_ns) as f64 / 1e6;
    (ms.abs() < 86_400e3).then_some(ms)
}

/// Keeps the keyframe's image and camera for viewers (one copy of the
/// colour image per keyframe: small beside the keyframe's work).
fn keep_image(frame: &latentam_io::Frame, keyframe: u64, shared: &Shared) {
    let image = KeyframeImage {
        keyframe,
        stamp_ns: frame.stamp_ns,
        camera: camera_of(frame),
        color: frame.color.clone(),
    };
    *shared
        .last_keyframe
        .write()
        .unwrap_or_else(|e| e.into_inner()) = Some(Arc::new(image));
}

/// Takes a snapshot of the map (between frames) and makes it the one
/// readers see, as of `keyframes` mapped through the handle; wakes the
/// readers waiting for it. A failure stops the worker when `fatal` (see
/// [`take_snapshot`]).
fn publish(mapper: &Mapper, shared: &Shared, keyframes: u64, fatal: bool) {
    let taken = take_snapshot(mapper, shared, fatal);
    shared.lock().record_snapshot(taken, keyframes);
    shared.room.notify_all();
}

/// Takes a snapshot of the map and makes it the one readers see; a
/// failure (or a panic) is the last error, and stops the worker when
/// `fatal` (while mapping, a map that cannot be read back cannot be
/// trusted either). Returns whether it was taken, for
/// [`State::record_snapshot`](super::shared::State::record_snapshot).
fn take_snapshot(mapper: &Mapper, shared: &Shared, fatal: bool) -> bool {
    let taken = catch_unwind(AssertUnwindSafe(|| {
        MapSnapshot::of(mapper, shared.options.index)
    }))
    .unwrap_or_else(|panic| Err(Error::Panicked(panic_message(&*panic))));
    match taken {
        Ok(snapshot) => {
            *shared.snapshot.write().unwrap_or_else(|e| e.into_inner()) = Arc::new(snapshot);
            // Under the indexer's lock, so that it cannot miss the wake
            // between its look at the newest snapshot and its wait.
            drop(shared.lock());
            shared.index_wake.notify_all();
            true
        }
        Err(e) if fatal => {
            shared.fail(e, true);
            false
        }
        Err(e) => {
            shared.lock().last_error = Some(Arc::new(e));
            false
        }
    }
}

/// The text of a caught panic.
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}

/// Ends the worker as failed when its thread unwinds.
struct ExitOnPanic<'a>(&'a Shared);

impl Drop for ExitOnPanic<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0
                .fail(Error::Panicked("the mapping worker panicked".into()), true);
            self.0.exit();
        }
    }
}

/// The relevance indexer: while queries are being asked, it indexes each
/// new snapshot off the query path, so a query finds its index built.
pub(super) fn index_snapshots(shared: Arc<Shared>) {
    latentam_base::background::lowest_priority();
    loop {
        let snapshot = {
            let mut st = shared.lock();
            loop {
                if st.exited || st.close.is_some() {
                    return;
                }
                let latest = shared.latest();
                if st.wants_index && latest.decoder.is_some() && !latest.is_indexed() {
                    break latest;
                }
                st = shared
                    .index_wake
                    .wait(st)
                    .unwrap_or_else(|e| e.into_inner());
            }
        };
        if snapshot.index_cancellable(Some(&shared.closing)).is_ok() {
            let mut indexed = shared.indexed.write().unwrap_or_else(|e| e.into_inner());
            if indexed
                .as_ref()
                .is_none_or(|i| i.keyframes <= snapshot.keyframes)
            {
                *indexed = Some(snapshot);
            }
        }
    }
}

//! The README's "Library use" as a program: a log replayed at its recorded
//! rate into the live handle, as a camera driver would feed it, while a
//! planner thread asks twice a second where a word of the vocabulary is.
//!
//! ```sh
//! latentam gen-scene -o scene.mcap
//! cargo run --release -p latentam --example live -- scene.mcap out/ chair
//! ```

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use latentam::frames::{read_vocabulary, AssemblyConfig, McapFrames};
use latentam::{LiveMapper, LiveOptions, TextQuery};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, log, out, word] = args.as_slice() else {
        return Err("usage: live LOG OUT_DIR WORD".into());
    };
    // Compiles every kernel before it returns: the first frame does not wait.
    let live = Arc::new(LiveMapper::new(
        latentam::Config::default(),
        LiveOptions::default(),
    )?);
    println!(
        "ready after {:.0} ms",
        live.status().ready_ms.unwrap_or(0.0)
    );

    // The planner: text embeddings come from a vision-language model; the
    // demo scene carries its vocabulary's.
    let vocabulary =
        read_vocabulary(log.as_ref(), "/vocabulary")?.ok_or("the log has no vocabulary")?;
    let query = TextQuery::vocabulary_word(&vocabulary, word, 0.1)?;
    let done = Arc::new(AtomicBool::new(false));
    let planner = {
        let (live, done) = (live.clone(), done.clone());
        std::thread::spawn(move || {
            while !done.load(Ordering::Relaxed) {
                match live.relevance(&query) {
                    Ok(answer) => {
                        let best = answer.scores.iter().cloned().fold(0.0, f32::max);
                        println!(
                            "keyframe {}: {} Gaussians, best match {best:.2}",
                            answer.snapshot.keyframes,
                            answer.scores.len()
                        );
                    }
                    Err(latentam::Error::NoEmbeddings) => {} // nothing mapped yet
                    Err(e) => eprintln!("query: {e}"),
                }
                std::thread::sleep(Duration::from_millis(500));
            }
        })
    };

    // The camera: frames at their recorded rate. `submit` never waits for
    // the GPU; when the mapper falls behind, frames are dropped by policy.
    let start = Instant::now();
    let mut first_stamp = None;
    for frame in McapFrames::open(log.as_ref(), AssemblyConfig::default())? {
        let frame = frame?;
        let t0 = *first_stamp.get_or_insert(frame.stamp_ns);
        let due = Duration::from_nanos((frame.stamp_ns - t0).max(0) as u64);
        if let Some(wait) = due.checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        live.submit(frame)?;
    }
    let status = live.status();
    println!(
        "submitted {}, dropped {:?}, last keyframe {:.0} ms after its frame came",
        status.submitted,
        status.dropped,
        status.last_keyframe_latency_ms.unwrap_or(0.0)
    );
    done.store(true, Ordering::Relaxed);
    planner.join().map_err(|_| "the planner panicked")?;
    let live = Arc::into_inner(live).ok_or("the handle is still shared")?;
    let mut mapper = live.finish()?; // maps what is still queued
    let state = mapper.save(out)?;
    println!(
        "{} keyframes, {} Gaussians; saved {}",
        mapper.stats().keyframes,
        mapper.stats().gaussians,
        state.display()
    );
    Ok(())
}

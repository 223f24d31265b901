//! From a robot's topics to the live mapper: the topics are chosen from
//! the ROS graph by the rules a bag's are chosen by, one thread per topic
//! takes its samples, and one thread assembles frames and submits them.
//! Submitting never waits: a frame the mapper has no room for is dropped
//! by the live handle's policy and counted.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use futures::StreamExt;
use latentam::frames::{AssemblyConfig, IngestReport, PlannedInput, Vocabulary};
use latentam::logs::{Channel, RawMessage};
use latentam::LiveMapper;

use crate::dds::{Dds, Profile, RawReader};

/// What went through the inputs.
#[derive(Clone, Debug, Default)]
pub struct InputStats {
    /// Messages received, all topics.
    pub messages: u64,
    /// Frames assembled and handed to the mapper.
    pub frames: u64,
    /// Messages the assembler skipped (bad, unpaired), by its report.
    pub refused: u64,
    /// Microseconds from the arrival of the message that completed a
    /// frame to the frame being queued (the node's own delay), for the
    /// last frames (at most 10 000).
    pub queue_latency_us: VecDeque<u32>,
    /// Microseconds from a colour image's arrival to its frame being
    /// queued: the node's delay plus the wait for the depth, pose and
    /// embeddings it pairs with (a pose after the image, to interpolate).
    pub pairing_wait_us: VecDeque<u32>,
    /// The vocabulary, once its topic delivered one.
    pub vocabulary: Option<Arc<Vocabulary>>,
    /// The first error that stopped the inputs.
    pub error: Option<String>,
}

/// The topics chosen, and the threads reading them.
pub struct Inputs {
    pub topics: Vec<Channel>,
    pub stats: Arc<Mutex<InputStats>>,
    assembler: Option<JoinHandle<IngestReport>>,
    stop: Arc<AtomicBool>,
}

/// The ROS 2 topics with their types, as channels the topic plan reads.
fn graph_channels(dds: &Dds) -> Vec<Channel> {
    dds.published_topics()
        .into_iter()
        .map(|(topic, ty)| Channel::ros2(&topic, &ty))
        .collect()
}

/// Waits until the graph has every topic `config` needs (or `stop`),
/// saying what is missing every few seconds.
pub fn plan(
    dds: &Dds,
    config: &AssemblyConfig,
    stop: &AtomicBool,
) -> anyhow::Result<(PlannedInput, Vec<Channel>)> {
    let started = Instant::now();
    let mut said = Instant::now();
    // Discovery first: a topic seen early may have a sibling a moment later
    // (depth beside colour) that would change the choice.
    std::thread::sleep(crate::dds::DISCOVERY.min(Duration::from_secs(1)));
    loop {
        let channels = graph_channels(dds);
        match PlannedInput::new(&channels, config.clone(), "the ROS graph") {
            Ok(p) if started.elapsed() >= crate::dds::DISCOVERY => return Ok((p, channels)),
            Ok(_) => {}
            Err(e) => {
                if said.elapsed() >= Duration::from_secs(5) {
                    eprintln!("waiting for topics: {e}");
                    said = Instant::now();
                }
            }
        }
        if stop.load(Ordering::SeqCst) {
            anyhow::bail!("stopped before the input topics were published");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// The QoS a topic is read with: latched topics are transient-local, the
/// rest best effort (which matches reliable publishers too).
fn profile_of(topic: &str, config: &AssemblyConfig) -> Profile {
    if topic == "/tf_static" || topic == config.topics.vocabulary {
        Profile::Latched
    } else {
        Profile::SensorData
    }
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64)
}

/// A thread that sends every sample of `channel` (read with its topic's
/// QoS profile) to the assembler's queue as `(index, bytes, arrival)`,
/// until the queue is gone.
fn spawn_reader(
    dds: &Dds,
    channel: &Channel,
    index: usize,
    config: &AssemblyConfig,
    to: mpsc::Sender<(usize, Vec<u8>, Instant)>,
) -> anyhow::Result<()> {
    let reader: RawReader = dds.reader(
        &channel.topic,
        &channel.schema_name,
        profile_of(&channel.topic, config),
    )?;
    std::thread::Builder::new()
        .name(format!("latentam-ros-in-{index}"))
        .spawn(move || {
            let mut stream = reader.async_sample_stream();
            futures::executor::block_on(async {
                while let Some(sample) = stream.next().await {
                    let Ok(sample) = sample else { continue };
                    if to
                        .send((index, sample.into_value().0, Instant::now()))
                        .is_err()
                    {
                        return;
                    }
                }
            });
        })?;
    Ok(())
}

impl Inputs {
    /// Starts reading the planned topics into `live`.
    pub fn start(
        dds: &Dds,
        planned: PlannedInput,
        channels: Vec<Channel>,
        config: &AssemblyConfig,
        live: Arc<LiveMapper>,
    ) -> anyhow::Result<Inputs> {
        let PlannedInput {
            mut assembler,
            topics,
            ..
        } = planned;
        let read: Vec<Channel> = topics
            .iter()
            .filter_map(|t| channels.iter().find(|c| &c.topic == t).cloned())
            .collect();
        let (to_assembler, messages) = mpsc::channel::<(usize, Vec<u8>, Instant)>();
        for (i, c) in read.iter().enumerate() {
            spawn_reader(dds, c, i, config, to_assembler.clone())?;
        }
        drop(to_assembler);
        let stats = Arc::new(Mutex::new(InputStats::default()));
        let stop = Arc::new(AtomicBool::new(false));
        // Colour images come first among the planned topics; their
        // arrival times the queue latency.
        let color = topics.first().cloned().unwrap_or_default();
        let (s, st) = (stats.clone(), stop.clone());
        let channels_read = read.clone();
        let thread = std::thread::Builder::new()
            .name("latentam-ros-frames".into())
            .spawn(move || {
                let mut arrived: Option<Instant> = None;
                loop {
                    if st.load(Ordering::SeqCst) {
                        break;
                    }
                    let (i, data, at) = match messages.recv_timeout(Duration::from_millis(50)) {
                        Ok(m) => m,
                        Err(mpsc::RecvTimeoutError::Timeout) => continue,
                        Err(mpsc::RecvTimeoutError::Disconnected) => break,
                    };
                    let channel = &channels_read[i];
                    if channel.topic == color {
                        arrived = Some(at);
                    }
                    let pushed = assembler.push(RawMessage {
                        channel,
                        log_time: now_ns(),
                        data: &data,
                    });
                    let mut stats = s.lock().unwrap_or_else(|e| e.into_inner());
                    stats.messages += 1;
                    if let Err(e) = pushed {
                        stats.error.get_or_insert(e.to_string());
                        break;
                    }
                    if stats.vocabulary.is_none() {
                        stats.vocabulary = assembler.vocabulary().cloned().map(Arc::new);
                    }
                    stats.refused = assembler.report().total_skipped();
                    drop(stats);
                    while let Some(frame) = assembler.pop() {
                        let submitted = live.submit(frame);
                        let mut stats = s.lock().unwrap_or_else(|e| e.into_inner());
                        match submitted {
                            Ok(()) => {
                                stats.frames += 1;
                                keep(&mut stats.queue_latency_us, at);
                                if let Some(a) = arrived {
                                    keep(&mut stats.pairing_wait_us, a);
                                }
                            }
                            Err(e) => {
                                stats.error.get_or_insert(e.to_string());
                            }
                        }
                    }
                }
                assembler.report().clone()
            })?;
        Ok(Inputs {
            topics: read,
            stats,
            assembler: Some(thread),
            stop,
        })
    }

    /// Stops taking messages and lets go of the mapper (the reader
    /// threads, which wait on DDS, end with the process); what the inputs
    /// held and what of them was skipped (`None` after a first call).
    pub fn stop(&mut self) -> Option<IngestReport> {
        self.stop.store(true, Ordering::SeqCst);
        self.assembler.take().and_then(|t| t.join().ok())
    }
}

/// Keeps the time since `since` in `v`, the last 10 000 of them.
fn keep(v: &mut VecDeque<u32>, since: Instant) {
    if v.len() >= 10_000 {
        v.pop_front();
    }
    v.push_back(since.elapsed().as_micros() as u32);
}

//! The live view: a Foxglove WebSocket server that shows a map while it
//! is being mapped. A publisher thread wakes after each keyframe (at most
//! once per [`ViewOptions::min_interval`]), reads the newest snapshot
//! through a [`LiveReader`] and publishes the topics a client subscribed
//! to; a client that subscribes later gets the current state at once.

use std::collections::HashSet;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use foxglove::messages::{PointCloud, PoseInFrame, PosesInFrame, RawImage};
use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{WebSocketServer, WebSocketServerHandle};

use latentam_base::{Error, Result};
use latentam_core::latent::{softmax_rows, Relevance, TextQuery};
use latentam_core::live::{KeyframeImage, LiveReader, MapSnapshot};
use latentam_io::{CameraPose, Vocabulary};

use crate::map_points::{heat_rgba, MapPoints};
use crate::messages::{topic_word, Cloud, PointValue, RgbImage};
use crate::topics::Topics;

/// The map's points (`foxglove.PointCloud`, an `opacity` field).
pub const MAP_TOPIC: &str = "/latentam/map";
/// The keyframe trajectory (`foxglove.PosesInFrame`).
pub const TRAJECTORY_TOPIC: &str = "/latentam/trajectory";
/// The last keyframe's camera pose (`foxglove.PoseInFrame`).
pub const CAMERA_TOPIC: &str = "/latentam/camera";
/// The last keyframe's colour image (`foxglove.RawImage`, frame `camera`).
pub const IMAGE_TOPIC: &str = "/latentam/image";
/// The map rendered from the last keyframe's camera (`foxglove.RawImage`).
pub const RENDER_TOPIC: &str = "/latentam/render";
/// Prefix of the relevance clouds, one per word: `/latentam/relevance/WORD`.
pub const RELEVANCE_PREFIX: &str = "/latentam/relevance/";

/// Frame id of the images.
const CAMERA_FRAME: &str = "camera";

/// What the live view serves and how often.
///
/// ```
/// use latentam_view::ViewOptions;
/// // Every interface, port 8765, at most 50 000 points, every 2 s.
/// let options = ViewOptions {
///     listen: "0.0.0.0:8765".parse().unwrap(),
///     point_budget: 50_000,
///     min_interval: std::time::Duration::from_secs(2),
///     ..ViewOptions::default()
/// };
/// assert_eq!(options.frame_id, "map");
/// ```
#[derive(Clone, Debug)]
pub struct ViewOptions {
    /// Address and port the WebSocket server listens on (port 0: any
    /// free port, see [`LiveView::port`]). Default `127.0.0.1:8765`,
    /// Foxglove's default, reachable from this machine only.
    pub listen: SocketAddr,
    /// The world frame of the map and poses.
    pub frame_id: String,
    /// Most points in a published cloud: a larger map is shown by an
    /// even subset (17 bytes a point on the wire, see
    /// [`PointValue::Unorm8`]).
    pub point_budget: usize,
    /// Least time between two publications of the map.
    pub min_interval: Duration,
    /// Width of the map rendered from the keyframe's camera, pixels (its
    /// height follows the camera's aspect); 0: no render.
    pub render_width: u32,
    /// Least time between two renders. A render borrows the mapper
    /// between keyframes, so mapping waits for it: about a millisecond on
    /// a discrete GPU, a few hundred on a CPU driver.
    pub render_interval: Duration,
    /// Words whose relevance clouds are published.
    pub words: Vec<ViewWord>,
}

impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            listen: SocketAddr::from(([127, 0, 0, 1], 8765)),
            frame_id: "map".into(),
            point_budget: 100_000,
            min_interval: Duration::from_secs(1),
            render_width: 320,
            render_interval: Duration::from_secs(5),
            words: Vec::new(),
        }
    }
}

/// A word whose relevance the view shows, on
/// `/latentam/relevance/<topic>`.
#[derive(Clone, Debug)]
pub struct ViewWord {
    /// The word.
    pub name: String,
    /// Its topic-safe form.
    pub topic: String,
    /// Its column among `vocabulary`'s.
    index: usize,
    vocabulary: Arc<(Vec<f32>, usize)>,
    temperature: f32,
}

impl ViewWord {
    /// The words `names` of `vocabulary` (every word when empty), each
    /// scored by a softmax over the whole vocabulary at `temperature`, as
    /// `latentam query --name` scores it.
    pub fn from_vocabulary(
        vocabulary: &Vocabulary,
        names: &[String],
        temperature: f32,
    ) -> Result<Vec<ViewWord>> {
        // Checks the temperature and the names.
        for name in names {
            TextQuery::vocabulary_word(vocabulary, name, temperature)?;
        }
        if vocabulary.names.is_empty() {
            return Err(Error::bad_input("the vocabulary", "it has no word"));
        }
        TextQuery::vocabulary_word(vocabulary, &vocabulary.names[0], temperature)?;
        let shared = Arc::new((vocabulary.vectors.clone(), vocabulary.names.len()));
        let mut taken = Vec::new();
        Ok(vocabulary
            .names
            .iter()
            .enumerate()
            .filter(|(_, n)| names.is_empty() || names.contains(n))
            .map(|(index, name)| ViewWord {
                name: name.clone(),
                topic: topic_word(name, &mut taken),
                index,
                vocabulary: shared.clone(),
                temperature,
            })
            .collect())
    }
}

/// What the view published so far.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct ViewStats {
    /// Publications of the map (each a set of topics).
    pub publications: u64,
    /// Messages sent to subscribed clients.
    pub messages: u64,
    /// Their bytes.
    pub bytes: u64,
    /// Time spent publishing, ms (reading snapshots, scoring, encoding).
    pub busy_ms: f64,
    /// Publications whose relevance or render failed (logged).
    pub failures: u64,
}

/// Subscriptions reported by the server: a topic subscribed since its
/// last message is sent the current state at once.
#[derive(Default)]
struct Subscriptions {
    fresh: Mutex<HashSet<String>>,
}

impl ServerListener for Subscriptions {
    fn on_subscribe(&self, _client: Client, channel: ChannelView) {
        self.fresh
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(channel.topic().to_string());
    }
}

/// A Foxglove WebSocket server showing a live map: open Foxglove,
/// "Open connection", `ws://HOST:PORT`, and add a 3D panel (the map,
/// trajectory, camera and relevance clouds) and Image panels
/// (`/latentam/image`, `/latentam/render`).
///
/// ```no_run
/// use latentam_core::live::{LiveMapper, LiveOptions};
/// use latentam_view::{LiveView, ViewOptions};
///
/// let live = LiveMapper::new(Default::default(), LiveOptions::default())?;
/// let view = LiveView::serve(live.reader(), ViewOptions::default())?;
/// println!("Foxglove: ws://127.0.0.1:{}", view.port());
/// // ... submit frames ...
/// let stats = view.close(); // after a last publication of the map
/// # Ok::<(), latentam_base::Error>(())
/// ```
pub struct LiveView {
    server: Option<WebSocketServerHandle>,
    publisher: Option<JoinHandle<()>>,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<ViewStats>>,
    port: u16,
}

impl LiveView {
    /// Starts the server on `options.listen` and the publisher thread
    /// reading `reader`. Errors when the address cannot be bound.
    pub fn serve(reader: LiveReader, options: ViewOptions) -> Result<LiveView> {
        // Clouds carry their values as bytes: 17 bytes a point on the wire.
        let topics = Arc::new(Topics::new(&options.frame_id).with_point_value(PointValue::Unorm8));
        let subscriptions = Arc::new(Subscriptions::default());
        let server = WebSocketServer::new()
            .name(concat!("latentam ", env!("CARGO_PKG_VERSION")))
            .context(topics.context())
            .bind(options.listen.ip().to_string(), options.listen.port())
            .listener(subscriptions.clone())
            .start_blocking()
            .map_err(|e| {
                Error::bad_input(
                    format!("the live view's address {}", options.listen),
                    format!("cannot listen on it: {e}"),
                )
            })?;
        let port = server.port();
        let listen = options.listen;
        // Every topic is there before the first keyframe, so a client can
        // subscribe to it at once.
        topics.advertise::<PointCloud>(MAP_TOPIC)?;
        topics.advertise::<PosesInFrame>(TRAJECTORY_TOPIC)?;
        topics.advertise::<PoseInFrame>(CAMERA_TOPIC)?;
        topics.advertise::<RawImage>(IMAGE_TOPIC)?;
        if options.render_width > 0 {
            topics.advertise::<RawImage>(RENDER_TOPIC)?;
        }
        for w in &options.words {
            topics.advertise::<PointCloud>(&w.relevance_topic())?;
        }
        let stop = Arc::new(AtomicBool::new(false));
        let stats = Arc::new(Mutex::new(ViewStats::default()));
        let publisher = Publisher {
            reader,
            topics,
            options,
            subscriptions,
            stop: stop.clone(),
            stats: stats.clone(),
            last_render: None,
        };
        let thread = std::thread::Builder::new()
            .name("latentam-view".into())
            .spawn(move || publisher.run())
            .map_err(|e| Error::Io {
                path: "(thread)".into(),
                source: e,
            })?;
        log::info!("live view on ws://{}:{port}", listen.ip());
        Ok(LiveView {
            server: Some(server),
            publisher: Some(thread),
            stop,
            stats,
            port,
        })
    }

    /// The port the server listens on.
    pub fn port(&self) -> u16 {
        self.port
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.server.as_ref().map_or(0, |s| s.client_count())
    }

    /// What it published so far.
    pub fn stats(&self) -> ViewStats {
        *self.stats.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Publishes the map a last time (when its mapper has ended, what it
    /// ended with), stops the server and returns what was published.
    pub fn close(mut self) -> ViewStats {
        self.shut_down();
        self.stats()
    }

    fn shut_down(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(p) = self.publisher.take() {
            let _ = p.join();
        }
        if let Some(s) = self.server.take() {
            if s.client_count() > 0 {
                // The last publication is queued per client: give it a
                // moment to leave before the connections close.
                std::thread::sleep(LINGER);
            }
            let shutdown = s.stop();
            // Waiting blocks, which an async caller's thread must not do.
            if tokio::runtime::Handle::try_current().is_ok() {
                shutdown.detach_all();
            } else {
                shutdown.wait_blocking();
            }
        }
    }
}

impl Drop for LiveView {
    fn drop(&mut self) {
        self.shut_down();
    }
}

/// The publisher thread's state.
struct Publisher {
    reader: LiveReader,
    topics: Arc<Topics>,
    options: ViewOptions,
    subscriptions: Arc<Subscriptions>,
    stop: Arc<AtomicBool>,
    stats: Arc<Mutex<ViewStats>>,
    last_render: Option<Instant>,
}

/// How long a closing view waits for its last messages to reach clients.
const LINGER: Duration = Duration::from_millis(500);

/// How often the publisher looks for new subscriptions and the stop flag.
const TICK: Duration = Duration::from_millis(100);

impl Publisher {
    fn run(mut self) {
        latentam_base::background::lowest_priority();
        let mut published: Option<u64> = None;
        let mut last = Instant::now() - self.options.min_interval;
        loop {
            let stopping = self.stop.load(Ordering::SeqCst);
            let keyframes = self.reader.status().keyframes;
            let fresh = std::mem::take(
                &mut *self
                    .subscriptions
                    .fresh
                    .lock()
                    .unwrap_or_else(|e| e.into_inner()),
            );
            // A new map goes to every subscriber (at most once per
            // interval, and once more when closing); otherwise only the
            // topics subscribed since get the current state.
            let full = published != Some(keyframes)
                && (last.elapsed() >= self.options.min_interval || stopping);
            if full || !fresh.is_empty() {
                let started = Instant::now();
                let sent = self.publish((!full).then_some(&fresh));
                let mut st = self.stats.lock().unwrap_or_else(|e| e.into_inner());
                st.publications += 1;
                st.messages += sent.messages;
                st.bytes += sent.bytes;
                st.failures += sent.failed as u64;
                st.busy_ms += started.elapsed().as_secs_f64() * 1e3;
                drop(st);
                if full {
                    published = Some(keyframes);
                    last = Instant::now();
                }
            }
            if stopping {
                return;
            }
            if published == Some(keyframes) && self.reader.is_running() {
                self.reader.wait_for_keyframe(keyframes, TICK);
            } else {
                std::thread::sleep(TICK);
            }
        }
    }

    /// Publishes the newest state on every subscribed topic (or only on
    /// `only`'s).
    fn publish(&mut self, only: Option<&HashSet<String>>) -> Sent {
        let wanted =
            |topic: &str| self.topics.subscribed(topic) && only.is_none_or(|o| o.contains(topic));
        let snapshot = self.reader.snapshot();
        let keyframe = self.reader.last_keyframe();
        let stamp = stamp_of(&snapshot, keyframe.as_deref());
        let mut sent = Sent::default();
        if wanted(MAP_TOPIC) {
            let points = MapPoints::of(&snapshot.gaussians, self.options.point_budget);
            sent.add(self.topics.cloud(MAP_TOPIC, stamp, &points.cloud()));
        }
        if wanted(TRAJECTORY_TOPIC) {
            let poses: Vec<CameraPose> = snapshot.trajectory.iter().map(|&(_, p)| p).collect();
            sent.add(self.topics.poses(TRAJECTORY_TOPIC, stamp, &poses));
        }
        if let Some(k) = &keyframe {
            if wanted(CAMERA_TOPIC) {
                sent.add(self.topics.pose(CAMERA_TOPIC, stamp, &pose_of(k)));
            }
            if wanted(IMAGE_TOPIC) {
                let rgb = k.color.to_rgb8();
                let image = RgbImage {
                    width: k.color.width,
                    height: k.color.height,
                    rgb: &rgb,
                };
                sent.add(self.topics.image(IMAGE_TOPIC, CAMERA_FRAME, stamp, &image));
            }
            // A render borrows the mapper: not once its worker has ended,
            // and at most once per interval, unless a client just asked.
            let render_due = self
                .last_render
                .is_none_or(|t| t.elapsed() >= self.options.render_interval)
                || only.is_some_and(|o| o.contains(RENDER_TOPIC));
            if self.options.render_width > 0
                && wanted(RENDER_TOPIC)
                && render_due
                && self.reader.is_running()
            {
                self.last_render = Some(Instant::now());
                sent.add(self.render(k, stamp));
            }
        }
        let words: Vec<&ViewWord> = self
            .options
            .words
            .iter()
            .filter(|w| wanted(&w.relevance_topic()))
            .collect();
        if !words.is_empty() && snapshot.decoder.is_some() {
            sent.add_all(self.relevance(&words));
        }
        sent
    }

    /// The map rendered from the keyframe's camera, at `render_width`.
    fn render(&self, k: &KeyframeImage, stamp: u64) -> Result<usize> {
        let mut camera = k.camera;
        let scale = self.options.render_width as f64 / camera.width as f64;
        if scale < 1.0 {
            camera.width = self.options.render_width;
            camera.height = ((camera.height as f64 * scale).round() as u32).max(1);
            camera.fx *= scale;
            camera.fy *= scale;
            // Pixel centres at (i + 0.5) / scale - 0.5 of the original.
            camera.cx = (camera.cx + 0.5) * scale - 0.5;
            camera.cy = (camera.cy + 0.5) * scale - 0.5;
        }
        let view = self.reader.render(&camera)?;
        let rgb: Vec<u8> = view
            .rgbd
            .iter()
            .flat_map(|p| [p[0], p[1], p[2]].map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8))
            .collect();
        let image = RgbImage {
            width: view.width,
            height: view.height,
            rgb: &rgb,
        };
        self.topics.image(RENDER_TOPIC, CAMERA_FRAME, stamp, &image)
    }

    /// One relevance cloud per word of `words`, on the snapshot the
    /// relevance index was built for (the newest, or one keyframe
    /// behind while the indexer catches up): bytes per message.
    fn relevance(&self, words: &[&ViewWord]) -> Result<Vec<usize>> {
        let (vectors, count) = &*words[0].vocabulary;
        // Cosines against the whole vocabulary once; each word's column
        // of their softmax is its relevance (as `query --name` gives it).
        let query = TextQuery {
            embeddings: vectors.clone(),
            texts: *count,
            relevance: Relevance::Cosine,
        };
        let answer = self.reader.relevance(&query)?;
        let points = MapPoints::of(&answer.snapshot.gaussians, self.options.point_budget);
        let cosines = points.pick_rows(&answer.scores, *count);
        let stamp = stamp_of(&answer.snapshot, None);
        let mut bytes = Vec::new();
        for w in words {
            let rel: Vec<f32> = softmax_rows(&cosines, *count, w.temperature)
                .chunks_exact(*count)
                .map(|row| row[w.index])
                .collect();
            let colours: Vec<[u8; 4]> = rel.iter().map(|&r| heat_rgba(r)).collect();
            let cloud = Cloud {
                positions: &points.positions,
                colours: &colours,
                value: ("relevance", &rel),
            };
            bytes.push(self.topics.cloud(&w.relevance_topic(), stamp, &cloud)?);
        }
        Ok(bytes)
    }
}

impl ViewWord {
    fn relevance_topic(&self) -> String {
        format!("{RELEVANCE_PREFIX}{}", self.topic)
    }
}

/// Counts what a publication sent; a failed part is logged and counted.
#[derive(Default)]
struct Sent {
    messages: u64,
    bytes: u64,
    failed: bool,
}

impl Sent {
    fn add_all(&mut self, r: Result<Vec<usize>>) {
        match r {
            Ok(sizes) => sizes.into_iter().for_each(|n| self.add(Ok(n))),
            Err(e) => self.add(Err(e)),
        }
    }

    fn add(&mut self, r: Result<usize>) {
        match r {
            Ok(0) => {}
            Ok(n) => {
                self.messages += 1;
                self.bytes += n as u64;
            }
            Err(e) => {
                log::warn!("live view: {e}");
                self.failed = true;
            }
        }
    }
}

/// The stamp of a publication: the last keyframe's (or the last pose's).
fn stamp_of(snapshot: &MapSnapshot, keyframe: Option<&KeyframeImage>) -> u64 {
    keyframe
        .map(|k| k.stamp_ns)
        .or_else(|| snapshot.trajectory.last().map(|&(s, _)| s))
        .unwrap_or(0)
        .max(0) as u64
}

fn pose_of(k: &KeyframeImage) -> CameraPose {
    let (_, rotation, translation) = k.camera.cam_to_world.to_scale_rotation_translation();
    CameraPose {
        rotation,
        translation,
    }
}

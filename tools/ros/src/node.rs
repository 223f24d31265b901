//! The node's life: join DDS, plan the inputs, map, publish, answer, and
//! save on Ctrl-C.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context as _, Result};
use latentam::frames::Vocabulary;
use latentam::messages::{RosMessage, StringMessage};
use latentam::runs::{RunFolder, Written};
use latentam::{
    softmax_rows, Ending, LiveMapper, LiveOptions, LogRun, MapSnapshot, RunObserver, RunReport,
    Scoring, TextQuery,
};
use latentam_args::interrupt;
use latentam_view::MapPoints;

use crate::args::Args;
use crate::dds::{Dds, Profile, RawMessage, RawReader, RawWriter};
use crate::graph;
use crate::inputs::{self, Inputs};
use crate::outputs;
use crate::param_services::ParameterServices;
use crate::params::{Parameters, Publishing};
use crate::services::{Mapping, Service};

/// The node's own topics and services under its namespace.
struct Own {
    map: RawWriter,
    trajectory: RawWriter,
    status: RawWriter,
    relevance: RawWriter,
    saved: RawWriter,
    query: RawReader,
    save: RawReader,
    query_service: Service,
    save_service: Service,
    parameters: ParameterServices,
}

fn join(ns: &str, name: &str) -> String {
    format!("{}/{name}", ns.trim_end_matches('/'))
}

impl Own {
    fn new(dds: &Dds, ns: &str, mapping: Mapping) -> Result<Self> {
        let cloud = "sensor_msgs/msg/PointCloud2";
        Ok(Own {
            map: dds.writer(&join(ns, "map"), cloud, Profile::Latched)?,
            trajectory: dds.writer(
                &join(ns, "trajectory"),
                "nav_msgs/msg/Path",
                Profile::Latched,
            )?,
            status: dds.writer(
                &join(ns, "status"),
                "diagnostic_msgs/msg/DiagnosticArray",
                Profile::Default,
            )?,
            relevance: dds.writer(&join(ns, "query/relevance"), cloud, Profile::Default)?,
            saved: dds.writer(&join(ns, "saved"), "std_msgs/msg/String", Profile::Default)?,
            query: dds.reader(
                &join(ns, "query"),
                "latentam_msgs/msg/TextEmbeddings",
                Profile::Default,
            )?,
            save: dds.reader(&join(ns, "save"), "std_msgs/msg/String", Profile::Default)?,
            query_service: Service::new(
                dds,
                &join(ns, "query"),
                "latentam_msgs/srv/Query",
                mapping,
            )?,
            save_service: Service::new(dds, &join(ns, "save"), "latentam_msgs/srv/Save", mapping)?,
            parameters: ParameterServices::new(dds, ns, mapping)?,
        })
    }
}

fn write(w: &RawWriter, bytes: Vec<u8>, what: &str) {
    if let Err(e) = w.write(RawMessage(bytes), None) {
        log::warn!("publishing {what}: {e:?}");
    }
}

fn take(r: &mut RawReader) -> Option<Vec<u8>> {
    match r.take_next_sample() {
        Ok(Some(s)) => Some(s.into_value().0),
        _ => None,
    }
}

fn p99(v: &std::collections::VecDeque<u32>) -> Option<u32> {
    if v.is_empty() {
        return None;
    }
    let mut s: Vec<u32> = v.iter().copied().collect();
    s.sort_unstable();
    Some(s[((s.len() - 1) as f64 * 0.99).round() as usize])
}

pub fn run(args: Args) -> Result<()> {
    if !(args.map_every >= 0.0 && args.map_every.is_finite()) {
        bail!("--map-every must be a number of seconds, 0 or more");
    }
    if args.map_points == 0 {
        bail!("--map-points must be at least 1");
    }
    if !(args.temperature > 0.0 && args.temperature.is_finite()) {
        bail!(
            "--temperature must be positive and finite, got {} (a value past f32's range reads as inf)",
            args.temperature
        );
    }
    if !args.live.live_words.is_empty() {
        // The vocabulary arrives on a topic after the view starts.
        bail!(
            "--live-words is for logs; on the node, --words adds relevance fields to the map cloud"
        );
    }
    let config = args.config.load()?;
    let params = Parameters::new(
        &config.to_toml(),
        Publishing {
            frame_id: args.frame_id.clone(),
            map_every: args.map_every,
            map_points: args.map_points,
            words: args.words.clone(),
            temperature: args.temperature,
        },
    )?;
    let assembly = args.input.assembly()?;
    args.live.check()?;
    let domain = match args.domain {
        Some(d) => d,
        None => match std::env::var("ROS_DOMAIN_ID") {
            Ok(v) if !v.trim().is_empty() => v
                .trim()
                .parse()
                .with_context(|| format!("ROS_DOMAIN_ID={v} is not a domain id"))?,
            _ => 0,
        },
    };
    interrupt::install();
    let dds = Dds::join(domain)?;
    let mapping = Mapping::of(std::env::var("RMW_IMPLEMENTATION").ok().as_deref());
    let own = Own::new(&dds, &args.namespace, mapping)?;
    // In the ROS 2 graph at once, with its own topics; again below once
    // it reads its inputs.
    let (node_ns, node_name) = graph::node_of(&args.namespace);
    dds.announce(&node_ns, &node_name)?;
    eprintln!(
        "latentam-ros: DDS domain {domain}, topics under {}",
        args.namespace
    );
    eprintln!(
        "latentam-ros: building the mapper's kernels (seconds; tens of seconds where the GPU \
         driver has never compiled them)"
    );
    // A run folder's report lists every keyframe.
    let options = LiveOptions {
        keep_keyframe_reports: args.out.is_some(),
        ..LiveOptions::default()
    };
    let started = Instant::now();
    let live = Arc::new(LiveMapper::new(config, options)?);
    let reader = live.reader();
    eprintln!(
        "mapper ready in {:.0} ms; waiting for the input topics",
        live.status().ready_ms.unwrap_or(0.0)
    );
    let (planned, channels) = inputs::plan(&dds, &assembly, interrupt::flag())?;
    for line in &planned.plan {
        eprintln!("input: {line}");
    }
    let mut inputs = Inputs::start(&dds, planned, channels, &assembly, live.clone())?;
    dds.announce(&node_ns, &node_name)?;
    for c in &inputs.topics {
        eprintln!("reading {} ({})", c.topic, c.schema_name);
    }
    let view = match args.live.options(None)? {
        Some(options) => Some(latentam::view::LiveView::serve(live.reader(), options)?),
        None => None,
    };
    let result = serve(&args, &live, &mut inputs, own, params);
    let ingest = inputs.stop().unwrap_or_default();
    if let Some(view) = view {
        view.close();
    }
    let live = Arc::try_unwrap(live).map_err(|_| anyhow::anyhow!("the mapper is still in use"))?;
    let mapper = live.finish()?;
    if let Some(out) = &args.out {
        let ending = match &result {
            Ok(()) => Ending::Interrupted,
            Err(e) => Ending::Failed(format!("{e:#}")),
        };
        let keyframes = reader.take_keyframe_reports();
        let run = LogRun {
            frames: ingest.frames,
            not_keyframes: ingest.frames.saturating_sub(keyframes.len() as u64),
            mapper,
            log: format!("ros2:{}", args.namespace).into(),
            skipped: 0,
            keyframes,
            wall_s: started.elapsed().as_secs_f64(),
            ending,
            ingest,
            autosaved_at: None,
            autosave_failures: Vec::new(),
        };
        save_run_folder(run, out)?;
    }
    result
}

/// Publishes and answers until Ctrl-C (or the inputs fail).
fn serve(
    args: &Args,
    live: &LiveMapper,
    inputs: &mut Inputs,
    mut own: Own,
    mut params: Parameters,
) -> Result<()> {
    let mut published: Option<u64> = None;
    let mut last_map = Instant::now() - Duration::from_secs_f64(params.publishing.map_every);
    let mut last_status = Instant::now() - Duration::from_secs(1);
    while !interrupt::requested() {
        let status = live.status();
        // Only what this turn needs, so the frames thread never waits long
        // on the lock.
        let (error, vocabulary) = {
            let s = inputs.stats.lock().unwrap_or_else(|e| e.into_inner());
            (s.error.clone(), s.vocabulary.clone())
        };
        if let Some(e) = error {
            bail!("reading the input topics: {e}");
        }
        let map_every = Duration::from_secs_f64(params.publishing.map_every);
        if published != Some(status.keyframes) && last_map.elapsed() >= map_every {
            publish_map(&params.publishing, live, vocabulary.as_deref(), &own)?;
            published = Some(status.keyframes);
            last_map = Instant::now();
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            let stats = inputs
                .stats
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone();
            // From the status, not a snapshot: a snapshot copies the map.
            let report = outputs::Report {
                status: &status,
                gaussians: status.gaussians,
                gpu_bytes: status.gpu_bytes,
                messages: stats.messages,
                frames: stats.frames,
                refused: stats.refused,
                queue_latency_p99_us: p99(&stats.queue_latency_us),
                pairing_wait_p99_us: p99(&stats.pairing_wait_us),
                stamp_ns: live.reader().last_keyframe().map_or(0, |k| k.stamp_ns),
            };
            write(&own.status, outputs::status(&report), "the status");
            last_status = Instant::now();
        }
        while let Some(bytes) = take(&mut own.query) {
            let p = &params.publishing;
            match answer(p, live, &bytes) {
                Ok(a) => write(
                    &own.relevance,
                    outputs::map_cloud(&p.frame_id, a.stamp, &a.points, &a.fields),
                    "a query's relevance",
                ),
                Err(e) => log::warn!("a query on {}/query: {e:#}", args.namespace),
            }
        }
        while let Some(bytes) = take(&mut own.save) {
            let reply = match save(args, live, &bytes) {
                Ok(path) => format!("saved {path}"),
                Err(e) => format!("error: {e:#}"),
            };
            eprintln!("{reply}");
            write(
                &own.saved,
                StringMessage { data: &reply }.encode(),
                "a save reply",
            );
        }
        // The services: success, a message, and for a query its cloud
        // (empty when it failed).
        while let Some(request) = own.query_service.take() {
            let p = &params.publishing;
            let answered = answer(p, live, &request.message);
            own.query_service.reply(request, |w| {
                let empty = Answer::default();
                let (a, message) = match &answered {
                    Ok(a) => (a, String::new()),
                    Err(e) => (&empty, format!("{e:#}")),
                };
                w.bool(answered.is_ok());
                w.string(&message);
                outputs::map_cloud_fields(w, &p.frame_id, a.stamp, &a.points, &a.fields);
            });
        }
        while let Some(request) = own.save_service.take() {
            let saved = save(args, live, &request.message);
            let message = match &saved {
                Ok(path) => path.clone(),
                Err(e) => format!("{e:#}"),
            };
            eprintln!("save service: {message}");
            own.save_service.reply(request, |w| {
                w.bool(saved.is_ok());
                w.string(&message);
            });
        }
        own.parameters
            .serve(&mut params, vocabulary.as_deref(), &args.namespace);
        std::thread::sleep(Duration::from_millis(20));
    }
    eprintln!("stopping: {}", summary(live, inputs));
    Ok(())
}

fn summary(live: &LiveMapper, inputs: &Inputs) -> String {
    let s = live.status();
    let stats = inputs
        .stats
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .clone();
    format!(
        "{} messages, {} frames, {} keyframes, {} frames dropped ({:?}); p99 from the message \
         completing a frame to the queue {} µs, from its colour image {} µs",
        stats.messages,
        stats.frames,
        s.keyframes,
        s.dropped.total(),
        s.dropped,
        p99(&stats.queue_latency_us).map_or("-".into(), |v| v.to_string()),
        p99(&stats.pairing_wait_us).map_or("-".into(), |v| v.to_string())
    )
}

/// The map's points (within `--map-points`) and their cosines to the
/// `n` embeddings back to back in `embeddings` (`points × n`), from the
/// newest snapshot whose relevance index is built.
fn scored_points(
    p: &Publishing,
    live: &LiveMapper,
    embeddings: &[f32],
    n: usize,
) -> Result<(Arc<MapSnapshot>, MapPoints, Vec<f32>)> {
    let query = TextQuery {
        embeddings: embeddings.to_vec(),
        texts: n,
        relevance: Scoring::Cosine,
    };
    let answer = live.relevance(&query)?;
    let points = MapPoints::of(&answer.snapshot.gaussians, p.map_points);
    let cosines = points.pick_rows(&answer.scores, n);
    Ok((answer.snapshot, points, cosines))
}

/// Column `k` of `rows` (`n` values a row).
fn column(rows: &[f32], n: usize, k: usize) -> Vec<f32> {
    rows.chunks_exact(n).map(|row| row[k]).collect()
}

/// The map cloud (with a relevance field per `--words` word once the
/// vocabulary is known) and the trajectory.
fn publish_map(
    p: &Publishing,
    live: &LiveMapper,
    vocabulary: Option<&Vocabulary>,
    own: &Own,
) -> Result<()> {
    let mut extra = Vec::new();
    let (snapshot, points) = match vocabulary {
        Some(v) if !p.words.is_empty() && live.snapshot().decoder.is_some() => {
            let n = v.names.len();
            let (snapshot, points, cosines) = scored_points(p, live, &v.vectors, n)?;
            let probabilities = softmax_rows(&cosines, n, p.temperature);
            for w in &p.words {
                let Some(k) = v.names.iter().position(|name| name == w) else {
                    bail!(
                        "--words: `{w}` is not in the vocabulary; it has: {}",
                        v.names.join(", ")
                    );
                };
                let field = format!(
                    "relevance_{}",
                    latentam_view::topic_word(w, &mut Vec::new())
                );
                extra.push((field, column(&probabilities, n, k)));
            }
            (snapshot, points)
        }
        _ => {
            let snapshot = live.snapshot();
            let points = MapPoints::of(&snapshot.gaussians, p.map_points);
            (snapshot, points)
        }
    };
    let stamp = snapshot.trajectory.last().map_or(0, |&(s, _)| s);
    write(
        &own.map,
        outputs::map_cloud(&p.frame_id, stamp, &points, &extra),
        "the map",
    );
    write(
        &own.trajectory,
        outputs::trajectory(&p.frame_id, &snapshot),
        "the trajectory",
    );
    Ok(())
}

/// A query's answer: the map's points at the stamp of the snapshot it
/// scored, with a relevance field per text.
#[derive(Default)]
struct Answer {
    stamp: i64,
    points: MapPoints,
    fields: Vec<(String, Vec<f32>)>,
}

/// A query: one text embedding scores by cosine; several by a softmax
/// over them; one `relevance_<name>` field each, on the map's points.
fn answer(p: &Publishing, live: &LiveMapper, bytes: &[u8]) -> Result<Answer> {
    let texts = Vocabulary::decode(bytes).map_err(|e| anyhow::anyhow!("{e}"))?;
    let n = texts.names.len();
    if n == 0 {
        bail!("the query holds no embedding");
    }
    let (snapshot, points, cosines) = scored_points(p, live, &texts.vectors, n)?;
    let values = if n == 1 {
        cosines
    } else {
        softmax_rows(&cosines, n, p.temperature)
    };
    let mut taken = Vec::new();
    let extra: Vec<(String, Vec<f32>)> = texts
        .names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            let field = format!("relevance_{}", latentam_view::topic_word(name, &mut taken));
            (field, column(&values, n, k))
        })
        .collect();
    Ok(Answer {
        stamp: snapshot.trajectory.last().map_or(0, |&(s, _)| s),
        points,
        fields: extra,
    })
}

/// A save request: the folder named in the message, else `--out`.
fn save(args: &Args, live: &LiveMapper, bytes: &[u8]) -> Result<String> {
    let msg = StringMessage::decode(bytes).map_err(|e| anyhow::anyhow!("{e}"))?;
    let dir = match (msg.data.trim(), &args.out) {
        ("", Some(out)) => out.clone(),
        ("", None) => bail!("a save request names no folder and the node has no --out"),
        (d, _) => d.into(),
    };
    Ok(live.save(&dir)?.display().to_string())
}

/// Writes the run folder `out` as `latentam map` does, whole or not at
/// all: the resumable state, `map.ply`, `trajectory.txt`, `config.toml`,
/// `report.json` and `report.html`.
fn save_run_folder(mut run: LogRun, out: &std::path::Path) -> Result<()> {
    let folder = RunFolder::lock(out)?;
    match run.write_folder(&folder, &mut HtmlReport)? {
        Written::Saved(report) => eprintln!(
            "saved {} ({} keyframes; report.json and report.html beside the map)",
            out.display(),
            report.keyframes
        ),
        Written::Kept(why) => eprintln!("{} kept as it was: {why}", out.display()),
    }
    Ok(())
}

/// Adds `report.html` beside `report.json`.
struct HtmlReport;

impl RunObserver for HtmlReport {
    fn write_extra_files(
        &mut self,
        dir: &std::path::Path,
        report: &RunReport,
    ) -> latentam::Result<()> {
        latentam_report::write_report_html(dir, report)
    }
}

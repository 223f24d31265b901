//! `latentam bench ingest`: CPU cost of turning log messages into frames.
//!
//! A frame set is a 640×480 `rgb8` colour image, a `16UC1` depth image, a
//! camera info, a pose and a `MaskFeatures` message (a full-resolution
//! label image and `regions × dim` f16 vectors). Three measurements, each
//! the calling thread's CPU time (`CLOCK_THREAD_CPUTIME_ID`):
//! * **decode**: CDR decoding of the three large messages (zero-copy views);
//! * **assemble**: pushing one frame set's serialized messages through the
//!   [`FrameAssembler`] and taking the checked, owned frame out (what the
//!   mapper pays per frame once the bytes are in memory), with frames
//!   handed back for reuse (`recycle`) and without (fresh buffers cost
//!   page faults);
//! * **from MCAP**: the whole path from a memory-mapped log, per frame
//!   (frames recycled), for
//!   uncompressed, lz4 and zstd chunks (the last two include
//!   decompression).

use std::path::PathBuf;

use anyhow::Result;
use latentam_io::{
    cdr, AssemblyConfig, CameraInfo, Channel, Compression, FrameAssembler, Header, Image,
    LogWriter, MaskFeatures, McapFrames, Pose, PoseStamped, RawMessage, RosMessage,
};
use serde::Serialize;

use super::common::{median, write_json};

/// Settings of `latentam bench ingest`.
pub struct IngestBench {
    pub width: u32,
    pub height: u32,
    pub regions: u32,
    pub dim: u32,
    pub frames: usize,
    pub json: Option<PathBuf>,
}

fn thread_cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: clock_gettime writes one timespec through a valid pointer.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

#[derive(Serialize)]
struct McapRow {
    compression: &'static str,
    file_mb: f64,
    cpu_ms_per_frame: f64,
    wall_ms_per_frame: f64,
}

#[derive(Serialize)]
struct Report {
    cpu: String,
    width: u32,
    height: u32,
    regions: u32,
    dim: u32,
    frames: usize,
    frame_set_mb: f64,
    decode_us_median: f64,
    assemble_ms_median: f64,
    assemble_ms_p90: f64,
    assemble_fresh_buffers_ms_median: f64,
    assemble_gbps: f64,
    from_mcap: Vec<McapRow>,
}

fn cpu_name() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into())
}

struct Topics {
    color: Channel,
    depth: Channel,
    info: Channel,
    pose: Channel,
    embeddings: Channel,
}

/// One frame set's serialized messages, in publication order.
fn frame_set(b: &IngestBench, i: usize) -> FrameSet {
    let (w, h) = (b.width, b.height);
    let t = 1_700_000_000_000_000_000 + i as i64 * 33_333_333;
    let header = Header::at(t, "camera");
    let color: Vec<u8> = (0..w * h * 3).map(|k| (k as usize ^ i) as u8).collect();
    let depth: Vec<u8> = (0..w * h)
        .flat_map(|k| (500 + (k % 4000) as u16).to_le_bytes())
        .collect();
    // Regions as vertical bands, so every label is in range.
    let labels: Vec<u8> = (0..w * h)
        .flat_map(|k| (((k % w) * b.regions / w) as u16).to_le_bytes())
        .collect();
    let data: Vec<u8> = (0..b.regions * b.dim)
        .flat_map(|k| half::f16::from_f32((k % 97) as f32 / 97.0).to_le_bytes())
        .collect();
    let image = |encoding, data: &[u8]| Image::packed(header, w, h, encoding, data).encode();
    vec![
        (
            2,
            t,
            // A Kinect-like camera (525 px at 640 wide), scaled to the size.
            {
                let f = 525.0 * w as f64 / 640.0;
                let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
                CameraInfo::pinhole(header, w, h, [f, f, cx, cy]).encode()
            },
        ),
        (
            3,
            t,
            PoseStamped {
                header: Header::at(t, "map"),
                pose: Pose::IDENTITY,
            }
            .encode(),
        ),
        (0, t, image("rgb8", &color)),
        (1, t, image("16UC1", &depth)),
        (
            4,
            t,
            MaskFeatures {
                header,
                height: h,
                width: w,
                labels: cdr::Seq::new(&labels, cdr::Endian::Little),
                count: b.regions,
                dim: b.dim,
                dtype: "f16",
                data: &data,
                model: "bench",
            }
            .encode(),
        ),
    ]
}

/// A frame set: (role, stamp, serialized message) in publication order.
type FrameSet = Vec<(u8, i64, Vec<u8>)>;

/// CPU time decoding each set's images and embeddings (zero-copy), µs.
fn decode_times(sets: &[FrameSet]) -> Result<Vec<f64>> {
    let mut decode_us = Vec::new();
    for set in sets {
        let t0 = thread_cpu_seconds();
        for (role, _, data) in set {
            match role {
                0 | 1 => {
                    std::hint::black_box(Image::decode(data)?);
                }
                4 => {
                    std::hint::black_box(MaskFeatures::decode(data)?);
                }
                _ => {}
            }
        }
        decode_us.push((thread_cpu_seconds() - t0) * 1e6);
    }
    Ok(decode_us)
}

/// CPU time assembling each set from its serialized messages, ms, frames
/// handed back to the pool (`recycle`) or not; the first two sets, which
/// only fill the pipeline and the pool, left out.
fn assemble_times(sets: &[FrameSet], by_role: &[&Channel; 5], recycle: bool) -> Result<Vec<f64>> {
    let mut assembler = FrameAssembler::new(AssemblyConfig::default(), true, false);
    let mut times = Vec::new();
    let mut frames_out = 0;
    for set in sets {
        let t0 = thread_cpu_seconds();
        for (role, t, data) in set {
            assembler.push(RawMessage {
                channel: by_role[*role as usize],
                log_time: *t as u64,
                data,
            })?;
        }
        while let Some(f) = assembler.pop() {
            std::hint::black_box(&f);
            frames_out += 1;
            if recycle {
                assembler.recycle(f);
            }
        }
        times.push((thread_cpu_seconds() - t0) * 1e3);
    }
    assembler.finish()?;
    frames_out += std::iter::from_fn(|| assembler.pop()).count();
    anyhow::ensure!(
        frames_out == sets.len(),
        "assembled {frames_out} of {} frames: {}",
        sets.len(),
        assembler.report()
    );
    // The first sets only fill the pipeline and the pool.
    Ok(times[2..].to_vec())
}

/// The whole path from a log, per chunk compression: the sets written to
/// an MCAP file, then read back into frames (page cache warm).
fn from_mcap_rows(sets: &[FrameSet], by_role: &[&Channel; 5]) -> Result<Vec<McapRow>> {
    let dir = std::env::temp_dir().join(format!("latentam-bench-ingest-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let mut from_mcap = Vec::new();
    for (name, compression) in [
        ("none", Compression::None),
        ("lz4", Compression::Lz4),
        ("zstd", Compression::Zstd),
    ] {
        let path = dir.join(format!("{name}.mcap"));
        let mut log = LogWriter::create(&path, compression)?;
        for set in sets {
            for (role, t, data) in set {
                let topic = &by_role[*role as usize].topic;
                match role {
                    0 | 1 => log.write_raw::<Image>(topic, *t as u64, data)?,
                    2 => log.write_raw::<CameraInfo>(topic, *t as u64, data)?,
                    3 => log.write_raw::<PoseStamped>(topic, *t as u64, data)?,
                    _ => log.write_raw::<MaskFeatures>(topic, *t as u64, data)?,
                }
            }
        }
        log.finish()?;
        let file_mb = std::fs::metadata(&path)?.len() as f64 / 1e6;
        // Warm the page cache, then measure.
        for f in McapFrames::open(&path, AssemblyConfig::default())? {
            std::hint::black_box(f?);
        }
        let wall = std::time::Instant::now();
        let t0 = thread_cpu_seconds();
        let mut n = 0;
        let mut frames = McapFrames::open(&path, AssemblyConfig::default())?;
        while let Some(f) = frames.next() {
            frames.recycle(std::hint::black_box(f?));
            n += 1;
        }
        let cpu = thread_cpu_seconds() - t0;
        let wall = wall.elapsed().as_secs_f64();
        anyhow::ensure!(
            n == sets.len(),
            "read {n} of {} frames from {name}",
            sets.len()
        );
        from_mcap.push(McapRow {
            compression: name,
            file_mb,
            cpu_ms_per_frame: cpu * 1e3 / n as f64,
            wall_ms_per_frame: wall * 1e3 / n as f64,
        });
        let _ = std::fs::remove_file(&path);
    }
    let _ = std::fs::remove_dir(&dir);
    Ok(from_mcap)
}

fn print_report(report: &Report) {
    println!(
        "ingest of {}×{} colour + 16UC1 depth + {} regions × {} f16 ({:.2} MB per frame set), {} frames, CPU: {}",
        report.width, report.height, report.regions, report.dim, report.frame_set_mb, report.frames, report.cpu
    );
    println!(
        "  CDR decode (zero-copy)          {:>8.1} µs median",
        report.decode_us_median
    );
    println!(
        "  assemble from memory            {:>8.3} ms median, {:.3} ms p90 ({:.1} GB/s), frames recycled",
        report.assemble_ms_median, report.assemble_ms_p90, report.assemble_gbps
    );
    println!(
        "  assemble, fresh buffers         {:>8.3} ms median (frames not recycled)",
        report.assemble_fresh_buffers_ms_median
    );
    for r in &report.from_mcap {
        println!(
            "  from MCAP, {:<5} chunks         {:>8.3} ms CPU per frame, {:.3} ms wall ({:.1} MB file)",
            r.compression, r.cpu_ms_per_frame, r.wall_ms_per_frame, r.file_mb
        );
    }
}

pub fn run(b: IngestBench) -> Result<()> {
    anyhow::ensure!(b.frames >= 4, "--frames must be at least 4");
    let topics = Topics {
        color: Channel::ros2("/camera/color/image_raw", Image::TYPE_NAME),
        depth: Channel::ros2("/camera/depth/image_raw", Image::TYPE_NAME),
        info: Channel::ros2("/camera/color/camera_info", CameraInfo::TYPE_NAME),
        pose: Channel::ros2("/camera/pose", PoseStamped::TYPE_NAME),
        embeddings: Channel::ros2("/camera/embeddings", MaskFeatures::TYPE_NAME),
    };
    let by_role = [
        &topics.color,
        &topics.depth,
        &topics.info,
        &topics.pose,
        &topics.embeddings,
    ];
    eprintln!(
        "building {} frame sets of {}×{} …",
        b.frames, b.width, b.height
    );
    let sets: Vec<_> = (0..b.frames).map(|i| frame_set(&b, i)).collect();
    let set_bytes: usize = sets[0].iter().map(|m| m.2.len()).sum();

    let decode_us = decode_times(&sets)?;

    // Assembly from serialized messages in memory, with frames recycled
    // (steady state of a mapper that hands frames back) and without.
    let fresh = assemble_times(&sets, &by_role, false)?;
    let steady = assemble_times(&sets, &by_role, true)?;
    let mut sorted = steady.clone();
    sorted.sort_by(f64::total_cmp);
    let p90 = sorted[(sorted.len() * 9 / 10).min(sorted.len() - 1)];

    let from_mcap = from_mcap_rows(&sets, &by_role)?;

    let assemble = median(&steady);
    let report = Report {
        cpu: cpu_name(),
        width: b.width,
        height: b.height,
        regions: b.regions,
        dim: b.dim,
        frames: b.frames,
        frame_set_mb: set_bytes as f64 / 1e6,
        decode_us_median: median(&decode_us),
        assemble_ms_median: assemble,
        assemble_ms_p90: p90,
        assemble_fresh_buffers_ms_median: median(&fresh),
        assemble_gbps: set_bytes as f64 / (assemble * 1e-3) / 1e9,
        from_mcap,
    };
    print_report(&report);
    write_json(b.json.as_deref(), &report)
}

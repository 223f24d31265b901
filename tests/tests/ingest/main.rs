//! Converters, the demo scene and the MCAP reader end to end, on the real
//! test data in `../shared/data` and on generated folders, one module per
//! data set; here, what they share.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use latentam::embedding_files::npy;
use latentam_cli::convert::features::FeatureDir;
use latentam_cli::convert::oracle::Oracle;
use latentam_cli::convert::{convert, datasets, ConvertOptions, EmbeddingSource, Registration};
use latentam_io::{
    codec, AssemblyConfig, Compression, DepthData, Dtype, EmbeddingLayout, Frame, McapFrames,
};
use latentam_tests::shared_data;

mod demo_scene;
mod features;
mod replica_and_tum;
mod seven_scenes;

/// A directory removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        use std::sync::atomic::{AtomicUsize, Ordering};
        static N: AtomicUsize = AtomicUsize::new(0);
        let p = std::env::temp_dir().join(format!(
            "latentam-it-{tag}-{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn options(kind: &str, embeddings: EmbeddingSource, max_frames: Option<usize>) -> ConvertOptions {
    ConvertOptions {
        embeddings,
        intrinsics: None,
        registration: Registration::Dataset,
        raw_depth: false,
        depth_units_per_metre: None,
        dtype: Dtype::F16,
        compression: Compression::Zstd,
        max_frames,
        kind: kind.into(),
        source: PathBuf::from("test"),
    }
}

/// The shared 7-Scenes frames converted into `out` with `options`.
fn convert_seven_scenes(
    out: &Path,
    options: ConvertOptions,
) -> latentam_cli::convert::ConvertSummary {
    let src = shared_data("7scenes-redkitchen");
    convert(
        datasets::seven_scenes(&src, 30.0).unwrap(),
        &options,
        out,
        |_, _| {},
    )
    .unwrap()
}

fn frames_of(path: &Path) -> (Vec<Frame>, latentam_io::IngestReport) {
    let mut it = McapFrames::open(path, AssemblyConfig::default()).unwrap();
    let frames: Vec<Frame> = (&mut it).map(|f| f.unwrap()).collect();
    (frames, it.report().clone())
}

fn depth_units(f: &Frame) -> &[u16] {
    match &f.depth.data {
        DepthData::Units { values, .. } => values,
        other => panic!("expected integer depth, got {other:?}"),
    }
}

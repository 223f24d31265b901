//! `latentam export`: a mapped run for other tools. `--foxglove` writes
//! the map as a Foxglove point cloud, one relevance cloud per vocabulary
//! word and the keyframe trajectory, to open beside the bag it came from.

use std::path::{Path, PathBuf};

use crate::own_inputs::{refuse_overwriting_inputs, Input};

use anyhow::{bail, Context as _, Result};
use latentam::frames::{read_vocabulary, CameraPose, Vocabulary};
use latentam::text::{shown, shown_path};
use latentam::{softmax_rows, Mapper, Scored, Scoring, TextQuery};
use latentam_cli::progress::Stages;

use crate::pictures::to_bytes;
use latentam_view::{heat_rgba, topic_word, write_foxglove_file, Cloud};

#[derive(clap::Args)]
pub struct Args {
    /// Run folder written by `latentam map`.
    pub dir: PathBuf,
    /// Write a Foxglove file (MCAP, Foxglove's protobuf messages):
    /// `/latentam/map` (foxglove.PointCloud: position, colour, alpha =
    /// opacity, and an `opacity` field), `/latentam/relevance/WORD` per
    /// vocabulary word (a `relevance` field: the softmax over the
    /// vocabulary, coloured blue to red) and `/latentam/trajectory`
    /// (foxglove.PosesInFrame, the keyframe poses).
    #[arg(long, value_name = "OUT.mcap")]
    pub foxglove: PathBuf,
    /// Log holding the vocabulary for the relevance clouds; default: the
    /// mapped log named in the run's report.json, when it has one.
    #[arg(long, value_name = "LOG")]
    pub vocabulary: Option<PathBuf>,
    /// Topic of the vocabulary in that log.
    #[arg(long, default_value = "/vocabulary")]
    pub vocabulary_topic: String,
    /// Only these vocabulary words (comma-separated); default: every word.
    #[arg(long, value_delimiter = ',', value_name = "WORD,...")]
    pub words: Vec<String>,
    /// Softmax temperature over the vocabulary.
    #[arg(long, default_value_t = 0.1)]
    pub temperature: f32,
    /// Frame id of every message: the world frame of the mapped poses
    /// (e.g. the `--tf-world` frame of the bag).
    #[arg(long, default_value = "map")]
    pub frame_id: String,
}

/// The vocabulary to score against, and the log it came from; `None` when
/// none was given and the mapped log has none (or is gone).
fn vocabulary_of(args: &Args) -> Result<Option<(Vocabulary, PathBuf)>> {
    if let Some(log) = &args.vocabulary {
        let v = read_vocabulary(log, &args.vocabulary_topic)?.with_context(|| {
            format!(
                "{} has no vocabulary on {}",
                log.display(),
                args.vocabulary_topic
            )
        })?;
        return Ok(Some((v, log.clone())));
    }
    let Some(report) = crate::loaded_map::read_run_report(&args.dir)? else {
        return Ok(None);
    };
    let Some(log) = report_log(&report) else {
        return Ok(None);
    };
    // The mapped log is a convenience: one without a vocabulary (or no
    // longer readable) only means no relevance clouds.
    Ok(read_vocabulary(&log, &args.vocabulary_topic)
        .ok()
        .flatten()
        .map(|v| (v, log)))
}

/// The mapped log a run's report names, when it names an existing file
/// by an absolute path. Reports from before paths were made absolute name
/// the log as it was given, relative to a directory that is unknown now:
/// such a path is not guessed from the current directory.
fn report_log(report: &serde_json::Value) -> Option<PathBuf> {
    report["log"]
        .as_str()
        .map(PathBuf::from)
        .filter(|p| p.is_absolute() && p.is_file())
}

pub fn run(args: Args) -> Result<()> {
    latentam::TextQuery::check_temperature(args.temperature)
        .map_err(latentam_args::flag_error("--temperature"))?;
    if args.frame_id.trim().is_empty() {
        bail!("--frame-id must name a frame");
    }
    // The mapped log named in the run's report is read for its vocabulary.
    let mapped_log = crate::loaded_map::read_run_report(&args.dir)?.and_then(|r| report_log(&r));
    let mut inputs = vec![Input::RunFolder(&args.dir)];
    inputs.extend(args.vocabulary.as_deref().map(Input::File));
    inputs.extend(mapped_log.as_deref().map(Input::File));
    refuse_overwriting_inputs(&inputs, &[("--foxglove", &args.foxglove)])?;
    let stages = Stages::new("export");
    let (_ctx, mut mapper) = crate::loaded_map::load_nonempty_map(&stages, &args.dir, "export")?;
    // What the Foxglove file shows of each Gaussian, taken from a snapshot
    // that is dropped here (its queries are most of its size).
    let (positions, opacity, colours, trajectory, has_head) = {
        let map = mapper.snapshot()?;
        let g = map.gaussians;
        let opacity: Vec<f32> = g
            .opacity_logits
            .iter()
            .map(|l| 1.0 / (1.0 + (-l).exp()))
            .collect();
        let colours: Vec<[u8; 4]> = g
            .colors
            .iter()
            .zip(&opacity)
            .map(|(&c, &a)| {
                let [r, gr, b] = to_bytes(c);
                [r, gr, b, to_bytes([a; 3])[0]]
            })
            .collect();
        (
            g.means,
            opacity,
            colours,
            map.trajectory,
            map.decoder.is_some(),
        )
    };
    let stamp = trajectory.last().map_or(0, |&(s, _)| s.max(0) as u64);

    // Relevance per word: a softmax over the whole vocabulary, as
    // `query --name` gives it.
    let mut relevance: Vec<WordRelevance> = Vec::new();
    let vocabulary = if has_head {
        vocabulary_of(&args)?
    } else {
        None
    };
    if !args.words.is_empty() && vocabulary.is_none() {
        bail!(
            "--words needs a vocabulary: {}",
            if has_head {
                "give --vocabulary LOG"
            } else {
                "the map was mapped without embeddings"
            }
        );
    }
    if let Some((vocab, log)) = &vocabulary {
        relevance = word_relevance(&args, &stages, &mut mapper, vocab, log)?;
    }

    stages.start(format_args!("writing {}", args.foxglove.display()));
    write_foxglove_file(&args.foxglove, &args.frame_id, |topics| {
        topics.cloud(
            "/latentam/map",
            stamp,
            &Cloud {
                positions: &positions,
                colours: &colours,
                value: ("opacity", &opacity),
            },
        )?;
        for (_, word, rel) in &relevance {
            let heat_colours: Vec<[u8; 4]> = rel.iter().map(|&r| heat_rgba(r)).collect();
            topics.cloud(
                &format!("/latentam/relevance/{word}"),
                stamp,
                &Cloud {
                    positions: &positions,
                    colours: &heat_colours,
                    value: ("relevance", rel),
                },
            )?;
        }
        let poses: Vec<CameraPose> = trajectory.iter().map(|&(_, p)| p).collect();
        topics.poses("/latentam/trajectory", stamp, &poses)?;
        Ok(())
    })?;
    print_summary(
        &args.foxglove,
        positions.len(),
        &relevance,
        trajectory.len(),
        &args.frame_id,
        has_head,
        vocabulary.is_some(),
    );
    Ok(())
}

/// A word, its topic name and each Gaussian's relevance to it.
type WordRelevance = (String, String, Vec<f32>);

/// The relevance of every Gaussian to each word `args` asks for (all of
/// `vocab` when none): a softmax over the whole vocabulary, as
/// `query --name` gives it.
fn word_relevance(
    args: &Args,
    stages: &Stages,
    mapper: &mut Mapper,
    vocab: &Vocabulary,
    log: &Path,
) -> Result<Vec<WordRelevance>> {
    mapper
        .stats()
        .check_vocabulary(vocab)
        .with_context(|| format!("the vocabulary in {}", log.display()))?;
    for w in &args.words {
        if !vocab.names.contains(w) {
            bail!(
                "`{w}` is not in the vocabulary; it has: {}",
                vocab.names.join(", ")
            );
        }
    }
    let count = vocab.names.len();
    stages.start(format_args!(
        "scoring {} Gaussians against {count} words of {}",
        mapper.stats().gaussians,
        log.display()
    ));
    let cosines = TextQuery {
        embeddings: vocab.vectors.clone(),
        texts: count,
        relevance: Scoring::Cosine,
    };
    let cosines = mapper.relevance(&cosines, Scored::Gaussians)?;
    let probabilities = softmax_rows(&cosines, count, args.temperature);
    let mut relevance = Vec::new();
    let mut taken = Vec::new();
    for (index, name) in vocab.names.iter().enumerate() {
        if !args.words.is_empty() && !args.words.contains(name) {
            continue;
        }
        let rel: Vec<f32> = probabilities
            .chunks_exact(count)
            .map(|row| row[index])
            .collect();
        relevance.push((name.clone(), topic_word(name, &mut taken), rel));
    }
    Ok(relevance)
}

fn print_summary(
    path: &Path,
    gaussians: usize,
    relevance: &[WordRelevance],
    poses: usize,
    frame_id: &str,
    has_head: bool,
    has_vocabulary: bool,
) {
    println!("{} (frame `{}`):", shown_path(path), shown(frame_id));
    println!("  /latentam/map  {gaussians} points");
    for (name, word, _) in relevance {
        println!(
            "  /latentam/relevance/{word}  relevance of `{}`",
            shown(name)
        );
    }
    println!("  /latentam/trajectory  {poses} keyframe poses");
    if !has_head {
        println!("  (mapped without embeddings: no relevance clouds)");
    } else if !has_vocabulary {
        println!("  (no vocabulary: give --vocabulary LOG for relevance clouds)");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn topic_words_are_safe_and_unique() {
        let mut taken = Vec::new();
        assert_eq!(topic_word("Coffee table", &mut taken), "coffee_table");
        assert_eq!(topic_word("coffee-table", &mut taken), "coffee_table_2");
        assert_eq!(topic_word("  ", &mut taken), "word");
        assert_eq!(topic_word("é/x", &mut taken), "__x");
    }
}

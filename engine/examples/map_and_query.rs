//! The README's "Library use" as a program: map a log, ask the map which
//! Gaussians match a word of the log's vocabulary, save it.
//!
//! ```sh
//! latentam gen-scene -o scene.mcap
//! cargo run --release -p latentam --example map_and_query -- scene.mcap out/ chair
//! ```

use latentam::frames::{read_vocabulary, AssemblyConfig, McapFrames};
use latentam::{Scored, TextQuery};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, log, out, word] = args.as_slice() else {
        return Err("usage: map_and_query LOG OUT_DIR WORD".into());
    };
    let config = latentam::Config::from_toml("gpu_budget = 2_000_000_000")?;
    let mut mapper = latentam::Mapper::new(config)?;
    for frame in McapFrames::open(log.as_ref(), AssemblyConfig::default())? {
        mapper.integrate(&frame?)?; // keyframes are mapped, others skipped
    }
    // A robot gets its text embedding from its vision-language model; the
    // demo scene carries its vocabulary's.
    let vocabulary =
        read_vocabulary(log.as_ref(), "/vocabulary")?.ok_or("the log has no vocabulary")?;
    let i = vocabulary
        .names
        .iter()
        .position(|n| n == word)
        .ok_or_else(|| format!("`{word}` is not in the vocabulary {:?}", vocabulary.names))?;
    let d = vocabulary.dim as usize;
    let word_embedding = TextQuery::embedding(vocabulary.vectors[i * d..(i + 1) * d].to_vec());
    let scores = mapper.relevance(&word_embedding, Scored::Gaussians)?; // one per Gaussian
    let state = mapper.save(out)?;
    let stats = mapper.stats();
    let best = scores.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
    println!(
        "{} keyframes, {} Gaussians; `{word}`: best relevance {best:.3}; saved {}",
        stats.keyframes,
        scores.len(),
        state.display()
    );
    Ok(())
}

//! The vocabulary a log carries: class names with their text embeddings.

use std::path::Path;

use super::log::{McapLog, ReadFilter};
use super::messages::{RosMessage, TextEmbeddings};
use super::parts::check_vectors;
use super::InputError;
use latentam_base::Rejection;

/// The vocabulary found in a log.
///
/// ```no_run
/// # fn f(query: impl Fn(&[f32]) -> latentam_io::Result<Vec<f32>>) -> Result<(), Box<dyn std::error::Error>> {
/// let vocab = latentam_io::read_vocabulary("scene.mcap".as_ref(), "/vocabulary")?.expect("a vocabulary");
/// // Score the map against the text embedding of one class.
/// let i = vocab.names.iter().position(|n| n == "chair").expect("`chair` in the vocabulary");
/// let d = vocab.dim as usize;
/// let scores = query(&vocab.vectors[i * d..(i + 1) * d])?; // `latentam::Mapper::relevance`
/// println!("class {} ({}): {} Gaussians scored", vocab.ids[i], vocab.model, scores.len());
/// # Ok(())
/// # }
/// ```
#[derive(Clone, Debug, PartialEq)]
pub struct Vocabulary {
    /// Class names.
    pub names: Vec<String>,
    /// Class id of each name.
    pub ids: Vec<u16>,
    /// Embedding dimension.
    pub dim: u32,
    /// `names.len() × dim` vectors.
    pub vectors: Vec<f32>,
    /// Embedding model id.
    pub model: String,
}

/// The first query vocabulary (`TextEmbeddings`) on `topic` of the log at
/// `path`, without assembling frames: `Ok(None)` when the topic carries
/// none. A vocabulary message that does not decode is an error, since the
/// caller asked for exactly that message.
///
/// ```no_run
/// let vocab = latentam_io::read_vocabulary("scene.mcap".as_ref(), "/vocabulary")?;
/// if let Some(v) = vocab {
///     println!("{} classes of {}-d {} embeddings", v.names.len(), v.dim, v.model);
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
pub fn read_vocabulary(path: &Path, topic: &str) -> Result<Option<Vocabulary>, InputError> {
    let log = McapLog::open(path)?;
    let mut reader = log.reader(ReadFilter {
        topics: Some(vec![topic.to_string()]),
        ..Default::default()
    });
    let Some(next) = reader.next_with(|m| {
        let reject = |rejection| InputError::Rejected {
            topic: topic.to_string(),
            stamp_ns: m.log_time as i64,
            rejection,
        };
        let msg = TextEmbeddings::decode(m.data).map_err(|e| {
            reject(Rejection::new(
                "vocabulary: undecodable message",
                e.to_string(),
            ))
        })?;
        vocabulary_of(&msg).map_err(reject)
    }) else {
        return Ok(None);
    };
    Ok(Some(next??))
}

impl Vocabulary {
    /// The vocabulary in a serialized `latentam_msgs/TextEmbeddings`
    /// message (a live query, a vocabulary topic).
    ///
    /// ```no_run
    /// # fn f(bytes: &[u8]) -> Result<(), latentam_io::Rejection> {
    /// let words = latentam_io::Vocabulary::decode(bytes)?;
    /// println!("{} words of {} dimensions", words.names.len(), words.dim);
    /// # Ok(())
    /// # }
    /// ```
    pub fn decode(bytes: &[u8]) -> Result<Vocabulary, Rejection> {
        let msg = TextEmbeddings::decode(bytes)
            .map_err(|e| Rejection::new("vocabulary: undecodable message", e.to_string()))?;
        vocabulary_of(&msg)
    }
}

pub(super) fn vocabulary_of(m: &TextEmbeddings<'_>) -> Result<Vocabulary, Rejection> {
    if m.names.len() != m.ids.len() {
        return Err(Rejection::new(
            "vocabulary: size mismatch",
            format!("{} names but {} ids", m.names.len(), m.ids.len()),
        ));
    }
    let dtype = check_vectors(
        "vocabulary: size mismatch",
        m.names.len() as u64,
        m.dim,
        m.dtype,
        m.data.len(),
    )?;
    let names: Vec<String> = m.names.iter().map(|s| s.to_string()).collect();
    let mut seen = std::collections::HashSet::new();
    if let Some(twice) = names.iter().find(|n| !seen.insert(n.as_str())) {
        return Err(Rejection::new(
            "vocabulary: duplicate name",
            format!("`{twice}` appears more than once"),
        ));
    }
    let vectors = super::frame::decode_floats(m.data, dtype);
    for (name, v) in names.iter().zip(vectors.chunks_exact(m.dim as usize)) {
        if v.iter().any(|x| !x.is_finite()) || v.iter().all(|&x| x == 0.0) {
            return Err(Rejection::new(
                "vocabulary: unusable vector",
                format!("the embedding of `{name}` is zero or holds NaN or infinite values"),
            ));
        }
    }
    Ok(Vocabulary {
        names,
        ids: m.ids.to_vec(),
        dim: m.dim,
        vectors,
        model: m.model.to_string(),
    })
}

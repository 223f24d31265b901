//! `latentam_msgs`: region and grid embeddings and the query vocabulary.

use super::common::Header;
use super::message::RosMessage;
use crate::cdr::Seq;
use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// `latentam_msgs/MaskFeatures`: one embedding per region of a label image.
///
/// ```
/// use latentam_io::cdr::{Endian, Seq};
/// use latentam_io::{encode_floats, Dtype, Header, MaskFeatures};
///
/// // Two regions on a 2×2 mask (one pixel in none), with 4-d embeddings.
/// let labels: Vec<u8> = [0u16, 0, 1, 65535].iter().flat_map(|l| l.to_le_bytes()).collect();
/// let data = encode_floats(&[1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0], Dtype::F16);
/// let msg = MaskFeatures {
///     header: Header::at(1_000, "camera"), height: 2, width: 2,
///     labels: Seq::new(&labels, Endian::Little), count: 2, dim: 4,
///     dtype: "f16", data: &data, model: "clip-vit-b16",
/// };
/// assert_eq!(msg.labels.get(2), Some(1));
/// ```
#[derive(Clone, Copy, Debug)]
pub struct MaskFeatures<'a> {
    /// Stamp of the colour image the regions belong to.
    pub header: Header<'a>,
    /// Label image rows.
    pub height: u32,
    /// Label image columns.
    pub width: u32,
    /// Row-major region index per pixel, 65535 = none.
    pub labels: Seq<'a, u16>,
    /// Number of regions.
    pub count: u32,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32` (little-endian).
    pub dtype: &'a str,
    /// `count × dim` vectors.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

cdr_message! {
    MaskFeatures = "latentam_msgs/msg/MaskFeatures" {
        header: header,
        height: read,
        width: read,
        labels: seq,
        count: read,
        dim: read,
        dtype: string,
        data: bytes,
        model: string,
    }
}

/// `latentam_msgs/FeatureGrid`: embeddings on a coarse grid.
///
/// ```
/// use latentam_io::{encode_floats, Compression, Dtype, FeatureGrid, Header, LogWriter};
///
/// let values = vec![0.5f32; 2 * 3 * 8]; // a 2×3 grid of 8-d embeddings
/// let data = encode_floats(&values, Dtype::F32);
/// let grid = FeatureGrid {
///     header: Header::at(1_000, "camera"), rows: 2, cols: 3, dim: 8,
///     dtype: "f32", data: &data, model: "clip-vit-b16",
/// };
/// let mut log = LogWriter::new(std::io::Cursor::new(Vec::new()), Compression::Zstd)?;
/// log.write("/camera/embeddings", 1_000, &grid)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct FeatureGrid<'a> {
    /// Stamp of the colour image.
    pub header: Header<'a>,
    /// Grid rows.
    pub rows: u32,
    /// Grid columns.
    pub cols: u32,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32`.
    pub dtype: &'a str,
    /// `rows × cols × dim` values.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

cdr_message! {
    FeatureGrid = "latentam_msgs/msg/FeatureGrid" {
        header: header,
        rows: read,
        cols: read,
        dim: read,
        dtype: string,
        data: bytes,
        model: string,
    }
}

/// `latentam_msgs/TextEmbeddings`: the query vocabulary.
///
/// ```
/// use latentam_io::cdr::{Endian, Seq};
/// use latentam_io::{encode_floats, Compression, Dtype, Header, LogWriter, TextEmbeddings};
///
/// let ids: Vec<u8> = [3u16, 7].iter().flat_map(|i| i.to_le_bytes()).collect();
/// let data = encode_floats(&[1.0, 0.0, 0.0, 1.0], Dtype::F32); // one 2-d vector per name
/// let vocabulary = TextEmbeddings {
///     header: Header::at(0, ""), names: vec!["chair", "table"], ids: Seq::new(&ids, Endian::Little),
///     dim: 2, dtype: "f32", data: &data, model: "clip-vit-b16",
/// };
/// let mut log = LogWriter::new(std::io::Cursor::new(Vec::new()), Compression::Zstd)?;
/// log.write("/vocabulary", 0, &vocabulary)?;
/// log.finish()?;
/// # Ok::<(), latentam_io::InputError>(())
/// ```
#[derive(Clone, Debug)]
pub struct TextEmbeddings<'a> {
    /// Stamp.
    pub header: Header<'a>,
    /// Class names.
    pub names: Vec<&'a str>,
    /// Class id of each name, as in the semantic label images.
    pub ids: Seq<'a, u16>,
    /// Embedding dimension.
    pub dim: u32,
    /// `f16` or `f32`.
    pub dtype: &'a str,
    /// `names.len() × dim` values.
    pub data: &'a [u8],
    /// Embedding model id.
    pub model: &'a str,
}

cdr_message! {
    TextEmbeddings = "latentam_msgs/msg/TextEmbeddings" {
        header: header,
        names: strings,
        ids: seq,
        dim: read,
        dtype: string,
        data: bytes,
        model: string,
    }
}

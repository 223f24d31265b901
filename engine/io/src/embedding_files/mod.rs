//! The embedding files users bring, as `.npy` arrays (format versions
//! 1–3, little-endian, C order) and safetensors files:
//!
//! * one frame's embeddings from a feature extractor
//!   ([`features_from_safetensors`], [`regions_from_npy`],
//!   [`grid_from_npy`] into [`FrameFeatures`]);
//! * class vectors and class-id images, which oracle embeddings are made
//!   of ([`ClassVectors`], [`class_ids_from_npy`]);
//! * one vector to query a map with ([`read_vector`],
//!   [`vector_from_bytes`]);
//! * the `.npy` format itself ([`npy`]).
//!
//! The readers take a file's bytes and a name for it (`origin`) and refuse
//! what they cannot use with an error beginning with that name:
//! [`Error::Damaged`](crate::Error::Damaged) for a file that is no `.npy`
//! or safetensors file (cut short, another version or byte order, a
//! safetensors header naming a key twice), and
//! [`Error::BadInput`](crate::Error::BadInput) for one whose contents they
//! cannot use (a type or shape they do not take, a non-finite value, a
//! label out of range, a dimension or size a log cannot hold). They never
//! panic on any bytes (the fuzz target `embedding_files` drives them all).

mod class_vectors;
mod features;
pub mod npy;
mod query_vector;
mod tensor;

pub use class_vectors::{class_ids_from_npy, ClassVectors};
pub use features::{
    features_from_safetensors, grid_from_npy, regions_from_npy, FrameFeatures, LoadedFeatures,
};
pub use npy::{Npy, NpyType};
pub use query_vector::{read_vector, vector_from_bytes};

#[cfg(test)]
mod tests;

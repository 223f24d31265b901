//! The latent feature head: region pooling of rendered queries, the
//! dictionary attention decoder, and the streaming k-means that maintains the
//! dictionary. CPU references live in the same-named modules of
//! [`crate::reference`].

mod decoder;

pub use decoder::{AttentionDecoder, DecoderConfig, DecoderGrads, DecoderParams};

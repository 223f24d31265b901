//! The latent feature head: region pooling of rendered queries, the
//! dictionary attention decoder, and the streaming k-means that maintains the
//! dictionary, and [`LatentHead`], which owns W, D and D⁰ and trains them.
//! CPU references live in the same-named modules of
//! `latentam_reference`.

mod decoder;
mod device_pixel_decoder;
mod head;
mod host_decoder;
mod kmeans;
mod pixel_decoder;
mod pooling;
mod query_init;
mod relevance;

pub use decoder::{AttentionDecoder, DecoderConfig, DecoderGrads, DecoderParams};
pub(crate) use device_pixel_decoder::unit_rows;
pub use device_pixel_decoder::{DecodedPixels, DevicePixelDecoder, PixelsToDecode, TextOutput};
pub use head::{LatentHead, LatentHeadConfig};
pub use host_decoder::HostDecoder;
pub use kmeans::{KMeansConfig, KMeansStep, StreamingKMeans, MAX_KMEANS_ATOMS};
pub use pixel_decoder::{FactorisedDecoder, NORM_CUTOFF};
pub use pooling::{
    LabelImage, RegionCounts, RegionPooling, RegionRows, RegionSource, Regions, ViewRegions,
    NO_REGION, NO_REGION_LABEL,
};
pub use query_init::projected_queries;
pub use relevance::{
    softmax_rows, Relevance, RelevanceScorer, TextQuery, MAX_TEMPERATURE, MIN_TEMPERATURE,
};

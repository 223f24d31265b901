//! Reading MCAP logs: one file or a rosbag2 directory of split files,
//! memory-mapped, read through the summary's chunk index by topic and time
//! (or scanned linearly when a file has no summary, e.g. a recording that
//! was cut off). Only the chunks being read are decompressed, so a log far
//! larger than RAM streams.
//!
//! Every chunk that carries a CRC is checked against it, on both paths,
//! before any of its messages is handed out: a flipped bit in an image
//! would otherwise be mapped as if it were what the camera saw.

mod chunks;
mod file;
mod mcap_log;
mod reader;
mod records;

pub use mcap_log::McapLog;
pub use reader::MessageReader;
pub use records::{Channel, Metadata, RawMessage, ReadFilter, MAX_RECORD_BYTES};

//! Chunks of an MCAP file: which need no decompression, unpacking one
//! with its CRC checked, and saying where a damaged one lies.

use std::collections::HashMap;

use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::McapError;

use super::records::MAX_RECORD_BYTES;

/// The summary as the indexed reader is given it, with every chunk
/// described as uncompressed.
///
/// `IndexedReader` decompresses what it is handed but never checks a
/// chunk's CRC (the CRC is in the chunk record's header, which it does not
/// read). So each chunk is decompressed and checked here first (see
/// [`unpack_chunk`]), and the reader is handed the plain records;
/// describing them as uncompressed keeps it from decompressing a second
/// time.
pub(super) struct PlainChunks {
    pub(super) summary: mcap::Summary,
    /// The file's own chunk index of each chunk, by the data offset the
    /// reader asks for.
    pub(super) original: HashMap<u64, mcap::records::ChunkIndex>,
}

impl PlainChunks {
    pub(super) fn new(summary: &mcap::Summary) -> Self {
        let mut plain = summary.clone();
        let mut original = HashMap::new();
        for index in &mut plain.chunk_indexes {
            let file_index = index.clone();
            index.compression.clear();
            index.compressed_size = index.uncompressed_size;
            // An offset that overflows is refused by the reader itself.
            if let Ok(offset) = index.compressed_data_offset() {
                original.insert(offset, file_index);
            }
        }
        PlainChunks {
            summary: plain,
            original,
        }
    }
}

/// Why a chunk could not be unpacked.
pub(super) enum ChunkProblem {
    /// The index points past the end of the file.
    Truncated,
    /// The index points at something other than a chunk record.
    NotAChunk,
    /// The chunk's records do not match its CRC.
    Crc { saved: u32, calculated: u32 },
    /// Anything else the chunk record gets wrong.
    Corrupt(String),
}

impl From<McapError> for ChunkProblem {
    fn from(e: McapError) -> Self {
        match e {
            McapError::BadChunkCrc { saved, calculated } => ChunkProblem::Crc { saved, calculated },
            e => ChunkProblem::Corrupt(e.to_string()),
        }
    }
}

/// The records of the chunk `index` describes, checked against the
/// chunk's CRC (when it has one) before anything reads them: for an
/// uncompressed chunk, the file's own bytes; for a compressed one,
/// decompressed into `scratch`.
pub(super) fn unpack_chunk<'a>(
    map: &'a [u8],
    index: &mcap::records::ChunkIndex,
    scratch: &'a mut Vec<u8>,
) -> Result<&'a [u8], ChunkProblem> {
    let record = usize::try_from(index.chunk_start_offset)
        .ok()
        .zip(usize::try_from(index.chunk_length).ok())
        .and_then(|(start, len)| map.get(start..start.checked_add(len)?))
        .ok_or(ChunkProblem::Truncated)?;
    if record.first() != Some(&mcap::records::op::CHUNK) {
        return Err(ChunkProblem::NotAChunk);
    }
    // The chunk header after the opcode and record length: start and end
    // times, uncompressed size, CRC, compression (a length-prefixed
    // string), compressed size, then the data.
    let field = |at: usize, n: usize| record.get(9 + at..9 + at + n);
    let le_u64 = |b: &[u8]| u64::from_le_bytes(b.try_into().expect("8 bytes"));
    let le_u32 = |b: &[u8]| u32::from_le_bytes(b.try_into().expect("4 bytes"));
    let header = field(16, 24).ok_or(ChunkProblem::Truncated)?;
    let (uncompressed, saved, compression_len) = (
        le_u64(&header[..8]),
        le_u32(&header[8..12]),
        le_u32(&header[12..16]),
    );
    if compression_len == 0 {
        // Uncompressed: the data is the records, hashed where it lies.
        let size = le_u64(&header[16..24]);
        let data = usize::try_from(size)
            .ok()
            .and_then(|n| field(40, n))
            .ok_or_else(|| {
                ChunkProblem::Corrupt(format!("its {size} bytes of data overrun the record"))
            })?;
        if size != uncompressed {
            return Err(ChunkProblem::Corrupt(format!(
                "uncompressed, yet {size} bytes of data for {uncompressed} bytes of records"
            )));
        }
        if saved != 0 {
            let calculated = crc32fast::hash(data);
            if calculated != saved {
                return Err(ChunkProblem::Crc { saved, calculated });
            }
        }
        return Ok(data);
    }
    // Compressed: a linear reader over just this record decompresses it,
    // checks the CRC before yielding the first record (and refuses sizes
    // beyond the limit before allocating), then yields the records, which
    // are framed again here as they were before compression.
    let options = LinearReaderOptions::default()
        .with_skip_start_magic(true)
        .with_skip_end_magic(true)
        .with_prevalidate_chunk_crcs(true)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = LinearReader::new_with_options(options);
    let mut rest = record;
    scratch.clear();
    while let Some(event) = reader.next_event() {
        match event? {
            LinearReadEvent::ReadRequest(need) => {
                let n = need.min(rest.len());
                reader.insert(n).copy_from_slice(&rest[..n]);
                reader.notify_read(n);
                rest = &rest[n..];
            }
            LinearReadEvent::Record { data, opcode } => {
                scratch.push(opcode);
                scratch.extend_from_slice(&(data.len() as u64).to_le_bytes());
                scratch.extend_from_slice(data);
            }
        }
    }
    Ok(scratch)
}

pub(super) fn crc_mismatch(at: u64, saved: u32, calculated: u32) -> String {
    format!(
        "chunk at byte {at} is corrupt: CRC mismatch (the chunk says {saved:08x}, \
         its records hash to {calculated:08x})"
    )
}

/// The message for a chunk at byte `at` that [`unpack_chunk`] refused.
pub(super) fn chunk_problem(at: u64, map: &[u8], problem: ChunkProblem) -> String {
    match problem {
        ChunkProblem::Truncated => format!(
            "chunk at byte {at} runs past the end of the file ({} bytes); \
             the file is truncated",
            map.len()
        ),
        ChunkProblem::NotAChunk => {
            format!("the index points at byte {at}, which is not a chunk record")
        }
        ChunkProblem::Crc { saved, calculated } => crc_mismatch(at, saved, calculated),
        ChunkProblem::Corrupt(why) => format!("chunk at byte {at} is corrupt: {why}"),
    }
}

/// The start of the last chunk record that begins before byte `pos`,
/// stepping over the top-level records from the start of the file (only
/// done to name the chunk in an error: the linear reader does not say
/// where the records it reports on began).
pub(super) fn chunk_before(map: &[u8], pos: usize) -> Option<usize> {
    let mut at = mcap::MAGIC.len();
    let mut found = None;
    while at < pos {
        let (Some(&opcode), Some(len)) = (map.get(at), map.get(at + 1..at + 9)) else {
            break;
        };
        if opcode == mcap::records::op::CHUNK {
            found = Some(at);
        }
        // Slices of 8 bytes by the range above.
        let len = u64::from_le_bytes(len.try_into().expect("8 bytes"));
        match usize::try_from(len)
            .ok()
            .and_then(|n| (at + 9).checked_add(n))
        {
            Some(next) => at = next,
            None => break,
        }
    }
    found
}

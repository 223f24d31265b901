//! Reading messages in log-time order across the files of a log, through
//! the chunk index, or linearly where a file has none.

use std::collections::HashMap;
use std::sync::Arc;

use mcap::sans_io::indexed_reader::{IndexedReadEvent, IndexedReader, IndexedReaderOptions};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use super::chunks::*;
use super::file::LogFile;
use super::mcap_log::McapLog;
use super::records::{channel_of, Channel, RawMessage, ReadFilter, MAX_RECORD_BYTES};
use crate::InputError;
use mcap::McapError;

/// Reads messages one at a time; see [`McapLog::reader`].
///
/// ```no_run
/// use latentam_io::{McapLog, ReadFilter};
///
/// let log = McapLog::open("run.mcap".as_ref())?;
/// let mut reader = log.reader(ReadFilter {
///     topics: Some(vec!["/camera/pose".into()]),
///     ..ReadFilter::default()
/// });
/// while let Some(bytes) = reader.next_with(|m| m.data.len()) {
///     println!("{} bytes", bytes?);
/// }
/// # Ok::<(), latentam_io::InputError>(())
/// ```
pub struct MessageReader {
    pub(super) log: McapLog,
    pub(super) filter: ReadFilter,
    pub(super) file: usize,
    pub(super) current: Option<FileReader>,
}

impl MessageReader {
    /// Reads the next admitted message and passes it to `f`; `None` at the
    /// end of the log. The message borrows the reader's buffers, so it only
    /// lives for the call.
    pub fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMessage<'_>) -> R,
    ) -> Option<Result<R, InputError>> {
        loop {
            let file = self.log.files.get(self.file)?;
            let reader = match &mut self.current {
                Some(r) => r,
                None => self.current.insert(FileReader::new(file, &self.filter)),
            };
            // `f` is called at most once per iteration; the result is moved
            // out through `out` so the borrow of `reader` ends here.
            let mut out = None;
            match reader.next_with(file, &self.filter, |m| out = Some(f(m))) {
                // `FileReader::next_with` returns `Some(Ok(()))` only right
                // after calling the callback, which set `out`.
                Some(Ok(())) => return Some(Ok(out.expect("callback ran"))),
                Some(Err(e)) => {
                    // Give up on this file after an error.
                    self.current = None;
                    self.file += 1;
                    return Some(Err(e));
                }
                None => {
                    self.current = None;
                    self.file += 1;
                }
            }
        }
    }
}

pub(super) enum Source {
    Indexed {
        reader: Box<IndexedReader>,
        /// Where compressed chunks are decompressed to be checked (kept
        /// to reuse its allocation).
        records: Vec<u8>,
    },
    Linear {
        reader: Box<LinearReader>,
        pos: usize,
    },
    Failed(Option<InputError>),
}

pub(super) struct FileReader {
    pub(super) source: Source,
    pub(super) channels: HashMap<u16, Arc<Channel>>,
    pub(super) schemas: HashMap<u16, (String, String)>,
}

impl FileReader {
    pub(super) fn new(file: &LogFile, filter: &ReadFilter) -> Self {
        match (&file.summary, &file.plain) {
            (Some(summary), Some(plain)) => {
                let mut options =
                    IndexedReaderOptions::new().with_record_length_limit(MAX_RECORD_BYTES);
                if let Some(topics) = &filter.topics {
                    options = options.include_topics(topics.iter().cloned());
                }
                if let Some(s) = filter.start_ns {
                    options = options.starting_at(s);
                }
                if let Some(e) = filter.end_ns {
                    options = options.ending_before(e);
                }
                let channels = summary
                    .channels
                    .iter()
                    .map(|(id, c)| (*id, Arc::new(channel_of(c))))
                    .collect();
                let source = match IndexedReader::new_with_options(&plain.summary, options) {
                    Ok(r) => Source::Indexed {
                        reader: Box::new(r),
                        records: Vec::new(),
                    },
                    Err(e) => Source::Failed(Some(file.error(e))),
                };
                FileReader {
                    source,
                    channels,
                    schemas: HashMap::new(),
                }
            }
            _ => Self::linear(file, filter),
        }
    }

    pub(super) fn linear(_file: &LogFile, _filter: &ReadFilter) -> Self {
        // Checking a chunk's CRC only after its last record (the reader's
        // `validate_chunk_crcs`) would hand out the records before it.
        let options = LinearReaderOptions::default()
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES);
        FileReader {
            source: Source::Linear {
                reader: Box::new(LinearReader::new_with_options(options)),
                pos: 0,
            },
            channels: HashMap::new(),
            schemas: HashMap::new(),
        }
    }

    /// Calls `f` with the next admitted message: `Some(Ok(()))` after a
    /// call, `None` at the end of the file.
    //
    // Why one long function: each arm borrows its reader out of
    // `self.source`, and the linear one replaces the source with `Failed`
    // on a fatal error while that borrow is live; split into methods, the
    // two could not both hold it.
    pub(super) fn next_with(
        &mut self,
        file: &LogFile,
        filter: &ReadFilter,
        mut f: impl FnMut(RawMessage<'_>),
    ) -> Option<Result<(), InputError>> {
        let FileReader {
            source,
            channels,
            schemas,
        } = self;
        match source {
            Source::Failed(e) => e.take().map(Err),
            Source::Indexed { reader, records } => loop {
                match reader.next_event()? {
                    Err(e) => return Some(Err(file.error(e))),
                    Ok(IndexedReadEvent::ReadChunkRequest { offset, .. }) => {
                        // `plain` exists whenever the reader is indexed.
                        let Some(index) = file.plain.as_ref().and_then(|p| p.original.get(&offset))
                        else {
                            return Some(Err(file.error(format!(
                                "the index asked for an unknown chunk (data at byte {offset})"
                            ))));
                        };
                        let at = index.chunk_start_offset;
                        let plain = match unpack_chunk(&file.map, index, records) {
                            Ok(plain) => plain,
                            Err(e) => {
                                return Some(Err(file.error(chunk_problem(at, &file.map, e))))
                            }
                        };
                        if let Err(e) = reader.insert_chunk_record_data(offset, plain) {
                            return Some(Err(
                                file.error(format!("chunk at byte {at} is corrupt: {e}"))
                            ));
                        }
                    }
                    Ok(IndexedReadEvent::Message { header, data }) => {
                        let Some(channel) = channels.get(&header.channel_id) else {
                            return Some(Err(file.error(format!(
                                "message on unknown channel id {}",
                                header.channel_id
                            ))));
                        };
                        // The indexed reader reads every topic when none of
                        // the requested ones is in the file, so the filter
                        // is applied here too.
                        if !filter.admits(&channel.topic, header.log_time) {
                            continue;
                        }
                        f(RawMessage {
                            channel,
                            log_time: header.log_time,
                            data,
                        });
                        return Some(Ok(()));
                    }
                }
            },
            Source::Linear { reader, pos } => loop {
                match reader.next_event()? {
                    Err(McapError::BadChunkCrc { saved, calculated }) => {
                        let reason = match chunk_before(&file.map, *pos) {
                            Some(at) => crc_mismatch(at as u64, saved, calculated),
                            None => format!(
                                "a chunk before byte {pos} is corrupt: {}",
                                McapError::BadChunkCrc { saved, calculated }
                            ),
                        };
                        *source = Source::Failed(None);
                        return Some(Err(file.error(reason)));
                    }
                    Err(e) => {
                        let err = file.error(format!(
                            "unreadable near byte {pos} of {}: {e} (truncated or corrupt file)",
                            file.map.len()
                        ));
                        *source = Source::Failed(None);
                        return Some(Err(err));
                    }
                    Ok(LinearReadEvent::ReadRequest(need)) => {
                        // `pos` never passes the end: it only grows by `n`,
                        // which is at most what is left.
                        let n = need.min(file.map.len() - *pos);
                        reader.insert(n).copy_from_slice(&file.map[*pos..*pos + n]);
                        reader.notify_read(n);
                        *pos += n;
                    }
                    Ok(LinearReadEvent::Record { data, opcode }) => {
                        let record = match mcap::parse_record(opcode, data) {
                            Ok(r) => r,
                            Err(e) => {
                                let err =
                                    file.error(format!("corrupt record near byte {pos}: {e}"));
                                *source = Source::Failed(None);
                                return Some(Err(err));
                            }
                        };
                        match record {
                            mcap::records::Record::Schema { header, .. } => {
                                schemas.insert(header.id, (header.name, header.encoding));
                            }
                            mcap::records::Record::Channel(c) => {
                                let (schema_name, schema_encoding) =
                                    schemas.get(&c.schema_id).cloned().unwrap_or_default();
                                channels.insert(
                                    c.id,
                                    Arc::new(Channel {
                                        topic: c.topic,
                                        schema_name,
                                        schema_encoding,
                                        message_encoding: c.message_encoding,
                                    }),
                                );
                            }
                            mcap::records::Record::Message { header, data } => {
                                let Some(channel) = channels.get(&header.channel_id) else {
                                    let err = file.error(format!(
                                        "message on channel id {} before its channel record",
                                        header.channel_id
                                    ));
                                    *source = Source::Failed(None);
                                    return Some(Err(err));
                                };
                                if filter.admits(&channel.topic, header.log_time) {
                                    f(RawMessage {
                                        channel,
                                        log_time: header.log_time,
                                        data: &data,
                                    });
                                    return Some(Ok(()));
                                }
                            }
                            _ => {}
                        }
                    }
                }
            },
        }
    }
}

impl McapLog {
    /// A reader over the messages `filter` admits: in log-time order within
    /// each file, files one after the other.
    pub fn reader(&self, filter: ReadFilter) -> MessageReader {
        MessageReader {
            log: self.clone(),
            filter,
            file: 0,
            current: None,
        }
    }
}

impl LogFile {
    /// The channels of a file without a summary, found by reading it once
    /// (a damaged file still lists those before the damage).
    pub(super) fn scanned_channels(&self) -> &(Vec<Channel>, Option<InputError>) {
        self.scanned.get_or_init(|| {
            let filter = ReadFilter::default();
            let mut reader = FileReader::linear(self, &filter);
            let mut problem = None;
            while let Some(r) = reader.next_with(self, &filter, |_| ()) {
                if let Err(e) = r {
                    problem = Some(e);
                    break;
                }
            }
            let mut v: Vec<Channel> = reader
                .channels
                .into_values()
                .map(|c| (*c).clone())
                .collect();
            v.sort_by(|a, b| a.topic.cmp(&b.topic));
            (v, problem)
        })
    }
}

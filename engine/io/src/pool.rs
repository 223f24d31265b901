//! Reuse of frame buffers.
//!
//! Every frame owns a few large buffers (colour, depth, labels, vectors:
//! about 2.5 MB at 640×480). Allocated fresh for each frame, they come from
//! newly mapped pages that the kernel zero-fills on first touch, which
//! costs more than the copy itself; frames handed back with `recycle` give
//! their buffers to the next frames instead.

use super::cdr::Seq;
use super::frame::{DepthData, EmbeddingLayout, Embeddings, Frame};

/// Buffers of recycled frames.
#[derive(Default)]
pub(crate) struct BufferPool {
    bytes: Vec<Vec<u8>>,
    words: Vec<Vec<u16>>,
}

/// Buffers kept per element type (a frame holds at most three of each).
const KEEP: usize = 8;

fn take<T>(pool: &mut Vec<Vec<T>>, len: usize) -> Vec<T> {
    match pool.iter().position(|b| b.capacity() >= len) {
        Some(i) => pool.swap_remove(i),
        None => Vec::new(),
    }
}

fn put<T>(pool: &mut Vec<Vec<T>>, buf: Vec<T>) {
    if buf.capacity() > 0 && pool.len() < KEEP {
        pool.push(buf);
    }
}

impl BufferPool {
    /// An empty byte buffer with room for `len` bytes when one is free.
    pub(crate) fn bytes(&mut self, len: usize) -> Vec<u8> {
        take(&mut self.bytes, len)
    }
    /// An empty `u16` buffer with room for `len` when one is free.
    pub(crate) fn words(&mut self, len: usize) -> Vec<u16> {
        take(&mut self.words, len)
    }
    /// `src` copied into a pooled buffer.
    pub(crate) fn copy_bytes(&mut self, src: &[u8]) -> Vec<u8> {
        let mut v = self.bytes(src.len());
        v.clear();
        v.extend_from_slice(src);
        v
    }
    /// A sequence decoded into a pooled buffer.
    pub(crate) fn copy_words(&mut self, src: &Seq<'_, u16>) -> Vec<u16> {
        let mut v = self.words(src.len());
        v.clear();
        v.resize(src.len(), 0);
        if src.endian() == super::cdr::Endian::Little && cfg!(target_endian = "little") {
            bytemuck::cast_slice_mut::<u16, u8>(&mut v).copy_from_slice(src.raw_bytes());
        } else {
            for (o, x) in v.iter_mut().zip(src.iter()) {
                *o = x;
            }
        }
        v
    }
    /// Takes back one `u16` buffer.
    pub(crate) fn recycle_words(&mut self, buf: Vec<u16>) {
        put(&mut self.words, buf);
    }
    /// Takes back the buffers of embeddings not used.
    pub(crate) fn recycle_embeddings(&mut self, e: Embeddings) {
        put(&mut self.bytes, e.data);
        if let EmbeddingLayout::Regions(l) = e.layout {
            put(&mut self.words, l.labels);
        }
    }
    /// Takes back a frame's buffers.
    pub(crate) fn recycle(&mut self, frame: Frame) {
        put(&mut self.bytes, frame.color.data);
        if let DepthData::Units { values, .. } = frame.depth.data {
            put(&mut self.words, values);
        }
        if let Some(e) = frame.embeddings {
            self.recycle_embeddings(e);
        }
        if let Some(s) = frame.semantic {
            put(&mut self.words, s.labels);
        }
    }
}

//! ROS 2 CDR (XCDR1) encoding and decoding, zero-copy on the read side.
//!
//! A serialized ROS 2 message starts with a 4-byte encapsulation header
//! (`00 00` big-endian or `00 01` little-endian, then two option bytes);
//! every primitive after it is aligned to its own size, counted from the
//! first byte *after* that header. Strings carry a `u32` length that includes
//! their NUL terminator; sequences carry a `u32` element count.
//!
//! [`CdrReader`] hands out borrowed views ([`&str`], `&[u8]`, [`Seq`]) into
//! the message bytes, so image payloads are never copied element by element.
//! MCAP gives no alignment guarantee for a message's bytes, so every
//! multi-byte read is unaligned.

use std::marker::PhantomData;

/// Byte order of a CDR payload, from its encapsulation header.
///
/// ```
/// use latentam_io::cdr::{CdrReader, Endian};
///
/// let msg = [0u8, 1, 0, 0, 7, 0, 0, 0]; // CDR_LE header, then a u32
/// assert_eq!(CdrReader::new(&msg)?.endian(), Endian::Little);
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Endian {
    /// `CDR_LE` (representation id `0x0001`), what ROS 2 writes on every
    /// common platform.
    Little,
    /// `CDR_BE` (representation id `0x0000`).
    Big,
}

impl Endian {
    fn native() -> Self {
        if cfg!(target_endian = "little") {
            Endian::Little
        } else {
            Endian::Big
        }
    }
}

/// Why a CDR payload could not be decoded.
///
/// ```
/// use latentam_io::cdr::CdrReader;
///
/// let msg = [0u8, 1, 0, 0, 7, 0]; // a u32 cut short
/// let e = CdrReader::new(&msg).unwrap().read::<u32>("stamp.sec").unwrap_err();
/// assert_eq!(e.field, "stamp.sec");
/// println!("{e}"); // names the field and the byte offset
/// ```
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("CDR field `{field}` at byte {offset}: {reason}")]
pub struct CdrError {
    /// The field being read, as named in the message definition.
    pub field: &'static str,
    /// Offset from the start of the serialized message (header included).
    pub offset: usize,
    /// What was wrong.
    pub reason: String,
}

/// A primitive that can appear in a CDR sequence or fixed array.
///
/// ```
/// use latentam_io::cdr::{CdrPrimitive, Endian};
///
/// let mut out = Vec::new();
/// 1.5f32.put(&mut out, Endian::Big);
/// assert_eq!(f32::from_bytes(&out, Endian::Big), 1.5);
/// ```
pub trait CdrPrimitive: Copy + bytemuck::Pod {
    /// Decodes one value from exactly `size_of::<Self>()` bytes.
    fn from_bytes(bytes: &[u8], endian: Endian) -> Self;
    /// Appends the encoding of `self`.
    fn put(self, out: &mut Vec<u8>, endian: Endian);
}

macro_rules! primitive {
    ($($t:ty),*) => {$(
        impl CdrPrimitive for $t {
            #[inline]
            fn from_bytes(bytes: &[u8], endian: Endian) -> Self {
                // Every caller slices exactly `size_of::<Self>()` bytes
                // (`CdrReader::take(n)`, `chunks_exact(n)`, `Seq::get`).
                let raw = bytes.try_into().expect("caller passes exactly size_of bytes");
                match endian {
                    Endian::Little => <$t>::from_le_bytes(raw),
                    Endian::Big => <$t>::from_be_bytes(raw),
                }
            }
            #[inline]
            fn put(self, out: &mut Vec<u8>, endian: Endian) {
                match endian {
                    Endian::Little => out.extend_from_slice(&self.to_le_bytes()),
                    Endian::Big => out.extend_from_slice(&self.to_be_bytes()),
                }
            }
        }
    )*};
}
primitive!(u8, i8, u16, i16, u32, i32, u64, i64, f32, f64);

/// A borrowed CDR sequence or array of primitives: the raw bytes plus their
/// byte order. Nothing is decoded until an element is asked for.
///
/// ```
/// use latentam_io::cdr::{Endian, Seq};
///
/// let bytes = [1u8, 0, 2, 0, 3, 0];
/// let seq: Seq<u16> = Seq::new(&bytes, Endian::Little);
/// assert_eq!(seq.len(), 3);
/// assert_eq!(seq.get(2), Some(3));
/// assert_eq!(seq.to_vec(), vec![1, 2, 3]);
/// ```
#[derive(Clone, Copy)]
pub struct Seq<'a, T> {
    bytes: &'a [u8],
    endian: Endian,
    _t: PhantomData<T>,
}

impl<T: CdrPrimitive> std::fmt::Debug for Seq<'_, T>
where
    T: std::fmt::Debug,
{
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_list().entries(self.iter().take(16)).finish()?;
        if self.len() > 16 {
            write!(f, " ({} elements)", self.len())?;
        }
        Ok(())
    }
}

impl<'a, T: CdrPrimitive> Seq<'a, T> {
    /// A view of `bytes` (a whole number of elements) in the given order.
    pub fn new(bytes: &'a [u8], endian: Endian) -> Self {
        debug_assert_eq!(bytes.len() % size_of::<T>(), 0);
        Seq {
            bytes,
            endian,
            _t: PhantomData,
        }
    }
    /// Number of elements.
    pub fn len(&self) -> usize {
        self.bytes.len() / size_of::<T>()
    }
    /// Whether there are no elements.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }
    /// Element `i`, or `None` past the end.
    pub fn get(&self, i: usize) -> Option<T> {
        let n = size_of::<T>();
        let start = i.checked_mul(n)?;
        self.bytes
            .get(start..start.checked_add(n)?)
            .map(|b| T::from_bytes(b, self.endian))
    }
    /// The elements in order.
    pub fn iter(&self) -> impl ExactSizeIterator<Item = T> + 'a {
        let endian = self.endian;
        self.bytes
            .chunks_exact(size_of::<T>())
            .map(move |b| T::from_bytes(b, endian))
    }
    /// The undecoded bytes.
    pub fn raw_bytes(&self) -> &'a [u8] {
        self.bytes
    }
    /// Byte order of the elements.
    pub fn endian(&self) -> Endian {
        self.endian
    }
    /// Copies the elements into a vector: one `memcpy` when the payload is
    /// in the machine's byte order, a decoding loop otherwise.
    pub fn to_vec(&self) -> Vec<T> {
        if self.endian == Endian::native() {
            bytemuck::pod_collect_to_vec(self.bytes)
        } else {
            self.iter().collect()
        }
    }
}

/// Reads one serialized message.
///
/// ```
/// use latentam_io::cdr::{CdrReader, CdrWriter, Endian};
///
/// let mut w = CdrWriter::new(Endian::Little);
/// w.put(42u32);
/// w.string("camera_color_optical_frame");
/// let msg = w.finish();
/// let mut r = CdrReader::new(&msg)?;
/// assert_eq!(r.read::<u32>("seq")?, 42);
/// assert_eq!(r.string("frame_id")?, "camera_color_optical_frame");
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
pub struct CdrReader<'a> {
    /// The whole message including the 4-byte header.
    msg: &'a [u8],
    /// Position in `msg`; alignment is counted from `msg[4]`.
    pos: usize,
    endian: Endian,
}

const HEADER: usize = 4;

impl<'a> CdrReader<'a> {
    /// Checks the encapsulation header of `msg` and positions the reader on
    /// the first field. Only plain CDR (XCDR1, both byte orders) is accepted.
    pub fn new(msg: &'a [u8]) -> Result<Self, CdrError> {
        let err = |reason: String| CdrError {
            field: "encapsulation header",
            offset: 0,
            reason,
        };
        if msg.len() < HEADER {
            return Err(err(format!(
                "message is {} bytes, shorter than the 4-byte header",
                msg.len()
            )));
        }
        let endian = match (msg[0], msg[1]) {
            (0, 0) => Endian::Big,
            (0, 1) => Endian::Little,
            (a, b) => {
                return Err(err(format!(
                    "representation id {a:#04x}{b:02x} is not plain CDR (0x0000 big-endian or \
                     0x0001 little-endian)"
                )))
            }
        };
        Ok(CdrReader {
            msg,
            pos: HEADER,
            endian,
        })
    }

    /// Byte order of the payload.
    pub fn endian(&self) -> Endian {
        self.endian
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.msg.len() - self.pos
    }

    /// An error about `field` at the current position, for checks the
    /// message types make on decoded values.
    pub fn invalid(&self, field: &'static str, reason: impl Into<String>) -> CdrError {
        CdrError {
            field,
            offset: self.pos,
            reason: reason.into(),
        }
    }

    fn align(&mut self, field: &'static str, n: usize) -> Result<(), CdrError> {
        let rel = self.pos - HEADER;
        let pad = (n - rel % n) % n;
        if pad > self.remaining() {
            return Err(self.invalid(field, "message ends inside alignment padding"));
        }
        self.pos += pad;
        Ok(())
    }

    fn take(&mut self, field: &'static str, n: usize) -> Result<&'a [u8], CdrError> {
        if n > self.remaining() {
            return Err(self.invalid(
                field,
                format!(
                    "needs {n} bytes but the message has {} left (truncated or a size field is wrong)",
                    self.remaining()
                ),
            ));
        }
        // In range: `n <= remaining()` was checked just above.
        let bytes = &self.msg[self.pos..self.pos + n];
        self.pos += n;
        Ok(bytes)
    }

    /// One aligned primitive.
    pub fn read<T: CdrPrimitive>(&mut self, field: &'static str) -> Result<T, CdrError> {
        let n = size_of::<T>();
        self.align(field, n)?;
        let bytes = self.take(field, n)?;
        Ok(T::from_bytes(bytes, self.endian))
    }

    /// A `bool` (one byte, 0 or 1).
    pub fn bool(&mut self, field: &'static str) -> Result<bool, CdrError> {
        match self.read::<u8>(field)? {
            0 => Ok(false),
            1 => Ok(true),
            v => Err(self.invalid(field, format!("bool byte is {v}, not 0 or 1"))),
        }
    }

    /// A `string`: `u32` length including the NUL, the bytes, the NUL.
    pub fn string(&mut self, field: &'static str) -> Result<&'a str, CdrError> {
        let len = self.read::<u32>(field)? as usize;
        if len == 0 {
            // Some writers encode the empty string with no terminator.
            return Ok("");
        }
        let bytes = self.take(field, len)?;
        let (text, nul) = bytes.split_at(len - 1);
        if nul != [0] {
            return Err(self.invalid(field, "string is not NUL-terminated"));
        }
        std::str::from_utf8(text)
            .map_err(|e| self.invalid(field, format!("string is not UTF-8: {e}")))
    }

    /// A sequence length, checked against the bytes left so a corrupt count
    /// can never make the caller reserve gigabytes.
    pub fn sequence_len(
        &mut self,
        field: &'static str,
        min_element_bytes: usize,
    ) -> Result<usize, CdrError> {
        let count = self.read::<u32>(field)? as usize;
        if count.saturating_mul(min_element_bytes) > self.remaining() {
            return Err(self.invalid(
                field,
                format!(
                    "sequence of {count} elements cannot fit in the {} bytes left",
                    self.remaining()
                ),
            ));
        }
        Ok(count)
    }

    /// A `uint8[]` / `byte[]`, borrowed.
    pub fn bytes(&mut self, field: &'static str) -> Result<&'a [u8], CdrError> {
        let len = self.sequence_len(field, 1)?;
        self.take(field, len)
    }

    /// A sequence of primitives, borrowed.
    pub fn seq<T: CdrPrimitive>(&mut self, field: &'static str) -> Result<Seq<'a, T>, CdrError> {
        let count = self.sequence_len(field, size_of::<T>())?;
        self.array(field, count)
    }

    /// A fixed-size array of `count` primitives (no length prefix), borrowed.
    pub fn array<T: CdrPrimitive>(
        &mut self,
        field: &'static str,
        count: usize,
    ) -> Result<Seq<'a, T>, CdrError> {
        if count > 0 {
            self.align(field, size_of::<T>())?;
        }
        let len = count.checked_mul(size_of::<T>()).ok_or_else(|| {
            self.invalid(
                field,
                format!("array of {count} elements cannot fit in a message"),
            )
        })?;
        let bytes = self.take(field, len)?;
        Ok(Seq::new(bytes, self.endian))
    }

    /// A fixed-size array decoded into a Rust array.
    pub fn fixed<T: CdrPrimitive + Default, const N: usize>(
        &mut self,
        field: &'static str,
    ) -> Result<[T; N], CdrError> {
        let seq = self.array::<T>(field, N)?;
        let mut out = [T::default(); N];
        for (o, v) in out.iter_mut().zip(seq.iter()) {
            *o = v;
        }
        Ok(out)
    }

    /// A `string[]`.
    pub fn strings(&mut self, field: &'static str) -> Result<Vec<&'a str>, CdrError> {
        // Each string takes at least its 4-byte length.
        let count = self.sequence_len(field, 4)?;
        (0..count).map(|_| self.string(field)).collect()
    }
}

/// Writes one serialized message (the inverse of [`CdrReader`]).
///
/// ```
/// use latentam_io::cdr::{CdrWriter, Endian};
///
/// let mut w = CdrWriter::new(Endian::Little);
/// w.seq(&[1.0f32, 2.0, 3.0]);
/// let bytes = w.finish(); // 4-byte header, u32 length, then the floats
/// assert_eq!(bytes.len(), 4 + 4 + 12);
/// ```
pub struct CdrWriter {
    out: Vec<u8>,
    endian: Endian,
}

impl CdrWriter {
    /// An empty message in the given byte order (little-endian is what
    /// ROS 2 writes).
    pub fn new(endian: Endian) -> Self {
        let id = match endian {
            Endian::Big => 0,
            Endian::Little => 1,
        };
        CdrWriter {
            out: vec![0, id, 0, 0],
            endian,
        }
    }

    /// An empty message with room for `bytes` of payload.
    pub fn with_capacity(endian: Endian, bytes: usize) -> Self {
        let mut w = CdrWriter::new(endian);
        w.out.reserve(bytes);
        w
    }

    fn align(&mut self, n: usize) {
        let rel = self.out.len() - HEADER;
        let pad = (n - rel % n) % n;
        self.out.resize(self.out.len() + pad, 0);
    }

    /// One aligned primitive.
    pub fn put<T: CdrPrimitive>(&mut self, v: T) {
        self.align(size_of::<T>());
        v.put(&mut self.out, self.endian);
    }

    /// A `bool`.
    pub fn bool(&mut self, v: bool) {
        self.put(v as u8);
    }

    // The writers' `expect`s below: a string or sequence of 4 GiB or more
    // cannot be encoded in CDR at all. Messages over `MAX_RECORD_BYTES`
    // (1 GiB) could not be read back either, and the converters check
    // payload sizes against that before writing (`convert::check_payload`).

    /// A `string` (length includes the NUL).
    pub fn string(&mut self, s: &str) {
        self.put(u32::try_from(s.len() + 1).expect("string shorter than 4 GiB"));
        self.out.extend_from_slice(s.as_bytes());
        self.out.push(0);
    }

    /// A `uint8[]`.
    pub fn bytes(&mut self, b: &[u8]) {
        self.put(u32::try_from(b.len()).expect("sequence shorter than 4 GiB"));
        self.out.extend_from_slice(b);
    }

    /// A sequence of primitives.
    pub fn seq<T: CdrPrimitive>(&mut self, values: &[T]) {
        self.put(u32::try_from(values.len()).expect("sequence shorter than 4 Gi elements"));
        self.array(values);
    }

    /// A fixed-size array (no length prefix).
    pub fn array<T: CdrPrimitive>(&mut self, values: &[T]) {
        if values.is_empty() {
            return;
        }
        self.align(size_of::<T>());
        if self.endian == Endian::native() {
            self.out.extend_from_slice(bytemuck::cast_slice(values));
        } else {
            for &v in values {
                v.put(&mut self.out, self.endian);
            }
        }
    }

    /// A `string[]`.
    pub fn strings(&mut self, values: &[&str]) {
        self.put(u32::try_from(values.len()).expect("sequence shorter than 4 Gi elements"));
        for s in values {
            self.string(s);
        }
    }

    /// The finished message, header included.
    pub fn finish(self) -> Vec<u8> {
        self.out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn alignment_counts_from_after_the_header() {
        // u8 then u32: the u32 sits at payload offset 4 (3 bytes padding),
        // then a u64 at payload offset 8, then a string.
        let mut w = CdrWriter::new(Endian::Little);
        w.put(7u8);
        w.put(0x0102_0304u32);
        w.put(-2i64);
        w.string("ab");
        let bytes = w.finish();
        assert_eq!(
            bytes,
            [
                0, 1, 0, 0, // header
                7, 0, 0, 0, // u8 + padding
                4, 3, 2, 1, // u32
                0xfe, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, // i64
                3, 0, 0, 0, b'a', b'b', 0 // string incl. NUL
            ]
        );
        let mut r = CdrReader::new(&bytes).unwrap();
        assert_eq!(r.read::<u8>("a").unwrap(), 7);
        assert_eq!(r.read::<u32>("b").unwrap(), 0x0102_0304);
        assert_eq!(r.read::<i64>("c").unwrap(), -2);
        assert_eq!(r.string("d").unwrap(), "ab");
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn big_endian_round_trip_and_unaligned_views() {
        let mut w = CdrWriter::new(Endian::Big);
        w.string("x");
        w.seq(&[1u16, 2, 0xfffe]);
        w.array(&[1.5f64, -2.0]);
        let bytes = w.finish();
        assert_eq!(&bytes[..2], &[0, 0]);
        // Shift the message to an odd address: views must still decode.
        let mut shifted = vec![0u8];
        shifted.extend_from_slice(&bytes);
        let mut r = CdrReader::new(&shifted[1..]).unwrap();
        assert_eq!(r.endian(), Endian::Big);
        assert_eq!(r.string("s").unwrap(), "x");
        let s = r.seq::<u16>("q").unwrap();
        assert_eq!(s.to_vec(), vec![1, 2, 0xfffe]);
        assert_eq!(s.get(2), Some(0xfffe));
        assert_eq!(s.get(3), None);
        assert_eq!(r.fixed::<f64, 2>("a").unwrap(), [1.5, -2.0]);
    }

    #[test]
    fn corrupt_input_is_an_error_not_a_panic() {
        assert!(CdrReader::new(&[0, 1]).is_err());
        let e = CdrReader::new(&[0, 7, 0, 0]).err().unwrap();
        assert!(e.reason.contains("not plain CDR"), "{e}");
        // A sequence that claims 1e9 elements.
        let mut w = CdrWriter::new(Endian::Little);
        w.put(1_000_000_000u32);
        let bytes = w.finish();
        let e = CdrReader::new(&bytes).unwrap().bytes("data").unwrap_err();
        assert_eq!(e.field, "data");
        // A string without its terminator, and one that is not UTF-8.
        for body in [&[2u8, 0, 0, 0, b'a', b'b'][..], &[2, 0, 0, 0, 0xff, 0]] {
            let mut msg = vec![0, 1, 0, 0];
            msg.extend_from_slice(body);
            assert!(CdrReader::new(&msg).unwrap().string("s").is_err());
        }
        // Every truncation of a valid message fails cleanly.
        let mut w = CdrWriter::new(Endian::Little);
        w.string("frame");
        w.seq(&[1.0f32, 2.0]);
        let full = w.finish();
        for cut in 4..full.len() {
            let mut r = CdrReader::new(&full[..cut]).unwrap();
            let ok = r.string("s").is_ok() && r.seq::<f32>("v").is_ok();
            assert!(!ok, "a {cut}-byte prefix decoded");
        }
    }

    #[test]
    fn huge_counts_and_indices_are_errors_not_overflows() {
        let msg = [0u8, 1, 0, 0, 1, 2, 3, 4];
        // `count × 8` does not fit in a usize.
        let e = CdrReader::new(&msg)
            .unwrap()
            .array::<f64>("a", usize::MAX / 2)
            .unwrap_err();
        assert_eq!(e.field, "a");
        let s = CdrReader::new(&msg).unwrap().array::<u32>("b", 1).unwrap();
        assert_eq!(s.get(0), Some(0x0403_0201));
        assert_eq!(s.get(usize::MAX), None);
        assert_eq!(s.get(usize::MAX / 4), None);
    }
}

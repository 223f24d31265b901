//! What every message type is: a CDR layout, decoded in place and encoded
//! from one description of its fields.

use crate::cdr::{CdrError, CdrReader, CdrWriter, Endian};

/// A message type with a CDR layout.
///
/// ```
/// use latentam_io::{Header, Pose, PoseStamped, RosMessage};
///
/// let msg = PoseStamped { header: Header::at(1_000, "map"), pose: Pose::IDENTITY };
/// let bytes = msg.encode(); // little-endian CDR, as ROS 2 publishes it
/// let back = PoseStamped::decode(&bytes)?;
/// assert_eq!(back.header.frame_id, "map");
/// assert_eq!(PoseStamped::TYPE_NAME, "geometry_msgs/msg/PoseStamped");
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
pub trait RosMessage<'a>: Sized {
    /// `pkg/msg/Type`.
    const TYPE_NAME: &'static str;
    /// Reads the fields after the encapsulation header.
    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError>;
    /// Writes the fields.
    fn encode_fields(&self, w: &mut CdrWriter);

    /// Decodes a whole serialized message.
    fn decode(bytes: &'a [u8]) -> Result<Self, CdrError> {
        Self::decode_fields(&mut CdrReader::new(bytes)?)
    }
    /// Encodes to little-endian CDR, as ROS 2 does.
    fn encode(&self) -> Vec<u8> {
        self.encode_with(Endian::Little)
    }
    /// Encodes in the given byte order.
    fn encode_with(&self, endian: Endian) -> Vec<u8> {
        let mut w = CdrWriter::new(endian);
        self.encode_fields(&mut w);
        w.finish()
    }
}

/// Declares how a message type is laid out in CDR, field by field in wire
/// order, and implements [`RosMessage`] from that one description: the
/// decoder and the encoder cannot disagree on a field's order or kind.
///
/// Each entry is `field: kind` (the field's name in errors is its own, or
/// `as "name"`), or `skip [T; N] as "name"` for wire data the type does not
/// keep (read past, written as zeros). Kinds:
/// `read` (a primitive), `flag` (a `u8` whose non-zero value is true),
/// `bool` (strict 0/1), `string`, `bytes`, `strings`, `seq` (a borrowed
/// primitive sequence), `fixed` (an array of known length), `header`,
/// `pose`, `roi` (a `RegionOfInterest`: four `u32` and a bool), and
/// `transforms` (a sequence of `TransformStamped`).
macro_rules! cdr_message {
    (
        $ty:ident = $type_name:literal {
            $( $entry:tt )*
        }
    ) => {
        impl<'a> RosMessage<'a> for $ty<'a> {
            const TYPE_NAME: &'static str = $type_name;
            fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
                cdr_message!(@decode r, $ty, [], $( $entry )*)
            }
            fn encode_fields(&self, w: &mut CdrWriter) {
                cdr_message!(@encode self, w, $( $entry )*);
            }
        }
    };

    // Decoding: fields read in order into locals, then the struct.
    (@decode $r:ident, $ty:ident, [$($done:ident)*], skip [$t:ty; $n:expr] as $name:literal, $($rest:tt)*) => {{
        $r.array::<$t>($name, $n)?;
        cdr_message!(@decode $r, $ty, [$($done)*], $($rest)*)
    }};
    (@decode $r:ident, $ty:ident, [$($done:ident)*], $f:ident : $kind:ident as $name:literal, $($rest:tt)*) => {{
        let $f = cdr_message!(@read $r, $kind, $name);
        cdr_message!(@decode $r, $ty, [$($done)* $f], $($rest)*)
    }};
    (@decode $r:ident, $ty:ident, [$($done:ident)*], $f:ident : $kind:ident, $($rest:tt)*) => {{
        let $f = cdr_message!(@read $r, $kind, stringify!($f));
        cdr_message!(@decode $r, $ty, [$($done)* $f], $($rest)*)
    }};
    (@decode $r:ident, $ty:ident, [$($done:ident)*], ) => {
        Ok($ty { $($done),* })
    };

    // Encoding: the same entries, written in the same order.
    (@encode $s:ident, $w:ident, skip [$t:ty; $n:expr] as $name:literal, $($rest:tt)*) => {
        $w.array(&[<$t>::default(); $n]);
        cdr_message!(@encode $s, $w, $($rest)*);
    };
    (@encode $s:ident, $w:ident, $f:ident : $kind:ident $(as $name:literal)?, $($rest:tt)*) => {
        cdr_message!(@write $s.$f, $w, $kind);
        cdr_message!(@encode $s, $w, $($rest)*);
    };
    (@encode $s:ident, $w:ident, ) => {};

    (@read $r:ident, read, $name:expr) => { $r.read($name)? };
    (@read $r:ident, flag, $name:expr) => { $r.read::<u8>($name)? != 0 };
    (@read $r:ident, bool, $name:expr) => { $r.bool($name)? };
    (@read $r:ident, string, $name:expr) => { $r.string($name)? };
    (@read $r:ident, bytes, $name:expr) => { $r.bytes($name)? };
    (@read $r:ident, strings, $name:expr) => { $r.strings($name)? };
    (@read $r:ident, seq, $name:expr) => { $r.seq($name)? };
    (@read $r:ident, fixed, $name:expr) => { $r.fixed($name)? };
    (@read $r:ident, header, $name:expr) => { Header::decode($r)? };
    (@read $r:ident, pose, $name:expr) => { Pose::decode($r, $name)? };
    (@read $r:ident, roi, $name:expr) => { ($r.fixed($name)?, $r.bool(concat!($name, ".do_rectify"))?) };
    (@read $r:ident, transforms, $name:expr) => { TransformStamped::decode_all($r)? };

    (@write $v:expr, $w:ident, read) => { $w.put($v) };
    (@write $v:expr, $w:ident, flag) => { $w.put($v as u8) };
    (@write $v:expr, $w:ident, bool) => { $w.bool($v) };
    (@write $v:expr, $w:ident, string) => { $w.string($v) };
    (@write $v:expr, $w:ident, bytes) => { $w.bytes($v) };
    (@write $v:expr, $w:ident, strings) => { $w.strings(&$v) };
    (@write $v:expr, $w:ident, seq) => { $w.seq(&$v.to_vec()) };
    (@write $v:expr, $w:ident, fixed) => { $w.array(&$v) };
    (@write $v:expr, $w:ident, header) => { $v.encode($w) };
    (@write $v:expr, $w:ident, pose) => { $v.encode($w) };
    (@write $v:expr, $w:ident, roi) => {{ $w.array(&$v.0); $w.bool($v.1) }};
    (@write $v:expr, $w:ident, transforms) => { TransformStamped::encode_all(&$v, $w) };
}

//! The PLY header: elements, properties and their types.

use std::io::{BufRead, Read};

use super::format::*;

/// The parts of a header the reader uses.
pub(super) struct Header {
    pub(super) count: u64,
    pub(super) properties: Vec<(ScalarType, String)>,
}

pub(super) enum HeaderError {
    Io(std::io::Error),
    Format(String),
}

impl From<std::io::Error> for HeaderError {
    fn from(e: std::io::Error) -> Self {
        HeaderError::Io(e)
    }
}

/// Reads the header up to and including `end_header`; returns it and its
/// length in bytes.
pub(super) fn read_header(
    reader: &mut impl BufRead,
) -> std::result::Result<(Header, u64), HeaderError> {
    let fail = |m: String| Err(HeaderError::Format(m));
    let mut limited = reader.take(MAX_HEADER_BYTES);
    let mut consumed = 0u64;
    let mut line = Vec::new();
    let mut parser = HeaderLines::default();
    let mut line_no = 0;
    loop {
        line_no += 1;
        line.clear();
        let n = limited.read_until(b'\n', &mut line)?;
        consumed += n as u64;
        if line_no == 1 {
            if n == 0 {
                return fail("empty file, not a PLY file".to_owned());
            }
            if !matches!(line.as_slice(), b"ply\n" | b"ply\r\n") {
                return fail("does not start with the `ply` magic line".to_owned());
            }
            continue;
        }
        if line.last() != Some(&b'\n') {
            return fail(if consumed >= MAX_HEADER_BYTES {
                format!("no end_header in the first {MAX_HEADER_BYTES} bytes")
            } else {
                "no end_header before the end of the file".to_owned()
            });
        }
        let Ok(text) = std::str::from_utf8(&line) else {
            return fail(format!(
                "header line {line_no} is not text; not a PLY file?"
            ));
        };
        match parser.line(line_no, text.trim_end_matches(['\n', '\r'])) {
            Ok(Some(vertex)) => return Ok((vertex, consumed)),
            Ok(None) => {}
            Err(m) => return fail(m),
        }
    }
}

/// What the header lines read so far declared.
#[derive(Default)]
struct HeaderLines {
    format_seen: bool,
    vertex: Option<Header>,
}

impl HeaderLines {
    /// Takes one header line after the magic: the header once `text` is
    /// `end_header`, or why the file cannot be read.
    fn line(&mut self, line_no: usize, text: &str) -> std::result::Result<Option<Header>, String> {
        let mut words = text.split_ascii_whitespace();
        let keyword = words.next().unwrap_or("");
        let rest: Vec<&str> = words.collect();
        match keyword {
            "format" => {
                match rest.as_slice() {
                    ["binary_little_endian", "1.0"] => {}
                    [format @ ("ascii" | "binary_big_endian"), _] => {
                        return Err(format!(
                            "PLY format `{format}` is not supported; only \
                         binary_little_endian 1.0 is"
                        ))
                    }
                    _ => {
                        return Err(format!(
                            "header line {line_no}: unknown format line `{text}`; only \
                         `format binary_little_endian 1.0` is supported"
                        ))
                    }
                }
                self.format_seen = true;
            }
            "comment" | "obj_info" => {}
            "element" => {
                if !self.format_seen {
                    return Err(format!("header line {line_no}: element before format"));
                }
                let [name, count] = rest.as_slice() else {
                    return Err(format!("header line {line_no}: malformed `{text}`"));
                };
                if *name != "vertex" {
                    return Err(format!(
                        "element `{name}` is not supported; only a single `vertex` element is"
                    ));
                }
                if self.vertex.is_some() {
                    return Err("more than one vertex element".to_owned());
                }
                let Ok(count) = count.parse::<u64>() else {
                    return Err(format!("header line {line_no}: bad vertex count `{count}`"));
                };
                self.vertex = Some(Header {
                    count,
                    properties: Vec::new(),
                });
            }
            "property" => {
                let Some(element) = self.vertex.as_mut() else {
                    return Err(format!(
                        "header line {line_no}: property outside an element"
                    ));
                };
                match rest.as_slice() {
                    ["list", ..] => {
                        return Err(format!(
                            "header line {line_no}: list properties are not supported in \
                         vertices"
                        ))
                    }
                    [ty, name] => {
                        let Some(ty) = ScalarType::parse(ty) else {
                            return Err(format!(
                                "header line {line_no}: unknown property type `{ty}`"
                            ));
                        };
                        element.properties.push((ty, (*name).to_owned()));
                    }
                    _ => return Err(format!("header line {line_no}: malformed `{text}`")),
                }
            }
            "end_header" if rest.is_empty() => {
                if !self.format_seen {
                    return Err("no format line".to_owned());
                }
                return match self.vertex.take() {
                    Some(vertex) => Ok(Some(vertex)),
                    None => Err("no vertex element".to_owned()),
                };
            }
            _ => {
                return Err(format!(
                    "header line {line_no}: unknown line `{}`",
                    text.chars().take(80).collect::<String>()
                ))
            }
        }
        Ok(None)
    }
}

/// A PLY scalar property type.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    pub(super) fn parse(name: &str) -> Option<Self> {
        Some(match name {
            "char" | "int8" => Self::I8,
            "uchar" | "uint8" => Self::U8,
            "short" | "int16" => Self::I16,
            "ushort" | "uint16" => Self::U16,
            "int" | "int32" => Self::I32,
            "uint" | "uint32" => Self::U32,
            "float" | "float32" => Self::F32,
            "double" | "float64" => Self::F64,
            _ => return None,
        })
    }

    pub(super) fn size(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::F64 => 8,
        }
    }

    /// The little-endian value at the start of `b`, as `f32`.
    pub(super) fn read(self, b: &[u8]) -> f32 {
        // `b` starts at the property's offset within a row, and
        // `Layout::new` makes the row long enough for every property's
        // size, so the first `N` bytes are there.
        fn arr<const N: usize>(b: &[u8]) -> [u8; N] {
            b[..N].try_into().expect("slice of N bytes")
        }
        match self {
            Self::I8 => f32::from(b[0] as i8),
            Self::U8 => f32::from(b[0]),
            Self::I16 => f32::from(i16::from_le_bytes(arr(b))),
            Self::U16 => f32::from(u16::from_le_bytes(arr(b))),
            Self::I32 => i32::from_le_bytes(arr(b)) as f32,
            Self::U32 => u32::from_le_bytes(arr(b)) as f32,
            Self::F32 => f32::from_le_bytes(arr(b)),
            Self::F64 => f64::from_le_bytes(arr(b)) as f32,
        }
    }
}

//! Saved maps and decoder files through their parsers
//! (`SavedState::parse`, `DecoderFile::parse`): raw bytes, byte-level
//! corruption of a valid file, and structured edits of a valid file's
//! metadata, tensor shapes, types, offsets and values. They may refuse
//! anything but must not panic; what they accept must write back out and
//! read again.

use std::path::Path;
use std::sync::OnceLock;

use arbitrary::{Arbitrary, Unstructured};
use latentam_core::mapper::{archive_join_resealed, DecoderFile, SavedState};
use serde_json::{Map, Value};

/// Byte-level damage to a file.
#[derive(Arbitrary, Debug)]
enum Splice {
    Overwrite { at: u16, bytes: Vec<u8> },
    Flip { at: u16, bit: u8 },
    Insert { at: u16, bytes: Vec<u8> },
    Remove { at: u16, len: u8 },
    Truncate { len: u16 },
}

/// A metadata value.
#[derive(Arbitrary, Debug)]
enum Text {
    Int(i64),
    Uint(u64),
    Float(f64),
    Nasty(u8),
    Free(String),
}

const NASTY: &[&str] = &[
    "",
    "NaN",
    "inf",
    "-inf",
    "-0",
    "1e308",
    "4294967296",
    "2147483648",
    "18446744073709551615",
    "18446744073709551616",
    "0x10",
    " 1",
    "latentam-map",
];

impl Text {
    fn value(&self) -> String {
        match self {
            Text::Int(v) => v.to_string(),
            Text::Uint(v) => v.to_string(),
            Text::Float(v) => v.to_string(),
            Text::Nasty(i) => NASTY[*i as usize % NASTY.len()].to_string(),
            Text::Free(s) => s.clone(),
        }
    }
}

/// An edit of a valid file's header or data.
#[derive(Arbitrary, Debug)]
enum Edit {
    /// Sets metadata key number `key` (or a new key) to `value`.
    Meta {
        key: u8,
        value: Text,
    },
    DropMeta {
        key: u8,
    },
    /// Replaces the first `setting = ` line of the saved configuration.
    Config {
        line: u8,
        value: Text,
    },
    Shape {
        tensor: u8,
        shape: Vec<u64>,
    },
    /// Reshapes keeping the element count (rows halved, columns doubled...).
    Reshape {
        tensor: u8,
        factor: u8,
    },
    Dtype {
        tensor: u8,
        dtype: u8,
    },
    Offsets {
        tensor: u8,
        start: u64,
        end: u64,
    },
    DropTensor {
        tensor: u8,
    },
    RenameTensor {
        tensor: u8,
        to: u8,
    },
    /// Writes `value` (little endian, the tensor's element width) over
    /// element `index` of a tensor.
    Element {
        tensor: u8,
        index: u16,
        value: u64,
    },
    /// Resizes a tensor to `len` elements of `fill`, fixing the offsets
    /// of the ones after it (a consistent file with other counts).
    Resize {
        tensor: u8,
        len: u16,
        fill: u8,
    },
}

const TENSORS: &[&str] = &[
    "map/keys",
    "map/gaussians",
    "window/keys",
    "window/state/0",
    "window/state/17",
    "head/W",
    "head/D",
    "head/D0",
    "head/kmeans_weights",
    "head/adam/0",
    "head/adam/5",
    "history/stamp",
    "history/camera",
    "history/size",
    "history/rgb",
    "history/depth_mm",
    "history/regions",
    "history/labels",
    "history/vectors",
    "trajectory/stamp",
    "trajectory/pose",
    "selector/pose",
    "state/last_sync",
    "W",
    "D",
    "D0",
    "atom_weights",
    "tau",
];
const DTYPES: &[&str] = &[
    "U8", "I8", "U16", "I32", "U32", "F32", "F64", "I64", "BF16", "F16", "BOOL", "F4", "F8_E4M3",
];
const CONFIG_KEYS: &[&str] = &[
    "voxel_size",
    "atoms",
    "max_regions",
    "replay",
    "history_cell",
    "window_capacity",
    "temperature",
    "seed",
    "gpu_budget",
    "stride",
    "interval",
    "[keyframes]",
    "[seeding]",
];

fn example_map() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        SavedState::example()
            .to_bytes()
            .expect("the example writes")
    })
}

fn example_decoder() -> &'static [u8] {
    static BYTES: OnceLock<Vec<u8>> = OnceLock::new();
    BYTES.get_or_init(|| {
        let dim = 3;
        DecoderFile {
            dim,
            w: (0..32 * dim).map(|i| i as f32 * 0.01).collect(),
            atoms: vec![1.0, 0.0, 0.0, 0.0, 0.6, 0.8],
            anchors: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
            atom_weights: vec![2.0, 1.0],
            temperature: 0.05,
            eps: 1e-6,
            model: "example".into(),
            run_id: Some("0123456789abcdef".into()),
        }
        .to_bytes()
        .expect("the example writes")
    })
}

fn splice(mut bytes: Vec<u8>, ops: &[Splice]) -> Vec<u8> {
    for op in ops {
        let at = |i: u16, len: usize| if len == 0 { 0 } else { i as usize % (len + 1) };
        match op {
            Splice::Overwrite { at: i, bytes: b } => {
                let i = at(*i, bytes.len());
                for (k, v) in b.iter().enumerate() {
                    if let Some(x) = bytes.get_mut(i + k) {
                        *x = *v;
                    }
                }
            }
            Splice::Flip { at: i, bit } => {
                if !bytes.is_empty() {
                    let i = *i as usize % bytes.len();
                    bytes[i] ^= 1 << (bit % 8);
                }
            }
            Splice::Insert { at: i, bytes: b } => {
                let i = at(*i, bytes.len());
                bytes.splice(i..i, b.iter().copied());
            }
            Splice::Remove { at: i, len } => {
                let i = at(*i, bytes.len());
                let end = (i + *len as usize).min(bytes.len());
                bytes.drain(i..end);
            }
            Splice::Truncate { len } => bytes.truncate(*len as usize),
        }
    }
    bytes
}

fn split(bytes: &[u8]) -> (Map<String, Value>, Vec<u8>) {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    (
        serde_json::from_slice(&bytes[8..8 + n]).unwrap(),
        bytes[8 + n..].to_vec(),
    )
}

/// The file of `header` and `data`, its checksum sealed again over the
/// edits (where the header still names the tensors' bytes), so that they
/// reach the checks behind the checksum rather than stopping at it.
fn join(header: &Map<String, Value>, data: &[u8]) -> Vec<u8> {
    archive_join_resealed(header, data)
}

/// A tensor's data offsets (start, end) and element width, where its header
/// states them.
fn extent(header: &Map<String, Value>, tensor: &str) -> Option<(usize, usize, usize)> {
    let t = &header[tensor];
    Some((
        t["data_offsets"][0].as_u64()? as usize,
        t["data_offsets"][1].as_u64()? as usize,
        width(t["dtype"].as_str()?),
    ))
}

fn width(dtype: &str) -> usize {
    match dtype {
        "F64" | "I64" => 8,
        "F32" | "I32" | "U32" => 4,
        "U16" => 2,
        _ => 1,
    }
}

/// Tensor names of a header, in data order.
fn tensors(header: &Map<String, Value>) -> Vec<String> {
    let mut names: Vec<(u64, String)> = header
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(k, v)| (v["data_offsets"][0].as_u64().unwrap_or(0), k.clone()))
        .collect();
    names.sort();
    names.into_iter().map(|(_, k)| k).collect()
}

/// Applies structured edits to a valid file (edits that leave the header
/// unreadable to this harness end the sequence).
fn edit(bytes: &[u8], edits: &[Edit]) -> Vec<u8> {
    let (mut header, mut data) = split(bytes);
    for e in edits {
        let names = tensors(&header);
        let pick = |t: u8| -> Option<String> {
            // Half the picks by name (hitting the interesting tensors of
            // either file), half by position.
            if t & 1 == 0 {
                let name = TENSORS[(t >> 1) as usize % TENSORS.len()];
                header.contains_key(name).then(|| name.to_string())
            } else {
                names.get((t >> 1) as usize % names.len().max(1)).cloned()
            }
        };
        match e {
            Edit::Meta { key, value } => {
                let meta = header
                    .entry("__metadata__")
                    .or_insert_with(|| Value::Object(Map::new()));
                let Some(meta) = meta.as_object_mut() else {
                    continue;
                };
                let keys: Vec<String> = meta.keys().cloned().collect();
                let k = keys
                    .get(*key as usize % (keys.len() + 1))
                    .cloned()
                    .unwrap_or_else(|| "extra".into());
                meta.insert(k, value.value().into());
            }
            Edit::DropMeta { key } => {
                if let Some(meta) = header
                    .get_mut("__metadata__")
                    .and_then(Value::as_object_mut)
                {
                    let keys: Vec<String> = meta.keys().cloned().collect();
                    if !keys.is_empty() {
                        meta.remove(&keys[*key as usize % keys.len()]);
                    }
                }
            }
            Edit::Config { line, value } => {
                let Some(text) = header
                    .get("__metadata__")
                    .and_then(|m| m.get("config"))
                    .and_then(Value::as_str)
                else {
                    continue;
                };
                let key = CONFIG_KEYS[*line as usize % CONFIG_KEYS.len()];
                let text = if key.starts_with('[') {
                    text.replacen(key, &value.value(), 1)
                } else {
                    let from = format!("{key} = ");
                    match text.find(&from) {
                        Some(i) => {
                            let end = text[i..].find('\n').map_or(text.len(), |e| i + e);
                            format!("{}{from}{}{}", &text[..i], value.value(), &text[end..])
                        }
                        None => format!("{key} = {}\n{text}", value.value()),
                    }
                };
                header["__metadata__"]["config"] = text.into();
            }
            Edit::Shape { tensor, shape } => {
                if let Some(t) = pick(*tensor) {
                    header[&t]["shape"] = shape.iter().take(4).copied().collect::<Vec<_>>().into();
                }
            }
            Edit::Reshape { tensor, factor } => {
                let Some(t) = pick(*tensor) else { continue };
                let f = (*factor as u64 % 4) + 2;
                let Some(shape) = header[&t]["shape"].as_array() else {
                    continue;
                };
                let mut s: Vec<u64> = shape.iter().filter_map(Value::as_u64).collect();
                if s.len() >= 2 && s[0].is_multiple_of(f) {
                    s[0] /= f;
                    s[1] = s[1].saturating_mul(f);
                } else if s.len() == 1 && s[0].is_multiple_of(f) {
                    s = vec![s[0] / f, f];
                } else {
                    s.insert(0, 1);
                }
                header[&t]["shape"] = s.into();
            }
            Edit::Dtype { tensor, dtype } => {
                if let Some(t) = pick(*tensor) {
                    header[&t]["dtype"] = DTYPES[*dtype as usize % DTYPES.len()].into();
                }
            }
            Edit::Offsets { tensor, start, end } => {
                if let Some(t) = pick(*tensor) {
                    header[&t]["data_offsets"] = vec![*start, *end].into();
                }
            }
            Edit::DropTensor { tensor } => {
                if let Some(t) = pick(*tensor) {
                    header.remove(&t);
                }
            }
            Edit::RenameTensor { tensor, to } => {
                if let Some(t) = pick(*tensor) {
                    let to = TENSORS[*to as usize % TENSORS.len()];
                    if let Some(v) = header.remove(&t) {
                        header.insert(to.to_string(), v);
                    }
                }
            }
            Edit::Element {
                tensor,
                index,
                value,
            } => {
                let Some(t) = pick(*tensor) else { continue };
                let Some((s, e, w)) = extent(&header, &t) else {
                    continue;
                };
                let e = e.min(data.len());
                let count = e.saturating_sub(s) / w;
                if count > 0 {
                    let i = s + (*index as usize % count) * w;
                    data[i..i + w].copy_from_slice(&value.to_le_bytes()[..w]);
                }
            }
            Edit::Resize { tensor, len, fill } => {
                let Some(t) = pick(*tensor) else { continue };
                let Some((s, e, w)) = extent(&header, &t) else {
                    continue;
                };
                if s > e || e > data.len() {
                    continue;
                }
                let new = *len as usize % 512 * w;
                let shift = new as i64 - (e - s) as i64;
                data.splice(s..e, std::iter::repeat_n(*fill, new));
                header[&t]["shape"] = vec![(new / w) as u64].into();
                header[&t]["data_offsets"] = vec![s as u64, (s + new) as u64].into();
                for (k, v) in header.iter_mut() {
                    if *k == t || k == "__metadata__" {
                        continue;
                    }
                    let Some(offsets) = v.get_mut("data_offsets").and_then(Value::as_array_mut)
                    else {
                        continue;
                    };
                    for o in offsets.iter_mut() {
                        if let Some(x) = o.as_u64().filter(|&x| x as usize >= e) {
                            *o = ((x as i64).saturating_add(shift).max(0) as u64).into();
                        }
                    }
                }
            }
        }
    }
    join(&header, &data)
}

fn check_map(bytes: &[u8]) {
    if let Ok(state) = SavedState::parse(bytes, Path::new("fuzz.latentam")) {
        // What is accepted writes back out and reads the same; the writer
        // refuses only a version 1 state from before run ids.
        let again = match state.to_bytes() {
            Ok(again) => again,
            Err(e) if state.run_id().is_none() && e.to_string().contains("no run id") => return,
            Err(e) => panic!("an accepted state did not write: {e}"),
        };
        let back =
            SavedState::parse(&again, Path::new("fuzz.latentam")).expect("a written state reads");
        assert_eq!(format!("{back:?}"), format!("{state:?}"));
    }
}

fn check_decoder(bytes: &[u8]) {
    if let Ok(d) = DecoderFile::parse(bytes, Path::new("fuzz.safetensors")) {
        let again = d.to_bytes().expect("an accepted decoder writes");
        let back = DecoderFile::parse(&again, Path::new("fuzz.safetensors"))
            .expect("a written decoder reads");
        assert_eq!(format!("{back:?}"), format!("{d:?}"));
        let q = [0.5f32; 32];
        let out = d.decode(&[q, [0.0; 32]]);
        assert_eq!(out.len(), 2 * d.dim as usize);
    }
}

/// One input.
pub fn run(data: &[u8]) {
    let Some((&mode, rest)) = data.split_first() else {
        return;
    };
    match mode % 6 {
        0 => check_map(rest),
        1 => check_decoder(rest),
        m => {
            let mut u = Unstructured::new(rest);
            let map = m % 2 == 0;
            let base = if map {
                example_map()
            } else {
                example_decoder()
            };
            let bytes = if m < 4 {
                let Ok(ops) = Vec::<Splice>::arbitrary(&mut u) else {
                    return;
                };
                splice(base.to_vec(), &ops)
            } else {
                let Ok(edits) = Vec::<Edit>::arbitrary(&mut u) else {
                    return;
                };
                edit(base, &edits)
            };
            if map {
                check_map(&bytes);
            } else {
                check_decoder(&bytes);
            }
        }
    }
}

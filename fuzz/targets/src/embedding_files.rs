//! The embedding files users bring, through every reader of them:
//! `.npy` arrays and safetensors files as per-frame features
//! (`convert --features`), class vectors (`convert --class-vectors`),
//! class-id images (`convert --oracle-labels`) and query vectors
//! (`query --embedding`). Raw bytes, and files assembled from
//! arbitrary headers (any element type, shape, offsets, duplicate keys,
//! metadata). The readers may refuse anything but must not panic, and what
//! they accept must be consistent: sizes that match, finite values, labels
//! within range.

use arbitrary::{Arbitrary, Unstructured};
use latentam_io::embedding_files::{
    class_ids_from_npy, features_from_safetensors, grid_from_npy, npy, regions_from_npy,
    vector_from_bytes, ClassVectors, FrameFeatures,
};

const DESCRS: &[&str] = &[
    "<f4", "<f2", "<u2", "|u1", "<i4", "<i8", ">f4", "<f8", "|b1", "<c8", "", "<f4'",
];
const NAMES: &[&str] = &[
    "labels",
    "features",
    "grid",
    "vectors",
    "embedding",
    "x",
    "",
];
/// Data built for one file stops here: a shape or offsets past it make a
/// file whose data falls short, which the readers must refuse anyway.
const MAX_DATA: usize = 1 << 20;
const DTYPES: &[&str] = &[
    "F32", "F16", "U16", "U8", "I32", "I64", "F64", "BF16", "BOOL", "U64",
];

/// An `.npy` file from its parts.
#[derive(Arbitrary, Debug)]
struct BuiltNpy {
    version: u8,
    descr: u8,
    fortran: bool,
    shape: Vec<u32>,
    /// Names `descr` or `shape` a second time.
    repeat: Option<bool>,
    data: Vec<u8>,
    /// Bytes more or fewer than the shape needs.
    slack: i8,
}

impl BuiltNpy {
    fn bytes(&self) -> Vec<u8> {
        let descr = DESCRS[self.descr as usize % DESCRS.len()];
        let dims: Vec<String> = self
            .shape
            .iter()
            .take(4)
            .map(|d| (d % 300).to_string())
            .collect();
        let tuple = match dims.len() {
            1 => format!("({},)", dims[0]),
            _ => format!("({})", dims.join(", ")),
        };
        let mut header = format!(
            "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {tuple}, ",
            if self.fortran { "True" } else { "False" }
        );
        match self.repeat {
            Some(true) => header.push_str("'descr': '<f2', "),
            Some(false) => header.push_str("'shape': (1,), "),
            None => {}
        }
        header.push_str("}\n");
        let size = match descr {
            "<f8" | "<i8" | "<c8" => 8,
            "<f4" | ">f4" | "<i4" => 4,
            "<f2" | "<u2" => 2,
            _ => 1,
        };
        let count: usize = self
            .shape
            .iter()
            .take(4)
            .map(|d| (d % 300) as usize)
            .product();
        let want = (count.saturating_mul(size) as i64 + self.slack as i64 % 3)
            .clamp(0, MAX_DATA as i64) as usize;
        let mut data: Vec<u8> = self.data.iter().copied().cycle().take(want).collect();
        data.resize(want, 0x3c);
        let mut out = b"\x93NUMPY".to_vec();
        match self.version % 3 {
            0 => {
                out.extend([1, 0]);
                out.extend((header.len() as u16).to_le_bytes());
            }
            v => {
                out.extend([v + 1, 0]);
                out.extend((header.len() as u32).to_le_bytes());
            }
        }
        out.extend(header.as_bytes());
        out.extend(data);
        out
    }
}

/// One tensor of a safetensors file from its parts.
#[derive(Arbitrary, Debug)]
struct BuiltTensor {
    name: u8,
    dtype: u8,
    shape: Vec<u16>,
    /// Offsets of its own instead of the next free bytes.
    offsets: Option<(u32, u32)>,
}

/// A safetensors file from its parts.
#[derive(Arbitrary, Debug)]
struct BuiltSafetensors {
    tensors: Vec<BuiltTensor>,
    model: Option<String>,
    names: Option<String>,
    /// Names the first tensor a second time.
    repeat: bool,
    data: Vec<u8>,
    slack: i8,
}

impl BuiltSafetensors {
    fn bytes(&self) -> Vec<u8> {
        let mut entries = Vec::new();
        let mut at = 0u64;
        for t in self.tensors.iter().take(4) {
            let dtype = DTYPES[t.dtype as usize % DTYPES.len()];
            let size = match dtype {
                "F64" | "I64" | "U64" => 8,
                "F32" | "I32" => 4,
                "F16" | "BF16" | "U16" => 2,
                _ => 1,
            };
            let shape: Vec<u64> = t
                .shape
                .iter()
                .take(4)
                .map(|&d| u64::from(d % 200))
                .collect();
            let len = shape.iter().product::<u64>() * size;
            let (s, e) = t
                .offsets
                .map_or((at, at + len), |(s, e)| (u64::from(s), u64::from(e)));
            at = at.max(e);
            entries.push(format!(
                "\"{}\": {{\"dtype\": \"{dtype}\", \"shape\": {shape:?}, \"data_offsets\": [{s}, {e}]}}",
                NAMES[t.name as usize % NAMES.len()]
            ));
        }
        if self.repeat {
            if let Some(first) = entries.first().cloned() {
                entries.push(first);
            }
        }
        let mut meta = serde_json::Map::new();
        if let Some(m) = &self.model {
            meta.insert("model".into(), m.clone().into());
        }
        if let Some(n) = &self.names {
            meta.insert("names".into(), n.clone().into());
        }
        if !meta.is_empty() {
            entries.push(format!(
                "\"__metadata__\": {}",
                serde_json::Value::Object(meta)
            ));
        }
        let header = format!("{{{}}}", entries.join(", "));
        let want = (at as i64 + self.slack as i64 % 3).clamp(0, MAX_DATA as i64) as usize;
        let mut data: Vec<u8> = self.data.iter().copied().cycle().take(want).collect();
        data.resize(want, 0x3c);
        let mut out = (header.len() as u64).to_le_bytes().to_vec();
        out.extend(header.as_bytes());
        out.extend(data);
        out
    }
}

#[derive(Arbitrary, Debug)]
enum Input {
    RawNpy(Vec<u8>),
    RawSafetensors(Vec<u8>),
    Npy(BuiltNpy),
    /// `S.labels.npy` and `S.features.npy`.
    NpyPair(BuiltNpy, BuiltNpy),
    Safetensors(BuiltSafetensors),
}

fn check_features(f: &FrameFeatures, dim: usize) {
    assert!(dim > 0);
    match f {
        FrameFeatures::Regions {
            width,
            height,
            labels,
            count,
            vectors,
        } => {
            assert_eq!(labels.len(), *width as usize * *height as usize);
            assert_eq!(vectors.len(), *count as usize * dim);
            assert!(labels
                .iter()
                .all(|&l| l == u16::MAX || u32::from(l) < *count));
            assert!(vectors.iter().all(|x| x.is_finite()));
        }
        FrameFeatures::Grid {
            rows,
            cols,
            vectors,
        } => {
            assert_eq!(vectors.len(), *rows as usize * *cols as usize * dim);
            assert!(vectors.iter().all(|x| x.is_finite()));
        }
    }
}

fn check_vector(v: &[f32]) {
    assert!(!v.is_empty());
    assert!(v.iter().all(|x| x.is_finite()));
    assert!(v.iter().any(|&x| x != 0.0));
}

fn check_classes(c: &ClassVectors) {
    assert!(c.vectors.len() >= 2);
    assert_eq!(c.names.len(), c.vectors.len());
    let d = c.vectors[0].len();
    assert!(d > 0);
    assert!(c
        .vectors
        .iter()
        .all(|v| v.len() == d && v.iter().all(|x| x.is_finite())));
}

/// Every reader of a `.npy` file.
fn check_npy(bytes: &[u8]) {
    if let Ok(a) = npy::parse(bytes) {
        let count: usize = a.shape.iter().product();
        assert_eq!(a.data.len(), count * a.dtype.size());
        // What reads writes back out the same.
        let again = npy::write(a.dtype, &a.shape, &a.data);
        assert_eq!(npy::parse(&again).expect("a written array reads"), a);
    }
    if let Ok((f, dim)) = grid_from_npy(bytes, "fuzz.grid.npy") {
        check_features(&f, dim);
    }
    if let Ok(v) = vector_from_bytes(bytes, false, "fuzz.npy") {
        check_vector(&v);
    }
    if let Ok(c) = ClassVectors::parse(bytes, false, "fuzz.npy") {
        check_classes(&c);
    }
    if let Ok((w, h, ids)) = class_ids_from_npy(bytes, "fuzz.npy") {
        assert!(w > 0 && h > 0);
        assert_eq!(ids.len(), w as usize * h as usize);
    }
}

/// Every reader of a safetensors file.
fn check_safetensors(bytes: &[u8]) {
    if let Ok(l) = features_from_safetensors(bytes, "fuzz.safetensors", None) {
        check_features(&l.features, l.dim);
    }
    if let Ok(v) = vector_from_bytes(bytes, true, "fuzz.safetensors") {
        check_vector(&v);
    }
    if let Ok(c) = ClassVectors::parse(bytes, true, "fuzz.safetensors") {
        check_classes(&c);
    }
}

/// One input.
pub fn run(data: &[u8]) {
    let Ok(input) = Input::arbitrary_take_rest(Unstructured::new(data)) else {
        return;
    };
    match input {
        Input::RawNpy(b) => check_npy(&b),
        Input::RawSafetensors(b) => check_safetensors(&b),
        Input::Npy(n) => check_npy(&n.bytes()),
        Input::NpyPair(l, f) => {
            if let Ok((f, dim)) = regions_from_npy(&l.bytes(), &f.bytes(), "l.npy", "f.npy") {
                check_features(&f, dim);
            }
        }
        Input::Safetensors(s) => check_safetensors(&s.bytes()),
    }
}

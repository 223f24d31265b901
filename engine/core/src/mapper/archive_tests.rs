//! Tests of the saved-map file: round trips and refusals, malformed
//! headers, unaligned tensors.

use super::*;

#[test]
fn round_trip_and_refusals() {
    let dir = std::env::temp_dir().join(format!("latentam-archive-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("a.map");
    let mut w = ArchiveWriter::default();
    w.meta("answer", 42);
    w.tensor("x", &[2, 3], &[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0]);
    w.tensor("k", &[2], &[-7i32, 9]);
    w.bytes("raw", 1, 3, &[1, 2, 3]);
    latentam_base::files::write_bytes_atomically(&path, &w.into_bytes().unwrap()).unwrap();
    let a = Archive::open(&path).unwrap();
    assert_eq!(a.meta_parse::<u32>("answer").unwrap(), 42);
    assert_eq!(a.exact::<f32>("x", &[2, 3]).unwrap()[5], 6.0);
    assert!(a.exact::<f32>("x", &[3, 2]).is_err());
    assert!(a.flat::<f32>("x").is_err());
    assert_eq!(a.flat::<i32>("k").unwrap(), vec![-7, 9]);
    assert!(a.flat::<i64>("k").is_err());
    assert!(a.flat::<f32>("missing").is_err());
    assert_eq!(a.shape::<u8>("raw").unwrap(), &[1, 3]);
    assert!(a.meta("missing").is_err());
    assert!(a.has("raw") && !a.has("nope"));
    // No temporary files left behind.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);

    // Truncated, foreign, or from a future version: clear errors.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
    assert!(Archive::open(&path).is_err());
    std::fs::write(&path, b"not a map at all").unwrap();
    let e = Archive::open(&path).err().unwrap().to_string();
    assert!(e.contains("not a latentam map"), "{e}");
    let views = vec![(
        "x".to_string(),
        safetensors::tensor::TensorView::new(Dtype::U8, vec![1], &[0u8]).unwrap(),
    )];
    let mut meta = HashMap::new();
    meta.insert("format".to_string(), FORMAT.to_string());
    meta.insert("version".to_string(), "99".to_string());
    std::fs::write(&path, safetensors::serialize(views, Some(meta)).unwrap()).unwrap();
    let e = Archive::open(&path).err().unwrap().to_string();
    assert!(e.contains("version 99"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn streamed_tensors_are_written_in_one_pass_and_read_back() {
    let dir = std::env::temp_dir().join(format!("latentam-stream-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("s.map");
    let values: Vec<f32> = (0..1000).map(|i| i as f32 * 0.5 - 7.0).collect();
    let build = |values: &[f32]| {
        let values = values.to_vec();
        let mut w = ArchiveWriter::default();
        w.meta("note", "streamed \"quoted\" crc32:00000000");
        w.tensor("a/held", &[2], &[1u16, 2]);
        w.stream::<f32>("b/streamed", &[10, 100], move |sink| {
            values
                .chunks(7)
                .try_for_each(|c| sink.put(bytemuck::cast_slice(c)))
        });
        w.tensor_ref("c/borrowed", &[3], &[5i64, 6, 7]);
        w
    };
    build(&values).write_file(&path).unwrap();
    // The same bytes as written to memory, and a file the safetensors
    // crate reads too.
    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes, build(&values).into_bytes().unwrap());
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    assert_eq!(st.tensor("b/streamed").unwrap().shape(), &[10, 100]);
    // Its checksum checks: any changed byte of the streamed tensor is
    // refused.
    let a = Archive::open(&path).unwrap();
    assert_eq!(a.exact::<f32>("b/streamed", &[10, 100]).unwrap(), values);
    assert_eq!(a.flat::<i64>("c/borrowed").unwrap(), vec![5, 6, 7]);
    assert_eq!(
        a.meta("note").unwrap(),
        "streamed \"quoted\" crc32:00000000"
    );
    let mut flipped = bytes.clone();
    let at = bytes.len() - 30;
    flipped[at] ^= 1;
    assert!(parse(&flipped).is_err());
    // Read from the file in parts: the same rows, the same refusal.
    let streamed = Archive::open_streaming(&path).unwrap();
    assert_eq!(
        streamed.rows::<f32>("b/streamed", 3, 4).unwrap(),
        values[300..700]
    );
    assert!(streamed.rows::<f32>("b/streamed", 8, 3).is_err());
    let flipped_path = dir.join("flipped.map");
    std::fs::write(&flipped_path, &flipped).unwrap();
    let e = Archive::open_streaming(&flipped_path)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("checksum"), "{e}");
    std::fs::remove_file(&flipped_path).unwrap();

    // A producer that gives the wrong number of bytes, or fails, leaves
    // the file as it was and nothing beside it.
    for short in [true, false] {
        let mut w = ArchiveWriter::default();
        w.stream::<f32>("x", &[4], move |sink| {
            if short {
                sink.put(&[0u8; 12])
            } else {
                Err(Error::bad_input("the source", "gone"))
            }
        });
        let e = w.write_file(&path).unwrap_err().to_string();
        assert!(
            e.contains(if short { "12 bytes, not 16" } else { "gone" }),
            "{e}"
        );
        assert_eq!(std::fs::read(&path).unwrap(), bytes);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A safetensors file with a hand-written header.
fn raw(header: &str, data: &[u8]) -> Vec<u8> {
    let mut v = (header.len() as u64).to_le_bytes().to_vec();
    v.extend_from_slice(header.as_bytes());
    v.extend_from_slice(data);
    v
}

fn parse(bytes: &[u8]) -> Result<Archive<'_>> {
    Archive::parse_as(Cow::Borrowed(bytes), Path::new("t"), FORMAT, VERSION, "map")
}

#[test]
fn malformed_headers_are_errors_not_panics() {
    let meta = r#""__metadata__":{"format":"latentam-map","version":"1"}"#;
    // Offsets near usize::MAX (the safetensors 0.8 reader overflows
    // adding them to the header length).
    let huge = usize::MAX - 7;
    let h =
        format!(r#"{{{meta},"a":{{"dtype":"U8","shape":[{huge}],"data_offsets":[0,{huge}]}}}}"#);
    assert!(parse(&raw(&h, &[0; 8])).is_err());
    // Shapes whose element count overflows, or with a zero dimension.
    let h = format!(
        r#"{{{meta},"a":{{"dtype":"F64","shape":[4294967296,4294967296,16],"data_offsets":[0,0]}}}}"#
    );
    assert!(parse(&raw(&h, &[])).is_err());
    let h = format!(r#"{{{meta},"a":{{"dtype":"F32","shape":[{huge},0],"data_offsets":[0,0]}}}}"#);
    let bytes = raw(&h, &[]);
    let a = parse(&bytes).unwrap();
    assert!(a.exact::<f32>("a", &[huge, 0]).unwrap().is_empty());
    assert!(a.flat::<f32>("a").is_err());
    // Overlapping tensors, gaps, trailing bytes, short files.
    let two = |a: (usize, usize), b: (usize, usize)| {
        format!(
            r#"{{{meta},"a":{{"dtype":"U8","shape":[{}],"data_offsets":[{},{}]}},"b":{{"dtype":"U8","shape":[{}],"data_offsets":[{},{}]}}}}"#,
            a.1 - a.0,
            a.0,
            a.1,
            b.1 - b.0,
            b.0,
            b.1
        )
    };
    assert!(parse(&raw(&two((0, 2), (0, 2)), &[0; 2])).is_err());
    assert!(parse(&raw(&two((0, 2), (1, 3)), &[0; 3])).is_err());
    assert!(parse(&raw(&two((0, 1), (2, 3)), &[0; 3])).is_err());
    assert!(parse(&raw(&two((0, 1), (1, 3)), &[0; 4])).is_err());
    assert!(parse(&raw(&two((0, 1), (1, 3)), &[0; 2])).is_err());
    assert!(parse(&raw(&two((0, 1), (1, 3)), &[0; 3])).is_ok());
    for n in 0..8 {
        assert!(parse(&[0xff; 8][..n]).is_err());
    }
    assert!(parse(&u64::MAX.to_le_bytes()).is_err());
    // Metadata that is not strings.
    let h = r#"{"__metadata__":{"format":1}}"#;
    assert!(parse(&raw(h, &[])).is_err());
}

#[test]
fn unaligned_tensors_are_read() {
    // One byte, then f64s starting at an odd offset.
    let meta = r#""__metadata__":{"format":"latentam-map","version":"1"}"#;
    let h = format!(
        r#"{{{meta},"a":{{"dtype":"U8","shape":[1],"data_offsets":[0,1]}},"b":{{"dtype":"F64","shape":[2],"data_offsets":[1,17]}}}}"#
    );
    let mut data = vec![7u8];
    data.extend(1.5f64.to_le_bytes());
    data.extend((-2.25f64).to_le_bytes());
    for pad in 0..8 {
        // Header lengths of every residue move the data's alignment.
        let h = format!("{h}{}", " ".repeat(pad));
        let bytes = raw(&h, &data);
        let a = parse(&bytes).unwrap();
        assert_eq!(a.flat::<f64>("b").unwrap(), vec![1.5, -2.25]);
        assert_eq!(a.flat::<u8>("a").unwrap(), vec![7]);
    }
}

/// `bytes` with its header's metadata edited by `edit` and nothing sealed
/// again (as a hand edit leaves it).
fn with_metadata(
    bytes: &[u8],
    edit: impl Fn(&mut serde_json::Map<String, serde_json::Value>),
) -> Vec<u8> {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let mut header: serde_json::Map<String, serde_json::Value> =
        serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    edit(header["__metadata__"].as_object_mut().unwrap());
    raw(&serde_json::to_string(&header).unwrap(), &bytes[8 + n..])
}

/// Removing the checksum does not turn the checks off: an archive of this
/// version without one is refused. Only a file that names the legacy
/// version, from before the checksum, loads without one.
#[test]
fn a_current_archive_without_its_checksum_is_refused() {
    let mut w = ArchiveWriter::default();
    w.meta("last_stamp_ns", 12);
    w.tensor("x", &[2], &[1.0f32, 2.0]);
    let sealed = w.into_bytes().unwrap();
    let a = parse(&sealed).unwrap();
    assert!(a.sealed());
    assert_eq!(a.meta("version").unwrap(), VERSION.to_string());

    let stripped = with_metadata(&sealed, |m| _ = m.remove(CHECKSUM_KEY));
    let e = parse(&stripped).err().unwrap().to_string();
    assert!(
        e.contains("damaged") && e.contains("without its checksum"),
        "{e}"
    );
    // Stripped and edited: still refused.
    let edited = with_metadata(&sealed, |m| {
        m.remove(CHECKSUM_KEY);
        m.insert("last_stamp_ns".into(), i64::MIN.to_string().into());
    });
    assert!(parse(&edited).is_err());

    // A legacy file: no checksum to check; with one, it is checked.
    let legacy = with_metadata(&stripped, |m| {
        m.insert("version".into(), LEGACY_VERSION.to_string().into());
    });
    let a = parse(&legacy).unwrap();
    assert!(!a.sealed());
    let wrong = with_metadata(&legacy, |m| {
        m.insert(CHECKSUM_KEY.into(), "00000000".into());
    });
    assert!(parse(&wrong).err().unwrap().to_string().contains("damaged"));
}

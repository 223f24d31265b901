use super::*;

#[test]
fn round_trip_and_errors() {
    let data: Vec<u8> = (0..24u8).collect();
    let bytes = write(NpyType::F16, &[3, 4], &data);
    assert_eq!(
        (10 + u16::from_le_bytes([bytes[8], bytes[9]]) as usize) % 64,
        0
    );
    let a = parse(&bytes).unwrap();
    assert_eq!(
        (a.dtype, a.shape.as_slice(), a.data.as_slice()),
        (NpyType::F16, &[3, 4][..], &data[..])
    );
    let v = parse(&write(NpyType::U16, &[5], &[0; 10])).unwrap();
    assert_eq!(v.shape, [5]);
    assert!(parse(&bytes[..bytes.len() - 1]).is_err());
    assert!(parse(b"hello world").is_err());
    let mut big = write(NpyType::F32, &[2], &[0; 8]);
    let at = big.windows(3).position(|w| w == b"<f4").unwrap();
    big[at] = b'>';
    assert!(parse(&big).unwrap_err().to_string().contains(">f4"));
}

#[test]
fn a_header_naming_a_key_twice_is_refused() {
    // The same length as the written header, so the data still fits.
    let good = write(NpyType::F32, &[2], &[0; 8]);
    for (from, to) in [
        ("'fortran_order': False", "'shape': (4,)"),
        ("'fortran_order': False", "'descr': '<f2'"),
    ] {
        let at = good
            .windows(from.len())
            .position(|w| w == from.as_bytes())
            .unwrap();
        let to = format!("{to:<width$}", width = from.len());
        let mut bad = good.clone();
        bad[at..at + from.len()].copy_from_slice(to.as_bytes());
        let e = parse(&bad).unwrap_err().to_string();
        assert!(e.contains("twice"), "{e}");
    }
}

//! Checksums: a damaged chunk or a flipped pixel stops the frames before
//! any message of it is used.

use super::*;

/// A log of `n` messages of 400 KiB of noise on `/blob`, one per
/// millisecond: several chunks (a chunk closes past 1 MiB), whose
/// payloads no compressor shrinks, so a flipped byte stays one flipped
/// byte of a payload.
fn write_blobs(path: &Path, compression: Compression, n: u64) {
    use rand::{RngCore, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut log = LogWriter::create(path, compression).unwrap();
    let mut payload = vec![0u8; 400 << 10];
    for i in 0..n {
        rng.fill_bytes(&mut payload);
        log.write_raw::<Image>("/blob", i * MS as u64, &payload)
            .unwrap();
    }
    log.finish().unwrap();
}

/// Reads every message of `path` through the index (or linearly when it
/// has no summary): the log times delivered, then the error, if any.
fn read_until_error(path: &Path) -> (Vec<u64>, Option<InputError>) {
    let log = McapLog::open(path).unwrap();
    let mut reader = log.reader(ReadFilter::default());
    let mut times = Vec::new();
    while let Some(m) = reader.next_with(|m| m.log_time) {
        match m {
            Ok(t) => times.push(t),
            Err(e) => return (times, Some(e)),
        }
    }
    (times, None)
}

#[test]
fn chunk_crcs_are_checked_before_any_message_is_used() {
    let dir = TempDir::new("crc");
    // The payloads are noise, so compressed chunks store them nearly as
    // they are and the flipped byte still decompresses (to a wrong value).
    for (compression, name) in [
        (Compression::None, "none"),
        (Compression::Lz4, "lz4"),
        (Compression::Zstd, "zstd"),
    ] {
        let path = dir.path().join(format!("{name}.mcap"));
        write_blobs(&path, compression, 12);
        let bytes = std::fs::read(&path).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
        assert!(summary.chunk_indexes.len() >= 3, "{name}: too few chunks");
        let (times, err) = read_until_error(&path);
        assert_eq!(times.len(), 12, "{name}: the intact log reads whole");
        assert!(err.is_none(), "{name}: {err:?}");

        // One byte flipped in the middle of the second chunk's data: inside
        // a payload (a chunk holds a few 400 KiB messages and their
        // headers are 31 bytes).
        let chunk = &summary.chunk_indexes[1];
        let data = chunk.compressed_data_offset().unwrap() as usize;
        let mut damaged = bytes.clone();
        damaged[data + chunk.compressed_size as usize / 2] ^= 0x01;
        let at = chunk.chunk_start_offset as usize;
        // The chunk header's CRC: after the opcode, record length, start
        // and end times and uncompressed size.
        let stored = u32::from_le_bytes(damaged[at + 33..at + 37].try_into().unwrap());
        assert_ne!(stored, 0, "the writer stores chunk CRCs");
        let indexed = dir.path().join(format!("{name}-flipped.mcap"));
        std::fs::write(&indexed, &damaged).unwrap();
        // Without the summary: cut where it starts, as a recording that
        // stopped before writing it.
        let footer = mcap::read::footer(&damaged).unwrap();
        let linear = dir.path().join(format!("{name}-flipped-cut.mcap"));
        std::fs::write(&linear, &damaged[..footer.summary_start as usize]).unwrap();
        assert_eq!(McapLog::open(&linear).unwrap().unindexed_files().len(), 1);

        for file in [&indexed, &linear] {
            let (times, err) = read_until_error(file);
            let err =
                err.unwrap_or_else(|| panic!("{}: the damage went unnoticed", file.display()));
            assert!(matches!(err, InputError::Log { .. }), "{err:?}");
            let msg = err.to_string();
            assert!(msg.contains(&file.display().to_string()), "{msg}");
            assert!(
                msg.contains(&format!("chunk at byte {at} is corrupt")),
                "{msg}"
            );
            assert!(
                msg.contains(&format!("CRC mismatch (the chunk says {stored:08x}")),
                "{msg}"
            );
            // Everything delivered came before the damaged chunk.
            assert!(!times.is_empty(), "{msg}: the first chunk is intact");
            assert!(
                times.iter().all(|&t| t < chunk.message_start_time),
                "{}: a message of the damaged chunk was used: {times:?}",
                file.display()
            );
        }
    }
}

#[test]
fn a_flipped_pixel_in_an_uncompressed_log_stops_the_frames() {
    let dir = TempDir::new("crc-frames");
    let path = dir.path().join("log.mcap");
    let spec = Spec {
        compression: Compression::None,
        ..Spec::default()
    };
    write_log(&path, &spec, &|_, _, _| {});
    let mut bytes = std::fs::read(&path).unwrap();
    // A pixel of the fourth colour image.
    let pixels = color_bytes(3);
    let pos = bytes
        .windows(pixels.len())
        .position(|w| w == pixels)
        .expect("uncompressed chunks hold the pixels as written");
    bytes[pos + 10] ^= 0x80;
    std::fs::write(&path, &bytes).unwrap();
    let mut frames = McapFrames::open(&path, AssemblyConfig::default()).unwrap();
    let err = frames
        .find_map(|f| f.err())
        .expect("a damaged chunk is an error");
    assert!(err.to_string().contains("CRC mismatch"), "{err}");
    // The log is one chunk, so nothing of it became a frame.
    assert_eq!(frames.report().frames, 0);
    // Without its summary, the damaged chunk hides every topic: the error
    // says why rather than only that they are missing.
    let footer = mcap::read::footer(&bytes).unwrap();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..footer.summary_start as usize]).unwrap();
    let err = McapFrames::open(&cut, AssemblyConfig::default())
        .err()
        .expect("no topic can be found")
        .to_string();
    assert!(
        err.contains("became unreadable") && err.contains("CRC mismatch"),
        "{err}"
    );
}

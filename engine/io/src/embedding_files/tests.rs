//! Tests across the readers.

use super::*;

/// A safetensors file whose header names a tensor (or the metadata)
/// twice: other readers would take the first, serde the last.
#[test]
fn every_safetensors_reader_refuses_a_key_named_twice() {
    let entry = |name: &str, v: f32| {
        (
            format!(
                "\"{name}\": {{\"dtype\": \"F32\", \"shape\": [1, 2], \"data_offsets\": [0, 8]}}"
            ),
            [v.to_le_bytes(), 1f32.to_le_bytes()].concat(),
        )
    };
    let file = |entries: &[String], data: &[u8]| {
        let header = format!("{{{}}}", entries.join(", "));
        let mut out = (header.len() as u64).to_le_bytes().to_vec();
        out.extend(header.as_bytes());
        out.extend(data);
        out
    };
    let model = "\"__metadata__\": {\"model\": \"m\"}".to_string();
    for name in ["embedding", "vectors", "grid"] {
        let (e, data) = entry(name, 0.5);
        // Once it reads (where the reader takes such a tensor alone)...
        let once = file(&[e.clone(), model.clone()], &data);
        let twice = file(&[e.clone(), e.clone(), model.clone()], &data);
        let meta_twice = file(&[e, model.clone(), model.clone()], &data);
        fn vector(b: &[u8]) -> latentam_base::Result<()> {
            vector_from_bytes(b, true, "f").map(|_| ())
        }
        fn classes(b: &[u8]) -> latentam_base::Result<()> {
            ClassVectors::parse(b, true, "f").map(|_| ())
        }
        fn frame(b: &[u8]) -> latentam_base::Result<()> {
            features_from_safetensors(b, "f", None).map(|_| ())
        }
        for read in [vector, classes, frame] {
            let _ = read(&once);
            for bad in [&twice, &meta_twice] {
                let e = read(bad).unwrap_err().to_string();
                assert!(e.contains("appears twice"), "{name}: {e}");
            }
        }
    }
    // The single files read where their reader takes them.
    let (e, data) = entry("embedding", 0.5);
    assert_eq!(
        vector_from_bytes(&file(&[e], &data), true, "f").unwrap(),
        [0.5, 1.0]
    );
}

/// Errors name the file first, as a user reads them, whichever reader
/// found the fault.
#[test]
fn errors_name_the_file() {
    let e = grid_from_npy(b"hello world", "S.grid.npy").unwrap_err();
    assert!(
        matches!(&e, latentam_base::Error::Damaged { path, .. } if path.as_os_str() == "S.grid.npy"),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "S.grid.npy: not a .npy file (no \\x93NUMPY magic)"
    );
    let e = vector_from_bytes(b"hello world", false, "q.npy").unwrap_err();
    assert!(
        e.to_string()
            .ends_with("q.npy: not a .npy array: not a .npy file (no \\x93NUMPY magic)"),
        "{e}"
    );
    let zeros = npy::write(npy::NpyType::F32, &[2], &[0; 8]);
    let e = vector_from_bytes(&zeros, false, "q.npy").unwrap_err();
    assert!(matches!(e, latentam_base::Error::BadInput { .. }), "{e:?}");
    assert!(
        e.to_string().ends_with("q.npy: the vector is all zeros"),
        "{e}"
    );
    let e = read_vector("/nonexistent/latentam/q.npy".as_ref()).unwrap_err();
    assert!(matches!(e, latentam_base::Error::Io { .. }), "{e:?}");
}

use super::*;
use crate::embedding_files::npy::{self, NpyType};

#[test]
fn sizes_a_log_cannot_hold_are_errors() {
    // More classes than 16-bit class ids can name.
    let c = u16::MAX as usize + 2;
    let vectors = npy::write(NpyType::F16, &[c, 1], &vec![0; c * 2]);
    let e = ClassVectors::parse(&vectors, false, "vectors.npy").unwrap_err();
    assert!(e.to_string().contains("16-bit"), "{e}");
    let vectors = npy::write(NpyType::F16, &[2, 1], &[0; 4]);
    assert_eq!(
        ClassVectors::parse(&vectors, false, "vectors.npy")
            .unwrap()
            .vectors
            .len(),
        2
    );
    // An empty label image.
    let e = class_ids_from_npy(&npy::write(NpyType::U16, &[0, 3], &[]), "f.npy").unwrap_err();
    assert!(
        e.to_string().contains("f.npy: label image 3×0 is empty"),
        "{e}"
    );
    let (w, h, ids) = class_ids_from_npy(
        &npy::write(NpyType::I32, &[1, 2], &[[1, 0, 0, 0], [0xff; 4]].concat()),
        "f.npy",
    )
    .unwrap();
    assert_eq!((w, h, ids), (2, 1, vec![1, u16::MAX]));
}

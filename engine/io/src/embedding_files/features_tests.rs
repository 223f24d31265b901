use super::*;
use crate::embedding_files::npy::NpyType;
use crate::MAX_EMBEDDING_DIM;

fn tensor(dtype: NpyType, shape: &[usize]) -> Tensor {
    let n: usize = shape.iter().product();
    Tensor {
        dtype,
        shape: shape.to_vec(),
        data: vec![0; n * dtype.size()],
    }
}

#[test]
fn sizes_a_log_cannot_hold_are_errors() {
    // An embedding dimension past the ingest's limit.
    let d = MAX_EMBEDDING_DIM as usize + 1;
    let e = regions(
        tensor(NpyType::U16, &[1, 1]),
        tensor(NpyType::F16, &[1, d]),
        "f",
    )
    .unwrap_err();
    assert!(e.to_string().contains("dimension"), "{e}");
    let e = grid(tensor(NpyType::F16, &[1, 1, d]), "g").unwrap_err();
    assert!(e.to_string().contains("dimension"), "{e}");
}

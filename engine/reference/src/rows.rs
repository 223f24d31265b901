//! Rows moved by index between a row-major buffer and a packed staging
//! buffer (kernels `glsl/rows.comp`), and within one buffer
//! (`glsl/rows_move.comp`), as plain loops over 32-bit words.

/// `staging[i * width + j] = data[index[i] * width + j]` for every listed
/// row `i` and word `j`.
pub fn gather(data: &[u32], width: usize, index: &[u32]) -> Vec<u32> {
    let mut staging = Vec::with_capacity(index.len() * width);
    for &row in index {
        let at = row as usize * width;
        staging.extend_from_slice(&data[at..at + width]);
    }
    staging
}

/// `data[index[i] * width + j] = staging[i * width + j]` for every listed
/// row `i` and word `j`, in list order (a row listed twice keeps the last).
pub fn scatter(data: &mut [u32], width: usize, index: &[u32], staging: &[u32]) {
    for (i, &row) in index.iter().enumerate() {
        let at = row as usize * width;
        data[at..at + width].copy_from_slice(&staging[i * width..(i + 1) * width]);
    }
}

/// Row `from[i]` of `data` copied to row `to[i]`, for every `i`, reading
/// every source before writing any destination (the kernel may run the
/// moves in any order; its callers keep sources and destinations apart,
/// which makes the two readings agree).
pub fn move_rows(data: &mut [u32], width: usize, from: &[u32], to: &[u32]) {
    let moved: Vec<u32> = gather(data, width, from);
    scatter(data, width, to, &moved);
}

//! Stable key-value sort (kernels `radix_histogram`/`radix_scatter` in
//! `shaders/wgsl/radix_sort.wgsl`).

/// Sorts (key, value) pairs by the low `key_bits` bits of the key, stably:
/// equal keys keep their input order. Higher key bits are ignored for the
/// order but kept in the output.
pub fn sort_pairs(keys: &[u32], values: &[u32], key_bits: u32) -> (Vec<u32>, Vec<u32>) {
    let mask = if key_bits >= 32 {
        u32::MAX
    } else {
        (1u32 << key_bits) - 1
    };
    let mut idx: Vec<usize> = (0..keys.len()).collect();
    idx.sort_by_key(|&i| keys[i] & mask); // `sort_by_key` is stable
    (
        idx.iter().map(|&i| keys[i]).collect(),
        idx.iter().map(|&i| values[i]).collect(),
    )
}

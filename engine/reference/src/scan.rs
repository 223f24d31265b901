//! Exclusive prefix sum (kernel `glsl/scan.comp`).

/// `out[i]` = sum of `data[..i]`, wrapping on u32 overflow like the GPU.
pub fn exclusive_scan_u32(data: &[u32]) -> Vec<u32> {
    let mut run = 0u32;
    data.iter()
        .map(|&x| {
            let before = run;
            run = run.wrapping_add(x);
            before
        })
        .collect()
}

//! Which Gaussians pruning removes (kernel `glsl/prune_mask.comp`): the
//! nearly transparent and the too large.

/// One bit a row, 32 rows a word (bit `b` of word `w` is row `32w + b`),
/// set where the row is pruned: its opacity logit is not at least
/// `min_logit` (a NaN is pruned), or the largest of its log scales is not
/// at most `max_log_scale` (NaN scales are passed over: a row whose every
/// scale is NaN keeps its size). Bits past the rows are clear.
pub fn prune_mask(
    log_scales: &[[f32; 3]],
    opacity_logits: &[f32],
    min_logit: f32,
    max_log_scale: f32,
) -> Vec<u32> {
    let rows = opacity_logits.len();
    let mut mask = vec![0u32; rows.div_ceil(32)];
    for (r, (s, &o)) in log_scales.iter().zip(opacity_logits).enumerate() {
        let largest = s.iter().copied().fold(f32::MIN, f32::max);
        let keep = o >= min_logit && largest <= max_log_scale;
        if !keep {
            mask[r / 32] |= 1 << (r % 32);
        }
    }
    mask
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faint_large_and_nan_opacity_rows_are_marked() {
        let scales = [
            [0.0, 0.0, 0.0],      // kept
            [0.0, 2.0, 0.0],      // too large
            [0.0, 0.0, 0.0],      // too faint
            [f32::NAN, 0.0, 0.0], // a NaN scale is passed over
            [0.0, 0.0, 0.0],      // NaN opacity
        ];
        let opacity = [0.0, 0.0, -9.0, 0.0, f32::NAN];
        assert_eq!(prune_mask(&scales, &opacity, -5.0, 1.0), [0b10110]);
        let many = vec![[0.0; 3]; 33];
        let mut faint = vec![0.0; 33];
        faint[32] = -9.0;
        assert_eq!(prune_mask(&many, &faint, -5.0, 1.0), [0, 1]);
    }
}

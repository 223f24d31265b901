//! Adam with per-row step counts, row masks and moment reset (kernels
//! `glsl/adam_step.comp`, `adam_count.comp`, `adam_reset.comp`; GPU side in
//! `engine/core/src/optim/adam.rs`).

/// Adam's hyper-parameters, as the GPU optimiser's `AdamHyper` holds them
/// (there in f32).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamHyper {
    /// Learning rate.
    pub lr: f64,
    /// First-moment decay β₁.
    pub beta1: f64,
    /// Second-moment decay β₂.
    pub beta2: f64,
    /// Added to √v̂.
    pub eps: f64,
}

/// State of one parameter tensor (rows × width) under Adam.
///
/// ```
/// use latentam_reference::adam::{AdamHyper, AdamState};
///
/// let mut state = AdamState::new(2, 3);
/// let mut param = vec![1.0f64; 6];
/// let h = AdamHyper { lr: 0.1, beta1: 0.9, beta2: 0.999, eps: 1e-8 };
/// state.step(&h, &mut param, &[0.5f32; 6], 2, Some(&[true, false]));
/// // Adam's first step moves each element by lr against its gradient's sign;
/// // row 1 was masked out.
/// assert!((param[0] - 0.9).abs() < 1e-6);
/// assert_eq!(param[3], 1.0);
/// assert_eq!(state.steps, vec![1, 0]);
/// ```
#[derive(Clone, Debug)]
pub struct AdamState {
    /// Columns per row.
    pub width: usize,
    /// First moments.
    pub m: Vec<f64>,
    /// Second moments.
    pub v: Vec<f64>,
    /// Updates taken per row.
    pub steps: Vec<u32>,
}

impl AdamState {
    /// Zero state for `rows` × `width` parameters.
    pub fn new(rows: usize, width: usize) -> Self {
        Self {
            width,
            m: vec![0.0; rows * width],
            v: vec![0.0; rows * width],
            steps: vec![0; rows],
        }
    }

    /// One update of the first `rows` rows; rows with `mask[row] == false`
    /// are skipped, and so are elements whose gradient is not finite.
    pub fn step(
        &mut self,
        h: &AdamHyper,
        param: &mut [f64],
        grad: &[f32],
        rows: usize,
        mask: Option<&[bool]>,
    ) {
        for row in 0..rows {
            if mask.is_some_and(|m| !m[row]) {
                continue;
            }
            let (lr, b1, b2, eps) = (h.lr, h.beta1, h.beta2, h.eps);
            let t = (self.steps[row] + 1) as i32;
            for i in row * self.width..(row + 1) * self.width {
                let g = grad[i] as f64;
                if !g.is_finite() {
                    continue;
                }
                self.m[i] = b1 * self.m[i] + (1.0 - b1) * g;
                self.v[i] = b2 * self.v[i] + (1.0 - b2) * g * g;
                let mhat = self.m[i] / (1.0 - b1.powi(t));
                let vhat = self.v[i] / (1.0 - b2.powi(t));
                param[i] -= lr * mhat / (vhat.sqrt() + eps);
            }
            self.steps[row] += 1;
        }
    }

    /// Forgets the history of the flagged rows.
    pub fn reset(&mut self, flags: &[bool]) {
        for (row, _) in flags.iter().enumerate().filter(|(_, &f)| f) {
            for i in row * self.width..(row + 1) * self.width {
                self.m[i] = 0.0;
                self.v[i] = 0.0;
            }
            self.steps[row] = 0;
        }
    }
}

//! A keyframe's exposure against the map: how much brighter the camera saw
//! the surfaces the map already holds than the map renders them.
//!
//! Cameras with auto-exposure (most RGB-D sensors) change their gain as
//! the view moves from a window to a dark corner. Without compensation a
//! surface keeps the brightness of the view that seeded it, and a surface
//! seen at two gains has no colour that fits both. With it, every
//! keyframe's colours are divided by its gain before they seed or train
//! the map, so the map holds one consistent brightness (the first
//! keyframe's), and a view is rendered at its own time's gain by
//! interpolating between the keyframes around it ([`ExposureTrack`]).

/// Pixels darker or brighter than this (0..1, per channel) are left out of
/// the estimate: clipped channels say nothing about the gain.
const DARKEST: f32 = 8.0 / 255.0;
const BRIGHTEST: f32 = 247.0 / 255.0;
/// Covered pixels need at least this accumulated alpha.
const COVERED: f32 = 0.95;
/// Ratios more than this factor from the median are outliers (misaligned
/// edges, specular highlights, moved objects).
const OUTLIER_FACTOR: f32 = 1.5;
/// Fewer usable pixels than this share of the view give no estimate (the
/// mapper then keeps the last keyframe's gain). Small overlaps are the
/// edge of the mapped space and less certain (on the demo scene, whose
/// exposure is constant, overlaps of 3.6 % and 6.9 % of the view gave
/// 1.098 and 1.068, every larger one within 3 % of 1), but keeping the last
/// gain there instead missed a swinging exposure by up to 6 %
/// (`auto_exposure_is_measured_and_undone` with the share at 10 %), so only
/// overlaps too small to measure anything are refused.
const MIN_SHARE: f64 = 0.02;
/// The estimate is kept within these bounds (a factor of 4 either way
/// is beyond any exposure step between two keyframes).
pub const EXPOSURE_RANGE: (f32, f32) = (0.25, 4.0);

/// The frame's gain over the map, `observed ≈ gain × rendered`, from the
/// pixels the map renders opaquely on the same surface the frame measured.
/// `observed` is packed RGB; `rendered` the map's RGB-and-unnormalised-depth
/// image at the frame's pose with its accumulated `alpha`; `depth` the
/// measured depth in metres (`None` where invalid; such pixels count when
/// the map is opaque there). `None` when too few pixels qualify.
///
/// ```
/// use latentam_core::map::relative_exposure;
///
/// // The camera saw the map's grey surface 20 % brighter.
/// let rendered = vec![[0.4, 0.5, 0.3, 2.0]; 100];
/// let observed: Vec<u8> = (0..100).flat_map(|_| [122u8, 153, 92]).collect();
/// let gain = relative_exposure(&observed, &rendered, &[1.0; 100], |_| Some(2.0), 0.05).unwrap();
/// assert!((gain - 1.2).abs() < 0.01);
/// ```
pub fn relative_exposure(
    observed: &[u8],
    rendered: &[[f32; 4]],
    alpha: &[f32],
    depth: impl Fn(usize) -> Option<f32>,
    depth_tolerance: f32,
) -> Option<f32> {
    let mut pairs = Vec::new();
    for (i, ((o, r), &a)) in observed
        .chunks_exact(3)
        .zip(rendered)
        .zip(alpha)
        .enumerate()
    {
        if a < COVERED {
            continue;
        }
        if let Some(z) = depth(i) {
            if (r[3] / a - z).abs() > depth_tolerance * z {
                continue;
            }
        }
        let o = [o[0], o[1], o[2]].map(|c| c as f32 / 255.0);
        if o.iter().any(|&c| !(DARKEST..=BRIGHTEST).contains(&c)) {
            continue;
        }
        let seen = o[0] + o[1] + o[2];
        let map = (r[0] + r[1] + r[2]) / a;
        let brightest = r[0].max(r[1]).max(r[2]) / a;
        if map > 3.0 * DARKEST {
            pairs.push((seen, map, brightest));
        }
    }
    if (pairs.len() as f64) < MIN_SHARE * alpha.len() as f64 || pairs.is_empty() {
        return None;
    }
    let mut ratios: Vec<f32> = pairs.iter().map(|(s, m, _)| s / m).collect();
    let mid = ratios.len() / 2;
    let median = *ratios.select_nth_unstable_by(mid, f32::total_cmp).1;
    // The ratio of sums over the inliers: blur moves dark pixels up and
    // bright ones down, which a ratio of sums cancels and a median not.
    // Pixels the camera would have clipped at the gain are left out too,
    // as the clipped ones were: otherwise only the map's bright pixels
    // that a blur darkened would stay, and the gain would come out high.
    let (seen, map) = pairs
        .iter()
        .filter(|(s, m, brightest)| {
            let r = s / m;
            r <= median * OUTLIER_FACTOR
                && r * OUTLIER_FACTOR >= median
                && brightest * median <= BRIGHTEST
        })
        .fold((0.0f64, 0.0f64), |(a, b), (s, m, _)| {
            (a + *s as f64, b + *m as f64)
        });
    // No inliers left (every pixel one the camera would clip): no estimate.
    if map <= 0.0 {
        return None;
    }
    let gain = (seen / map) as f32;
    gain.is_finite()
        .then(|| gain.clamp(EXPOSURE_RANGE.0, EXPOSURE_RANGE.1))
}

/// Each keyframe's exposure by time stamp, and the exposure at any time in
/// between (linear in the logarithm of the gain; the nearest keyframe's
/// before the first and after the last).
///
/// ```
/// use latentam_core::map::ExposureTrack;
///
/// let mut track = ExposureTrack::default();
/// track.push(0, 1.0);
/// track.push(100, 4.0);
/// assert!((track.at(50) - 2.0).abs() < 1e-6); // geometric mean halfway
/// assert_eq!(track.at(-10), 1.0);
/// assert_eq!(track.at(500), 4.0);
/// ```
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExposureTrack {
    stamps: Vec<i64>,
    gains: Vec<f32>,
}

impl ExposureTrack {
    /// Adds a keyframe's gain; stamps must not go back in time (a stamp
    /// before the last one is placed in order).
    pub fn push(&mut self, stamp_ns: i64, gain: f32) {
        let at = self.stamps.partition_point(|&s| s <= stamp_ns);
        self.stamps.insert(at, stamp_ns);
        self.gains.insert(at, gain);
    }

    /// The gain at `stamp_ns` (1 for an empty track).
    pub fn at(&self, stamp_ns: i64) -> f32 {
        let after = self.stamps.partition_point(|&s| s <= stamp_ns);
        match (after.checked_sub(1), self.gains.get(after)) {
            (None, None) => 1.0,
            (None, Some(&g)) => g,
            (Some(b), None) => self.gains[b],
            (Some(b), Some(&g)) => {
                let (s0, s1) = (self.stamps[b], self.stamps[after]);
                let t = (stamp_ns - s0) as f64 / (s1 - s0).max(1) as f64;
                let (l0, l1) = ((self.gains[b] as f64).ln(), (g as f64).ln());
                (l0 + t * (l1 - l0)).exp() as f32
            }
        }
    }

    /// Stamps and gains, in time order.
    pub fn iter(&self) -> impl Iterator<Item = (i64, f32)> + '_ {
        self.stamps.iter().copied().zip(self.gains.iter().copied())
    }

    /// Keyframes on the track.
    pub fn len(&self) -> usize {
        self.stamps.len()
    }

    /// No keyframe yet.
    pub fn is_empty(&self) -> bool {
        self.stamps.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(gain: f32, n: usize) -> (Vec<u8>, Vec<[f32; 4]>) {
        let mut rng = latentam_base::random::SplitMix(7);
        let rendered: Vec<[f32; 4]> = (0..n)
            .map(|_| {
                let c = [0; 3].map(|_| 0.1 + 0.6 * rng.uniform());
                [c[0], c[1], c[2], 1.5]
            })
            .collect();
        let observed = rendered
            .iter()
            .flat_map(|p| [0, 1, 2].map(|c| (p[c] * gain * 255.0).round().min(255.0) as u8))
            .collect();
        (observed, rendered)
    }

    #[test]
    fn the_gain_is_found_despite_outliers_and_clipped_pixels() {
        for gain in [0.6f32, 1.0, 1.35] {
            let (mut observed, rendered) = scene(gain, 4000);
            // A highlight and a moved object: 10 % of the pixels wrong.
            for p in observed.chunks_exact_mut(3).step_by(10) {
                p.copy_from_slice(&[250, 30, 200]);
            }
            let g = relative_exposure(&observed, &rendered, &[1.0; 4000], |_| Some(1.5), 0.05)
                .expect("enough pixels");
            assert!((g - gain).abs() < 0.01 * gain, "{g} for {gain}");
        }
    }

    #[test]
    fn other_surfaces_and_uncovered_pixels_are_left_out() {
        let (observed, mut rendered) = scene(1.2, 2000);
        let mut alpha = vec![1.0; 2000];
        // Half the view: the map renders another surface (a wall behind
        // what the frame measured), dark, or not at all.
        for (i, p) in rendered.iter_mut().enumerate().skip(1000) {
            p[0] *= 0.2;
            if i % 2 == 0 {
                p[3] = 3.0;
            } else {
                alpha[i] = 0.3;
            }
        }
        let g = relative_exposure(&observed, &rendered, &alpha, |_| Some(1.5), 0.05).unwrap();
        assert!((g - 1.2).abs() < 0.012, "{g}");
        assert_eq!(
            relative_exposure(&observed, &rendered, &[0.5; 2000], |_| None, 0.05),
            None
        );
        // The map covers only the view's edge: too little to tell.
        let edge: Vec<f32> = (0..2000).map(|i| if i < 30 { 1.0 } else { 0.3 }).collect();
        assert_eq!(
            relative_exposure(&observed, &rendered, &edge, |_| Some(1.5), 0.05),
            None
        );
        let more: Vec<f32> = (0..2000).map(|i| if i < 60 { 1.0 } else { 0.3 }).collect();
        assert!(relative_exposure(&observed, &rendered, &more, |_| Some(1.5), 0.05).is_some());
        // A red wall the map holds brighter than 1 (divided by a gain below
        // one), seen just below clipping: every pixel would clip at the
        // gain, so there is no estimate rather than a gain of 0.
        let wall = vec![[1.2, 0.3, 0.3, 1.5]; 500];
        let seen: Vec<u8> = (0..500).flat_map(|_| [246u8, 75, 75]).collect();
        assert_eq!(
            relative_exposure(&seen, &wall, &[1.0; 500], |_| Some(1.5), 0.05),
            None
        );
    }

    #[test]
    fn the_track_interpolates_in_log_gain_and_keeps_time_order() {
        let mut t = ExposureTrack::default();
        assert_eq!(t.at(5), 1.0);
        t.push(10, 0.5);
        t.push(0, 2.0);
        assert_eq!(t.iter().collect::<Vec<_>>(), vec![(0, 2.0), (10, 0.5)]);
        assert!((t.at(5) - 1.0).abs() < 1e-6);
        assert_eq!(t.at(0), 2.0);
        assert_eq!(t.at(10), 0.5);
        assert_eq!(t.at(11), 0.5);
    }
}

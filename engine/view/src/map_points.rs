//! The points a map shows: one per Gaussian (or an even subset within a
//! point budget), at its mean, in its colour, with its opacity as alpha.

use latentam_base::HostGaussians;

use crate::messages::Cloud;

/// Points of a map, ready for a [`Cloud`].
///
/// ```
/// use latentam_base::HostGaussians;
/// use latentam_view::MapPoints;
///
/// let g = HostGaussians::zeros(10);
/// let points = MapPoints::of(&g, 4);
/// assert_eq!(points.indices, vec![0, 3, 6, 9]); // evenly through the map
/// assert_eq!(points.opacity[0], 0.5); // a logit of 0
/// let scores: Vec<f32> = (0..20).map(|i| i as f32).collect(); // two per Gaussian
/// assert_eq!(points.pick_rows(&scores, 2)[2..4], [6.0, 7.0]); // Gaussian 3's
/// ```
#[derive(Clone, Debug, Default)]
pub struct MapPoints {
    /// Which Gaussians, in map order.
    pub indices: Vec<usize>,
    /// Their means, metres.
    pub positions: Vec<[f32; 3]>,
    /// Their colours, alpha = opacity.
    pub colours: Vec<[u8; 4]>,
    /// Their opacities.
    pub opacity: Vec<f32>,
}

fn byte(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

impl MapPoints {
    /// At most `budget` points of `g` (every Gaussian when it has fewer),
    /// spread evenly over its order, which follows the map's voxels, so
    /// the subset covers the whole map.
    pub fn of(g: &HostGaussians, budget: usize) -> Self {
        let n = g.means.len();
        let k = n.min(budget);
        let indices: Vec<usize> = if k == n {
            (0..n).collect()
        } else if k == 1 {
            vec![0]
        } else {
            // Evenly from the first to the last.
            (0..k).map(|i| i * (n - 1) / (k - 1)).collect()
        };
        let opacity: Vec<f32> = indices
            .iter()
            .map(|&i| 1.0 / (1.0 + (-g.opacity_logits[i]).exp()))
            .collect();
        MapPoints {
            positions: indices.iter().map(|&i| g.means[i]).collect(),
            colours: indices
                .iter()
                .zip(&opacity)
                .map(|(&i, &a)| {
                    let [r, gr, b] = g.colors[i];
                    [byte(r), byte(gr), byte(b), byte(a)]
                })
                .collect(),
            opacity,
            indices,
        }
    }

    /// The cloud of these points with their opacity as the value.
    pub fn cloud(&self) -> Cloud<'_> {
        Cloud {
            positions: &self.positions,
            colours: &self.colours,
            value: ("opacity", &self.opacity),
        }
    }

    /// The rows of `values` (`per_point` values per Gaussian of the map,
    /// e.g. one cosine per text) at these points, back to back.
    pub fn pick_rows(&self, values: &[f32], per_point: usize) -> Vec<f32> {
        self.indices
            .iter()
            .flat_map(|&i| values[i * per_point..(i + 1) * per_point].iter().copied())
            .collect()
    }
}

/// The heat colour of `t` in [0, 1]: blue, cyan, green, yellow, red
/// (anything not finite is blue).
pub fn heat(t: f32) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [0.05, 0.05, 0.45],
        [0.0, 0.75, 0.9],
        [0.1, 0.8, 0.2],
        [0.95, 0.85, 0.1],
        [0.85, 0.1, 0.05],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let f = x - i as f32;
    std::array::from_fn(|c| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f)
}

/// [`heat`] as opaque RGBA bytes, for a cloud.
pub fn heat_rgba(t: f32) -> [u8; 4] {
    let [r, g, b] = heat(t);
    [byte(r), byte(g), byte(b), 255]
}

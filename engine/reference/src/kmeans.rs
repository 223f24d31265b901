//! Streaming k-means with a fixed number of atoms (paper Sec. III-C, Eq. 10; GPU side in
//! `engine/core/src/latent/kmeans.rs`), in f64, step for step as the kernels do
//! it, including their tie rules (lowest index wins).
//!
//! Per keyframe:
//! 1. **Micro-clusters**: the keyframe's region embeddings are clustered
//!    into m weighted centres (farthest-point seeds, Lloyd by cosine).
//! 2. **Append** while the dictionary has room for all m.
//! 3. Otherwise **re-cluster** the atoms and the micro-centres into K:
//!    micro-centres unlike every atom (cosine below the novelty threshold)
//!    replace the lighter atom of the most similar pair as warm-start
//!    centres; then weighted Lloyd over the points [atoms; micro-centres]
//!    (atom masses scaled by the decay), warm-started from the atoms. In
//!    the first assignment an atom whose centre was not replaced stays in
//!    its own cluster (its cosine to itself is 1, which no centre exceeds;
//!    an exact duplicate does not take it), so that assignment needs only
//!    the other points' similarities. In later assignments a point whose
//!    centre did not move keeps it unless a centre that moved beats it,
//!    as the GPU's sparse iterations do.
//! 4. Report which atoms moved, for the optimiser's moment reset.
//!
//! Every choice above compares two numbers (two cosines, a cosine and
//! the novelty threshold, two weights, a distance and the tolerance).
//! [`update_dictionary_with_margin`] also returns the narrowest of those
//! gaps: a GPU computing in f32 may choose the other way where it is
//! below f32 rounding, so a comparison against this reference is only
//! meaningful on inputs with a clear margin.

/// Settings of the algorithm.
///
/// ```
/// use latentam_reference::kmeans::{micro_clusters, KMeansSettings};
///
/// let s = KMeansSettings {
///     micro_clusters: 2, local_iterations: 5, global_iterations: 3, decay: 1.0,
///     novelty_threshold: 0.5, normalize: true, moved_tolerance: 1e-4,
/// };
/// // Four regions of a keyframe, in two directions.
/// let points = vec![vec![1.0, 0.0], vec![0.9, 0.1], vec![0.0, 1.0], vec![0.1, 0.9]];
/// let (centres, weights) = micro_clusters(&s, &points, &[1.0; 4]);
/// assert_eq!(centres.len(), 2);
/// assert_eq!(weights, vec![2.0, 2.0]);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KMeansSettings {
    /// Micro-clusters per keyframe, m (at most the keyframe's region count).
    pub micro_clusters: usize,
    /// Lloyd iterations of the micro-clustering.
    pub local_iterations: usize,
    /// Lloyd iterations of the re-clustering into K.
    pub global_iterations: usize,
    /// Factor on the old atoms' weights at each keyframe (1 = no
    /// forgetting).
    pub decay: f64,
    /// A micro-centre whose best cosine to the atoms is below this is a new
    /// concept and gets an atom of its own.
    pub novelty_threshold: f64,
    /// Re-normalise centres to unit length after each update.
    pub normalize: bool,
    /// An atom that moved by more than this (L2) is reported as moved.
    pub moved_tolerance: f64,
}

/// Points as rows of a matrix, with a mass each.
fn unit_rows(points: &[Vec<f64>]) -> Vec<Vec<f64>> {
    points
        .iter()
        .map(|p| {
            let n = p.iter().map(|v| v * v).sum::<f64>().sqrt();
            p.iter().map(|v| v / (n + 1e-12)).collect()
        })
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The narrowest gap between two compared numbers seen so far, relative
/// to the larger of them where that exceeds 1 (cosines and distances are
/// compared absolutely, weights relatively).
#[derive(Clone, Copy, Debug)]
struct Margin(f64);

impl Margin {
    fn new() -> Self {
        Self(f64::INFINITY)
    }

    fn note(&mut self, a: f64, b: f64) {
        if a.is_finite() && b.is_finite() {
            self.0 = self.0.min((a - b).abs() / a.abs().max(b.abs()).max(1.0));
        }
    }
}

/// (value, index) of the best column; ties to the lowest index; `skip`
/// excludes one column.
fn best(values: impl Iterator<Item = f64>, skip: Option<usize>) -> Option<(f64, usize)> {
    best_and_runner_up(values, skip).map(|(v, i, _)| (v, i))
}

/// [`best`], with the runner-up's value (-inf when there is none).
fn best_and_runner_up(
    values: impl Iterator<Item = f64>,
    skip: Option<usize>,
) -> Option<(f64, usize, f64)> {
    let mut out: Option<(f64, usize, f64)> = None;
    for (i, v) in values.enumerate() {
        if Some(i) == skip {
            continue;
        }
        out = Some(match out {
            None => (v, i, f64::NEG_INFINITY),
            Some((w, _, _)) if v > w => (v, i, w),
            Some((w, j, second)) => (w, j, second.max(v)),
        });
    }
    out
}

/// Index of each point's most similar centre (cosine).
fn assign(points: &[Vec<f64>], centres: &[Vec<f64>], margin: &mut Margin) -> Vec<usize> {
    let (p, c) = (unit_rows(points), unit_rows(centres));
    p.iter()
        .map(|x| {
            best_and_runner_up(c.iter().map(|y| dot(x, y)), None).map_or(0, |(v, i, second)| {
                margin.note(v, second);
                i
            })
        })
        .collect()
}

/// A centre's direction counts as moved once it is this far (L2) from the
/// one its similarities were computed with (the GPU's `STALE_TOLERANCE`).
const MOVED_DIRECTION: f64 = 1e-6;

/// A Lloyd assignment after the first: a point whose centre moved takes
/// the best centre; one whose centre did not move keeps it unless a moved
/// centre beats it (larger cosine, or equal and a lower index). Without
/// exact ties this is the nearest centre of every point; with them, an
/// atom that began in its own cluster keeps it against an exact duplicate
/// that did not move. `seen` holds the directions last compared against and
/// is updated for the centres that moved.
fn reassign(
    unit_points: &[Vec<f64>],
    centres: &[Vec<f64>],
    seen: &mut [Vec<f64>],
    assignment: &mut [usize],
    margin: &mut Margin,
) {
    let now = unit_rows(centres);
    let moved: Vec<bool> = now
        .iter()
        .zip(seen.iter())
        .map(|(c, s)| {
            c.iter()
                .zip(s)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f64>()
                .sqrt()
                > MOVED_DIRECTION
        })
        .collect();
    for (j, m) in moved.iter().enumerate() {
        if *m {
            seen[j] = now[j].clone();
        }
    }
    for (p, a) in unit_points.iter().zip(assignment.iter_mut()) {
        let cosine = |j: usize| dot(p, &seen[j]);
        *a = if moved[*a] {
            best_and_runner_up((0..seen.len()).map(cosine), None).map_or(*a, |(v, i, second)| {
                margin.note(v, second);
                i
            })
        } else {
            let (mut value, mut index) = (cosine(*a), *a);
            for j in (0..seen.len()).filter(|&j| moved[j]) {
                let v = cosine(j);
                margin.note(v, value);
                if v > value || (v == value && j < index) {
                    (value, index) = (v, j);
                }
            }
            index
        };
    }
}

/// One weighted Lloyd update in place; returns the new weights.
fn update(
    points: &[Vec<f64>],
    mass: &[f64],
    assignment: &[usize],
    centres: &mut [Vec<f64>],
    normalize: bool,
) -> Vec<f64> {
    let mut weights = vec![0.0; centres.len()];
    for (j, centre) in centres.iter_mut().enumerate() {
        let total: f64 = (0..points.len())
            .filter(|&i| assignment[i] == j)
            .map(|i| mass[i])
            .sum();
        if total <= 0.0 {
            continue;
        }
        let mut c = vec![0.0; centre.len()];
        for i in (0..points.len()).filter(|&i| assignment[i] == j) {
            for (ck, pk) in c.iter_mut().zip(&points[i]) {
                *ck += mass[i] * pk;
            }
        }
        c.iter_mut().for_each(|v| *v /= total);
        if normalize {
            let n = c.iter().map(|v| v * v).sum::<f64>().sqrt();
            if n > 0.0 {
                c.iter_mut().for_each(|v| *v /= n);
            }
        }
        *centre = c;
        weights[j] = total;
    }
    weights
}

/// The micro-clusters of one keyframe: (centres, weights).
pub fn micro_clusters(
    s: &KMeansSettings,
    points: &[Vec<f64>],
    mass: &[f64],
) -> (Vec<Vec<f64>>, Vec<f64>) {
    micro_clusters_noting(s, points, mass, &mut Margin::new())
}

fn micro_clusters_noting(
    s: &KMeansSettings,
    points: &[Vec<f64>],
    mass: &[f64],
    margin: &mut Margin,
) -> (Vec<Vec<f64>>, Vec<f64>) {
    let m = s.micro_clusters.min(points.len());
    if m == 0 {
        return (Vec::new(), Vec::new());
    }
    let unit = unit_rows(points);
    let (_, mut seed, second) = best_and_runner_up(mass.iter().copied(), None).expect("points");
    margin.note(mass[seed], second);
    let mut centres = Vec::with_capacity(m);
    let mut closest = vec![f64::NEG_INFINITY; points.len()];
    for j in 0..m {
        centres.push(points[seed].clone());
        if j + 1 == m {
            break;
        }
        for (i, c) in closest.iter_mut().enumerate() {
            *c = c.max(dot(&unit[i], &unit[seed]));
        }
        let farthest = best_and_runner_up(closest.iter().map(|c| -c), None).expect("points");
        margin.note(farthest.0, farthest.2);
        seed = farthest.1;
    }
    let mut weights = vec![0.0; m];
    for _ in 0..s.local_iterations {
        let a = assign(points, &centres, margin);
        weights = update(points, mass, &a, &mut centres, s.normalize);
    }
    (centres, weights)
}

/// A dictionary with a fixed capacity, as streaming k-means maintains it.
///
/// ```
/// use latentam_reference::kmeans::{update_dictionary, Dictionary, KMeansSettings};
///
/// let s = KMeansSettings {
///     micro_clusters: 2, local_iterations: 5, global_iterations: 3, decay: 1.0,
///     novelty_threshold: 0.5, normalize: true, moved_tolerance: 1e-4,
/// };
/// let mut dict = Dictionary { atoms: Vec::new(), weights: Vec::new(), capacity: 4 };
/// let points = vec![vec![1.0, 0.0], vec![0.9, 0.1], vec![0.0, 1.0], vec![0.1, 0.9]];
/// let moved = update_dictionary(&s, &mut dict, &points, &[1.0; 4]);
/// assert_eq!(dict.atoms.len(), 2); // room left: the micro-centres are appended
/// assert_eq!(moved.len(), dict.atoms.len());
/// assert_eq!(dict.weights.iter().sum::<f64>(), 4.0);
/// ```
#[derive(Clone, Debug)]
pub struct Dictionary {
    /// Atoms in use.
    pub atoms: Vec<Vec<f64>>,
    /// Accumulated mass per atom.
    pub weights: Vec<f64>,
    /// K.
    pub capacity: usize,
}

impl Dictionary {
    /// The narrowest gap between the cosines of two different closest
    /// pairs (an atom and its most similar other atom). A re-clustering
    /// that finds a new concept replaces the lighter atom of the most
    /// similar pair, so these gaps are choices a later keyframe makes.
    ///
    /// ```
    /// use latentam_reference::kmeans::Dictionary;
    ///
    /// let dict = Dictionary {
    ///     atoms: vec![vec![1.0, 0.0], vec![0.8, 0.6], vec![0.0, 1.0]],
    ///     weights: vec![1.0; 3],
    ///     capacity: 3,
    /// };
    /// // Pairs (0, 1) at 0.8 and (1, 2) at 0.6.
    /// assert!((dict.pair_margin() - 0.2).abs() < 1e-12);
    /// ```
    pub fn pair_margin(&self) -> f64 {
        let unit = unit_rows(&self.atoms);
        let mut pairs: Vec<(usize, usize, f64)> = (0..unit.len())
            .filter_map(|a| {
                best(unit.iter().map(|b| dot(&unit[a], b)), Some(a))
                    .map(|(v, b)| (a.min(b), a.max(b), v))
            })
            .collect();
        pairs.sort_by(|x, y| x.2.total_cmp(&y.2));
        pairs.dedup_by(|x, y| (x.0, x.1) == (y.0, y.1));
        pairs
            .windows(2)
            .map(|w| w[1].2 - w[0].2)
            .fold(f64::INFINITY, f64::min)
    }
}

/// One keyframe's update; returns which atoms moved (one flag per atom now
/// in use).
pub fn update_dictionary(
    s: &KMeansSettings,
    dict: &mut Dictionary,
    points: &[Vec<f64>],
    mass: &[f64],
) -> Vec<bool> {
    update_dictionary_with_margin(s, dict, points, mass).0
}

/// [`update_dictionary`], with the narrowest gap between two numbers it
/// compared to make a choice (see the module documentation); infinite
/// when it made none.
pub fn update_dictionary_with_margin(
    s: &KMeansSettings,
    dict: &mut Dictionary,
    points: &[Vec<f64>],
    mass: &[f64],
) -> (Vec<bool>, f64) {
    let mut margin = Margin::new();
    let moved = update_noting(s, dict, points, mass, &mut margin);
    (moved, margin.0)
}

fn update_noting(
    s: &KMeansSettings,
    dict: &mut Dictionary,
    points: &[Vec<f64>],
    mass: &[f64],
    margin: &mut Margin,
) -> Vec<bool> {
    let (micro, micro_w) = micro_clusters_noting(s, points, mass, margin);
    let old = dict.atoms.clone();
    if micro.is_empty() {
        return vec![false; old.len()];
    }
    if old.len() + micro.len() <= dict.capacity {
        dict.atoms.extend(micro);
        dict.weights.extend(micro_w);
    } else {
        let k = old.len();
        let all: Vec<Vec<f64>> = old.iter().chain(&micro).cloned().collect();
        let all_mass: Vec<f64> = dict
            .weights
            .iter()
            .map(|w| w * s.decay)
            .chain(micro_w.iter().copied())
            .collect();
        // Novelty: similarities of every point to the atoms.
        let unit = unit_rows(&all);
        let best_of: Vec<Option<(f64, usize)>> = (0..all.len())
            .map(|r| {
                best(
                    unit[..k].iter().map(|a| dot(&unit[r], a)),
                    (r < k).then_some(r),
                )
            })
            .collect();
        let mut touched = vec![false; k];
        let mut replaced = vec![false; k];
        let mut centres = old.clone();
        for j in 0..micro.len() {
            if let Some((v, _)) = best_of[k + j] {
                margin.note(v, s.novelty_threshold);
                if v >= s.novelty_threshold {
                    continue;
                }
            }
            let pair = best(
                (0..k).map(|a| match best_of[a] {
                    Some((v, b)) if !touched[a] && !touched[b] => v,
                    _ => f64::NEG_INFINITY,
                }),
                None,
            )
            .filter(|&(v, _)| v > f64::NEG_INFINITY);
            let Some((value, a)) = pair else { break };
            let b = best_of[a].expect("pair").1;
            // The runner-up pair; (a, b) and (b, a) are the same pair.
            let other = (0..k)
                .filter(|&c| c != a && c != b)
                .filter_map(|c| match best_of[c] {
                    Some((v, d)) if !touched[c] && !touched[d] && (c, d) != (b, a) => Some(v),
                    _ => None,
                })
                .fold(f64::NEG_INFINITY, f64::max);
            margin.note(value, other);
            margin.note(dict.weights[a], dict.weights[b]);
            let lighter = if dict.weights[b] < dict.weights[a] {
                b
            } else {
                a
            };
            centres[lighter] = micro[j].clone();
            replaced[lighter] = true;
            touched[a] = true;
            touched[b] = true;
        }
        let mut a = assign(&all, &centres, margin);
        for (i, own) in a.iter_mut().enumerate().take(k) {
            if !replaced[i] {
                *own = i;
            }
        }
        // The directions each centre's similarities were last computed
        // with (before the replacements, as the GPU keeps them).
        let mut seen = unit_rows(&old);
        for iteration in 0..s.global_iterations {
            if iteration > 0 {
                reassign(&unit, &centres, &mut seen, &mut a, margin);
            }
            dict.weights = update(&all, &all_mass, &a, &mut centres, s.normalize);
        }
        dict.atoms = centres;
    }
    dict.atoms
        .iter()
        .enumerate()
        .map(|(i, a)| {
            if i >= old.len() {
                return true;
            }
            let distance = a
                .iter()
                .zip(&old[i])
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f64>()
                .sqrt();
            // An atom that kept its place moved by exactly nothing on
            // either side; only a real move is a close call.
            if distance > 0.0 {
                margin.note(distance, s.moved_tolerance);
            }
            distance > s.moved_tolerance
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings() -> KMeansSettings {
        KMeansSettings {
            micro_clusters: 1,
            local_iterations: 2,
            global_iterations: 2,
            decay: 1.0,
            novelty_threshold: 0.5,
            normalize: true,
            moved_tolerance: 1e-4,
        }
    }

    /// A full dictionary of two atoms and a keyframe whose one region
    /// lies `offset` (in angle) off the bisector of the atoms: the
    /// reported margin is the gap between its two cosines.
    fn margin_for(offset: f64) -> f64 {
        let mut dict = Dictionary {
            atoms: vec![vec![1.0, 0.0], vec![0.0, 1.0]],
            weights: vec![1.0, 2.0],
            capacity: 2,
        };
        let angle = std::f64::consts::FRAC_PI_4 + offset;
        let points = vec![vec![angle.cos(), angle.sin()]];
        update_dictionary_with_margin(&settings(), &mut dict, &points, &[1.0]).1
    }

    #[test]
    fn margin_is_the_closest_call() {
        for offset in [1e-9, 1e-6, 1e-3] {
            let want = (std::f64::consts::FRAC_PI_4 + offset).sin()
                - (std::f64::consts::FRAC_PI_4 + offset).cos();
            let got = margin_for(offset);
            assert!(got <= want * (1.0 + 1e-9), "{offset}: {got} vs {want}");
            assert!(got > 0.0, "{offset}");
        }
        // Far from the bisector, the closest call is elsewhere and wide.
        assert!(margin_for(0.5) > 0.05);
    }
}

//! Streaming k-means on the GPU against the CPU reference.

use rand::Rng;

use super::*;
use latentam_gpu::testing::{rng, with_context};
use latentam_reference::kmeans::{self as reference, Dictionary, KMeansSettings};

/// The GPU's atoms, weights and moved flags against the reference
/// dictionary's, atom by atom.
fn assert_matches_reference(
    got: &[f32],
    got_w: &[f32],
    got_moved: &[u32],
    dict: &Dictionary,
    want_moved: &[bool],
    dim: usize,
    what: &str,
) {
    for a in 0..dict.atoms.len() {
        for j in 0..dim {
            let (g, w) = (got[a * dim + j] as f64, dict.atoms[a][j]);
            assert!((g - w).abs() < 1e-4, "{what}: atom {a}[{j}]: {g} vs {w}");
        }
        let (g, w) = (got_w[a] as f64, dict.weights[a]);
        assert!(
            (g - w).abs() <= 1e-4 * w.max(1.0),
            "{what}: weight {a}: {g} vs {w}"
        );
        assert_eq!(got_moved[a] != 0, want_moved[a], "{what}: moved {a}");
    }
}

fn unit(v: Vec<f64>) -> Vec<f64> {
    let n = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    v.into_iter().map(|x| x / n).collect()
}

/// One keyframe's regions, rounded to f32 as the GPU sees them.
struct Frame {
    points: Vec<f32>,
    mass: Vec<f32>,
}

impl Frame {
    /// `per` noisy unit points around each of the given cluster
    /// directions, with distinct masses.
    fn new(r: &mut impl Rng, dirs: &[Vec<f64>], clusters: &[usize], per: usize) -> Self {
        let mut points = Vec::new();
        let mut mass = Vec::new();
        for &c in clusters {
            for _ in 0..per {
                let noise = 0.3 / (dirs[c].len() as f64).sqrt();
                let p = unit(
                    dirs[c]
                        .iter()
                        .map(|x| x + noise * r.random_range(-1.0..1.0))
                        .collect(),
                );
                points.extend(p.iter().map(|&v| v as f32));
                mass.push(r.random_range(0.5f32..2.0));
            }
        }
        Self { points, mass }
    }

    fn rows(&self, dim: usize) -> Vec<Vec<f64>> {
        self.points
            .chunks(dim)
            .map(|c| c.iter().map(|&v| v as f64).collect())
            .collect()
    }

    fn mass(&self) -> Vec<f64> {
        self.mass.iter().map(|&v| v as f64).collect()
    }

    /// Runs one GPU update with this keyframe.
    fn update(&self, ctx: &Context, kmeans: &StreamingKMeans, out: &[&Buffer; 3]) -> KMeansStep {
        let fb = ctx.upload_new("test/features", &self.points).unwrap();
        let mb = ctx.upload_new("test/mass", &self.mass).unwrap();
        let mut rec = ctx.recorder().unwrap();
        rec.fill_u32(out[2], 0x7fc0_0000);
        let n = self.mass.len() as u32;
        let step = kmeans
            .record_update(&mut rec, &fb, Some(&mb), n, out[0], out[1], out[2])
            .unwrap();
        rec.submit().unwrap().wait().unwrap();
        step
    }
}

/// One keyframe into a full dictionary (`atoms0`, `weights0`) on the
/// GPU and in the reference; checks that they agree and returns the
/// reference's result.
fn recluster_full(
    ctx: &Context,
    cfg: &KMeansConfig,
    atoms0: &[Vec<f64>],
    weights0: &[f64],
    frame: &Frame,
    what: &str,
) -> Dictionary {
    let (k, dim) = (atoms0.len(), cfg.dim as usize);
    let kmeans = StreamingKMeans::new(ctx, *cfg).unwrap();
    let flat: Vec<f32> = atoms0.iter().flatten().map(|&v| v as f32).collect();
    let atoms = ctx.upload_new("test/atoms", &flat).unwrap();
    let anchor = Buffer::device(ctx, "test/anchor", (k * dim * 4) as u64).unwrap();
    let moved = Buffer::device(ctx, "test/moved", (k * 4) as u64).unwrap();
    let w32: Vec<f32> = weights0.iter().map(|&w| w as f32).collect();
    kmeans.restore(ctx, k as u32, &w32).unwrap();
    let step = frame.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
    assert!(step.reclustered, "{what}: the dictionary is full");
    let mut dict = Dictionary {
        atoms: atoms0.to_vec(),
        weights: weights0.to_vec(),
        capacity: k,
    };
    let want_moved =
        reference::update_dictionary(&settings(cfg), &mut dict, &frame.rows(dim), &frame.mass());
    assert_eq!(dict.atoms.len(), k, "{what}: the dictionary stays full");
    let got = ctx.download::<f32>(&atoms).unwrap();
    let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
    let got_moved = ctx.download::<u32>(&moved).unwrap();
    assert_matches_reference(&got, &got_w, &got_moved, &dict, &want_moved, dim, what);
    dict
}

fn settings(cfg: &KMeansConfig) -> KMeansSettings {
    KMeansSettings {
        micro_clusters: cfg.micro_clusters as usize,
        local_iterations: cfg.local_iterations as usize,
        global_iterations: cfg.global_iterations as usize,
        decay: cfg.decay as f64,
        novelty_threshold: cfg.novelty_threshold as f64,
        normalize: cfg.normalize,
        moved_tolerance: cfg.moved_tolerance as f64,
    }
}

/// A stream with known clusters: the dictionary fills up (append), then
/// runs full (re-clustering), and two clusters first appear after it is
/// full. GPU and reference are compared after every keyframe; at the
/// end every cluster, the late ones included, has an atom, and no mass
/// was lost.
#[test]
fn streaming_kmeans_matches_reference_and_finds_late_clusters() {
    let mut r = rng("streaming_kmeans_matches_reference_and_finds_late_clusters");
    with_context(|ctx| {
        // One Lloyd iteration leaves the first (patched) assignment
        // visible in the result; three are the default.
        for global_iterations in [3, 1] {
            check_stream(ctx, &mut r, global_iterations);
        }
    });
}

/// The narrowest gap between two numbers the reference compares that
/// the GPU's f32 arithmetic is trusted to decide the same way (cosines
/// of 64-d unit vectors carry errors near 1e-7; atoms drift further
/// over a stream).
const CLEAR_IN_F32: f64 = 1e-5;

/// The three clusters keyframe `frame` sees: from the first eight
/// before frame 10, then one of the two late clusters and two others.
fn draw_clusters(r: &mut impl Rng, frame: usize) -> Vec<usize> {
    let pool = if frame < 10 { 8 } else { 10 };
    let mut clusters = Vec::new();
    if frame >= 10 {
        clusters.push(8 + frame % 2); // the late clusters
    }
    while clusters.len() < 3 {
        let c = r.random_range(0..pool);
        if !clusters.contains(&c) {
            clusters.push(c);
        }
    }
    clusters
}

fn check_stream(ctx: &Context, r: &mut impl Rng, global_iterations: u32) {
    let dim = 64usize;
    let dirs: Vec<Vec<f64>> = (0..10)
        .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
        .collect();
    let cfg = KMeansConfig {
        atoms: 12,
        dim: dim as u32,
        max_points: 64,
        micro_clusters: 3,
        global_iterations,
        ..Default::default()
    };
    let s = settings(&cfg);
    let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
    let k = cfg.atoms as usize;
    let atoms = Buffer::device(ctx, "test/atoms", (k * dim * 4) as u64).unwrap();
    let anchor = Buffer::device(ctx, "test/anchor", (k * dim * 4) as u64).unwrap();
    let moved = Buffer::device(ctx, "test/moved", (k * 4) as u64).unwrap();
    let mut dict = Dictionary {
        atoms: Vec::new(),
        weights: Vec::new(),
        capacity: k,
    };
    let mut total_mass = 0.0;
    let mut reclustered = 0;
    let mut seen = vec![0u32; dirs.len()];
    for frame in 0..16 {
        // A keyframe whose choices are all clear in f32: the reference
        // runs on a copy first, and a keyframe with a closer call than
        // f32 can resolve, or one that leaves two atom pairs too alike
        // for the next keyframe's choice, is drawn again.
        let mut attempts = 0;
        let (keyframe, clusters, want_moved) = loop {
            let clusters = draw_clusters(r, frame);
            let keyframe = Frame::new(r, &dirs, &clusters, 7);
            let mut next = dict.clone();
            let (moved, margin) = reference::update_dictionary_with_margin(
                &s,
                &mut next,
                &keyframe.rows(dim),
                &keyframe.mass(),
            );
            attempts += 1;
            // The next keyframe's choice of pair is made on these atoms.
            if margin.min(next.pair_margin()) > CLEAR_IN_F32 {
                dict = next;
                break (keyframe, clusters, moved);
            }
            assert!(
                attempts < 50,
                "frame {frame}: no keyframe with clear choices in 50 draws"
            );
        };
        for &c in &clusters {
            seen[c] += 1;
        }
        total_mass += keyframe.mass().iter().sum::<f64>();
        let step = keyframe.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
        reclustered += step.reclustered as u32;
        assert_eq!(step.atoms_after as usize, dict.atoms.len(), "frame {frame}");
        let count = dict.atoms.len();
        let got = ctx.download::<f32>(&atoms).unwrap();
        let got_anchor = ctx.download::<f32>(&anchor).unwrap();
        let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
        let got_moved = ctx.download::<u32>(&moved).unwrap();
        let what = format!("frame {frame}");
        assert_matches_reference(&got, &got_w, &got_moved, &dict, &want_moved, dim, &what);
        assert_eq!(
            got_anchor[..count * dim],
            got[..count * dim],
            "{what}: anchors"
        );
        // Mass is conserved: it moves between atoms, never vanishes.
        let w_sum: f64 = got_w[..count].iter().map(|&v| v as f64).sum();
        assert!(
            (w_sum - total_mass).abs() < 1e-3 * total_mass,
            "{w_sum} vs {total_mass}"
        );
    }
    assert!(
        reclustered >= 10,
        "the dictionary should have been full for most frames"
    );
    let got = ctx.download::<f32>(&atoms).unwrap();
    // A cluster drawn in only one or two early frames carries little
    // mass and may rightly be merged into another atom once the
    // dictionary is full; every cluster seen three times or more (the
    // late ones are, in frames 10–15) must keep an atom.
    assert!(seen[8] >= 3 && seen[9] >= 3, "{seen:?}");
    for (c, dir) in dirs.iter().enumerate().filter(|&(c, _)| seen[c] >= 3) {
        let best = (0..k)
            .map(|a| {
                (0..dim)
                    .map(|j| got[a * dim + j] as f64 * dir[j])
                    .sum::<f64>()
            })
            .fold(f64::NEG_INFINITY, f64::max);
        assert!(best > 0.9, "cluster {c} has no atom (best cosine {best})");
    }
}

/// Later Lloyd iterations only recompute the columns of the centres
/// that moved (`kmeans_resim.comp`) and reassign against them
/// (`kmeans_reassign`). A dictionary on an arc where each iteration
/// moves a point: a heavy micro-centre pulls atom A away from its own
/// point, which goes to A's close neighbour C in iteration 2; A, freed
/// of it, moves on, and a light micro-centre that sat nearer atom B
/// goes to A in iteration 3. The GPU must match the dense reference
/// after 1, 2, 3 and 6 iterations, and the reference must change at 2
/// and at 3 (so the sparse path had work to do).
#[test]
fn sparse_lloyd_iterations_match_the_dense_reference() {
    let mut r = rng("sparse_lloyd_iterations_match_the_dense_reference");
    with_context(|ctx| {
        let (dim, k, m) = (32usize, 12usize, 2usize);
        // Two random orthonormal directions span the arc.
        let e0 = unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect());
        let raw: Vec<f64> = (0..dim).map(|_| r.random_range(-1.0..1.0)).collect();
        let along: f64 = raw.iter().zip(&e0).map(|(a, b)| a * b).sum();
        let e1 = unit(raw.iter().zip(&e0).map(|(a, b)| a - along * b).collect());
        let on_arc = |angle: f64, r: &mut dyn rand::RngCore| -> Vec<f64> {
            unit(
                (0..dim)
                    .map(|j| {
                        angle.cos() * e0[j] + angle.sin() * e1[j] + 1e-4 * r.random_range(-1.0..1.0)
                    })
                    .collect(),
            )
        };
        let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>();
        // C, A, B, then atoms far along the arc.
        let mut angles = vec![-0.01, 0.0, 0.204];
        angles.extend((0..k - 3).map(|i| 0.5 + 0.12 * i as f64));
        let atoms0: Vec<Vec<f64>> = angles.iter().map(|&a| as_f32(&on_arc(a, &mut r))).collect();
        let weights0: Vec<f64> = (0..k).map(|_| r.random_range(0.8f32..1.2) as f64).collect();
        // The keyframe: six heavy regions at 0.1, two light ones at 0.15.
        let mut points = Vec::new();
        let mut mass = Vec::new();
        for (angle, count, each) in [(0.1, 6, 3.0f32), (0.15, 2, 0.002)] {
            for _ in 0..count {
                points.extend(on_arc(angle, &mut r).iter().map(|&v| v as f32));
                mass.push(each);
            }
        }
        let frame = Frame { points, mass };
        let mut results = Vec::new();
        for iterations in [1u32, 2, 3, 6] {
            let cfg = KMeansConfig {
                atoms: k as u32,
                dim: dim as u32,
                max_points: 64,
                micro_clusters: m as u32,
                global_iterations: iterations,
                ..Default::default()
            };
            let what = format!("{iterations} iterations");
            let dict = recluster_full(ctx, &cfg, &atoms0, &weights0, &frame, &what);
            results.push(dict.weights);
        }
        // Each further iteration moved mass between centres: the
        // sparse iterations had work to do.
        let change =
            |a: &[f64], b: &[f64]| -> f64 { a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum() };
        assert!(change(&results[0], &results[1]) > 0.5, "{results:?}");
        assert!(change(&results[1], &results[2]) > 1e-3, "{results:?}");
    });
}

/// Bitwise-identical atoms (a camera that stood still appends the same
/// micro-centre twice) each keep their own cluster when the keyframe
/// lands elsewhere: the later one is not merged into the earlier by a
/// tie. Known concepts and new ones, both checked against the
/// reference.
#[test]
fn duplicate_atoms_keep_their_own_clusters() {
    let mut r = rng("duplicate_atoms_keep_their_own_clusters");
    with_context(|ctx| {
        let (k, dim) = (8usize, 16usize);
        let dirs: Vec<Vec<f64>> = (0..k + 1)
            .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
            .collect();
        let as_f32 = |v: &[f64]| v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>();
        let mut atoms0: Vec<Vec<f64>> = dirs[..k].iter().map(|d| as_f32(d)).collect();
        atoms0[5] = atoms0[1].clone();
        let weights0: Vec<f64> = (0..k).map(|i| 1.0 + 0.25 * i as f64).collect();
        // Regions near atoms 3 and 6, then regions of a new concept.
        for (clusters, what) in [(vec![3usize, 6], "known"), (vec![k], "new")] {
            let frame = Frame::new(&mut r, &dirs, &clusters, 4);
            let cfg = KMeansConfig {
                atoms: k as u32,
                dim: dim as u32,
                max_points: 16,
                micro_clusters: clusters.len() as u32,
                decay: 0.9,
                ..Default::default()
            };
            let dict = recluster_full(ctx, &cfg, &atoms0, &weights0, &frame, what);
            if what == "known" {
                // Each copy kept its own (decayed) mass.
                for a in [1, 5] {
                    let want = cfg.decay as f64 * weights0[a];
                    assert!((dict.weights[a] - want).abs() < 1e-6, "{what}: weight {a}");
                }
            }
        }
    });
}

/// A centre with more members than the update kernel's shared list
/// (2048) takes the rescanning path; both paths must agree with the
/// reference.
#[test]
fn large_clusters_match_reference() {
    let mut r = rng("large_clusters_match_reference");
    with_context(|ctx| {
        let dim = 32usize;
        let dirs: Vec<Vec<f64>> = (0..2)
            .map(|_| unit((0..dim).map(|_| r.random_range(-1.0..1.0)).collect()))
            .collect();
        let mut frame = Frame::new(&mut r, &dirs, &[0], 3000);
        let other = Frame::new(&mut r, &dirs, &[1], 500);
        frame.points.extend(other.points);
        frame.mass.extend(other.mass);
        let cfg = KMeansConfig {
            atoms: 4,
            dim: dim as u32,
            max_points: frame.mass.len() as u32,
            micro_clusters: 2,
            ..Default::default()
        };
        let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
        let atoms = Buffer::device(ctx, "test/atoms", (4 * dim * 4) as u64).unwrap();
        let anchor = Buffer::device(ctx, "test/anchor", (4 * dim * 4) as u64).unwrap();
        let moved = Buffer::device(ctx, "test/moved", 16).unwrap();
        frame.update(ctx, &kmeans, &[&atoms, &anchor, &moved]);
        let (points64, mass64) = (frame.rows(dim), frame.mass());
        let (want, want_w) = reference::micro_clusters(&settings(&cfg), &points64, &mass64);
        let got = ctx.download::<f32>(&atoms).unwrap();
        let got_w = ctx.download::<f32>(kmeans.weights()).unwrap();
        for c in 0..2 {
            for j in 0..dim {
                assert!(
                    (got[c * dim + j] as f64 - want[c][j]).abs() < 1e-4,
                    "centre {c}[{j}]"
                );
            }
            assert!(
                (got_w[c] as f64 - want_w[c]).abs() < 1e-3 * want_w[c],
                "weight {c}"
            );
        }
    });
}

#[test]
fn small_and_empty_keyframes() {
    with_context(|ctx| {
        let cfg = KMeansConfig {
            atoms: 8,
            dim: 16,
            max_points: 4,
            ..Default::default()
        };
        let kmeans = StreamingKMeans::new(ctx, cfg).unwrap();
        let atoms = Buffer::device(ctx, "test/atoms", 8 * 16 * 4).unwrap();
        let anchor = Buffer::device(ctx, "test/anchor", 8 * 16 * 4).unwrap();
        let moved = Buffer::device(ctx, "test/moved", 8 * 4).unwrap();
        let f: Vec<f32> = (0..5 * 16).map(|i| ((i * 7) % 11) as f32 - 5.0).collect();
        let fb = ctx.upload_new("test/f", &f).unwrap();
        let mut rec = ctx.recorder().unwrap();
        let empty = kmeans
            .record_update(&mut rec, &fb, None, 0, &atoms, &anchor, &moved)
            .unwrap();
        assert_eq!(empty.atoms_after, 0);
        // Fewer regions than micro-clusters: one centre per region.
        let two = kmeans
            .record_update(&mut rec, &fb, None, 2, &atoms, &anchor, &moved)
            .unwrap();
        assert_eq!((two.micro_clusters, two.atoms_after), (2, 2));
        assert!(kmeans
            .record_update(&mut rec, &fb, None, 5, &atoms, &anchor, &moved)
            .is_err());
        rec.submit().unwrap().wait().unwrap();
        assert_eq!(kmeans.atom_count(), 2);
        for bad in [
            KMeansConfig { atoms: 0, ..cfg },
            KMeansConfig {
                micro_clusters: 9,
                ..cfg
            },
            KMeansConfig {
                global_iterations: 0,
                ..cfg
            },
            KMeansConfig { decay: 1.5, ..cfg },
            KMeansConfig {
                atoms: MAX_KMEANS_ATOMS + 1,
                ..cfg
            },
        ] {
            assert!(StreamingKMeans::new(ctx, bad).is_err(), "{bad:?}");
        }
    });
}

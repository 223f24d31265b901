//! What a snapshot caches so that an open-vocabulary query does not decode
//! every Gaussian again (paper Eq. 5 per Gaussian is d_s × K + K × d_f
//! multiply-adds; with K = 2000 and d_f = 768 that is 1.6 M per Gaussian).
//!
//! The attention of a Gaussian over the atoms does not depend on the
//! query. With `E = qW`, `Ê = E / (‖E‖ + ε)`, `D̂_k = D_k / (‖D_k‖ + ε)`:
//!
//! ```text
//! s_k = Ê · D̂_k / τ = q · M_k / ((‖qW‖ + ε) τ),   M = W D̂ᵀ  (d_s × K, once per snapshot)
//! α = softmax(s),   F̂ = Σ_k α_k D_k
//! cos(F̂, t) = Σ_k α_k (D_k · t̂) / ‖F̂‖
//! ```
//!
//! so the index keeps, per Gaussian, the atoms that carry its attention
//! (largest first, until all but `dropped_mass` of it is covered, at most
//! `max_atoms`) with their weights, and `1 / ‖F̂‖` over those atoms. A
//! query then costs K × d_f for `D t̂` plus a few multiply-adds per
//! Gaussian. Leaving out attention mass δ changes a cosine by at most
//! about 2δ‖D‖_max/‖F̂‖; with τ = 0.05 a Gaussian's attention sits on a
//! handful of atoms, so the default δ = 10⁻³ keeps 1–20 of them. CPU
//! reference: `latentam_reference::decoder::forward` and a cosine (the
//! tests compare the two).

use std::sync::atomic::{AtomicBool, Ordering};

use latentam_base::{Error, Result};

use crate::splat::QUERY_DIM;

/// How much of each Gaussian's attention the index keeps.
///
/// ```
/// let settings = latentam_core::live::IndexSettings { dropped_mass: 1e-4, ..Default::default() };
/// assert_eq!(settings.max_atoms, 64);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IndexSettings {
    /// Attention mass a Gaussian may leave out (its smallest weights).
    pub dropped_mass: f32,
    /// Atoms kept per Gaussian at most, whatever mass they leave out.
    pub max_atoms: usize,
}

impl Default for IndexSettings {
    fn default() -> Self {
        IndexSettings {
            dropped_mass: 1e-3,
            max_atoms: 64,
        }
    }
}

/// The decoder a snapshot was taken with, as the index needs it.
pub(crate) struct DecoderView<'a> {
    /// `QUERY_DIM × dim`, row-major.
    pub w: &'a [f32],
    /// `atoms × dim`, row-major.
    pub atoms: &'a [f32],
    pub dim: usize,
    pub temperature: f32,
    pub eps: f32,
}

impl<'a> DecoderView<'a> {
    /// The view of a decoder file's W, atoms and temperature.
    pub fn of(decoder: &'a crate::mapper::DecoderFile) -> Self {
        DecoderView {
            w: &decoder.w,
            atoms: &decoder.atoms,
            dim: decoder.dim as usize,
            temperature: decoder.temperature,
            eps: decoder.eps,
        }
    }
}

/// Each Gaussian's attention over the atoms, kept sparse, and the norm of
/// its decoded embedding: what relevance queries read.
///
/// ```no_run
/// # fn f(snapshot: &latentam_core::live::MapSnapshot) -> latentam_core::Result<()> {
/// let index = snapshot.relevance_index()?;
/// println!("{} bytes, {:.1} atoms per Gaussian", index.bytes(), index.mean_atoms());
/// # Ok(())
/// # }
/// ```
pub struct RelevanceIndex {
    dim: usize,
    atoms: Vec<f32>,
    /// Gaussian i's entries are `entries[offsets[i]..offsets[i + 1]]`.
    offsets: Vec<u32>,
    entries: Vec<(u32, f32)>,
    inv_norms: Vec<f32>,
    max_dropped: f32,
    build_ms: f64,
}

impl RelevanceIndex {
    /// Indexes `queries` against the decoder, on all CPU cores; gives up
    /// (an error) soon after `cancel` is set.
    pub(crate) fn build(
        queries: &[[f32; QUERY_DIM]],
        decoder: &DecoderView<'_>,
        settings: IndexSettings,
        cancel: Option<&AtomicBool>,
    ) -> Result<Self> {
        Self::build_streamed(decoder, settings, cancel, |add| add(queries))
    }

    /// [`RelevanceIndex::build`] of the queries `feed` hands over a batch
    /// at a time (a map read block by block from memory and disk): what is
    /// held is the batch and the index, never every query at once.
    pub(crate) fn build_streamed(
        decoder: &DecoderView<'_>,
        settings: IndexSettings,
        cancel: Option<&AtomicBool>,
        feed: impl FnOnce(&mut dyn FnMut(&[[f32; QUERY_DIM]]) -> Result<()>) -> Result<()>,
    ) -> Result<Self> {
        let start = std::time::Instant::now();
        let d = decoder.dim;
        let k = decoder.atoms.len() / d.max(1);
        if d == 0 || k == 0 || decoder.w.len() != QUERY_DIM * d || decoder.atoms.len() != k * d {
            return Err(Error::NoEmbeddings);
        }
        let shared = Shared::new(decoder, k);
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut index = RelevanceIndex {
            dim: d,
            atoms: decoder.atoms.to_vec(),
            offsets: vec![0],
            entries: Vec::new(),
            inv_norms: Vec::new(),
            max_dropped: 0.0,
            build_ms: 0.0,
        };
        feed(&mut |queries| {
            let chunk = queries.len().div_ceil(threads).max(256);
            let parts: Vec<Part> = std::thread::scope(|scope| {
                let handles: Vec<_> = queries
                    .chunks(chunk)
                    .map(|qs| {
                        let shared = &shared;
                        scope.spawn(move || shared.index(qs, decoder, settings, cancel))
                    })
                    .collect();
                handles
                    .into_iter()
                    .map(|h| h.join().expect("index worker"))
                    .collect::<Option<Vec<Part>>>()
            })
            .ok_or_else(|| {
                // Only a closing live handle cancels a build.
                Error::Stopped(std::sync::Arc::new(Error::bad_input(
                    "the relevance index",
                    "its build was cancelled: the live mapper is closing",
                )))
            })?;
            for part in parts {
                let base = index.entries.len() as u32;
                index
                    .offsets
                    .extend(part.offsets[1..].iter().map(|o| o + base));
                index.entries.extend(part.entries);
                index.inv_norms.extend(part.inv_norms);
                index.max_dropped = index.max_dropped.max(part.max_dropped);
            }
            Ok(())
        })?;
        index.build_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(index)
    }

    /// Gaussians indexed.
    pub fn len(&self) -> usize {
        self.inv_norms.len()
    }

    /// Whether no Gaussian is indexed.
    pub fn is_empty(&self) -> bool {
        self.inv_norms.is_empty()
    }

    /// Heap bytes the index holds (the atoms' copy included).
    pub fn bytes(&self) -> u64 {
        (self.atoms.len() * 4
            + self.offsets.len() * 4
            + self.entries.len() * 8
            + self.inv_norms.len() * 4) as u64
    }

    /// Atoms kept per Gaussian, on average.
    pub fn mean_atoms(&self) -> f64 {
        self.entries.len() as f64 / self.len().max(1) as f64
    }

    /// The largest attention mass any Gaussian left out.
    pub fn max_dropped_mass(&self) -> f32 {
        self.max_dropped
    }

    /// How long building it took, ms.
    pub fn build_ms(&self) -> f64 {
        self.build_ms
    }

    /// Cosine of every Gaussian's decoded embedding with each of the
    /// embeddings in `texts` (`m × d_f`, back to back, any norm; a zero
    /// text scores 0): Gaussians × m, row-major.
    pub fn cosines(&self, texts: &[f32]) -> Result<Vec<f32>> {
        let d = self.dim;
        if texts.is_empty() || !texts.len().is_multiple_of(d) {
            return Err(Error::EmbeddingDimension {
                map: d as u32,
                given: texts.len() as u32,
                context: Some("a query, or several back to back".into()),
            });
        }
        if texts.iter().any(|x| !x.is_finite()) {
            return Err(Error::bad_input(
                "a query embedding",
                "it has non-finite values",
            ));
        }
        let m = texts.len() / d;
        // u[k][j] = D_k · t̂_j.
        let mut u = vec![0f32; (self.atoms.len() / d) * m];
        for (j, t) in texts.chunks_exact(d).enumerate() {
            let n = t.iter().map(|&x| x as f64 * x as f64).sum::<f64>().sqrt();
            let s = if n > 0.0 { (1.0 / n) as f32 } else { 0.0 };
            for (a, atom) in self.atoms.chunks_exact(d).enumerate() {
                u[a * m + j] = dot(atom, t) * s;
            }
        }
        let mut out = vec![0f32; self.len() * m];
        for (i, row) in out.chunks_exact_mut(m).enumerate() {
            let span = self.offsets[i] as usize..self.offsets[i + 1] as usize;
            for &(a, w) in &self.entries[span] {
                let ua = &u[a as usize * m..(a as usize + 1) * m];
                row.iter_mut().zip(ua).for_each(|(r, x)| *r += w * x);
            }
            let inv = self.inv_norms[i];
            row.iter_mut().for_each(|r| *r *= inv);
        }
        Ok(out)
    }
}

/// One thread's share of the index.
struct Part {
    offsets: Vec<u32>,
    entries: Vec<(u32, f32)>,
    inv_norms: Vec<f32>,
    max_dropped: f32,
}

/// What every Gaussian's attention is computed from.
struct Shared {
    /// `M = W D̂ᵀ`, `QUERY_DIM × K`: row j holds every atom's value.
    m: Vec<f32>,
    /// `W Wᵀ`, so that `‖qW‖² = q (W Wᵀ) qᵀ`.
    gram: [[f32; QUERY_DIM]; QUERY_DIM],
    k: usize,
}

impl Shared {
    fn new(decoder: &DecoderView<'_>, k: usize) -> Self {
        let d = decoder.dim;
        let w_row = |j: usize| &decoder.w[j * d..(j + 1) * d];
        let mut m = vec![0f32; QUERY_DIM * k];
        for (a, atom) in decoder.atoms.chunks_exact(d).enumerate() {
            let norm = dot(atom, atom).sqrt() + decoder.eps;
            for j in 0..QUERY_DIM {
                m[j * k + a] = dot(w_row(j), atom) / norm;
            }
        }
        let mut gram = [[0f32; QUERY_DIM]; QUERY_DIM];
        for (i, row) in gram.iter_mut().enumerate() {
            for (j, g) in row.iter_mut().enumerate() {
                *g = dot(w_row(i), w_row(j));
            }
        }
        Shared { m, gram, k }
    }

    fn index(
        &self,
        queries: &[[f32; QUERY_DIM]],
        dec: &DecoderView<'_>,
        s: IndexSettings,
        cancel: Option<&AtomicBool>,
    ) -> Option<Part> {
        let (k, d) = (self.k, dec.dim);
        let mut part = Part {
            offsets: vec![0],
            entries: Vec::new(),
            inv_norms: Vec::with_capacity(queries.len()),
            max_dropped: 0.0,
        };
        let mut logits = vec![0f32; k];
        let mut kept: Vec<(u32, f32)> = Vec::new();
        let mut decoded = vec![0f32; d];
        // Atoms whose weight is below dropped_mass / K are left out before
        // the softmax: together they hold less than dropped_mass.
        let floor = (s.dropped_mass.max(1e-30) / k as f32).ln();
        for (i, q) in queries.iter().enumerate() {
            if i % 1024 == 0 && cancel.is_some_and(|c| c.load(Ordering::Relaxed)) {
                return None;
            }
            logits.iter_mut().for_each(|l| *l = 0.0);
            for (j, &qj) in q.iter().enumerate() {
                let row = &self.m[j * k..(j + 1) * k];
                logits
                    .iter_mut()
                    .zip(row)
                    .for_each(|(l, &mj)| *l += qj * mj);
            }
            let e_norm = self
                .gram
                .iter()
                .zip(q)
                .map(|(g, &qi)| qi * dot(g, q))
                .sum::<f32>()
                .max(0.0)
                .sqrt();
            let scale = 1.0 / ((e_norm + dec.eps) * dec.temperature);
            let max = logits.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b)) * scale;
            kept.clear();
            for (a, &l) in logits.iter().enumerate() {
                let x = l * scale - max;
                if x >= floor {
                    kept.push((a as u32, x.exp()));
                }
            }
            let sum: f32 = kept.iter().map(|e| e.1).sum();
            // Only the largest max_atoms can be kept: select them in
            // linear time, then sort those few.
            let cap = s.max_atoms.max(1);
            if kept.len() > cap {
                kept.select_nth_unstable_by(cap - 1, |a, b| b.1.total_cmp(&a.1));
                kept.truncate(cap);
            }
            kept.sort_unstable_by(|a, b| b.1.total_cmp(&a.1));
            let mut covered = 0f32;
            let mut n = 0;
            while n < kept.len() && n < s.max_atoms.max(1) && covered < (1.0 - s.dropped_mass) * sum
            {
                covered += kept[n].1;
                n += 1;
            }
            kept.truncate(n);
            kept.iter_mut().for_each(|e| e.1 /= sum);
            part.max_dropped = part.max_dropped.max(1.0 - covered / sum);
            decoded.iter_mut().for_each(|x| *x = 0.0);
            for &(a, w) in &kept {
                let atom = &dec.atoms[a as usize * d..(a as usize + 1) * d];
                decoded.iter_mut().zip(atom).for_each(|(x, &y)| *x += w * y);
            }
            let norm = dot(&decoded, &decoded).sqrt();
            part.inv_norms
                .push(if norm > 0.0 { 1.0 / norm } else { 0.0 });
            part.entries.extend_from_slice(&kept);
            part.offsets.push(part.entries.len() as u32);
        }
        Some(part)
    }
}

/// A dot product the compiler vectorises (eight partial sums).
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for i in 0..8 {
            acc[i] += x[i] * y[i];
        }
    }
    acc.iter().sum::<f32>() + tail
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam_gpu::testing::rng;
    use latentam_reference::decoder::{forward, DecoderShape};
    use rand::Rng;

    /// The exact cosines in f64: the reference decoder, then a cosine.
    fn exact(queries: &[[f32; QUERY_DIM]], dec: &DecoderView<'_>, texts: &[f32]) -> Vec<f64> {
        let d = dec.dim;
        let k = dec.atoms.len() / d;
        let shape = DecoderShape {
            n: queries.len(),
            query_dim: QUERY_DIM,
            dim: d,
            atoms: k,
            tau: dec.temperature as f64,
            eps: dec.eps as f64,
        };
        let flat: Vec<f32> = queries.iter().flatten().copied().collect();
        let f = forward(&shape, &flat, dec.w, dec.atoms);
        let mut out = Vec::new();
        for i in 0..queries.len() {
            let row = &f.output[i * d..(i + 1) * d];
            let rn = row.iter().map(|x| x * x).sum::<f64>().sqrt();
            for t in texts.chunks_exact(d) {
                let tn = t.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
                let dot: f64 = row.iter().zip(t).map(|(a, &b)| a * b as f64).sum();
                out.push(if tn > 0.0 { dot / (rn * tn) } else { 0.0 });
            }
        }
        out
    }

    fn random(r: &mut impl Rng, n: usize) -> Vec<f32> {
        (0..n).map(|_| r.random_range(-1.0..1.0)).collect()
    }

    #[test]
    fn cosines_match_the_reference_decoder() {
        let mut r = rng("relevance-index");
        for (dim, atoms, temperature) in [(24, 7, 0.2f32), (48, 300, 0.05), (16, 1, 0.05)] {
            let w = random(&mut r, QUERY_DIM * dim);
            let d = random(&mut r, atoms * dim);
            let queries: Vec<[f32; QUERY_DIM]> = (0..700)
                .map(|_| std::array::from_fn(|_| r.random_range(-1.0..1.0)))
                .collect();
            let mut texts = random(&mut r, 2 * dim);
            texts.extend(std::iter::repeat_n(0.0, dim));
            let dec = DecoderView {
                w: &w,
                atoms: &d,
                dim,
                temperature,
                eps: 1e-6,
            };
            let want = exact(&queries, &dec, &texts);
            // Nearly all the mass: the index is the decoder.
            let tight = IndexSettings {
                dropped_mass: 1e-7,
                max_atoms: atoms,
            };
            let index = RelevanceIndex::build(&queries, &dec, tight, None).unwrap();
            assert_eq!(index.len(), 700);
            let got = index.cosines(&texts).unwrap();
            for (g, w) in got.iter().zip(&want) {
                assert!((*g as f64 - w).abs() < 2e-4, "{g} vs {w} ({dim}, {atoms})");
            }
            // The default mass, with no cap on atoms: at most that mass is
            // left out, and the cosines stay close.
            let loose = IndexSettings {
                max_atoms: atoms,
                ..IndexSettings::default()
            };
            let index = RelevanceIndex::build(&queries, &dec, loose, None).unwrap();
            assert!(index.max_dropped_mass() <= 1e-3 + 1e-5);
            let got = index.cosines(&texts).unwrap();
            let worst = got
                .iter()
                .zip(&want)
                .map(|(g, w)| (*g as f64 - w).abs())
                .fold(0.0, f64::max);
            assert!(worst < 1e-2, "{worst} ({dim}, {atoms})");
        }
    }

    #[test]
    fn a_cancelled_build_gives_up() {
        let (w, d) = (vec![0.5f32; QUERY_DIM * 4], vec![1.0f32; 8]);
        let dec = DecoderView {
            w: &w,
            atoms: &d,
            dim: 4,
            temperature: 0.1,
            eps: 1e-6,
        };
        let cancel = AtomicBool::new(true);
        let queries = vec![[0.1; QUERY_DIM]; 5000];
        assert!(RelevanceIndex::build(&queries, &dec, Default::default(), Some(&cancel)).is_err());
    }

    #[test]
    fn bad_queries_are_refused() {
        let (w, d) = (vec![0.5f32; QUERY_DIM * 4], vec![1.0f32; 8]);
        let dec = DecoderView {
            w: &w,
            atoms: &d,
            dim: 4,
            temperature: 0.1,
            eps: 1e-6,
        };
        let index =
            RelevanceIndex::build(&[[0.1; QUERY_DIM]], &dec, Default::default(), None).unwrap();
        assert!(matches!(
            index.cosines(&[1.0; 3]),
            Err(Error::EmbeddingDimension {
                map: 4,
                given: 3,
                ..
            })
        ));
        assert!(index.cosines(&[f32::NAN, 0.0, 0.0, 0.0]).is_err());
        let none = DecoderView { atoms: &[], ..dec };
        assert!(matches!(
            RelevanceIndex::build(&[], &none, Default::default(), None),
            Err(Error::NoEmbeddings)
        ));
    }
}

//! Keyframes' colour and depth targets kept on the GPU in their compact
//! form (RGB bytes and millimetre depth: 5 bytes a pixel), so that a
//! replayed keyframe's targets cross the host link once, not at every
//! Stage I step. Every target, kept or not, reaches the image loss through
//! the same kernel (`glsl/target_unpack.comp`), so what trains does not
//! depend on what happened to be kept.
//!
//! Slots are fixed (one view of the largest size each); a keyframe not
//! kept takes a free slot, else the one used longest ago. Slots are
//! reused within one recording safely: the recorder orders an upload into
//! a slot after the expansion that read it before.

use std::cell::RefCell;

use super::super::history::{KeyframeRecord, ReplayKey};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::{bind, push, TARGET_UNPACK};

/// Invocations per workgroup of `glsl/target_unpack.comp`.
const THREADS: u64 = 256;

/// GPU bytes of one slot for views of `pixels` pixels: the RGB bytes and
/// the depth, each padded to whole 32-bit words.
pub(crate) fn slot_bytes(pixels: u64) -> u64 {
    4 * ((3 * pixels).div_ceil(4) + pixels.div_ceil(2))
}

/// Which keyframe each slot holds, and when it was last used.
#[derive(Default)]
struct Slots {
    held: Vec<Option<(ReplayKey, u64)>>,
    clock: u64,
    uploads: u64,
}

impl Slots {
    /// The slot holding `key`, marked used now.
    fn find(&mut self, key: ReplayKey) -> Option<usize> {
        self.clock += 1;
        let now = self.clock;
        let (i, used) = self
            .held
            .iter_mut()
            .enumerate()
            .find_map(|(i, s)| s.as_mut().filter(|(k, _)| *k == key).map(|(_, u)| (i, u)))?;
        *used = now;
        Some(i)
    }

    /// A free slot, else the one used longest ago, now holding `key`
    /// (`None`: held by nothing, the next keyframe may take it first).
    fn take(&mut self, key: Option<ReplayKey>) -> usize {
        self.clock += 1;
        let i = self
            .held
            .iter()
            .position(Option::is_none)
            .unwrap_or_else(|| {
                (0..self.held.len())
                    .min_by_key(|&i| self.held[i].map_or(0, |(_, used)| used))
                    .unwrap_or(0)
            });
        self.held[i] = key.map(|k| (k, self.clock));
        i
    }
}

/// The GPU store of kept keyframe targets (see the module's comment).
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_core::mapper::{KeptTargets, KeyframeRecord, ReplayKey};
/// # fn f(ctx: &Context, record: &KeyframeRecord) -> latentam_core::Result<()> {
/// let kept = KeptTargets::new(ctx, 8, record.camera.pixels())?;
/// let target = Buffer::device(ctx, "target", record.camera.pixels() * 16)?;
/// let key = ReplayKey::fresh();
/// let mut rec = ctx.recorder()?;
/// kept.record_expand(&mut rec, record, Some(key), &target, 0)?; // uploads it once
/// kept.record_expand(&mut rec, record, Some(key), &target, 0)?; // from the GPU copy
/// rec.submit()?.wait()?;
/// assert_eq!(kept.uploads(), 1);
/// # Ok(())
/// # }
/// ```
pub struct KeptTargets {
    packed: Buffer,
    slot_words: u64,
    max_pixels: u64,
    slots: RefCell<Slots>,
}

impl KeptTargets {
    /// Room for `slots` keyframes (at least one: a target is always
    /// expanded from a slot) of at most `max_pixels` pixels.
    pub fn new(ctx: &Context, slots: u32, max_pixels: u64) -> Result<Self> {
        let slots = slots.max(1);
        let slot_words = slot_bytes(max_pixels) / 4;
        Ok(KeptTargets {
            packed: Buffer::device(ctx, "trainer/kept_targets", slots as u64 * slot_words * 4)?,
            slot_words,
            max_pixels,
            slots: RefCell::new(Slots {
                held: vec![None; slots as usize],
                ..Default::default()
            }),
        })
    }

    /// Keyframes it holds at most.
    pub fn capacity(&self) -> usize {
        self.slots.borrow().held.len()
    }

    /// Keyframes uploaded into it so far (the others were expanded from
    /// their GPU copy).
    pub fn uploads(&self) -> u64 {
        self.slots.borrow().uploads
    }

    /// Records `record`'s target (`[r, g, b, z]` per pixel, colour divided
    /// by its exposure gain) into `target` from pixel `at`: from the slot
    /// holding `key` when there is one, else after uploading the compact
    /// form into a slot that then holds `key` (`None`: it is not kept).
    /// Returns whether it uploaded.
    pub fn record_expand<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        record: &KeyframeRecord,
        key: Option<ReplayKey>,
        target: &'a Buffer,
        at: u64,
    ) -> Result<bool> {
        let pixels = record.camera.pixels();
        if pixels > self.max_pixels
            || record.rgb.len() as u64 != 3 * pixels
            || record.depth_mm.len() as u64 != pixels
            || (at + pixels) * 16 > target.bytes()
            || !(record.exposure > 0.0 && record.exposure.is_finite())
        {
            return Err(Error::bad_input(
                "keyframe target",
                format!(
                    "a {pixels}-pixel view with {} colour bytes, {} depths and exposure {} at \
                     pixel {at} of a {}-pixel target; the store holds views of at most {} pixels",
                    record.rgb.len(),
                    record.depth_mm.len(),
                    record.exposure,
                    target.bytes() / 16,
                    self.max_pixels
                ),
            ));
        }
        let mut slots = self.slots.borrow_mut();
        let found = key.and_then(|k| slots.find(k));
        let uploaded = found.is_none();
        let slot = match found {
            Some(slot) => slot,
            None => slots.take(key),
        };
        let rgb_word = slot as u64 * self.slot_words;
        let depth_word = rgb_word + (3 * pixels).div_ceil(4);
        if uploaded {
            slots.uploads += 1;
            rec.upload(&self.packed, rgb_word * 4, &record.rgb)?;
            rec.upload(&self.packed, depth_word * 4, &record.depth_mm)?;
        }
        let words = |w: u64| {
            u32::try_from(w).map_err(|_| Error::bad_input("kept targets", "past 2^32 words"))
        };
        rec.dispatch_linear(
            &TARGET_UNPACK,
            pixels.div_ceil(THREADS) as u32,
            bind::TargetUnpackBuffers {
                packed: &self.packed,
                target,
            },
            &push::TargetUnpack {
                pixels: pixels as u32,
                rgb_word: words(rgb_word)?,
                depth_word: words(depth_word)?,
                target_pixel: words(at)?,
                // As the host computes it (`KeyframeRecord::target_rgbd`).
                scale: 255.0 * record.exposure,
            },
        )?;
        Ok(uploaded)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::splat::Camera;
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::targets::unpack_target;
    use rand::Rng;

    fn record(r: &mut impl Rng, width: u32, height: u32) -> KeyframeRecord {
        let n = (width * height) as usize;
        KeyframeRecord {
            stamp_ns: 0,
            camera: Camera::at_origin(width, height),
            rgb: (0..3 * n).map(|_| r.random()).collect(),
            depth_mm: (0..n)
                .map(|_| if r.random_bool(0.2) { 0 } else { r.random() })
                .collect(),
            regions: None,
            exposure: r.random_range(0.25..4.0),
        }
    }

    /// Within `ulps` units in the last place (the kernel divides in f32;
    /// Vulkan allows 2.5 ulp for a division).
    fn close(a: f32, b: f32, ulps: i64) -> bool {
        (a.to_bits() as i64 - b.to_bits() as i64).abs() <= ulps
    }

    #[test]
    fn kept_and_uploaded_targets_expand_as_the_reference_does() {
        let mut r = rng("kept_and_uploaded_targets_expand_as_the_reference_does");
        with_context(|ctx| {
            // Odd sizes: byte strings that end mid-word.
            let records: Vec<KeyframeRecord> = [(7u32, 5u32), (16, 9), (13, 11), (3, 1), (31, 7)]
                .iter()
                .map(|&(w, h)| record(&mut r, w, h))
                .collect();
            let keys: Vec<ReplayKey> = records.iter().map(|_| ReplayKey::fresh()).collect();
            let max = records.iter().map(|k| k.camera.pixels()).max().unwrap();
            // Two slots for five keyframes, replayed in a pattern that
            // hits, misses and reuses slots within one recording.
            let kept = KeptTargets::new(ctx, 2, max).unwrap();
            let order = [0usize, 1, 0, 2, 3, 2, 4, 0, 4, 4, 1];
            let total: u64 = order.iter().map(|&i| records[i].camera.pixels()).sum();
            let target = Buffer::device(ctx, "test/target", total * 16).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let mut at = 0;
            let mut misses = 0;
            let mut held: Vec<usize> = Vec::new(); // most recent last
            for &i in &order {
                let uploaded = kept
                    .record_expand(&mut rec, &records[i], Some(keys[i]), &target, at)
                    .unwrap();
                let expected_miss = !held.contains(&i);
                assert_eq!(uploaded, expected_miss, "keyframe {i}");
                held.retain(|&h| h != i);
                held.push(i);
                if held.len() > 2 {
                    held.remove(0);
                }
                misses += uploaded as u64;
                at += records[i].camera.pixels();
            }
            rec.submit().unwrap().wait().unwrap();
            assert_eq!(kept.uploads(), misses);
            let got = ctx.download::<[f32; 4]>(&target).unwrap();
            let mut at = 0;
            for &i in &order {
                let k = &records[i];
                let want = unpack_target(&k.rgb, &k.depth_mm, k.exposure);
                let host = k.target_rgbd();
                for (p, (w, h)) in want.iter().zip(&host).enumerate() {
                    let g = got[at + p];
                    for c in 0..4 {
                        assert!(
                            close(g[c], w[c], 2),
                            "keyframe {i} pixel {p}: {g:?} vs {w:?}"
                        );
                        assert!(close(h[c], w[c], 2), "host {h:?} vs reference {w:?}");
                    }
                }
                at += want.len();
            }
            // A view larger than the slots, or a target too small, is refused.
            let big = record(&mut r, 32, 32);
            let mut rec = ctx.recorder().unwrap();
            assert!(kept
                .record_expand(&mut rec, &big, None, &target, 0)
                .is_err());
            assert!(kept
                .record_expand(&mut rec, &records[0], None, &target, total)
                .is_err());
        });
    }

    #[test]
    fn the_slot_used_longest_ago_is_taken_first() {
        let mut s = Slots {
            held: vec![None; 2],
            ..Default::default()
        };
        let (a, b, c) = (ReplayKey::fresh(), ReplayKey::fresh(), ReplayKey::fresh());
        let (sa, sb) = (s.take(Some(a)), s.take(Some(b)));
        assert_ne!(sa, sb);
        assert_eq!(s.find(a), Some(sa)); // a is now the newer
        assert_eq!(s.take(Some(c)), sb, "b was used longest ago");
        assert_eq!(s.find(b), None);
        assert_eq!(s.find(a), Some(sa));
        // A slot taken for nothing holds nothing.
        let t = s.take(None);
        assert!(s.held[t].is_none());
    }
}

//! Keyframes' Stage I inputs kept on the GPU in their compact form: colour
//! and depth as the host keeps them (RGB bytes and millimetre depth) and
//! the region each pixel pools into (16-bit rows local to the view), 7
//! bytes a pixel, so that a replayed keyframe crosses the host link once,
//! not at every Stage I step. Every keyframe, kept or not, reaches the
//! image loss and the pooling through the same kernel
//! (`glsl/target_unpack.comp`), so what trains does not depend on what
//! happened to be kept.
//!
//! Slots are fixed (one view of the largest size each); a keyframe not
//! kept takes a free slot, else the one used longest ago. Slots are
//! reused within one recording safely: the recorder orders an upload into
//! a slot after the expansion that read it before.

use std::cell::RefCell;

use super::super::history::{KeyframeRecord, ReplayKey};
use crate::latent::{RegionRows, ViewRegions, NO_REGION};
use latentam_base::{Error, Result};
use latentam_gpu::{Buffer, Context, Recorder};
use latentam_shaders::{bind, push, TARGET_UNPACK};

/// Invocations per workgroup of `glsl/target_unpack.comp`.
const THREADS: u64 = 256;

/// A local region row that names no region.
const NO_LOCAL_ROW: u16 = u16::MAX;

/// 32-bit words of each part of a slot for views of `pixels` pixels: the
/// RGB bytes, the depths and the local region rows, each padded to whole
/// words.
fn slot_parts(pixels: u64) -> [u64; 3] {
    [
        (3 * pixels).div_ceil(4),
        pixels.div_ceil(2),
        pixels.div_ceil(2),
    ]
}

/// GPU bytes of one slot for views of `pixels` pixels.
pub(crate) fn slot_bytes(pixels: u64) -> u64 {
    4 * slot_parts(pixels).iter().sum::<u64>()
}

/// What a slot holds.
#[derive(Clone, Copy)]
struct Held {
    key: ReplayKey,
    used: u64,
    /// Whether its colour and depth were uploaded.
    colour: bool,
    /// Whether its region rows were (a keyframe that trained before the
    /// map had a latent head pooled nothing).
    labels: bool,
}

/// Which keyframe each slot holds, and when it was last used.
#[derive(Default)]
struct Slots {
    held: Vec<Option<Held>>,
    clock: u64,
    uploads: u64,
}

impl Slots {
    /// The slot holding `key`, marked used now.
    fn find(&mut self, key: ReplayKey) -> Option<usize> {
        self.clock += 1;
        let now = self.clock;
        let i = self
            .held
            .iter()
            .position(|s| s.is_some_and(|h| h.key == key))?;
        if let Some(h) = &mut self.held[i] {
            h.used = now;
        }
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
                    .min_by_key(|&i| self.held[i].map_or(0, |h| h.used))
                    .unwrap_or(0)
            });
        self.held[i] = key.map(|key| Held {
            key,
            used: self.clock,
            colour: false,
            labels: false,
        });
        i
    }
}

/// One view of a Stage I chunk, as [`KeptTargets::record_expand`] takes it.
#[derive(Clone, Copy)]
pub struct ChunkView<'r> {
    /// The keyframe.
    pub record: &'r KeyframeRecord,
    /// Its key (`None`: not kept).
    pub key: Option<ReplayKey>,
    /// Its index in the chunk.
    pub view: usize,
    /// The chunk's regions, when the chunk pools any.
    pub regions: Option<&'r RegionRows>,
}

/// Where [`KeptTargets::record_expand`] writes: the image loss's target
/// and the pooling's per-pixel rows, each indexed by the chunk's pixels.
#[derive(Clone, Copy)]
pub struct Outputs<'a> {
    /// `[r, g, b, z]` per pixel, when wanted.
    pub target: Option<&'a Buffer>,
    /// The chunk's region row per pixel (`NO_REGION`: none), when wanted.
    pub labels: Option<&'a Buffer>,
}

/// The GPU store of kept keyframes (see the module's comment).
///
/// ```no_run
/// # use latentam_gpu::{Buffer, Context};
/// # use latentam_core::mapper::{ChunkView, KeptTargets, KeyframeRecord, Outputs, ReplayKey};
/// # use latentam_core::splat::BatchLayout;
/// # fn f(ctx: &Context, record: &KeyframeRecord) -> latentam_core::Result<()> {
/// let layout = BatchLayout::for_cameras(&[record.camera])?;
/// let kept = KeptTargets::new(ctx, 8, record.camera.pixels())?;
/// let target = Buffer::device(ctx, "target", record.camera.pixels() * 16)?;
/// let view = ChunkView { record, key: Some(ReplayKey::fresh()), view: 0, regions: None };
/// let out = Outputs { target: Some(&target), labels: None };
/// let mut rec = ctx.recorder()?;
/// kept.record_expand(&mut rec, &layout, view, out)?; // uploads it once
/// kept.record_expand(&mut rec, &layout, view, out)?; // from the GPU copy
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
    /// Room for `slots` keyframes (at least one: every keyframe is
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

    /// Keyframes whose colour and depth were uploaded into it so far (the
    /// others were expanded from their GPU copy).
    pub fn uploads(&self) -> u64 {
        self.slots.borrow().uploads
    }

    /// Records the expansion of `view` of a chunk laid out as `layout`
    /// into `out`: its target (colour divided by its exposure gain), and
    /// the chunk's region row of each of its pixels (`NO_REGION` where it
    /// pools into none, everywhere when the view has no regions in the
    /// chunk). From the slot holding its key when there is one, else after
    /// uploading its compact form into a slot that then holds the key.
    /// Returns whether its colour and depth were uploaded.
    pub fn record_expand<'a>(
        &'a self,
        rec: &mut Recorder<'a>,
        layout: &crate::splat::BatchLayout,
        view: ChunkView<'_>,
        out: Outputs<'a>,
    ) -> Result<bool> {
        let record = view.record;
        let pixels = record.camera.pixels();
        let slot_of_view = layout.views.get(view.view).copied();
        let fits = |b: Option<&Buffer>, bytes: u64| b.is_none_or(|b| bytes <= b.bytes());
        let Some(chunk_slot) = slot_of_view.filter(|s| {
            pixels <= self.max_pixels
                && (s.width as u64 * s.height as u64) == pixels
                && record.rgb.len() as u64 == 3 * pixels
                && record.depth_mm.len() as u64 == pixels
                && fits(out.target, (s.first_pixel + pixels) * 16)
                && fits(out.labels, (s.first_pixel + pixels) * 4)
                && record.exposure > 0.0
                && record.exposure.is_finite()
        }) else {
            return Err(Error::bad_input(
                "keyframe target",
                format!(
                    "view {} of a {}-view chunk: a {pixels}-pixel keyframe with {} colour bytes, {} \
                     depths and exposure {}; the store holds views of at most {} pixels",
                    view.view,
                    layout.views.len(),
                    record.rgb.len(),
                    record.depth_mm.len(),
                    record.exposure,
                    self.max_pixels
                ),
            ));
        };
        let first_pixel = chunk_slot.first_pixel;
        // The view's regions in the chunk: its first row there and its
        // rows local to the view.
        let own = view
            .regions
            .and_then(|r| r.views().iter().find(|v| v.view == view.view));

        let mut slots = self.slots.borrow_mut();
        let slot = match view.key.and_then(|k| slots.find(k)) {
            Some(slot) => slot,
            None => slots.take(view.key),
        };
        let [rgb_words, depth_words, _] = slot_parts(self.max_pixels);
        let rgb_word = slot as u64 * self.slot_words;
        let depth_word = rgb_word + rgb_words;
        let label_word = depth_word + depth_words;
        // Upload what this expansion reads and the slot does not hold.
        let held = slots.held[slot];
        let uploaded = out.target.is_some() && !held.is_some_and(|h| h.colour);
        if uploaded {
            slots.uploads += 1;
            rec.upload(&self.packed, rgb_word * 4, &record.rgb)?;
            rec.upload(&self.packed, depth_word * 4, &record.depth_mm)?;
        }
        let own_labels = own.filter(|_| out.labels.is_some());
        let label_upload = own_labels.filter(|_| !held.is_some_and(|h| h.labels));
        if let Some(regions) = label_upload {
            let local = local_rows(record, regions)?;
            rec.upload(&self.packed, label_word * 4, &local)?;
        }
        if let Some(h) = &mut slots.held[slot] {
            h.colour |= uploaded;
            h.labels |= label_upload.is_some();
        }
        let words = |w: u64| {
            u32::try_from(w).map_err(|_| Error::bad_input("kept targets", "past 2^32 words"))
        };
        let placeholder = out.target.or(out.labels).unwrap_or(&self.packed);
        rec.dispatch_linear(
            &TARGET_UNPACK,
            pixels.div_ceil(THREADS) as u32,
            bind::TargetUnpackBuffers {
                packed: &self.packed,
                target: out.target.unwrap_or(placeholder),
                labels: out.labels.unwrap_or(placeholder),
            },
            &push::TargetUnpack {
                pixels: pixels as u32,
                rgb_word: words(rgb_word)?,
                depth_word: words(depth_word)?,
                label_word: words(label_word)?,
                first_pixel: words(first_pixel)?,
                row_base: own.map_or(0, |v| v.first_row),
                write_target: out.target.is_some() as u32,
                write_labels: out.labels.is_some() as u32,
                has_labels: own.is_some() as u32,
                // As the host computes it (`KeyframeRecord::target_rgbd`).
                scale: 255.0 * record.exposure,
            },
        )?;
        Ok(uploaded)
    }
}

/// The region row of each pixel of `record`, whose rows in its chunk are
/// `view`'s, local to the view (its first row is 0), as 16-bit values
/// with [`NO_LOCAL_ROW`] for none.
fn local_rows(record: &KeyframeRecord, view: &ViewRegions) -> Result<Vec<u16>> {
    let Some(targets) = &record.regions else {
        return Err(Error::bad_input(
            "keyframe regions",
            "rows for a keyframe without regions",
        ));
    };
    if view.sources.len() > NO_LOCAL_ROW as usize {
        return Err(Error::bad_input(
            "keyframe regions",
            format!("more than {NO_LOCAL_ROW} regions in one view"),
        ));
    }
    let (width, height) = (record.camera.width, record.camera.height);
    let mut local = vec![NO_LOCAL_ROW; width as usize * height as usize];
    view.for_each_pixel(width, height, targets.source(), |i, row| {
        if row != NO_REGION {
            local[i] = row as u16;
        }
    })?;
    Ok(local)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::latent::{LabelImage, Regions};
    use crate::mapper::RegionTargets;
    use crate::splat::{BatchLayout, Camera};
    use latentam_gpu::testing::{rng, with_context};
    use latentam_reference::targets::{unpack_labels, unpack_target};
    use rand::Rng;

    /// A keyframe of random colour and depth (a fifth without depth),
    /// with `regions` random regions on a label image of half its size
    /// (some pixels in none), or none.
    fn record(r: &mut impl Rng, width: u32, height: u32, regions: u32) -> KeyframeRecord {
        let n = (width * height) as usize;
        let (lw, lh) = (width.div_ceil(2), height.div_ceil(2));
        KeyframeRecord {
            stamp_ns: 0,
            camera: Camera::at_origin(width, height),
            rgb: (0..3 * n).map(|_| r.random()).collect(),
            depth_mm: (0..n)
                .map(|_| if r.random_bool(0.2) { 0 } else { r.random() })
                .collect(),
            regions: (regions > 0).then(|| RegionTargets {
                width: lw,
                height: lh,
                labels: (0..lw * lh)
                    .map(|_| match r.random_range(0..regions + 1) {
                        l if l == regions => u16::MAX,
                        l => l as u16,
                    })
                    .collect(),
                grid: false,
                count: regions,
                vectors: vec![0.0; regions as usize],
                dim: 1,
            }),
            exposure: r.random_range(0.25..4.0),
        }
    }

    /// The chunk's regions of `views`, as Stage I builds them.
    fn chunk_regions(layout: &BatchLayout, views: &[&KeyframeRecord]) -> Regions {
        let mut regions = Regions::new(layout, 2);
        for (v, k) in views.iter().enumerate() {
            if let Some(t) = &k.regions {
                let img = LabelImage {
                    width: t.width,
                    height: t.height,
                    labels: &t.labels,
                };
                regions.add_labels(v, img, t.count).unwrap();
            }
        }
        regions
    }

    /// Within `ulps` units in the last place (the kernel divides in f32;
    /// Vulkan allows 2.5 ulp for a division).
    fn close(a: f32, b: f32, ulps: i64) -> bool {
        (a.to_bits() as i64 - b.to_bits() as i64).abs() <= ulps
    }

    #[test]
    fn kept_and_uploaded_keyframes_expand_as_the_reference_does() {
        let mut r = rng("kept_and_uploaded_keyframes_expand_as_the_reference_does");
        with_context(|ctx| {
            // Odd sizes: byte strings that end mid-word; one keyframe
            // without regions.
            let sizes = [
                (7u32, 5u32, 3u32),
                (16, 9, 5),
                (13, 11, 0),
                (3, 1, 2),
                (31, 7, 9),
            ];
            let records: Vec<KeyframeRecord> = sizes
                .iter()
                .map(|&(w, h, n)| record(&mut r, w, h, n))
                .collect();
            let keys: Vec<ReplayKey> = records.iter().map(|_| ReplayKey::fresh()).collect();
            let max = records.iter().map(|k| k.camera.pixels()).max().unwrap();
            // Two slots for five keyframes, in chunks that hit, miss and
            // reuse slots within one recording, and put kept keyframes at
            // other places of a chunk (other first pixels and rows).
            let kept = KeptTargets::new(ctx, 2, max).unwrap();
            let chunks: [&[usize]; 5] = [&[0, 1], &[0, 2, 3], &[3, 0], &[4, 1, 4], &[2, 4]];
            let mut held: Vec<usize> = Vec::new(); // most recent last
                                                   // Keyframe 0 first expands its target alone (no pooling yet):
                                                   // its region rows are uploaded the first time a chunk pools.
            let alone = BatchLayout::for_cameras(&[records[0].camera]).unwrap();
            let scratch = Buffer::device(ctx, "test/scratch", max * 16).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let view = ChunkView {
                record: &records[0],
                key: Some(keys[0]),
                view: 0,
                regions: None,
            };
            let out = Outputs {
                target: Some(&scratch),
                labels: None,
            };
            assert!(kept.record_expand(&mut rec, &alone, view, out).unwrap());
            rec.submit().unwrap().wait().unwrap();
            held.push(0);
            for chunk in chunks {
                let views: Vec<&KeyframeRecord> = chunk.iter().map(|&i| &records[i]).collect();
                let cams: Vec<Camera> = views.iter().map(|k| k.camera).collect();
                let layout = BatchLayout::for_cameras(&cams).unwrap();
                let regions = chunk_regions(&layout, &views);
                let target = Buffer::device(ctx, "test/target", layout.pixels * 16).unwrap();
                let labels = Buffer::device(ctx, "test/labels", layout.pixels * 4).unwrap();
                let out = Outputs {
                    target: Some(&target),
                    labels: Some(&labels),
                };
                let mut rec = ctx.recorder().unwrap();
                rec.fill_u32(&labels, 7);
                for (v, &i) in chunk.iter().enumerate() {
                    let view = ChunkView {
                        record: &records[i],
                        key: Some(keys[i]),
                        view: v,
                        regions: Some(regions.rows()),
                    };
                    let uploaded = kept.record_expand(&mut rec, &layout, view, out).unwrap();
                    assert_eq!(uploaded, !held.contains(&i), "keyframe {i} in {chunk:?}");
                    held.retain(|&h| h != i);
                    held.push(i);
                    if held.len() > 2 {
                        held.remove(0);
                    }
                }
                rec.submit().unwrap().wait().unwrap();
                let got = ctx.download::<[f32; 4]>(&target).unwrap();
                let got_labels = ctx.download::<u32>(&labels).unwrap();
                assert_eq!(got_labels, regions.pixel_region(), "{chunk:?}");
                for (v, &i) in chunk.iter().enumerate() {
                    let k = &records[i];
                    let at = layout.views[v].first_pixel as usize;
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
                    // The reference of the labels from the view's own rows.
                    let n = k.camera.pixels();
                    let own = regions.views().iter().find(|x| x.view == v);
                    let base = own.map_or(0, |x| x.first_row);
                    let local: Vec<u16> = match own {
                        Some(_) => regions.pixel_region()[at..at + n as usize]
                            .iter()
                            .map(|&r| match r {
                                NO_REGION => NO_LOCAL_ROW,
                                r => (r - base) as u16,
                            })
                            .collect(),
                        None => vec![NO_LOCAL_ROW; n as usize],
                    };
                    assert_eq!(
                        unpack_labels(&local, base, own.is_some()),
                        got_labels[at..at + n as usize]
                    );
                }
            }
            // A view larger than the slots, or outputs too small, are refused.
            let big = record(&mut r, 32, 32, 0);
            let layout = BatchLayout::for_cameras(&[big.camera]).unwrap();
            let small = Buffer::device(ctx, "test/small", 16).unwrap();
            let mut rec = ctx.recorder().unwrap();
            let view = |record| ChunkView {
                record,
                key: None,
                view: 0,
                regions: None,
            };
            let out = Outputs {
                target: Some(&small),
                labels: None,
            };
            assert!(kept
                .record_expand(&mut rec, &layout, view(&big), out)
                .is_err());
            let layout = BatchLayout::for_cameras(&[records[1].camera]).unwrap();
            assert!(kept
                .record_expand(&mut rec, &layout, view(&records[1]), out)
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

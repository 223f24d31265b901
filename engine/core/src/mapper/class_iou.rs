//! Per-class pixel counts for mIoU (the paper's Sec. V protocol): each
//! evaluated pixel adds to its true class and to the class predicted
//! there; IoU = intersection / union per class, mIoU the mean over the
//! classes present in the ground truth.

use std::collections::BTreeMap;

/// Pixel counts of one class's masks over the evaluated pixels.
///
/// ```
/// use std::collections::BTreeMap;
/// use latentam_core::mapper::eval::{count_pixel, mean_iou, ClassCounts};
///
/// let mut counts: BTreeMap<u16, ClassCounts> = BTreeMap::new();
/// count_pixel(&mut counts, 3, Some(3)); // right
/// count_pixel(&mut counts, 3, Some(5)); // wrong
/// assert_eq!(counts[&3].iou(), 0.5);
/// assert_eq!(mean_iou(&counts), Some(0.5)); // class 5 is never true: not averaged
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct ClassCounts {
    /// Pixels both true and predicted for the class.
    pub intersection: u64,
    /// Pixels true or predicted for the class.
    pub union: u64,
    /// Pixels whose true class it is.
    pub truth: u64,
}

impl ClassCounts {
    /// Intersection over union (0 when the union is empty).
    pub fn iou(&self) -> f64 {
        if self.union == 0 {
            0.0
        } else {
            self.intersection as f64 / self.union as f64
        }
    }
}

/// mIoU over the classes that occur in the ground truth, from counts
/// summed over all evaluated views.
pub fn mean_iou(counts: &BTreeMap<u16, ClassCounts>) -> Option<f64> {
    let ious: Vec<f64> = counts
        .values()
        .filter(|c| c.truth > 0)
        .map(ClassCounts::iou)
        .collect();
    (!ious.is_empty()).then(|| ious.iter().sum::<f64>() / ious.len() as f64)
}

/// Adds `b`'s counts into `a`.
pub fn add_iou(a: &mut BTreeMap<u16, ClassCounts>, b: &BTreeMap<u16, ClassCounts>) {
    for (&c, n) in b {
        let e = a.entry(c).or_default();
        e.intersection += n.intersection;
        e.union += n.union;
        e.truth += n.truth;
    }
}

/// Adds one pixel to per-class counts: its true class and the predicted
/// one (`None`: nothing predicted there).
pub fn count_pixel(counts: &mut BTreeMap<u16, ClassCounts>, truth: u16, predicted: Option<u16>) {
    let t = counts.entry(truth).or_default();
    t.truth += 1;
    t.union += 1;
    match predicted {
        Some(p) if p == truth => t.intersection += 1,
        Some(p) => counts.entry(p).or_default().union += 1,
        None => {}
    }
}

//! Arbitrary bytes through every message decoder: errors are fine, panics
//! and out-of-bounds reads are not. Whatever decodes must re-encode and
//! decode to the same fields.

use latentam_io::{
    CameraInfo, CompressedImage, FeatureGrid, Image, MaskFeatures, Odometry, PoseStamped,
    RosMessage, TextEmbeddings, TfMessage,
};

fn round_trip<'a, M: RosMessage<'a>>(data: &'a [u8], same: impl Fn(&M, &[u8]) -> bool) {
    if let Ok(m) = M::decode(data) {
        let again = m.encode();
        assert!(same(&m, &again), "re-encoding changed {}", M::TYPE_NAME);
    }
}

/// One input.
pub fn run(data: &[u8]) {
    round_trip::<Image>(data, |m, b| {
        let n = Image::decode(b).unwrap();
        (n.width, n.height, n.encoding, n.step, n.data)
            == (m.width, m.height, m.encoding, m.step, m.data)
    });
    round_trip::<CompressedImage>(data, |m, b| {
        CompressedImage::decode(b).unwrap().data == m.data
    });
    round_trip::<CameraInfo>(data, |m, b| {
        let n = CameraInfo::decode(b).unwrap();
        n.k.iter()
            .zip(&m.k)
            .all(|(x, y)| x.to_bits() == y.to_bits())
            && n.d.len() == m.d.len()
    });
    round_trip::<PoseStamped>(data, |m, b| {
        PoseStamped::decode(b).unwrap().header.frame_id == m.header.frame_id
    });
    round_trip::<Odometry>(data, |m, b| {
        Odometry::decode(b).unwrap().child_frame_id == m.child_frame_id
    });
    round_trip::<TfMessage>(data, |m, b| {
        TfMessage::decode(b).unwrap().transforms.len() == m.transforms.len()
    });
    round_trip::<MaskFeatures>(data, |m, b| {
        let n = MaskFeatures::decode(b).unwrap();
        n.labels.to_vec() == m.labels.to_vec() && n.data == m.data && n.model == m.model
    });
    round_trip::<FeatureGrid>(data, |m, b| FeatureGrid::decode(b).unwrap().data == m.data);
    round_trip::<TextEmbeddings>(data, |m, b| {
        TextEmbeddings::decode(b).unwrap().names == m.names
    });
}

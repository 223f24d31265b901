//! Keyframe selection by interval, by overlap and only after motion.

use super::*;

#[test]
fn keyframes_by_interval_by_overlap_and_only_after_motion() {
    let map = GlobalMap::new(0.01);
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Interval(3),
        min_translation: 0.0,
        min_rotation_deg: 0.0,
    });
    let f = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 2000);
    let picks: Vec<bool> = (0..7).map(|_| sel.decide(&f, &map).keyframe).collect();
    assert_eq!(picks, [true, false, false, true, false, false, true]);

    // With a minimum translation, a camera standing still makes one keyframe.
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Interval(1),
        min_translation: 0.1,
        min_rotation_deg: 5.0,
    });
    let picks: Vec<bool> = (0..4).map(|_| sel.decide(&f, &map).keyframe).collect();
    assert_eq!(picks, [true, false, false, false]);
    let turned = wall_frame(DVec3::ZERO, DQuat::from_rotation_y(0.2), 2000);
    assert!(
        sel.decide(&turned, &map).keyframe,
        "11° of rotation counts as motion"
    );

    // Overlap: a view of what is mapped is not a keyframe, a new wall is.
    // (At 0.5 m the seeds are 2.5 cm apart, the overlap check's points fall
    // between them.)
    let f = wall_frame(DVec3::ZERO, DQuat::IDENTITY, 500);
    let mut map = GlobalMap::new(0.01);
    for g in seed_from_frame(&f, None, &map, &SeedingConfig::default(), 1, None) {
        map.insert(g);
    }
    let mut sel = KeyframeSelector::new(KeyframeConfig {
        policy: KeyframePolicy::Overlap {
            min_overlap: 0.7,
            stride: 2,
        },
        min_translation: 0.0,
        min_rotation_deg: 0.0,
    });
    assert!(sel.decide(&f, &map).keyframe, "the first frame always is");
    let same = sel.decide(&f, &map);
    assert!(!same.keyframe && same.overlap.unwrap() > 0.99, "{same:?}");
    let away = wall_frame(
        DVec3::ZERO,
        DQuat::from_rotation_y(std::f64::consts::PI),
        500,
    );
    let d = sel.decide(&away, &map);
    assert!(d.keyframe && d.overlap.unwrap() < 0.01, "{d:?}");
}

//! Every choice the engine makes from a device's limits, fed with the
//! reports of real GPUs (`testing::devices`): buffer sizes, dispatch
//! splits, workgroup and shared-memory sizes of every kernel, and the
//! transfer queue. The choices that need the mapper's types (the window,
//! kernel variants, decoding batches) are checked in `latentam-core`
//! (`device_limits_tests.rs` there).

use ash::vk;

use crate::context::QueueFamilies;
use crate::testing::devices::{family_properties, recorded_devices};
use crate::TransferQueue;

#[test]
fn there_are_reports_of_the_gpus_robots_carry() {
    let devices = recorded_devices();
    let has = |words: &[&str]| {
        devices
            .iter()
            .any(|d| words.iter().all(|w| d.label.contains(w)))
    };
    assert!(has(&["RTX 40"]), "an RTX 40-series");
    assert!(has(&["Orin"]), "a Jetson Orin");
    assert!(has(&["AMD", "RDNA"]), "an AMD RDNA2/3");
    assert!(has(&["Intel", "Arc"]), "an Intel Arc");
    for d in &devices {
        assert!(!d.source.is_empty(), "{}: no source", d.label);
    }
}

#[test]
fn buffers_fit_every_binding_and_allocation_limit() {
    for d in recorded_devices() {
        let i = &d.info;
        let max = i.max_buffer_bytes();
        assert!(max <= i.max_storage_buffer_range, "{}", d.label);
        assert!(max <= i.max_memory_allocation_size, "{}", d.label);
        assert_eq!(max % 16, 0, "{}: whole 16-byte elements", d.label);
        // Nothing is lost to the rounding beyond one element.
        let limit = i.max_storage_buffer_range.min(i.max_memory_allocation_size);
        assert!(limit - max < 16, "{}", d.label);
    }
}

#[test]
fn every_kernel_fits_every_device_or_needs_a_feature_it_has_a_fallback_for() {
    // The build measured each kernel's shared memory: the blending kernels
    // keep a batch of Gaussians there.
    let shared = |name: &str| {
        latentam_shaders::ALL
            .iter()
            .find(|k| k.name == name)
            .map(|k| k.shared_bytes)
    };
    assert!(
        shared("raster_forward").unwrap() >= 256 * 4,
        "{:?}",
        shared("raster_forward")
    );
    assert_eq!(shared("fma_peak"), Some(0));
    // Every kernel fits the 16 KiB that Vulkan guarantees on any device.
    for k in latentam_shaders::ALL {
        assert!(
            k.shared_bytes <= 16 * 1024,
            "`{}`: {} bytes",
            k.name,
            k.shared_bytes
        );
    }
    for d in recorded_devices() {
        for k in latentam_shaders::ALL {
            let invocations: u32 = k.workgroup.iter().product();
            assert!(
                invocations <= d.info.max_workgroup_invocations,
                "{}: `{}` has {invocations} invocations",
                d.label,
                k.name
            );
            assert!(
                k.shared_bytes <= d.info.max_shared_memory,
                "{}: `{}` uses {} bytes of shared memory",
                d.label,
                k.name,
                k.shared_bytes
            );
            match d.info.missing_for(k) {
                None => {}
                // The compare-and-swap variants serve devices without
                // float atomic add (the RX 6600).
                Some(what) if what.starts_with("float atomic") => assert!(
                    latentam_shaders::ALL
                        .iter()
                        .any(|c| c.name == format!("{}_cas", k.name)
                            || (c.source == k.source && !c.requires.float_atomics)),
                    "{}: `{}` needs float atomics and has no other variant",
                    d.label,
                    k.name
                ),
                Some(what) => panic!("{}: `{}` cannot run: {what}", d.label, k.name),
            }
        }
    }
}

#[test]
fn linear_dispatches_stay_within_the_workgroup_counts() {
    for d in recorded_devices() {
        let max = d.info.max_workgroup_count;
        // One group per pixel of six 1280x720 views, per Gaussian of a
        // 20-million window, and the most a linear dispatch can have.
        for groups in [
            0u32,
            1,
            65_535,
            65_536,
            5_529_600,
            20_000_000,
            65_535 * 65_535,
        ] {
            let [x, y, z] = d.info.linear_groups(groups);
            assert!(
                x <= max[0] && y <= max[1] && z == 1,
                "{}: {groups}",
                d.label
            );
            assert!(
                x as u64 * y as u64 >= groups as u64,
                "{}: {groups}",
                d.label
            );
            // Not more than one row of groups beyond the work.
            assert!(
                x as u64 * y as u64 <= (groups as u64 + x as u64).saturating_sub(1),
                "{}: {groups}",
                d.label
            );
        }
        // Beyond that the split exceeds the y limit, which `dispatch`
        // refuses with an error rather than dispatching too few groups.
        assert!(d.info.linear_groups(u32::MAX)[1] > max[1], "{}", d.label);
    }
}

#[test]
fn the_transfer_queue_is_a_dma_engine_where_the_device_has_one() {
    for d in recorded_devices() {
        let props = family_properties(&d.families);
        let auto = QueueFamilies::choose(props.clone(), d.label, TransferQueue::Auto).unwrap();
        let compute = &d.families[auto.compute as usize];
        assert!(
            compute.flags.contains(vk::QueueFlags::COMPUTE),
            "{}",
            d.label
        );
        match auto.transfer {
            Some((family, index)) => {
                let f = &d.families[family as usize];
                assert!(
                    f.flags.contains(vk::QueueFlags::TRANSFER)
                        && !f
                            .flags
                            .intersects(vk::QueueFlags::COMPUTE | vk::QueueFlags::GRAPHICS),
                    "{}: family {family} is not a DMA engine",
                    d.label
                );
                assert!(index < f.count);
                // NVIDIA's copy engines time copies (64 bits), its video
                // families (32 bits) are not taken.
                assert_eq!(f.timestamp_bits, 64, "{}", d.label);
                assert!(d.info.dedicated_transfer_queue && d.info.transfer_timestamps);
            }
            None => {
                assert!(
                    !d.families
                        .iter()
                        .any(|f| f.flags.contains(vk::QueueFlags::TRANSFER)
                            && !f
                                .flags
                                .intersects(vk::QueueFlags::COMPUTE | vk::QueueFlags::GRAPHICS)),
                    "{}: a DMA family was left out",
                    d.label
                );
                assert!(!d.info.dedicated_transfer_queue);
            }
        }
        // The rehearsal takes a second compute queue where there is one.
        let same =
            QueueFamilies::choose(props.clone(), d.label, TransferQueue::SameFamily).unwrap();
        let (family, index) = same.transfer.unwrap();
        assert_eq!(family, same.compute);
        assert_eq!(
            index,
            u32::from(d.families[family as usize].count > 1),
            "{}",
            d.label
        );
        let off = QueueFamilies::choose(props, d.label, TransferQueue::Off).unwrap();
        assert!(off.transfer.is_none());
    }
    // NVIDIA has copy engines; RADV and Intel's Mesa driver expose none.
    let by = |w: &str| {
        recorded_devices()
            .into_iter()
            .find(|d| d.label.contains(w))
            .unwrap()
            .info
            .dedicated_transfer_queue
    };
    assert!(by("RTX 4070") && by("H200"));
    assert!(!by("RX 7800") && !by("Arc"));
}

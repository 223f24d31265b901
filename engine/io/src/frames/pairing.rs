//! Pairing by stamp: per-stream queues, the rule that decides when a
//! colour image can be resolved, and the assembly of a frame from the
//! nearest parts within the tolerance.

use super::*;
use crate::DepthData;

impl FrameAssembler {
    /// Whether everything a colour image at `t` waits for has arrived: each
    /// partner stream has moved past `t` plus the tolerance since the image
    /// arrived or, while its stamps have only gone forward, at all.
    pub(super) fn can_resolve(&self, t: i64, seen: &SeenSince) -> bool {
        if self.ended {
            return true;
        }
        let tol = self.config.tolerance_ns;
        let past = |w: Option<i64>, until: i64| w.is_some_and(|w| w >= until);
        let ready = |since: Option<i64>, watermark: Option<i64>, went_back: bool, until: i64| {
            past(since, until) || (!went_back && past(watermark, until))
        };
        let latest_pose = match &self.config.topics.pose {
            PoseSource::Topic(_) => self.poses.latest(),
            PoseSource::Tf { .. } => self.tf.latest(),
        };
        let pose_ready = ready(seen.pose, latest_pose, self.poses_went_back, t);
        // Saturating: the tolerance is the user's (`--tolerance-ms`).
        let until = t.saturating_add(tol);
        let partner = |q_watermark: Option<i64>, went_back: bool, since: Option<i64>| {
            ready(since, q_watermark, went_back, until)
        };
        partner(self.depth.watermark, self.depth.went_back, seen.depth)
            && (self.config.intrinsics.is_some() || self.camera_info.is_some())
            && pose_ready
            && (!self.has_embeddings
                || partner(
                    self.embeddings.watermark,
                    self.embeddings.went_back,
                    seen.embeddings,
                ))
            && (!self.has_semantic
                || partner(
                    self.semantic.watermark,
                    self.semantic.went_back,
                    seen.semantic,
                ))
    }

    pub(super) fn resolve(&mut self, all: bool) -> Result<(), InputError> {
        while let Some(front) = self.color.items.front() {
            let t = front.stamp;
            let forced = all || self.color.items.len() > self.config.max_pending;
            if !forced && !self.can_resolve(t, &front.value.seen) {
                break;
            }
            // `front()` was `Some` just above.
            let pending = self.color.items.pop_front().expect("front exists");
            let late = self
                .last_resolved
                .filter(|&last| t < last.saturating_sub(self.config.tolerance_ns));
            // A duplicate takes no partners: they belong to the first.
            let assembled = if self.resolved_stamps.insert(t) {
                self.assemble(t, pending.value.color)
            } else {
                Err(Rejection::new(
                    "frame: duplicate stamp",
                    format!(
                        "a second colour image at {t} ns (overlapping bag files, or a log \
                         recorded twice?)"
                    ),
                ))
            };
            let result = match (assembled, late) {
                // Its partners went with the frames resolved before it.
                (Err(r), Some(last)) if r.kind.starts_with("frame: no ") => Err(Rejection::new(
                    "frame: out of order",
                    format!(
                        "colour image at {t} ns arrived after the frame at {last} ns was \
                         assembled ({})",
                        r.kind
                    ),
                )),
                (result, _) => result,
            };
            self.last_resolved = Some(self.last_resolved.map_or(t, |l| l.max(t)));
            // Saturating: tolerance and pose gap are the user's settings.
            let oldest = t.saturating_sub(self.config.tolerance_ns);
            // Whatever is now too old for any later colour image is unpaired.
            for (kind, n) in [
                ("depth: unpaired", self.depth.drain_older_than(oldest)),
                (
                    "embeddings: unpaired",
                    self.embeddings.drain_older_than(oldest),
                ),
                ("semantic: unpaired", self.semantic.drain_older_than(oldest)),
            ] {
                for _ in 0..n {
                    self.report.count(&Rejection::new(
                        kind,
                        "no colour image within the tolerance",
                    ));
                }
            }
            let pose_horizon = t.saturating_sub(self.config.max_pose_gap_ns);
            self.poses.forget_before(pose_horizon);
            self.tf.forget_before(pose_horizon);
            match result {
                Ok(frame) => {
                    self.report.frames += 1;
                    self.report.frames_with_embeddings += frame.embeddings.is_some() as u64;
                    self.ready.push_back(frame);
                }
                Err(r) => {
                    let topic = self.config.topics.color.clone();
                    self.reject(&topic, t, r)?;
                }
            }
        }
        // Bound the partner queues too.
        let max = self.config.max_pending;
        while self.depth.items.len() > max {
            self.depth.items.pop_front();
            self.report.count(&Rejection::new(
                "depth: unpaired",
                "no colour image arrived for it before the queue filled",
            ));
        }
        while self.embeddings.items.len() > max {
            self.embeddings.items.pop_front();
            self.report.count(&Rejection::new(
                "embeddings: unpaired",
                "no colour image arrived for it before the queue filled",
            ));
        }
        while self.semantic.items.len() > max {
            self.semantic.items.pop_front();
        }
        Ok(())
    }

    pub(super) fn assemble(&mut self, t: i64, pending: PendingColor) -> Result<Frame, Rejection> {
        let tol = self.config.tolerance_ns;
        let depth = self.depth.take_nearest(t, tol);
        let embeddings = self.embeddings.take_nearest(t, tol);
        let semantic = self.semantic.take_nearest(t, tol);
        let Some(depth) = depth else {
            return Err(Rejection::new(
                "frame: no depth within tolerance",
                format!("colour image at {t} ns"),
            ));
        };
        let depth = depth.value?;
        let intrinsics = self.intrinsics_at(t)?;
        let pose = self.pose_at(t)?;
        // Depth from another lens is re-projected into the colour camera,
        // whose image size it then takes.
        let registration = self.registration(t, &intrinsics);
        let expected = match registration {
            None => Some(codec::ExpectedSize {
                width: depth.width,
                height: depth.height,
                kind: "frame: depth size differs from colour",
                from: "the depth image",
            }),
            Some(_) => None,
        };
        let color = match pending {
            PendingColor::Raw(c) => c?,
            PendingColor::Compressed { format, data } => codec::color_from_compressed(
                &CompressedImage {
                    header: Default::default(),
                    format: &format,
                    data: &data,
                },
                expected,
            )?,
        };
        let depth = match registration {
            Some(reg) => self.register(&reg, depth, color.width, color.height)?,
            None => depth,
        };
        if (depth.width, depth.height) != (color.width, color.height) {
            return Err(Rejection::new(
                "frame: depth size differs from colour",
                format!(
                    "depth {}×{}, colour {}×{} (depth must be registered to the colour image)",
                    depth.width, depth.height, color.width, color.height
                ),
            ));
        }
        let intrinsics = of_image_size(intrinsics, color.width, color.height)?;
        check_intrinsics(&intrinsics)?;
        let extent = self.config.max_extent_m;
        if pose.translation.abs().max_element() > extent {
            return Err(Rejection::new(
                "frame: position beyond the world extent",
                format!(
                    "camera at {:?} m, beyond ±{extent} m (--max-extent)",
                    pose.translation.to_array()
                ),
            ));
        }
        let mut depth = depth;
        depth.invalidate_beyond(self.config.max_depth_m);
        if !depth.has_valid_sample() {
            return Err(Rejection::new(
                "frame: no valid depth",
                format!(
                    "every depth sample of the image at {t} ns is 0, invalid or beyond {} m \
                     (--max-depth)",
                    self.config.max_depth_m
                ),
            ));
        }
        Ok(Frame {
            stamp_ns: t,
            pose,
            intrinsics,
            color,
            depth,
            embeddings: embeddings.map(|e| e.value),
            semantic: semantic.map(|s| s.value),
        })
    }

    /// The camera calibration for a colour image at `t`: the configured
    /// intrinsics, else the last camera info.
    fn intrinsics_at(&self, t: i64) -> Result<Intrinsics, Rejection> {
        match (&self.config.intrinsics, &self.camera_info) {
            (Some(k), _) => Ok(*k),
            (None, Some(k)) => k.clone(),
            (None, None) => Err(Rejection::new(
                "frame: no camera info",
                format!("colour image at {t} ns arrived before any camera info"),
            )),
        }
    }

    /// `depth` re-projected by `reg` into a `width × height` colour image
    /// (16-bit units as they were; 32-bit metres become millimetres).
    fn register(
        &self,
        reg: &DepthRegistration,
        depth: DepthImage,
        width: u32,
        height: u32,
    ) -> Result<DepthImage, Rejection> {
        if let Some(Ok(k)) = &self.depth_camera {
            let stated = (k.width, k.height);
            if stated != (0, 0) && stated != (depth.width, depth.height) {
                return Err(Rejection::new(
                    "depth: size mismatch",
                    format!(
                        "the depth camera info is for {}×{}, the depth image is {}×{}",
                        k.width, k.height, depth.width, depth.height
                    ),
                ));
            }
        }
        let (values, metres_per_unit) = match depth.data {
            DepthData::Units {
                values,
                metres_per_unit,
            } => (values, metres_per_unit),
            DepthData::Metres(m) => (
                m.iter()
                    .map(|&z| {
                        if z.is_finite() && z >= crate::MIN_DEPTH_M {
                            (z * 1000.0).round().clamp(1.0, u16::MAX as f32) as u16
                        } else {
                            0
                        }
                    })
                    .collect(),
                0.001,
            ),
        };
        let registered = reg.register(
            depth.width as usize,
            depth.height as usize,
            &values,
            units_per_metre(metres_per_unit),
            width as usize,
            height as usize,
        );
        Ok(DepthImage {
            width,
            height,
            data: DepthData::Units {
                values: registered,
                metres_per_unit,
            },
        })
    }

    pub(super) fn pose_at(&self, t: i64) -> Result<CameraPose, Rejection> {
        let gap = self.config.max_pose_gap_ns;
        let pose = match &self.config.topics.pose {
            PoseSource::Topic(_) => self
                .poses
                .at(t, self.config.tolerance_ns, gap)
                .map_err(|why| Rejection::new("frame: no pose", format!("at {t} ns: {why}")))?,
            PoseSource::Tf {
                world_frame,
                camera_frame,
            } => {
                let camera = camera_frame
                    .as_deref()
                    .or(self.color_frame_id.as_deref())
                    .unwrap_or_default();
                self.tf
                    .lookup(world_frame, camera, t, gap)
                    .map_err(|why| Rejection::new("frame: no pose", format!("at {t} ns: {why}")))?
            }
        };
        Ok(CameraPose {
            rotation: pose.rotation,
            translation: pose.translation,
        })
    }
}

/// Units per metre of a unit given in metres as an f32, to the 7
/// significant digits an f32 carries: 1 / 0.001f32 is 999.99995 in f64,
/// and the unit meant is the millimetre (1000).
fn units_per_metre(metres_per_unit: f32) -> f64 {
    let u = 1.0 / metres_per_unit as f64;
    let scale = 10f64.powi(6 - u.log10().ceil() as i32);
    (u * scale).round() / scale
}

/// `intrinsics` for a `width × height` image: a calibration that states no
/// size (0 × 0) takes the image's; one for another size is refused.
fn of_image_size(intrinsics: Intrinsics, width: u32, height: u32) -> Result<Intrinsics, Rejection> {
    match (intrinsics.width, intrinsics.height) {
        (0, 0) => Ok(Intrinsics {
            width,
            height,
            ..intrinsics
        }),
        (w, h) if (w, h) == (width, height) => Ok(intrinsics),
        (w, h) => Err(Rejection::new(
            "frame: intrinsics size differs from colour",
            format!("camera info is for {w}×{h}, colour image is {width}×{height}"),
        )),
    }
}

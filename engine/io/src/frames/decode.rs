//! Decoding: each role's messages decoded, checked and queued for pairing,
//! or rejected with their reason.

use super::*;

impl FrameAssembler {
    pub(super) fn decode(&mut self, role: Role, msg: RawMessage<'_>) -> Result<(), Rejection> {
        let ty = normalize_type_name(&msg.channel.schema_name);
        let undecodable = undecodable(role);
        let data = msg.data;
        match role {
            Role::Color => self.decode_color(&ty, data, &undecodable)?,
            Role::Depth => self.decode_depth(&ty, data, &undecodable)?,
            Role::CameraInfo => {
                let m = CameraInfo::decode(data).map_err(undecodable)?;
                self.camera_info = Some(intrinsics_of(&m));
            }
            Role::DepthCameraInfo => {
                let m = CameraInfo::decode(data).map_err(undecodable)?;
                self.depth_camera = Some(intrinsics_of(&m));
            }
            Role::Pose => self.decode_pose(&ty, data, &undecodable)?,
            Role::Tf | Role::TfStatic => {
                let m = TfMessage::decode(data).map_err(undecodable)?;
                for t in &m.transforms {
                    self.tf.insert(t, role == Role::TfStatic)?;
                    if role == Role::Tf {
                        let stamp = t.header.stamp.as_nanos();
                        self.saw(Partner::Pose, stamp);
                    }
                }
            }
            Role::Embeddings => self.decode_embeddings(&ty, data, &undecodable)?,
            Role::Semantic => {
                let m = Image::decode(data).map_err(undecodable)?;
                let labels = codec::labels_from_image(&m)?;
                let stamp = m.header.stamp.as_nanos();
                self.semantic.push(stamp, labels);
                self.saw(Partner::Semantic, stamp);
            }
            Role::Vocabulary => {
                let m = TextEmbeddings::decode(data).map_err(undecodable)?;
                self.vocabulary = Some(vocabulary_of(&m)?);
            }
        }
        Ok(())
    }

    /// A colour image, raw or compressed, queued for pairing.
    fn decode_color(
        &mut self,
        ty: &str,
        data: &[u8],
        undecodable: &Undecodable,
    ) -> Result<(), Rejection> {
        if ty == CompressedImage::TYPE_NAME {
            let m = CompressedImage::decode(data).map_err(undecodable)?;
            self.note_color_frame(m.header.frame_id);
            self.color.push(
                m.header.stamp.as_nanos(),
                PendingFrame {
                    color: PendingColor::Compressed {
                        format: m.format.to_string(),
                        data: m.data.to_vec(),
                    },
                    seen: SeenSince::default(),
                },
            );
        } else {
            let m = Image::decode(data).map_err(undecodable)?;
            self.note_color_frame(m.header.frame_id);
            let color = PendingColor::Raw(codec::color_from_image_into(
                &m,
                self.pool.bytes(m.data.len()),
            ));
            self.color.push(
                m.header.stamp.as_nanos(),
                PendingFrame {
                    color,
                    seen: SeenSince::default(),
                },
            );
        }
        Ok(())
    }

    /// A depth image, raw or compressed (a bad one is kept as such so the
    /// colour image it belongs to is rejected for the right reason).
    fn decode_depth(
        &mut self,
        ty: &str,
        data: &[u8],
        undecodable: &Undecodable,
    ) -> Result<(), Rejection> {
        let scale = self.config.depth_metres_per_unit;
        let (stamp, depth) = if ty == CompressedImage::TYPE_NAME {
            let m = CompressedImage::decode(data).map_err(undecodable)?;
            self.note_depth_frame(m.header.frame_id);
            let expected = self
                .camera_size()
                .map(|(width, height)| codec::ExpectedSize {
                    width,
                    height,
                    kind: "depth: size mismatch",
                    from: "the camera info",
                });
            (
                m.header.stamp.as_nanos(),
                codec::depth_from_compressed(&m, scale, expected),
            )
        } else {
            let m = Image::decode(data).map_err(undecodable)?;
            self.note_depth_frame(m.header.frame_id);
            (
                m.header.stamp.as_nanos(),
                codec::depth_from_image_into(&m, scale, self.pool.words(m.data.len() / 2)),
            )
        };
        // A bad depth image is kept as such so the colour image it
        // belongs to is rejected for the right reason.
        self.depth.push(stamp, depth);
        self.saw(Partner::Depth, stamp);
        Ok(())
    }

    /// A camera pose from a `PoseStamped` or an `Odometry` message.
    fn decode_pose(
        &mut self,
        ty: &str,
        data: &[u8],
        undecodable: &Undecodable,
    ) -> Result<(), Rejection> {
        let (stamp, pose) = if ty == Odometry::TYPE_NAME {
            let m = Odometry::decode(data).map_err(undecodable)?;
            (m.header.stamp.as_nanos(), m.pose)
        } else {
            let m = PoseStamped::decode(data).map_err(undecodable)?;
            (m.header.stamp.as_nanos(), m.pose)
        };
        let pose = pose.checked()?;
        self.poses_went_back |= self.poses.latest().is_some_and(|l| stamp < l);
        self.poses.insert(stamp, pose);
        self.saw(Partner::Pose, stamp);
        Ok(())
    }

    /// Region or grid embeddings; regions that cannot be used are counted
    /// (or, under `BadInputPolicy::Stop`, refuse the message).
    fn decode_embeddings(
        &mut self,
        ty: &str,
        data: &[u8],
        undecodable: &Undecodable,
    ) -> Result<(), Rejection> {
        let (stamp, e) = if ty == FeatureGrid::TYPE_NAME {
            let m = FeatureGrid::decode(data).map_err(undecodable)?;
            (
                m.header.stamp.as_nanos(),
                grid_embeddings(&m, &mut self.pool)?,
            )
        } else {
            let m = MaskFeatures::decode(data).map_err(undecodable)?;
            (
                m.header.stamp.as_nanos(),
                mask_embeddings(&m, &mut self.pool)?,
            )
        };
        self.check_signature(&e)?;
        let mut e = e;
        let refused = drop_bad_regions(&mut e, stamp);
        if let (Some(first), BadInputPolicy::Stop) = (refused.first(), self.config.on_bad_input) {
            return Err(first.clone());
        }
        for r in &refused {
            self.report.count(r);
        }
        if refused.len() < e.count as usize {
            self.embeddings.push(stamp, e);
        } else {
            // Nothing left to learn from: the frame maps geometry
            // only, as if it had no embeddings.
            self.embeddings.note(stamp);
            self.pool.recycle_embeddings(e);
        }
        self.saw(Partner::Embeddings, stamp);
        Ok(())
    }

    fn note_color_frame(&mut self, frame_id: &str) {
        if note_frame(&mut self.color_frame_id, frame_id) {
            self.registration = None;
        }
    }

    fn note_depth_frame(&mut self, frame_id: &str) {
        if note_frame(&mut self.depth_frame_id, frame_id) {
            self.registration = None;
        }
    }

    fn check_signature(&mut self, e: &Embeddings) -> Result<(), Rejection> {
        let model = crate::embedding_space(&e.model).to_string();
        match &self.embedding_signature {
            None => {
                self.embedding_signature = Some((e.dim, model));
                Ok(())
            }
            Some((dim, _)) if *dim != e.dim => Err(Rejection::new(
                "embeddings: dimension changed",
                format!(
                    "dimension {} after earlier messages of dimension {dim}",
                    e.dim
                ),
            )),
            Some((_, m)) if *m != model => Err(Rejection::new(
                "embeddings: model changed",
                format!("model `{model}` after earlier messages from `{m}`"),
            )),
            Some(_) => Ok(()),
        }
    }
}

/// Keeps a stream's latest frame id; whether it changed.
fn note_frame(slot: &mut Option<String>, frame_id: &str) -> bool {
    if slot.as_deref() == Some(frame_id) {
        return false;
    }
    *slot = Some(frame_id.to_string());
    true
}

/// Turns a CDR error into the rejection of a message of one role.
type Undecodable = dyn Fn(crate::cdr::CdrError) -> Rejection;

/// The rejection of an undecodable message of `role`.
fn undecodable(role: Role) -> impl Fn(crate::cdr::CdrError) -> Rejection {
    let kind = match role {
        Role::Color => "colour: undecodable message",
        Role::Depth => "depth: undecodable message",
        Role::CameraInfo => "camera info: undecodable message",
        Role::DepthCameraInfo => "depth camera info: undecodable message",
        Role::Pose => "pose: undecodable message",
        Role::Tf | Role::TfStatic => "tf: undecodable message",
        Role::Embeddings => "embeddings: undecodable message",
        Role::Semantic => "semantic: undecodable message",
        Role::Vocabulary => "vocabulary: undecodable message",
    };
    move |e| Rejection::new(kind, e.to_string())
}

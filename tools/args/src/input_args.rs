//! How a log's messages become frames: the topic and pairing options the
//! commands that read logs share (`map`, `eval`, `profile`, `inspect`).

use latentam::frames::{AssemblyConfig, BadInputPolicy, PoseSource, TopicChoice, Topics};

#[derive(clap::Args, Clone, Debug)]
pub struct InputArgs {
    /// Colour image topic (sensor_msgs/Image or CompressedImage). Default
    /// /camera/color/image_raw; when the log does not have it, the one
    /// image topic that is not depth, infrared or labels (preferring
    /// `color`/`rgb` names and raw over /compressed).
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub color_topic: Option<String>,
    /// Depth image topic, registered to the colour images. Default
    /// /camera/depth/image_raw, unless the log also has the driver's
    /// registered depth (`aligned_depth_to_color`, then `depth_registered`),
    /// which is read instead; when absent, the one image topic named
    /// `depth`, with the same preference.
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub depth_topic: Option<String>,
    /// Camera calibration topic (sensor_msgs/CameraInfo). Default
    /// /camera/color/camera_info; when absent, the one beside the colour
    /// images.
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub camera_info_topic: Option<String>,
    /// The depth camera's own calibration (sensor_msgs/CameraInfo), for a
    /// raw depth stream stamped in another optical frame than colour: with
    /// the /tf_static transform between the lenses, each depth image is
    /// re-projected into the colour camera. Default
    /// /camera/depth/camera_info; when absent, the one beside the depth
    /// images (none for the driver's registered depth).
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub depth_camera_info_topic: Option<String>,
    /// Pose topic (PoseStamped or Odometry of the camera optical frame in
    /// the world); ignored with --tf-world. Default /camera/pose; when
    /// absent, the one pose or odometry topic, else /tf + /tf_static from
    /// the root of the tree.
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub pose_topic: Option<String>,
    /// Take poses from /tf + /tf_static instead, chained from this world
    /// frame (e.g. `map`) to the colour image's frame.
    #[arg(long, value_name = "FRAME", help_heading = "Input")]
    pub tf_world: Option<String>,
    /// Region embeddings topic (latentam_msgs MaskFeatures or FeatureGrid).
    /// Default /camera/embeddings; when absent, the one topic of those
    /// types.
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub embeddings_topic: Option<String>,
    /// Semantic class-id images (evaluation only).
    #[arg(long, default_value = "/camera/semantic", help_heading = "Input")]
    pub semantic_topic: String,
    /// Query vocabulary (latentam_msgs TextEmbeddings). Default
    /// /vocabulary; when absent, the one topic of that type.
    #[arg(long, value_name = "TOPIC", help_heading = "Input")]
    pub vocabulary_topic: Option<String>,
    /// Largest stamp difference between a colour image and the depth or
    /// embeddings paired with it, milliseconds.
    #[arg(long, default_value_t = 20.0, help_heading = "Input")]
    pub tolerance_ms: f64,
    /// Metres per unit of 16-bit depth.
    #[arg(long, default_value_t = 0.001, help_heading = "Input")]
    pub depth_scale: f32,
    /// Depth beyond this many metres is invalid; a frame with no valid
    /// depth is skipped (and counted).
    #[arg(
        long,
        default_value_t = 1000.0,
        value_name = "METRES",
        help_heading = "Input"
    )]
    pub max_depth: f32,
    /// Frames whose camera is farther than this from the world origin
    /// along any axis are skipped (and counted): beyond about 10 km, map
    /// coordinates lose centimetre precision, so re-centre such logs.
    #[arg(
        long,
        default_value_t = 10000.0,
        value_name = "METRES",
        help_heading = "Input"
    )]
    pub max_extent: f64,
    /// Stop at the first malformed or inconsistent frame instead of
    /// skipping and counting it.
    #[arg(long, help_heading = "Input")]
    pub stop_on_bad_input: bool,
}

impl InputArgs {
    /// The frame assembly these options describe.
    pub fn assembly(&self) -> anyhow::Result<AssemblyConfig> {
        if !(self.tolerance_ms >= 0.0 && self.tolerance_ms.is_finite()) {
            anyhow::bail!("--tolerance-ms must be a non-negative number of milliseconds");
        }
        if !(self.depth_scale > 0.0 && self.depth_scale.is_finite()) {
            anyhow::bail!("--depth-scale must be a positive number of metres per unit");
        }
        if !(self.max_depth > 0.0 && self.max_depth.is_finite()) {
            anyhow::bail!("--max-depth must be a positive number of metres");
        }
        // Beyond 1000 km, f32 map coordinates are metres apart and voxel
        // keys overflow.
        if !(self.max_extent > 0.0 && self.max_extent <= 1e6) {
            anyhow::bail!("--max-extent must be a positive number of metres, at most 1000000");
        }
        let d = Topics::default();
        let or = |given: &Option<String>, default: String| given.clone().unwrap_or(default);
        let default_pose = match d.pose {
            PoseSource::Topic(t) => t,
            PoseSource::Tf { .. } => unreachable!("the default poses come from a topic"),
        };
        let pose = match &self.tf_world {
            Some(world_frame) => PoseSource::Tf {
                world_frame: world_frame.clone(),
                camera_frame: None,
            },
            None => PoseSource::Topic(or(&self.pose_topic, default_pose)),
        };
        Ok(AssemblyConfig {
            topics: Topics {
                color: or(&self.color_topic, d.color),
                depth: or(&self.depth_topic, d.depth),
                camera_info: or(&self.camera_info_topic, d.camera_info),
                depth_camera_info: or(&self.depth_camera_info_topic, d.depth_camera_info),
                pose,
                embeddings: or(&self.embeddings_topic, d.embeddings),
                semantic: self.semantic_topic.clone(),
                vocabulary: or(&self.vocabulary_topic, d.vocabulary),
            },
            // Topics not named may be chosen from the log.
            choose: TopicChoice {
                color: self.color_topic.is_none(),
                depth: self.depth_topic.is_none(),
                camera_info: self.camera_info_topic.is_none(),
                depth_camera_info: self.depth_camera_info_topic.is_none(),
                pose: self.pose_topic.is_none() && self.tf_world.is_none(),
                embeddings: self.embeddings_topic.is_none(),
                vocabulary: self.vocabulary_topic.is_none(),
            },
            // Checked finite and ≥ 0 above; `as` saturates a huge value at
            // i64::MAX, which the assembler's stamp arithmetic allows.
            tolerance_ns: (self.tolerance_ms * 1e6).round() as i64,
            depth_metres_per_unit: self.depth_scale,
            max_depth_m: self.max_depth,
            max_extent_m: self.max_extent,
            on_bad_input: if self.stop_on_bad_input {
                BadInputPolicy::Stop
            } else {
                BadInputPolicy::Skip
            },
            ..AssemblyConfig::default()
        })
    }
}

impl Default for InputArgs {
    /// The command-line defaults (one source of truth: clap's).
    fn default() -> Self {
        #[derive(clap::Parser)]
        struct Only {
            #[command(flatten)]
            input: InputArgs,
        }
        <Only as clap::Parser>::parse_from(["latentam"]).input
    }
}

//! Every setting of the mapper, declared once: type, default, the text
//! `latentam config --print-defaults` prints, and the valid range (see
//! [`settings!`]).

use crate::latent::{MAX_KMEANS_ATOMS, MAX_TEMPERATURE, MIN_TEMPERATURE};
use crate::loss::LossWeights;
use crate::map::{KeyframeConfig, SeedingConfig};
use crate::optim::GaussianLearningRates;
use crate::splat::BlendLayout;
use latentam_base::settings;
use latentam_base::settings::{Setting, MAX_DISTANCE};
use latentam_base::{Error, Result};

/// Largest [`MapperConfig::max_regions`].
const MAX_REGIONS_SETTING: u32 = 1 << 24;
/// Largest [`MapperConfig::replay`].
const MAX_REPLAY: u32 = 1 << 16;
/// Largest [`MapperConfig::replay_on_gpu`].
const MAX_REPLAY_ON_GPU: u32 = 1 << 16;
/// Largest [`MapperConfig::stage_one_iterations`] and
/// [`MapperConfig::stage_two_iterations`].
pub const MAX_ITERATIONS: u32 = 1000;
/// Largest [`MapperConfig::window_capacity`] (window rows are `u32`).
const MAX_WINDOW_CAPACITY: u64 = 1 << 31;
/// Smallest [`MapperConfig::voxel_size`], metres.
const MIN_VOXEL_SIZE: f64 = 1e-4;
/// Largest [`MapperConfig::voxel_size`], metres.
const MAX_VOXEL_SIZE: f64 = 1.0;
/// Largest [`MapperConfig::latent_lr`].
const MAX_LATENT_LR: f32 = 10.0;

settings! {
    /// Every setting of the mapper; defaults are the paper's values where it
    /// gives them and chosen here otherwise (see docs/quality.md). Reads from and writes to TOML
    /// ([`MapperConfig::from_toml`]); every field may be left out, and
    /// [`MapperConfig::validate`] checks the ranges documented on each.
    ///
    /// ```
    /// let cfg = latentam_core::mapper::MapperConfig::from_toml(
    ///     "replay = 3\ngpu_budget = 2_000_000_000\n[keyframes]\npolicy = { interval = 5 }",
    /// )?;
    /// assert_eq!(cfg.replay, 3);
    /// # Ok::<(), latentam_core::Error>(())
    /// ```
    pub struct MapperConfig {
        /// Edge length of the global map's voxels, in metres (s_v); the map
        /// keeps at most one Gaussian per voxel.
        pub voxel_size: f64 = 0.01
            => value().range(MIN_VOXEL_SIZE, MAX_VOXEL_SIZE).unit("metres"),
        /// GPU memory budget in bytes for everything the mapper allocates;
        /// allocations past it are refused. Unset: half of the device's
        /// largest device-local memory heap.
        pub gpu_budget: Option<u64> = None => optional("2000000000").at_least(1u32),
        /// Number of Gaussians the GPU window holds. Unset: as many as the
        /// GPU memory budget allows.
        pub window_capacity: Option<u64> = None
            => optional("1000000").range(1u32, MAX_WINDOW_CAPACITY),
        /// Host memory budget of the global map's blocks, in bytes (their
        /// Gaussians, about 210 bytes each with keys and indexes). Past it,
        /// the blocks used longest ago (0.64 m cubes at the default voxel
        /// size) are written to a scratch file in `spill_dir` and read back
        /// when the camera comes near them again; 0 keeps every block in
        /// memory. The map's occupancy grids stay in memory, outside the
        /// budget. The default suits a robot computer of 8 GB or more; on
        /// disk a Gaussian takes 196 bytes.
        pub host_budget: u64 = 2_000_000_000 => value(),
        /// Directory of the global map's scratch file once it outgrows
        /// `host_budget`; unset: the OS temporary directory ($TMPDIR, else
        /// /tmp). Choose a disk, not a RAM-backed tmpfs. The file is
        /// unlinked as soon as it is created, so nothing is left behind.
        pub spill_dir: Option<String> = None => optional("\"/var/tmp\""),
        /// Radius of the local window around the camera, in metres: the
        /// Gaussians within it are kept on the GPU and trained.
        pub window_radius: f64 = 6.0 => value()
            .range(setting("voxel_size", |c: &MapperConfig| c.voxel_size), MAX_DISTANCE)
            .unit("metres"),
        /// The window is re-synchronised with the global map once the
        /// camera has moved this far (metres) since the last
        /// synchronisation; new Gaussians are always brought in.
        pub sync_distance: f64 = 0.5 => value()
            .range(0.0, setting("window_radius", |c: &MapperConfig| c.window_radius)),
        /// Past keyframes replayed in each Stage I batch (B), drawn
        /// uniformly among those whose camera lies within window_radius of
        /// the current one.
        pub replay: u32 = 5 => value().range(0u32, MAX_REPLAY),
        /// Keyframes kept for replay are thinned in space: a keyframe taken
        /// within the same cell of this size (metres) and looking the same
        /// way (45-degree bins) as a kept one replaces it, so memory grows
        /// with the space explored rather than with time. 0 keeps every
        /// keyframe (the paper's setting).
        pub history_cell: f64 = 0.25 => value().range(0.0, MAX_DISTANCE).unit("metres"),
        /// Keyframes whose colour, depth and region rows stay on the GPU
        /// (7 bytes a pixel each; at most a thirty-second of gpu_budget
        /// and one buffer), so that replaying them uploads nothing; the
        /// one replayed longest ago makes room first. Replay draws
        /// uniformly among the keyframes near the camera, so about this
        /// many over their number are found on the GPU. 0 uploads every
        /// target at every Stage I step.
        pub replay_on_gpu: u32 = 32 => value().range(0u32, MAX_REPLAY_ON_GPU),
        /// Stage I iterations per keyframe (R1): joint steps on the
        /// Gaussians, W and D over the keyframe and its replayed ones; the
        /// paper uses 1. Each costs one Stage I (render, backward, Adam
        /// step), so more suit offline mapping.
        pub stage_one_iterations: u32 = 1 => value().range(1u32, MAX_ITERATIONS),
        /// Stage II iterations per keyframe (R2): steps on W and D alone.
        pub stage_two_iterations: u32 = 5 => value().range(0u32, MAX_ITERATIONS),
        /// Let the feature loss move the Gaussians' opacity, position and
        /// shape too, not only their queries (true/false). Stage I then
        /// renders a 32-channel query image per view: 128 more bytes of GPU
        /// memory per pixel of a chunk, and slower backward passes.
        pub attach_feature_gradients: bool = false => value(),
        /// How the blending kernels spread a tile's pixels over
        /// invocations: "auto" (columns on a CPU driver, pixels on a GPU),
        /// "pixels" (one pixel per invocation, with subgroup reductions and
        /// float atomics: the GPU path) or "columns" (16 pixels per
        /// invocation: faster on CPU drivers). Both give the same maps up
        /// to f32 summation order; forcing "pixels" on a CPU driver runs
        /// the path a GPU takes.
        pub blend_layout: BlendLayout = BlendLayout::Auto => value(),
        /// Compensate the camera's auto-exposure (true/false). Each
        /// keyframe's brightness gain over the map is measured on the
        /// surfaces the map already renders, and its colours are divided by
        /// it before they seed or train the map, so that a surface seen at
        /// two exposures keeps one colour. Views rendered for evaluation
        /// take the gain of their time, interpolated between keyframes.
        pub exposure_compensation: bool = true => value(),
        /// Dictionary size (K): number of latent atoms.
        pub atoms: u32 = 2000 => value().range(1u32, MAX_KMEANS_ATOMS),
        /// Micro-clusters each keyframe's region embeddings are summarised
        /// into before they join the dictionary (m; the paper uses 5). The
        /// dictionary grows by up to this many atoms a keyframe until it
        /// holds `atoms`, then re-clusters; values above `atoms` act as
        /// `atoms`.
        pub micro_clusters: u32 = 5 => value().range(1u32, MAX_KMEANS_ATOMS),
        /// Softmax temperature (tau) of the latent decoder, over the cosine
        /// similarities between a query and the dictionary atoms (M3 uses
        /// 0.05).
        pub temperature: f32 = 0.05 => value().range(MIN_TEMPERATURE, MAX_TEMPERATURE),
        /// Learning rate of the latent weights W and the dictionary D.
        pub latent_lr: f32 = 0.01 => value().range(0.0, MAX_LATENT_LR),
        /// Most regions in one training batch, over all its views.
        pub max_regions: u32 = 2048 => value().range(1u32, MAX_REGIONS_SETTING),
        /// Regions smaller than this many pixels are ignored. Integer >= 0.
        pub min_region_pixels: u32 = 16 => value(),
        /// Prune the map every this many keyframes; 0 = never. Integer >= 0.
        pub prune_interval: u32 = 10 => value(),
        /// Gaussians less opaque than this are pruned (GS-ICP uses 0.005).
        pub prune_min_opacity: f32 = 0.005 => value().range(0.0, 1.0),
        /// Gaussians with a standard deviation above this many metres are
        /// pruned (GS-ICP's 0.1 x scene extent, for a 5 m indoor scene).
        pub prune_max_scale: f32 = 0.5 => value().above(0.0, MAX_DISTANCE).unit("metres"),
        /// Seed of every random choice (initial W, queries, replay
        /// sampling); the same seed and input give the same map. Integer
        /// >= 0.
        pub seed: u64 = 0 => value(),
        /// Keyframe selection: which frames of the stream the mapper trains
        /// on. The first frame always is a keyframe.
        pub keyframes: KeyframeConfig = KeyframeConfig::default() => section(),
        /// Seeding of new Gaussians from each keyframe: back-projected depth
        /// where the map does not yet explain the view, at most one
        /// Gaussian per free voxel; isotropic, with a scale from depth over
        /// focal length.
        pub seeding: SeedingConfig = SeedingConfig::default() => section(),
        /// Weights of the loss terms (the paper's values). The total is
        /// rgb * (rgb_l1 * L1 + ssim * (1 - SSIM)) + depth * L_depth +
        /// feature * (cosine * L_cos + l2 * L_l2 + trust_region * L_trust).
        /// The paper's 0.2/0.8 split between L1 and SSIM is the reverse of
        /// the reference 3DGS systems (0.8/0.2); swap rgb_l1 and ssim for
        /// theirs. A weight of 0 turns its term off.
        pub weights: LossWeights = LossWeights::default() => section(),
        /// Adam learning rates per Gaussian parameter (GS-ICP's values,
        /// raised where online mapping needs it; see docs/quality.md's
        /// ablation). A rate of 0 freezes the parameter.
        pub learning_rates: GaussianLearningRates = GaussianLearningRates::default()
            => section(),
    }
}

/// The `setting` of an [`Error::Config`] about the configuration as a
/// whole (TOML that does not parse, or does not fit the structure).
pub(crate) const WHOLE_CONFIGURATION: &str = "mapper configuration";

impl MapperConfig {
    /// Parses TOML (unknown keys are errors; missing keys keep defaults)
    /// and checks the values: errors are [`Error::Config`].
    pub fn from_toml(text: &str) -> Result<Self> {
        let cfg: MapperConfig =
            toml::from_str(text).map_err(|e| Error::config(WHOLE_CONFIGURATION, e.to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The configuration as TOML (every field).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("the configuration is plain data")
    }

    /// The settings that shape a saved state (buffer sizes, the voxel grid,
    /// the random stream), by name, as text: a loaded map keeps them.
    pub(super) fn shape_settings(&self) -> [(&'static str, String); 7] {
        [
            ("voxel_size", self.voxel_size.to_string()),
            ("atoms", self.atoms.to_string()),
            ("max_regions", self.max_regions.to_string()),
            ("replay", self.replay.to_string()),
            ("history_cell", self.history_cell.to_string()),
            ("seed", self.seed.to_string()),
            ("window_capacity", format!("{:?}", self.window_capacity)),
        ]
    }

    /// Takes `kept`'s [`MapperConfig::shape_settings`].
    pub(super) fn keep_shape_of(&mut self, kept: &MapperConfig) {
        self.voxel_size = kept.voxel_size;
        self.atoms = kept.atoms;
        self.max_regions = kept.max_regions;
        self.replay = kept.replay;
        self.history_cell = kept.history_cell;
        self.seed = kept.seed;
        self.window_capacity = kept.window_capacity;
    }

    /// Checks every value against the range its documentation states;
    /// the error ([`Error::Config`]) names the first key out of range.
    pub fn validate(&self) -> Result<()> {
        self.check_nested("").map_err(Error::from)
    }
}

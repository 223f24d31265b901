//! What a keyframe adds: the latent head on the first embeddings, the
//! dictionary's k-means update, the per-pixel workspace, and new Gaussians
//! seeded where the map does not explain the view.

use super::*;

impl OnlineMapper {
    pub(in crate::mapper) fn make_head(&self, dim: u32) -> Result<LatentHead> {
        LatentHead::new(
            &self.ctx,
            LatentHeadConfig {
                dim,
                atoms: self.cfg.atoms,
                max_regions: self.cfg.max_regions,
                temperature: self.cfg.temperature,
                lr_w: self.cfg.latent_lr,
                lr_d: self.cfg.latent_lr,
                weights: self.cfg.weights,
                seed: self.cfg.seed,
                kmeans: crate::latent::KMeansConfig {
                    // A dictionary smaller than m takes it whole at once.
                    micro_clusters: self.cfg.micro_clusters.min(self.cfg.atoms),
                    ..Default::default()
                },
            },
        )
    }

    /// Creates the latent head on the first keyframe with embeddings and
    /// folds the keyframe's region embeddings into the dictionary.
    pub(super) fn update_dictionary(&mut self, record: &KeyframeRecord) -> Result<()> {
        let Some(r) = &record.regions else {
            return Ok(());
        };
        if self.head.is_none() {
            self.head = Some(self.make_head(r.dim)?);
        }
        // `check_frame` refused another dimension before anything changed.
        let head = self.head.as_ref().expect("created above");
        let rows: Vec<f32> = r
            .vectors
            .chunks(r.dim as usize)
            .filter(|row| row.iter().any(|&x| x != 0.0))
            .flatten()
            .copied()
            .collect();
        if !rows.is_empty() {
            let mut rec = self.ctx.recorder()?;
            head.record_keyframe_update(&mut rec, &rows)?;
            rec.submit()?.wait()?;
        }
        Ok(())
    }

    /// Sizes the window from the budget and creates it and the trainer
    /// (first keyframe only).
    /// `dim` is the embedding dimension the head has or will have (the
    /// frame's), `None` when no embeddings were seen yet.
    pub(in crate::mapper) fn ensure_workspace(
        &mut self,
        pixels: u64,
        dim: Option<u32>,
    ) -> Result<()> {
        if self.trainer.is_some() {
            return Ok(());
        }
        // Stage I renders its batch a chunk of views at a time: the pixel
        // buffers and the rasterizer's per-view buffers are sized for one
        // chunk, whatever the number of replayed keyframes.
        let views = views_per_chunk(pixels, self.cfg.replay + 1, DEFAULT_CHUNK_PIXELS) as u64;
        let budget = Self::budget_of(&self.ctx, &self.cfg);
        // The head is created after the workspace, from this keyframe's
        // embeddings; one created later (embeddings arriving after the first
        // keyframes) must still fit: room for a 1024-d one is kept.
        let later_head = match &self.head {
            Some(_) => 0,
            None => head_bytes(
                self.cfg.atoms as u64,
                dim.unwrap_or(1024) as u64,
                self.cfg.max_regions as u64,
            ),
        };
        let in_use = self.ctx.memory_report().total.current;
        let later = pixel_bytes(pixels, views, self.cfg.attach_feature_gradients) + later_head;
        let max_buffer = self.ctx.info().max_buffer_bytes();
        let sized = match self.cfg.window_capacity {
            Some(capacity) => {
                let buffer_limit_rows = max_buffer / largest_row_bytes(views);
                if capacity > buffer_limit_rows {
                    return Err(Error::InvalidArgument(format!(
                        "window_capacity = {capacity}, but {} can hold at most {buffer_limit_rows} \
                         Gaussians in one buffer ({max_buffer} bytes); lower window_capacity",
                        self.ctx.info().name
                    )));
                }
                WindowBudget {
                    budget,
                    reserved: in_use + later,
                    bytes_per_row: crate::mapper::budget::bytes_per_window_row(views),
                    capacity,
                    buffer_limit_rows,
                }
            }
            None => window_budget(budget, in_use, later, views, max_buffer)?,
        };
        log::info!(
            "window: {} Gaussians ({} bytes each) in a GPU budget of {} bytes",
            sized.capacity,
            sized.bytes_per_row,
            budget
        );
        let window = LocalWindow::new(&self.ctx, sized.capacity)?;
        let trainer = Trainer::new(
            &self.ctx,
            TrainerConfig {
                capacity: sized.capacity,
                max_view_pixels: pixels,
                max_views: self.cfg.replay + 1,
                chunk_pixels: DEFAULT_CHUNK_PIXELS,
                max_regions: self.cfg.max_regions,
                min_region_pixels: self.cfg.min_region_pixels,
                weights: self.cfg.weights,
                learning_rates: self.cfg.learning_rates,
                attach_feature_gradients: self.cfg.attach_feature_gradients,
                blend_layout: self.cfg.blend_layout,
            },
            dim.unwrap_or(1),
        )?;
        self.window = Some(window);
        self.trainer = Some(trainer);
        self.window_budget = Some(sized);
        Ok(())
    }

    /// Renders the window at the keyframe's pose, seeds Gaussians where
    /// the map does not explain the view, and inserts them into the global
    /// map, nearest first. Returns their keys.
    pub(super) fn seed(
        &mut self,
        frame: &Frame,
        record: &mut KeyframeRecord,
        seed: u64,
    ) -> Result<Vec<VoxelKey>> {
        let coverage = self.render_coverage(record)?;
        if self.cfg.exposure_compensation {
            record.exposure = self.measure_exposure(frame, record, coverage.as_ref());
        }
        let window = self.window.as_ref().expect("ensured");
        // Paged-out Gaussians beyond the window's radius do not render: their
        // surface must not be seeded again.
        let complete = self.global.len() == window.len();
        let partial = self.window_partial || (!complete && self.last_sync.is_none());
        let complete_within = match (complete, self.last_sync) {
            (false, Some(c)) => Some((c, self.cfg.window_radius)),
            _ => None,
        };
        // New Gaussians in a region start from its embedding projected
        // through the decoder's W (read back once per keyframe, 32 × d_f).
        let projected = match (&record.regions, self.head.as_ref()) {
            (Some(r), Some(head)) if self.cfg.seeding.query_init == QueryInit::Embedding => {
                let w: Vec<f32> = self.ctx.download(head.w())?;
                let dim = r.dim as usize;
                Some((
                    r,
                    projected_queries(w.get(..QUERY_DIM * dim).unwrap_or(&[]), dim, &r.vectors),
                ))
            }
            _ => None,
        };
        let queries = projected.as_ref().map(|(r, queries)| RegionQueries {
            width: r.width,
            height: r.height,
            labels: &r.labels,
            queries,
        });
        let mut seeds = seed_from_frame(
            frame,
            coverage.as_ref().map(|(alpha, depth, _)| ViewCoverage {
                alpha,
                depth,
                partial,
                complete_within,
                exposure: record.exposure,
            }),
            &self.global,
            &self.cfg.seeding,
            seed,
            queries.as_ref(),
        );
        if coverage.is_none() {
            // Without a render seeding took the colours as they are.
            for g in &mut seeds {
                g.color = g.color.map(|c| c / record.exposure);
            }
        }
        self.check_guesses(frame);
        Ok(self.insert_seeds(frame, seeds))
    }

    /// The window rendered at the keyframe's pose: alpha, depth and the
    /// colour-and-depth image (`None` while the window is empty).
    fn render_coverage(&mut self, record: &KeyframeRecord) -> Result<Option<Coverage>> {
        let window = self.window.as_ref().expect("ensured");
        if window.is_empty() {
            return Ok(None);
        }
        let raster = self.trainer.as_mut().expect("ensured").rasterizer();
        // Coverage needs alpha and depth; exposure colour.
        raster.forward_channels(
            window.params(),
            window.len() as u64,
            &[record.camera],
            Channels::Colour,
        )?;
        let (alpha, rgbd) = raster.download_alpha_rgbd(0)?;
        let depth: Vec<f32> = rgbd.iter().map(|p| p[3]).collect();
        Ok(Some((alpha, depth, rgbd)))
    }

    /// The keyframe's exposure against the map where the map renders its
    /// surface; the last keyframe's where there is too little of the map
    /// in view to tell.
    fn measure_exposure(
        &self,
        frame: &Frame,
        record: &KeyframeRecord,
        coverage: Option<&Coverage>,
    ) -> f32 {
        let last_gain = self.exposure.iter().last().map_or(1.0, |(_, g)| g);
        let Some((alpha, _, rgbd)) = coverage else {
            return last_gain;
        };
        let measured = |i: usize| frame.depth.metres(i);
        relative_exposure(
            &record.rgb,
            rgbd,
            alpha,
            measured,
            self.cfg.seeding.depth_error,
        )
        .unwrap_or(last_gain)
    }

    /// Inserts the seeds into the global map, nearest the camera first
    /// (those whose voxel is taken are dropped); those seeded where the
    /// keyframe measured no depth are guesses. Returns their keys.
    fn insert_seeds(
        &mut self,
        frame: &Frame,
        mut seeds: Vec<crate::map::Gaussian>,
    ) -> Vec<VoxelKey> {
        let centre = frame.pose.translation;
        let dist = |m: [f32; 3]| DVec3::from(m.map(f64::from)).distance_squared(centre);
        seeds.sort_by(|a, b| dist(a.mean).total_cmp(&dist(b.mean)));
        let mut keys = Vec::with_capacity(seeds.len());
        for g in seeds {
            let guessed = matches!(measured_at(frame, g.mean), Some((_, None)));
            if let Some(key) = self.global.insert(g) {
                if guessed {
                    self.guesses.insert(key);
                }
                keys.push(key);
            }
        }
        keys
    }

    /// Guesses this keyframe measures: kept where its depth agrees, marked
    /// for removal where they float in front of the surface it measured.
    fn check_guesses(&mut self, frame: &Frame) {
        let tolerance = self.cfg.seeding.depth_error as f64;
        let global = &self.global;
        let superseded = &mut self.superseded;
        self.guesses.retain(|&key| {
            let Some(g) = global.get(key) else {
                return false;
            };
            let Some((z, Some(measured))) = measured_at(frame, g.mean) else {
                return true;
            };
            let measured = measured as f64;
            if z < measured * (1.0 - tolerance) {
                superseded.insert(key);
                false
            } else {
                // On the measured surface: no longer a guess. Behind it:
                // hidden, so nothing says it is wrong.
                z > measured * (1.0 + tolerance)
            }
        });
    }
}

/// The depth of `mean` in `frame`'s camera and what the frame measured at
/// the pixel it projects to (`None` there: no valid depth); `None` outside
/// the image or behind the camera.
fn measured_at(frame: &Frame, mean: [f32; 3]) -> Option<(f64, Option<f32>)> {
    let p =
        frame.pose.rotation.inverse() * (DVec3::from(mean.map(f64::from)) - frame.pose.translation);
    if p.z <= 1e-6 {
        return None;
    }
    let k = frame.intrinsics;
    let u = (k.fx * p.x / p.z + k.cx).round();
    let v = (k.fy * p.y / p.z + k.cy).round();
    let (w, h) = (frame.depth.width as f64, frame.depth.height as f64);
    if !(0.0..w).contains(&u) || !(0.0..h).contains(&v) {
        return None;
    }
    Some((
        p.z,
        frame.depth.metres(v as usize * w as usize + u as usize),
    ))
}

/// The window rendered at a keyframe's pose: alpha, depth and colour with
/// depth, per pixel.
type Coverage = (Vec<f32>, Vec<f32>, Vec<[f32; 4]>);

//! Writing a converted dataset's messages: the vocabulary and static
//! transform first, then each colour image (with its camera info and
//! embeddings), depth image and pose in time order, then the metadata.

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{bail, Context};
use latentam::embedding_files::{FrameFeatures, LoadedFeatures};
use latentam::frames::encode_floats;
use latentam::logs::LogWriter;
use latentam::messages::{
    cdr, codec, CameraInfo, CompressedImage, FeatureGrid, Header, Image, MaskFeatures, Pose,
    PoseStamped, TextEmbeddings, TfMessage, TransformStamped,
};

use super::{
    check_payload, datasets, stem, u16_bytes, Cameras, ConvertOptions, ConvertSummary,
    DepthRegistration, EmbeddingSource, Event, DEPTH_FRAME, FRAME,
};

/// The log being written, with what the conversion decided up front.
pub(super) struct LogOut<'o> {
    log: LogWriter<BufWriter<std::fs::File>>,
    options: &'o ConvertOptions,
    intrinsics: [f64; 4],
    units_per_metre: f64,
    /// The registration with the colour images' width and height.
    registration: Option<(DepthRegistration, usize, usize)>,
    /// Added to every stamp (see `timeline`).
    offset: i64,
    summary: ConvertSummary,
    /// The first frame's embedding dimension and model, which every
    /// later frame must share.
    first_space: Option<(usize, String)>,
    /// Whether the first frame with embeddings had a grid.
    first_layout: Option<bool>,
}

impl<'o> LogOut<'o> {
    pub fn create(
        path: &Path,
        options: &'o ConvertOptions,
        cameras: &Cameras,
        registration: Option<(DepthRegistration, usize, usize)>,
        offset: i64,
        summary: ConvertSummary,
    ) -> anyhow::Result<Self> {
        Ok(LogOut {
            log: LogWriter::create(path, options.compression)?,
            options,
            intrinsics: cameras.intrinsics,
            units_per_metre: cameras.units_per_metre,
            registration,
            offset,
            summary,
            first_space: None,
            first_layout: None,
        })
    }

    /// What was written so far.
    pub fn summary(&self) -> &ConvertSummary {
        &self.summary
    }

    /// With the dataset's first stamp: the oracle vocabulary and, for raw
    /// depth, the transform between the lenses.
    pub fn write_start(&mut self, first_stamp_ns: i64) -> anyhow::Result<()> {
        let t = first_stamp_ns + self.offset;
        if let EmbeddingSource::Oracle(o) = &self.options.embeddings {
            // `Oracle::new` checks 2 ≤ classes ≤ 65536, so `names[1..]`
            // exists and every id fits a u16.
            let names: Vec<&str> = o.names[1..].iter().map(String::as_str).collect();
            let ids: Vec<u16> = (1..o.names.len()).map(|i| i as u16).collect();
            let ids_bytes = u16_bytes(&ids);
            let data = encode_floats(&o.vectors[1..].concat(), self.options.dtype);
            self.log.write(
                "/vocabulary",
                t as u64,
                &TextEmbeddings {
                    header: Header::at(t, "map"),
                    names,
                    ids: cdr::Seq::new(&ids_bytes, cdr::Endian::Little),
                    dim: o.dim() as u32,
                    dtype: self.options.dtype.name(),
                    data: &data,
                    model: &o.model,
                },
            )?;
        }
        // Raw depth: the depth lens placed in the colour lens's frame.
        if let Some((reg, _, _)) = self.raw_depth() {
            let transform = Pose {
                translation: reg.translation,
                rotation: reg.rotation,
            };
            self.log.write(
                "/tf_static",
                t as u64,
                &TfMessage {
                    transforms: vec![TransformStamped {
                        header: Header::at(t, FRAME),
                        child_frame_id: DEPTH_FRAME,
                        transform,
                    }],
                },
            )?;
            self.summary.notes.push(format!(
                "depth written as recorded in `{DEPTH_FRAME}`, with its camera info and \
                 /tf_static, for the reader to register"
            ));
        }
        Ok(())
    }

    /// The registration when depth is written as recorded.
    fn raw_depth(&self) -> Option<&(DepthRegistration, usize, usize)> {
        self.registration
            .as_ref()
            .filter(|_| self.options.raw_depth)
    }

    /// One colour image, depth image or pose.
    pub fn write_event(&mut self, e: &Event<'_>) -> anyhow::Result<()> {
        let t = e.stamp() + self.offset;
        match e {
            Event::Pose(_, p) => {
                self.log.write(
                    "/camera/pose",
                    t as u64,
                    &PoseStamped {
                        header: Header::at(t, "world"),
                        pose: **p,
                    },
                )?;
                self.summary.poses += 1;
            }
            Event::Depth(s) => self.write_depth(s, t)?,
            Event::Color(s) => self.write_color(s, t)?,
        }
        Ok(())
    }

    /// A depth image in millimetres: registered to the colour camera, or
    /// as recorded beside its own camera info.
    fn write_depth(&mut self, s: &datasets::Stamped, t: i64) -> anyhow::Result<()> {
        let lt = t as u64;
        let bytes = latentam::files::read_input(&s.path)
            .with_context(|| format!("reading {}", s.path.display()))?;
        let (w, h, mut values) = codec::decode_png_u16(&bytes)
            .map_err(|e| anyhow::anyhow!("{}: {e}", s.path.display()))?;
        let units = self.units_per_metre;
        if (units - 1000.0).abs() > 1e-9 {
            let k = 1000.0 / units;
            for v in &mut values {
                *v = (*v as f64 * k).round().min(u16::MAX as f64) as u16;
            }
        }
        let (w, h, header) = match (&self.registration, self.options.raw_depth) {
            (Some((reg, _, _)), true) => {
                let header = Header::at(t, DEPTH_FRAME);
                self.log.write(
                    "/camera/depth/camera_info",
                    lt,
                    &CameraInfo::pinhole(header, w, h, reg.depth),
                )?;
                (w, h, header)
            }
            (Some((reg, cw, ch)), false) => {
                values = reg.register(w as usize, h as usize, &values, 1000.0, *cw, *ch);
                (*cw as u32, *ch as u32, Header::at(t, FRAME))
            }
            (None, _) => (w, h, Header::at(t, FRAME)),
        };
        // `values` holds the w × h samples `decode_png_u16` returned (at
        // most codec::MAX_IMAGE_PIXELS of them), as the encoder requires.
        let data = codec::encode_compressed_depth_u16(w, h, &values);
        self.log.write(
            "/camera/depth/image_raw",
            lt,
            &CompressedImage {
                header,
                format: "16UC1; compressedDepth png",
                data: &data,
            },
        )?;
        self.summary.depth += 1;
        Ok(())
    }

    /// A colour image as it is (no re-encoding), its camera info, and its
    /// embeddings (with the oracle's label image) when the source has any.
    fn write_color(&mut self, s: &datasets::Stamped, t: i64) -> anyhow::Result<()> {
        let lt = t as u64;
        let header = Header::at(t, FRAME);
        let bytes = latentam::files::read_input(&s.path)
            .with_context(|| format!("reading {}", s.path.display()))?;
        check_payload(&s.path.display().to_string(), bytes.len())?;
        let (w, h, format) = codec::compressed_image_size(&bytes)
            .map_err(|e| anyhow::anyhow!("{}: {e}", s.path.display()))?;
        self.log.write(
            "/camera/color/camera_info",
            lt,
            &CameraInfo::pinhole(header, w, h, self.intrinsics),
        )?;
        self.log.write(
            "/camera/color/image_raw",
            lt,
            &CompressedImage {
                header,
                format,
                data: &bytes,
            },
        )?;
        let name = stem(&s.path);
        match self.embeddings_of(&name, header, lt)? {
            Some(f) => {
                self.check_same_space(&name, &f)?;
                self.write_features(header, lt, &f)?;
                self.summary.with_embeddings += 1;
            }
            None if !matches!(self.options.embeddings, EmbeddingSource::None) => {
                self.summary.without_embeddings += 1
            }
            None => {}
        }
        self.summary.frames += 1;
        Ok(())
    }

    /// The embeddings of frame `name`; an oracle frame's label image is
    /// written as its semantic ground truth on the way.
    fn embeddings_of(
        &mut self,
        name: &str,
        header: Header<'_>,
        lt: u64,
    ) -> anyhow::Result<Option<LoadedFeatures>> {
        Ok(match &self.options.embeddings {
            EmbeddingSource::None => None,
            EmbeddingSource::Features(dir) => dir.load(name)?,
            EmbeddingSource::Oracle(o) => match o.load(name)? {
                Some(frame) => {
                    let (lw, lh) = (frame.width, frame.height);
                    let class_bytes = u16_bytes(&frame.classes);
                    self.log.write(
                        "/camera/semantic",
                        lt,
                        &Image::packed(header, lw, lh, "16UC1", &class_bytes),
                    )?;
                    Some(LoadedFeatures {
                        features: frame.features,
                        dim: o.dim(),
                        model: o.model.clone(),
                    })
                }
                None => None,
            },
        })
    }

    /// Refuses embeddings of another layout, dimension or model than the
    /// first frame's: one log holds one embedding space.
    fn check_same_space(&mut self, name: &str, f: &LoadedFeatures) -> anyhow::Result<()> {
        let grid = matches!(f.features, FrameFeatures::Grid { .. });
        if *self.first_layout.get_or_insert(grid) != grid {
            bail!(
                "{name}: {} after frames with {}; one log holds one kind (mask regions or a feature grid)",
                if grid { "a feature grid" } else { "mask regions" },
                if grid { "mask regions" } else { "a feature grid" }
            );
        }
        match &self.first_space {
            None => self.first_space = Some((f.dim, f.model.clone())),
            Some((d, m)) if *d != f.dim || *m != f.model => bail!(
                "{name}: embeddings of dimension {} from `{}` after {d} from `{m}`; one log holds one embedding space",
                f.dim,
                f.model
            ),
            Some(_) => {}
        }
        Ok(())
    }

    fn write_features(
        &mut self,
        header: Header<'_>,
        lt: u64,
        f: &LoadedFeatures,
    ) -> anyhow::Result<()> {
        let dtype = self.options.dtype;
        match &f.features {
            FrameFeatures::Regions {
                width,
                height,
                labels,
                count,
                vectors,
            } => {
                let label_bytes = u16_bytes(labels);
                let data = encode_floats(vectors, dtype);
                check_payload("region embeddings", data.len())?;
                self.log.write(
                    "/camera/embeddings",
                    lt,
                    &MaskFeatures {
                        header,
                        height: *height,
                        width: *width,
                        labels: cdr::Seq::new(&label_bytes, cdr::Endian::Little),
                        count: *count,
                        dim: f.dim as u32,
                        dtype: dtype.name(),
                        data: &data,
                        model: &f.model,
                    },
                )?;
            }
            FrameFeatures::Grid {
                rows,
                cols,
                vectors,
            } => {
                let data = encode_floats(vectors, dtype);
                check_payload("grid embeddings", data.len())?;
                self.log.write(
                    "/camera/embeddings",
                    lt,
                    &FeatureGrid {
                        header,
                        rows: *rows,
                        cols: *cols,
                        dim: f.dim as u32,
                        dtype: dtype.name(),
                        data: &data,
                        model: &f.model,
                    },
                )?;
            }
        }
        Ok(())
    }

    /// Writes the metadata (converter, source, units, embeddings, notes)
    /// and closes the log.
    pub fn finish(mut self) -> anyhow::Result<ConvertSummary> {
        let options = self.options;
        let mut meta = BTreeMap::from([
            (
                "converter".to_string(),
                format!("latentam convert {}", options.kind),
            ),
            ("source".to_string(), options.source.display().to_string()),
            (
                "depth".to_string(),
                format!(
                    "millimetres, converted from {} units per metre",
                    self.units_per_metre
                ),
            ),
            (
                "embeddings".to_string(),
                match &options.embeddings {
                    EmbeddingSource::None => "none".to_string(),
                    EmbeddingSource::Features(_) => "per-frame feature files".to_string(),
                    EmbeddingSource::Oracle(_) => {
                        "oracle: label images and class vectors (evaluation only)".to_string()
                    }
                },
            ),
        ]);
        if self.offset != 0 {
            meta.insert("stamps".into(), "synthetic (the dataset has none)".into());
        }
        for (i, n) in self.summary.notes.iter().enumerate() {
            meta.insert(format!("note_{i}"), n.clone());
        }
        self.log.metadata("latentam", meta)?;
        self.log.finish()?;
        Ok(self.summary)
    }
}

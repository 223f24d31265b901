//! Whether a frame built outside the log reader holds together: images of
//! the intrinsics' size with as many bytes as that takes, a rigid pose, a
//! pinhole camera, embeddings that match their layout. Frames read from
//! logs are assembled this way already; a program that builds its own
//! (the live handle, the Python and C bindings) is checked here, before
//! anything is queued.

use crate::frame::{DepthData, EmbeddingLayout, Frame, LabelImage};
use crate::parts::MAX_EMBEDDING_DIM;
use latentam_base::{Error, Result};

impl Frame {
    /// Checks that the frame holds together (see the module); the error
    /// says what does not.
    ///
    /// ```
    /// # use latentam_io::*;
    /// let pose = CameraPose { rotation: glam::DQuat::IDENTITY, translation: glam::DVec3::ZERO };
    /// let mut frame = Frame {
    ///     stamp_ns: 7,
    ///     pose,
    ///     intrinsics: Intrinsics { width: 4, height: 2, fx: 1.0, fy: 1.0, cx: 2.0, cy: 1.0 },
    ///     color: ColorImage { width: 4, height: 2, format: PixelFormat::Rgb8, data: vec![0; 24] },
    ///     depth: DepthImage { width: 4, height: 2, data: DepthData::Metres(vec![1.0; 8]) },
    ///     embeddings: None,
    ///     semantic: None,
    /// };
    /// assert!(frame.check().is_ok());
    /// frame.color.data.pop();
    /// assert!(frame.check().unwrap_err().to_string().contains("23 bytes"));
    /// ```
    pub fn check(&self) -> Result<()> {
        self.check_parts().map_err(|reason| Error::BadFrame {
            stamp_ns: self.stamp_ns,
            reason,
        })
    }

    fn check_parts(&self) -> std::result::Result<(), String> {
        let k = &self.intrinsics;
        let (w, h) = (k.width, k.height);
        if w == 0 || h == 0 {
            return Err(format!("a {w}×{h} image"));
        }
        if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(format!("intrinsics {k:?} are not a pinhole camera"));
        }
        let p = &self.pose;
        let unit = (p.rotation.length() - 1.0).abs() < 1e-3;
        if !(p.translation.is_finite() && p.rotation.is_finite() && unit) {
            return Err(format!(
                "pose {p:?} is not a rigid transform (a finite translation and a unit quaternion)"
            ));
        }
        let pixels = w as usize * h as usize;
        let c = &self.color;
        if (c.width, c.height) != (w, h) {
            return Err(format!(
                "a {}×{} colour image for {w}×{h} intrinsics",
                c.width, c.height
            ));
        }
        let want = pixels * c.format.bytes_per_pixel();
        if c.data.len() != want {
            return Err(format!(
                "the {w}×{h} {} colour image holds {} bytes, not {want}",
                c.format.ros_name(),
                c.data.len()
            ));
        }
        let d = &self.depth;
        if (d.width, d.height) != (w, h) {
            return Err(format!(
                "a {}×{} depth image for a {w}×{h} colour image (register depth to colour first)",
                d.width, d.height
            ));
        }
        let (values, kind) = match &d.data {
            DepthData::Units {
                values,
                metres_per_unit,
            } => {
                if !(metres_per_unit.is_finite() && *metres_per_unit > 0.0) {
                    return Err(format!("depth unit of {metres_per_unit} m"));
                }
                (values.len(), "unit")
            }
            DepthData::Metres(values) => (values.len(), "metre"),
        };
        if values != pixels {
            return Err(format!(
                "the {w}×{h} depth image holds {values} {kind} values, not {pixels}"
            ));
        }
        if let Some(e) = &self.embeddings {
            if e.count == 0 || e.dim == 0 || e.dim > MAX_EMBEDDING_DIM {
                return Err(format!(
                    "{} embeddings of {} values (at most {MAX_EMBEDDING_DIM})",
                    e.count, e.dim
                ));
            }
            let want = e.count as usize * e.dim as usize * e.dtype.size();
            if e.data.len() != want {
                return Err(format!(
                    "{} embeddings of {} {} values take {want} bytes, not {}",
                    e.count,
                    e.dim,
                    e.dtype.name(),
                    e.data.len()
                ));
            }
            match &e.layout {
                EmbeddingLayout::Regions(mask) => {
                    labels_fit(mask, w, h, "region mask")?;
                    let stray = mask
                        .labels
                        .iter()
                        .find(|&&l| l != u16::MAX && l as u32 >= e.count);
                    if let Some(id) = stray {
                        return Err(format!(
                            "region {id} in the mask, but {} embeddings (ids count from 0; {} marks no region)",
                            e.count,
                            u16::MAX
                        ));
                    }
                }
                EmbeddingLayout::Grid { rows, cols } => {
                    if *rows as u64 * *cols as u64 != e.count as u64 {
                        return Err(format!("a {rows}×{cols} grid of {} embeddings", e.count));
                    }
                }
            }
        }
        if let Some(s) = &self.semantic {
            labels_fit(s, w, h, "semantic image")?;
        }
        Ok(())
    }
}

fn labels_fit(l: &LabelImage, w: u32, h: u32, what: &str) -> std::result::Result<(), String> {
    if (l.width, l.height) != (w, h) {
        return Err(format!(
            "a {}×{} {what} for a {w}×{h} image",
            l.width, l.height
        ));
    }
    if l.labels.len() != w as usize * h as usize {
        return Err(format!(
            "the {w}×{h} {what} holds {} labels",
            l.labels.len()
        ));
    }
    Ok(())
}

impl crate::frame::CameraPose {
    /// The pose of a row-major 4×4 camera-to-world matrix, refused (with
    /// the reason) unless it is rigid: finite, the last row `[0, 0, 0, 1]`,
    /// a rotation orthonormal to 10⁻³ with determinant +1.
    ///
    /// ```
    /// use latentam_io::CameraPose;
    /// let mut m = [1.0, 0.0, 0.0, 0.5, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 1.0];
    /// assert_eq!(CameraPose::from_matrix(&m).unwrap().translation.z, 2.0);
    /// m[0] = 2.0; // a scale is no rotation
    /// assert!(CameraPose::from_matrix(&m).unwrap_err().contains("not a rigid transform"));
    /// ```
    pub fn from_matrix(m: &[f64; 16]) -> std::result::Result<Self, String> {
        use glam::{DMat3, DQuat, DVec3};
        if m.iter().any(|v| !v.is_finite()) {
            return Err("the camera-to-world matrix has values that are not finite".into());
        }
        if m[12..] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "the camera-to-world matrix's last row must be [0, 0, 0, 1], not {:?}",
                &m[12..]
            ));
        }
        let col = |j: usize| DVec3::new(m[j], m[4 + j], m[8 + j]);
        let r = DMat3::from_cols(col(0), col(1), col(2));
        let off = (r.transpose() * r - DMat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f64, |a, v| a.max(v.abs()));
        if off > 1e-3 || r.determinant() <= 0.0 {
            return Err(format!(
                "the camera-to-world matrix is not a rigid transform: its rotation part is off \
                 orthonormal by {off:.2e}, with determinant {:.4}",
                r.determinant()
            ));
        }
        Ok(crate::frame::CameraPose {
            rotation: DQuat::from_mat3(&r).normalize(),
            translation: col(3),
        })
    }

    /// The pose as a row-major 4×4 camera-to-world matrix.
    pub fn to_matrix(&self) -> [f64; 16] {
        let r = glam::DMat3::from_quat(self.rotation);
        let t = self.translation;
        [
            r.x_axis.x, r.y_axis.x, r.z_axis.x, t.x, //
            r.x_axis.y, r.y_axis.y, r.z_axis.y, t.y, //
            r.x_axis.z, r.y_axis.z, r.z_axis.z, t.z, //
            0.0, 0.0, 0.0, 1.0,
        ]
    }
}

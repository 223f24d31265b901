//! What a live node publishes and is asked: `sensor_msgs/PointCloud2`,
//! `nav_msgs/Path`, `diagnostic_msgs/DiagnosticArray` and
//! `std_msgs/String`. Their sequences of structures are written out here
//! (the `cdr_message!` kinds cover flat types only), decode and encode
//! side by side.

use super::common::{Header, Pose};
use super::message::RosMessage;
use crate::cdr::{CdrError, CdrReader, CdrWriter};

/// One field of a [`PointCloud2`] point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PointField<'a> {
    /// Its name (`x`, `rgb`, `relevance`, ...).
    pub name: &'a str,
    /// Byte offset in the point.
    pub offset: u32,
    /// [`PointField::FLOAT32`] and kin.
    pub datatype: u8,
    /// Elements (1 for a scalar).
    pub count: u32,
}

impl PointField<'_> {
    /// `sensor_msgs/PointField` datatype of an `f32`.
    pub const FLOAT32: u8 = 7;
    /// `sensor_msgs/PointField` datatype of a `u32`.
    pub const UINT32: u8 = 6;
}

/// `sensor_msgs/PointCloud2`: an unordered cloud (`height` 1) of packed
/// points.
///
/// ```
/// use latentam_io::{Header, PointCloud2, PointField, RosMessage};
///
/// let fields = [PointField { name: "x", offset: 0, datatype: PointField::FLOAT32, count: 1 }];
/// let data = 1.5f32.to_le_bytes();
/// let cloud = PointCloud2::unordered(Header::at(7, "map"), &fields, 4, &data);
/// let bytes = cloud.encode();
/// let back = PointCloud2::decode(&bytes)?;
/// assert_eq!((back.width, back.fields[0].name, back.data), (1, "x", &data[..]));
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Debug)]
pub struct PointCloud2<'a> {
    /// Stamp and the frame of the points.
    pub header: Header<'a>,
    /// Rows (1: unordered).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// The fields of a point.
    pub fields: Vec<PointField<'a>>,
    /// Whether multi-byte fields are big-endian.
    pub is_bigendian: bool,
    /// Bytes per point.
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// `row_step × height` bytes.
    pub data: &'a [u8],
    /// Whether every point is finite.
    pub is_dense: bool,
}

impl<'a> PointCloud2<'a> {
    /// An unordered little-endian cloud of `data.len() / point_step`
    /// finite points.
    pub fn unordered(
        header: Header<'a>,
        fields: &[PointField<'a>],
        point_step: u32,
        data: &'a [u8],
    ) -> Self {
        let width = data.len() as u32 / point_step.max(1);
        PointCloud2 {
            header,
            height: 1,
            width,
            fields: fields.to_vec(),
            is_bigendian: false,
            point_step,
            row_step: width * point_step,
            data,
            is_dense: true,
        }
    }
}

impl<'a> RosMessage<'a> for PointCloud2<'a> {
    const TYPE_NAME: &'static str = "sensor_msgs/msg/PointCloud2";

    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        let height = r.read("height")?;
        let width = r.read("width")?;
        let n = r.sequence_len("fields", 13)?;
        let mut fields = Vec::with_capacity(n);
        for _ in 0..n {
            fields.push(PointField {
                name: r.string("fields.name")?,
                offset: r.read("fields.offset")?,
                datatype: r.read("fields.datatype")?,
                count: r.read("fields.count")?,
            });
        }
        Ok(PointCloud2 {
            header,
            height,
            width,
            fields,
            is_bigendian: r.read::<u8>("is_bigendian")? != 0,
            point_step: r.read("point_step")?,
            row_step: r.read("row_step")?,
            data: r.bytes("data")?,
            is_dense: r.read::<u8>("is_dense")? != 0,
        })
    }

    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.height);
        w.put(self.width);
        w.put(self.fields.len() as u32);
        for f in &self.fields {
            w.string(f.name);
            w.put(f.offset);
            w.put(f.datatype);
            w.put(f.count);
        }
        w.put(self.is_bigendian as u8);
        w.put(self.point_step);
        w.put(self.row_step);
        w.bytes(self.data);
        w.put(self.is_dense as u8);
    }
}

/// `nav_msgs/Path`: poses in order, each with its own stamp.
///
/// ```
/// use latentam_io::{Header, Path, Pose, RosMessage};
///
/// let path = Path { header: Header::at(9, "map"), poses: vec![(Header::at(1, "map"), Pose::IDENTITY)] };
/// let bytes = path.encode();
/// let back = Path::decode(&bytes)?;
/// assert_eq!(back.poses.len(), 1);
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Debug)]
pub struct Path<'a> {
    /// Stamp and frame of the path.
    pub header: Header<'a>,
    /// Each pose (`geometry_msgs/PoseStamped`).
    pub poses: Vec<(Header<'a>, Pose)>,
}

impl<'a> RosMessage<'a> for Path<'a> {
    const TYPE_NAME: &'static str = "nav_msgs/msg/Path";

    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        // A PoseStamped: a header (at least 12 bytes) and 56 of pose.
        let n = r.sequence_len("poses", 68)?;
        let mut poses = Vec::with_capacity(n);
        for _ in 0..n {
            poses.push((Header::decode(r)?, Pose::decode(r, "poses.pose")?));
        }
        Ok(Path { header, poses })
    }

    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.poses.len() as u32);
        for (h, p) in &self.poses {
            h.encode(w);
            p.encode(w);
        }
    }
}

/// One `diagnostic_msgs/DiagnosticStatus`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DiagnosticStatus<'a> {
    /// 0 OK, 1 WARN, 2 ERROR, 3 STALE.
    pub level: u8,
    /// What is reported on.
    pub name: &'a str,
    /// A one-line summary.
    pub message: &'a str,
    /// The hardware it runs on.
    pub hardware_id: &'a str,
    /// Key/value pairs.
    pub values: Vec<(&'a str, &'a str)>,
}

/// `diagnostic_msgs/DiagnosticArray`: how a node is doing, as key/value
/// pairs (`ros2 topic echo`, `rqt_robot_monitor` show them).
///
/// ```
/// use latentam_io::{DiagnosticArray, DiagnosticStatus, Header, RosMessage};
///
/// let status = DiagnosticStatus { level: 0, name: "mapper", message: "ok", hardware_id: "", values: vec![("keyframes", "3")] };
/// let msg = DiagnosticArray { header: Header::at(5, ""), status: vec![status] };
/// assert_eq!(DiagnosticArray::decode(&msg.encode())?.status[0].values, [("keyframes", "3")]);
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Debug)]
pub struct DiagnosticArray<'a> {
    /// Stamp.
    pub header: Header<'a>,
    /// One status per reported part.
    pub status: Vec<DiagnosticStatus<'a>>,
}

impl<'a> RosMessage<'a> for DiagnosticArray<'a> {
    const TYPE_NAME: &'static str = "diagnostic_msgs/msg/DiagnosticArray";

    fn decode_fields(r: &mut CdrReader<'a>) -> Result<Self, CdrError> {
        let header = Header::decode(r)?;
        let n = r.sequence_len("status", 17)?;
        let mut status = Vec::with_capacity(n);
        for _ in 0..n {
            let level = r.read("status.level")?;
            let name = r.string("status.name")?;
            let message = r.string("status.message")?;
            let hardware_id = r.string("status.hardware_id")?;
            let m = r.sequence_len("status.values", 8)?;
            let mut values = Vec::with_capacity(m);
            for _ in 0..m {
                values.push((r.string("values.key")?, r.string("values.value")?));
            }
            status.push(DiagnosticStatus {
                level,
                name,
                message,
                hardware_id,
                values,
            });
        }
        Ok(DiagnosticArray { header, status })
    }

    fn encode_fields(&self, w: &mut CdrWriter) {
        self.header.encode(w);
        w.put(self.status.len() as u32);
        for s in &self.status {
            w.put(s.level);
            w.string(s.name);
            w.string(s.message);
            w.string(s.hardware_id);
            w.put(s.values.len() as u32);
            for (k, v) in &s.values {
                w.string(k);
                w.string(v);
            }
        }
    }
}

/// `std_msgs/String`.
///
/// ```
/// use latentam_io::{RosMessage, StringMessage};
///
/// let bytes = StringMessage { data: "runs/today" }.encode();
/// let back = StringMessage::decode(&bytes)?;
/// assert_eq!(back.data, "runs/today");
/// # Ok::<(), latentam_io::cdr::CdrError>(())
/// ```
#[derive(Clone, Copy, Debug)]
pub struct StringMessage<'a> {
    /// The text.
    pub data: &'a str,
}

cdr_message! {
    StringMessage = "std_msgs/msg/String" {
        data: string,
    }
}

//! Files written through the foxglove crate read back with the `mcap`
//! crate: schemas, encodings, stamps and every packed byte.

use foxglove::messages::packed_element_field::NumericType;
use foxglove::messages::{PointCloud, PosesInFrame, RawImage, Timestamp};
use foxglove::{Decode, Encode};

use latentam_io::CameraPose;

use crate::{point_cloud, write_foxglove_file, Cloud, PointValue, RgbImage};

fn temp_file(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("latentam-view-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join("out.mcap")
}

#[test]
fn a_file_reads_back_with_its_fields_schemas_and_stamps() {
    let path = temp_file("fields");
    let positions = [[1.0, -2.0, 3.5], [0.25, 0.5, 0.75]];
    let colours = [[1, 2, 3, 4], [250, 251, 252, 253]];
    let values = [0.5, -7.0];
    let pose = CameraPose {
        rotation: glam::DQuat::IDENTITY,
        translation: glam::DVec3::new(1.0, 2.0, 3.0),
    };
    let rgb: Vec<u8> = (0..2 * 3 * 3).map(|i| i as u8).collect();
    let cloud = Cloud {
        positions: &positions,
        colours: &colours,
        value: ("relevance", &values),
    };
    write_foxglove_file(&path, "map", |topics| {
        topics.cloud("/c", 1_500_000_000, &cloud)?;
        topics.poses("/p", 2_000_000_001, &[pose, pose])?;
        let image = RgbImage {
            width: 3,
            height: 2,
            rgb: &rgb,
        };
        topics.image("/i", "camera", 3, &image)?;
        Ok(())
    })
    .unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let messages: Vec<_> = mcap::MessageStream::new(&bytes)
        .unwrap()
        .map(Result::unwrap)
        .collect();
    assert_eq!(messages.len(), 3);
    for (m, name) in messages.iter().zip([
        "foxglove.PointCloud",
        "foxglove.PosesInFrame",
        "foxglove.RawImage",
    ]) {
        let schema = m.channel.schema.as_ref().unwrap();
        assert_eq!(
            (schema.name.as_str(), schema.encoding.as_str()),
            (name, "protobuf")
        );
        assert_eq!(m.channel.message_encoding, "protobuf");
    }
    let cloud_msg = &messages[0];
    assert_eq!(cloud_msg.log_time, 1_500_000_000);
    let c = PointCloud::decode(&cloud_msg.data[..]).unwrap();
    assert_eq!(c.timestamp, Some(Timestamp::new(1, 500_000_000)));
    assert_eq!(c.frame_id, "map");
    let stride = PointValue::Float32.stride();
    assert_eq!(
        (c.point_stride as usize, c.data.len()),
        (stride, 2 * stride)
    );
    let data = &c.data;
    let at = |name: &str| {
        let f = c.fields.iter().find(|f| f.name == name).unwrap();
        f.offset as usize
    };
    let f32_at = |i: usize, off: usize| {
        f32::from_le_bytes(data[i * stride + off..][..4].try_into().unwrap())
    };
    for i in 0..2 {
        assert_eq!(f32_at(i, at("x")), positions[i][0]);
        assert_eq!(f32_at(i, at("z")), positions[i][2]);
        assert_eq!(f32_at(i, at("relevance")), values[i]);
        assert_eq!(data[i * stride + at("blue")], colours[i][2]);
        assert_eq!(data[i * stride + at("alpha")], colours[i][3]);
    }
    let p = PosesInFrame::decode(&messages[1].data[..]).unwrap();
    assert_eq!(p.poses.len(), 2);
    assert_eq!(p.poses[1].position.as_ref().unwrap().z, 3.0);
    assert_eq!(p.timestamp, Some(Timestamp::new(2, 1)));
    let i = RawImage::decode(&messages[2].data[..]).unwrap();
    assert_eq!((i.width, i.height, i.step), (3, 2, 9));
    assert_eq!(
        (i.frame_id.as_str(), i.encoding.as_str()),
        ("camera", "rgb8")
    );
    assert_eq!(&i.data[..], &rgb[..]);
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

/// The live view's packing: a byte per value, 17 bytes a point, values
/// clamped to [0, 1] and rounded.
#[test]
fn byte_values_pack_seventeen_bytes_a_point() {
    let values = [0.0, 0.5, 1.0, -3.0, 7.0, f32::NAN, 0.2];
    let n = values.len();
    let positions: Vec<[f32; 3]> = (0..n).map(|i| [i as f32, 0.5, -1.0]).collect();
    let colours: Vec<[u8; 4]> = (0..n).map(|i| [i as u8, 9, 8, 7]).collect();
    let cloud = Cloud {
        positions: &positions,
        colours: &colours,
        value: ("opacity", &values),
    };
    let m = point_cloud("map", 0, &cloud, PointValue::Unorm8).unwrap();
    assert_eq!((m.point_stride, m.data.len()), (17, 17 * n));
    let field = m.fields.iter().find(|f| f.name == "opacity").unwrap();
    assert_eq!(field.offset, 16);
    assert_eq!(field.r#type, NumericType::Uint8 as i32);
    let got: Vec<u8> = (0..n).map(|i| m.data[i * 17 + 16]).collect();
    assert_eq!(got, [0, 128, 255, 0, 255, 0, 51]);
    for i in 0..n {
        let x = f32::from_le_bytes(m.data[i * 17..][..4].try_into().unwrap());
        assert_eq!(x, i as f32);
        assert_eq!(m.data[i * 17 + 12], i as u8);
    }
    // Encoded, the message is the points and a fixed header.
    let mut bytes = Vec::new();
    m.encode(&mut bytes).unwrap();
    assert!(bytes.len() < 17 * n + 200, "{} bytes", bytes.len());
}

#[test]
fn a_failing_body_leaves_no_file_and_bad_shapes_are_refused() {
    let path = temp_file("fail");
    let err = write_foxglove_file(&path, "map", |topics| {
        let cloud = Cloud {
            positions: &[[0.0; 3]; 2],
            colours: &[[0; 4]],
            value: ("v", &[0.0, 0.0]),
        };
        topics.cloud("/c", 0, &cloud)?;
        Ok(())
    })
    .unwrap_err();
    assert!(err.to_string().contains("2 positions, 1 colours"), "{err}");
    assert!(!path.exists());
    let err = write_foxglove_file(&path, "map", |topics| {
        let image = RgbImage {
            width: 4,
            height: 4,
            rgb: &[0; 10],
        };
        topics.image("/i", "camera", 0, &image)?;
        Ok(())
    })
    .unwrap_err();
    assert!(
        err.to_string().contains("4x4 RGB image of 10 bytes"),
        "{err}"
    );
    assert!(!path.exists());
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
}

/// Takes `room` bytes, then fails every write (a full disk).
struct FillsUp {
    room: usize,
}

impl std::io::Write for FillsUp {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.room == 0 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::StorageFull,
                "no space",
            ));
        }
        let n = buf.len().min(self.room);
        self.room -= n;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_write_that_failed_once_fails_the_file() {
    use std::io::Write as _;
    let latch = crate::file::Latched::new(FillsUp { room: 10 });
    let mut w = latch.clone();
    assert!(w.write_all(&[0u8; 100]).is_err());
    // A later flush that the writer itself would let through still fails,
    // and so does the file.
    assert!(w.flush().is_err());
    let err = latch.result("map.mcap".as_ref()).unwrap_err();
    assert!(matches!(err, latentam_base::Error::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("no space"), "{err}");
}

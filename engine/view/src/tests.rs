//! Files written through the foxglove crate read back with the `mcap`
//! crate: schemas, encodings, stamps and every packed byte.

use base64::Engine as _;
use serde_json::{json, Value};

use latentam_io::CameraPose;

use crate::schemas::{POINT_CLOUD, POSES_IN_FRAME, RAW_IMAGE};
use crate::{write_foxglove_file, Cloud, RgbImage, CLOUD_POINT_STRIDE};

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
    write_foxglove_file(&path, "map", |topics| {
        let cloud = Cloud {
            positions: &positions,
            colours: &colours,
            value: ("relevance", &values),
        };
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
    let cloud_msg = &messages[0];
    let schema = cloud_msg.channel.schema.as_ref().unwrap();
    assert_eq!(
        (schema.name.as_str(), schema.encoding.as_str()),
        (POINT_CLOUD, "jsonschema")
    );
    assert_eq!(cloud_msg.channel.message_encoding, "json");
    assert_eq!(cloud_msg.log_time, 1_500_000_000);
    let v: Value = serde_json::from_slice(&cloud_msg.data).unwrap();
    assert_eq!(v["timestamp"], json!({ "sec": 1, "nsec": 500_000_000 }));
    assert_eq!(v["frame_id"], "map");
    assert_eq!(v["point_stride"], CLOUD_POINT_STRIDE);
    let data = base64::engine::general_purpose::STANDARD
        .decode(v["data"].as_str().unwrap())
        .unwrap();
    assert_eq!(data.len(), 2 * CLOUD_POINT_STRIDE);
    let fields = v["fields"].as_array().unwrap();
    let at = |name: &str| {
        fields.iter().find(|f| f["name"] == name).unwrap()["offset"]
            .as_u64()
            .unwrap() as usize
    };
    let f32_at = |i: usize, off: usize| {
        f32::from_le_bytes(
            data[i * CLOUD_POINT_STRIDE + off..][..4]
                .try_into()
                .unwrap(),
        )
    };
    for i in 0..2 {
        assert_eq!(f32_at(i, at("x")), positions[i][0]);
        assert_eq!(f32_at(i, at("z")), positions[i][2]);
        assert_eq!(f32_at(i, at("relevance")), values[i]);
        assert_eq!(data[i * CLOUD_POINT_STRIDE + at("blue")], colours[i][2]);
        assert_eq!(data[i * CLOUD_POINT_STRIDE + at("alpha")], colours[i][3]);
    }
    let p: Value = serde_json::from_slice(&messages[1].data).unwrap();
    assert_eq!(
        messages[1].channel.schema.as_ref().unwrap().name,
        POSES_IN_FRAME
    );
    assert_eq!(p["poses"].as_array().unwrap().len(), 2);
    assert_eq!(p["poses"][1]["position"]["z"], 3.0);
    assert_eq!(p["timestamp"], json!({ "sec": 2, "nsec": 1 }));
    let i: Value = serde_json::from_slice(&messages[2].data).unwrap();
    assert_eq!(messages[2].channel.schema.as_ref().unwrap().name, RAW_IMAGE);
    assert_eq!(
        (
            i["width"].as_u64(),
            i["height"].as_u64(),
            i["step"].as_u64()
        ),
        (Some(3), Some(2), Some(9))
    );
    assert_eq!(i["frame_id"], "camera");
    let pixels = base64::engine::general_purpose::STANDARD
        .decode(i["data"].as_str().unwrap())
        .unwrap();
    assert_eq!(pixels, rgb);
    std::fs::remove_dir_all(path.parent().unwrap()).unwrap();
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

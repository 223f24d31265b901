//! `ros2msg` schema texts for every message type the engine reads or writes.
//!
//! A schema in an MCAP file is the message's own definition followed by the
//! definitions of every type it uses, each after a line of 80 `=` and a
//! `MSG: pkg/Type` line — the layout ROS 2's rosbag2 writes, so the logs the
//! engine writes open in Foxglove and ROS 2 tools. The engine's own types
//! live as `.msg` files under `engine/msg/`.

/// Definitions without comments for the standard types (ROS 2 Humble and
/// later; the field layout is what CDR decoding relies on).
const DEFINITIONS: &[(&str, &str)] = &[
    ("builtin_interfaces/msg/Time", "int32 sec\nuint32 nanosec\n"),
    (
        "std_msgs/msg/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    (
        "sensor_msgs/msg/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\n\
         uint8 is_bigendian\nuint32 step\nuint8[] data\n",
    ),
    (
        "sensor_msgs/msg/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    (
        "sensor_msgs/msg/RegionOfInterest",
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    ),
    (
        "sensor_msgs/msg/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n\
         float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n\
         uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
    ),
    (
        "geometry_msgs/msg/Point",
        "float64 x\nfloat64 y\nfloat64 z\n",
    ),
    (
        "geometry_msgs/msg/Vector3",
        "float64 x\nfloat64 y\nfloat64 z\n",
    ),
    (
        "geometry_msgs/msg/Quaternion",
        "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    ),
    (
        "geometry_msgs/msg/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    ),
    (
        "geometry_msgs/msg/PoseStamped",
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    ),
    (
        "geometry_msgs/msg/PoseWithCovariance",
        "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    ),
    (
        "geometry_msgs/msg/Twist",
        "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    ),
    (
        "geometry_msgs/msg/TwistWithCovariance",
        "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    ),
    (
        "nav_msgs/msg/Odometry",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n\
         geometry_msgs/TwistWithCovariance twist\n",
    ),
    (
        "geometry_msgs/msg/Transform",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    ),
    (
        "geometry_msgs/msg/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    ),
    (
        "tf2_msgs/msg/TFMessage",
        "geometry_msgs/TransformStamped[] transforms\n",
    ),
    (
        "latentam_msgs/msg/MaskFeatures",
        include_str!("../../msg/latentam_msgs/msg/MaskFeatures.msg"),
    ),
    (
        "latentam_msgs/msg/FeatureGrid",
        include_str!("../../msg/latentam_msgs/msg/FeatureGrid.msg"),
    ),
    (
        "latentam_msgs/msg/TextEmbeddings",
        include_str!("../../msg/latentam_msgs/msg/TextEmbeddings.msg"),
    ),
];

/// `pkg/Type` or `pkg/msg/Type` → `pkg/msg/Type`; anything else unchanged.
pub fn normalize_type_name(name: &str) -> String {
    let name = name.trim();
    match name.split('/').collect::<Vec<_>>().as_slice() {
        [pkg, ty] => format!("{pkg}/msg/{ty}"),
        _ => name.to_string(),
    }
}

fn short_name(full: &str) -> String {
    full.replacen("/msg/", "/", 1)
}

fn definition(full: &str) -> Option<&'static str> {
    DEFINITIONS
        .iter()
        .find(|(n, _)| *n == full)
        .map(|(_, d)| *d)
}

/// The types a definition's fields use (package-qualified ones only).
fn field_types(def: &str) -> impl Iterator<Item = String> + '_ {
    def.lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty() && !l.contains('='))
        .filter_map(|l| l.split_whitespace().next())
        .map(|t| t.split('[').next().unwrap_or(t))
        .filter(|t| t.contains('/'))
        .map(normalize_type_name)
}

/// The full `ros2msg` schema text for a type, dependencies included, or
/// `None` for a type the engine does not know.
pub fn schema_text(type_name: &str) -> Option<String> {
    let root = normalize_type_name(type_name);
    let mut text = definition(&root)?.to_string();
    let mut done = vec![root.clone()];
    let mut todo: Vec<String> = field_types(definition(&root)?).collect();
    while let Some(ty) = todo.first().cloned() {
        todo.remove(0);
        if done.contains(&ty) {
            continue;
        }
        let def = definition(&ty)?;
        text.push_str(&"=".repeat(80));
        text.push_str(&format!("\nMSG: {}\n", short_name(&ty)));
        text.push_str(def);
        todo.extend(field_types(def));
        done.push(ty);
    }
    Some(text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_dependency_is_defined_and_texts_are_ascii() {
        for (name, def) in DEFINITIONS {
            assert!(def.is_ascii(), "{name}");
            let text =
                schema_text(name).unwrap_or_else(|| panic!("{name} has an unknown dependency"));
            for dep in field_types(def) {
                assert!(
                    text.contains(&format!("MSG: {}\n", short_name(&dep))),
                    "{name} lacks {dep}"
                );
            }
        }
        let camera_info = schema_text("sensor_msgs/CameraInfo").unwrap();
        assert!(camera_info.starts_with("std_msgs/Header header\n"));
        assert_eq!(camera_info.matches("MSG: ").count(), 3, "{camera_info}");
        assert_eq!(normalize_type_name("a/B"), "a/msg/B");
        assert_eq!(normalize_type_name("a/msg/B"), "a/msg/B");
        assert!(schema_text("foo/msg/Bar").is_none());
    }
}

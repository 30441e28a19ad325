//! Built-in ROS 2 definitions of the message types robot recordings use, for bags that carry no
//! definitions (rosbag2's sqlite3 storage before Jazzy): images (raw and compressed), camera
//! intrinsics, joint states, poses, transforms and text. Field order is ROS 2's (its
//! `std_msgs/Header` has no `seq`); a bag's own definitions always win.

use crate::ingest::msgdef::{DefinitionError, MessageDefs};

/// (type, definition) of every built-in type.
const TYPES: &[(&str, &str)] = &[
    ("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
    (
        "std_msgs/Header",
        "builtin_interfaces/Time stamp\nstring frame_id\n",
    ),
    ("std_msgs/String", "string data\n"),
    (
        "sensor_msgs/Image",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
    ),
    (
        "sensor_msgs/CompressedImage",
        "std_msgs/Header header\nstring format\nuint8[] data\n",
    ),
    (
        "sensor_msgs/RegionOfInterest",
        "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
    ),
    (
        "sensor_msgs/CameraInfo",
        "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nsensor_msgs/RegionOfInterest roi\n",
    ),
    (
        "sensor_msgs/JointState",
        "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\nfloat64[] effort\n",
    ),
    ("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
    ("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
    (
        "geometry_msgs/Quaternion",
        "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n",
    ),
    (
        "geometry_msgs/Pose",
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n",
    ),
    (
        "geometry_msgs/PoseStamped",
        "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    ),
    (
        "geometry_msgs/Transform",
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n",
    ),
    (
        "geometry_msgs/TransformStamped",
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n",
    ),
    (
        "tf2_msgs/TFMessage",
        "geometry_msgs/TransformStamped[] transforms\n",
    ),
];

/// The built-in definitions (ROS 2).
pub fn ros2_types() -> Result<MessageDefs, DefinitionError> {
    let mut defs = MessageDefs::default();
    for (name, text) in TYPES {
        defs.add(name, text)?;
    }
    for (name, _) in TYPES {
        defs.check(name)?;
    }
    Ok(defs)
}

/// The names of the built-in types.
pub fn names() -> impl Iterator<Item = &'static str> {
    TYPES.iter().map(|(name, _)| *name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ingest::decode::{RosValue, Wire, decode};

    #[test]
    fn every_builtin_type_is_complete() {
        let defs = ros2_types().expect("built-in definitions");
        for name in names() {
            assert!(defs.knows(name), "{name}");
        }
    }

    #[test]
    fn a_joint_state_decodes() {
        let defs = ros2_types().expect("built-in definitions");
        let mut b = vec![0, 1, 0, 0];
        b.extend(3i32.to_le_bytes());
        b.extend(9u32.to_le_bytes());
        b.extend(1u32.to_le_bytes()); // frame_id "" (the NUL)
        b.push(0);
        b.extend([0, 0, 0]);
        b.extend(1u32.to_le_bytes()); // one name
        b.extend(4u32.to_le_bytes());
        b.extend(b"jaw\0");
        b.extend(1u32.to_le_bytes()); // one position (offset 28; its f64 at 32, aligned)
        b.extend(0.25f64.to_le_bytes());
        b.extend(0u32.to_le_bytes());
        b.extend(0u32.to_le_bytes());
        let value = decode(&defs, "sensor_msgs/JointState", Wire::Cdr, &b).expect("decode");
        assert_eq!(
            value.at("header.stamp").and_then(RosValue::as_time_ns),
            Some(3_000_000_009)
        );
        assert_eq!(
            value.at("position"),
            Some(&RosValue::Array(vec![RosValue::Float(0.25)]))
        );
        assert_eq!(value.at("effort"), Some(&RosValue::Array(Vec::new())));
    }
}

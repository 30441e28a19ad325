//! Helpers shared by the integration tests.

use nalgebra::{Isometry3, Translation3};
use surgvla::sim::psm::pointing_down;
use surgvla::sim::scene::TRAY_TOP_Z_M;
use surgvla::sim::{ObjectKind, ObjectSpec, SceneSpec, SimConfig, Simulator};

/// A scene with one object of each kind, resting on the tray (or `drop_m` above it).
pub fn three_objects(drop_m: f64) -> SceneSpec {
    let place = |name: &str, kind: ObjectKind, x: f64, y: f64| ObjectSpec {
        name: name.to_string(),
        kind,
        world_from_object: Isometry3::translation(
            x,
            y,
            TRAY_TOP_Z_M + kind.rest_height_m() + drop_m,
        ),
    };
    SceneSpec {
        objects: vec![
            place("gauze", ObjectKind::Gauze, 0.55, 0.0),
            place("needle", ObjectKind::Needle, 0.52, -0.03),
            place("block", ObjectKind::Block, 0.58, 0.03),
        ],
        organs: Vec::new(),
    }
}

pub fn simulator(scene: SceneSpec) -> Simulator {
    Simulator::new(SimConfig::default(), scene)
}

/// A pointing-down tip pose.
pub fn tip_at(x: f64, y: f64, z: f64, yaw_rad: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), pointing_down(yaw_rad))
}

//! Helpers shared by the integration tests.

use nalgebra::{Isometry3, Translation3};
use surgvla::sim::psm::pointing_down;
use surgvla::sim::{SceneSpec, SimConfig, Simulator};

/// A scene with one object of each kind, resting on the tray (or `drop_m` above it).
pub fn three_objects(drop_m: f64) -> SceneSpec {
    SceneSpec::one_of_each(drop_m)
}

pub fn simulator(scene: SceneSpec) -> Simulator {
    Simulator::new(SimConfig::default(), scene)
}

/// A pointing-down tip pose.
pub fn tip_at(x: f64, y: f64, z: f64, yaw_rad: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), pointing_down(yaw_rad))
}

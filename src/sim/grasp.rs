//! The grasp binding rule that replaces contact grasping for small objects.
//!
//! Binding happens when the jaws start closing with the tip within `max_vertical_m` of an
//! object's grasp point vertically and `max_horizontal_m` horizontally; a needle also needs the
//! jaws to cross its wire: the wire's tangent at the grasp point must run along the reported tip
//! frame's local z axis (the jaws close along local x) within `needle_yaw_tolerance_rad`.
//! While bound the object follows the tip rigidly; opening the jaws releases it.

use crate::scene::ObjectKind;
use nalgebra::{Isometry3, Vector3};
use std::f64::consts::{FRAC_PI_2, PI};

/// Thresholds of the binding rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraspRule {
    /// Largest vertical distance between the tip and the grasp point, metres (either side).
    pub max_vertical_m: f64,
    /// Largest horizontal distance between the tip and the grasp point, metres.
    pub max_horizontal_m: f64,
    /// Largest angle between the needle's tangent and the jaws' crossing axis, radians.
    pub needle_yaw_tolerance_rad: f64,
}

impl Default for GraspRule {
    fn default() -> Self {
        GraspRule {
            max_vertical_m: 0.003,
            max_horizontal_m: 0.009,
            needle_yaw_tolerance_rad: 20f64.to_radians(),
        }
    }
}

/// Angle between two undirected horizontal lines given by their angles, in [0, pi/2].
pub fn line_angle_difference(a_rad: f64, b_rad: f64) -> f64 {
    let d = (a_rad - b_rad).rem_euclid(PI);
    d.min(PI - d)
}

impl GraspRule {
    /// Whether an object of `kind` whose grasp frame is `world_from_grasp` binds to a tip at
    /// `tip_position_m` with yaw `tip_yaw_rad` (third Euler xyz angle of the reported tip frame).
    pub fn binds(
        &self,
        tip_position_m: &Vector3<f64>,
        tip_yaw_rad: f64,
        kind: ObjectKind,
        world_from_grasp: &Isometry3<f64>,
    ) -> bool {
        let offset = tip_position_m - world_from_grasp.translation.vector;
        let horizontal = (offset.x * offset.x + offset.y * offset.y).sqrt();
        if offset.z.abs() > self.max_vertical_m || horizontal > self.max_horizontal_m {
            return false;
        }
        match kind {
            ObjectKind::Needle => {
                let tangent = world_from_grasp.rotation * Vector3::x();
                if tangent.z.abs() > 0.9 {
                    return false;
                }
                let tangent_angle = tangent.y.atan2(tangent.x);
                line_angle_difference(tangent_angle, tip_yaw_rad + FRAC_PI_2)
                    <= self.needle_yaw_tolerance_rad
            }
            ObjectKind::Gauze | ObjectKind::Block => true,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion};

    fn at(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        )
    }

    #[test]
    fn gauze_binds_inside_and_not_outside_the_box() {
        let rule = GraspRule::default();
        let object = at(0.55, 0.0, 0.68, 0.0);
        let binds = |dx: f64, dz: f64| {
            rule.binds(
                &Vector3::new(0.55 + dx, 0.0, 0.68 + dz),
                0.0,
                ObjectKind::Gauze,
                &object,
            )
        };
        assert!(binds(0.0, 0.0029));
        assert!(binds(0.0089, 0.0));
        assert!(!binds(0.0, 0.004));
        assert!(!binds(0.010, 0.0));
    }

    #[test]
    fn needle_needs_the_jaws_across_the_wire() {
        let rule = GraspRule::default();
        // Needle tangent along world x: the jaws must close along y, i.e. tip yaw = +-pi/2.
        let needle = at(0.55, 0.0, 0.68, 0.0);
        let tip = Vector3::new(0.55, 0.0, 0.681);
        assert!(rule.binds(&tip, FRAC_PI_2, ObjectKind::Needle, &needle));
        assert!(rule.binds(&tip, -FRAC_PI_2 + 0.3, ObjectKind::Needle, &needle));
        assert!(!rule.binds(&tip, 0.0, ObjectKind::Needle, &needle));
        assert!(!rule.binds(&tip, FRAC_PI_2 + 0.4, ObjectKind::Needle, &needle));
    }

    #[test]
    fn line_angle_difference_is_undirected() {
        assert!(line_angle_difference(0.1, 0.1 + PI).abs() < 1e-12);
        assert!((line_angle_difference(0.0, FRAC_PI_2) - FRAC_PI_2).abs() < 1e-12);
    }
}

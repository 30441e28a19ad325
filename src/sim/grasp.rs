//! The grasp binding rule that replaces contact grasping for small objects.
//!
//! Binding happens when the jaws start closing on the object itself: with the tip at most
//! `max_gap_above_m` above the object's surface where they close, or at most
//! `max_depth_m` into it. A gauze (or block) binds when the tip is over its footprint and
//! that close to its top face (above it, or pressed into the soft pad); a needle binds when the
//! tip is that close to the nearest point of its wire, anywhere along the arc but not past
//! either end, with the jaws across the wire's tangent at that point (the tangent along the
//! reported tip frame's local z axis: the jaws close along local x) within
//! `needle_yaw_tolerance_rad`. Jaws closing in the air above an object, past the needle's end,
//! or inside its arc where no wire is, bind nothing. While bound the object follows the tip rigidly, keeping
//! the point grasped; opening the jaws releases it.

use crate::scene::{
    BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, NEEDLE_ARC_RADIUS_M, NEEDLE_WIRE_RADIUS_M,
    ObjectKind,
};
use nalgebra::{Isometry3, Point3, Vector3};
use std::f64::consts::{FRAC_PI_2, PI};

/// Thresholds of the binding rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GraspRule {
    /// Largest height of the tip above the object's surface where the jaws close, metres.
    pub max_gap_above_m: f64,
    /// Deepest the tip may be pressed into the object where the jaws close, metres.
    pub max_depth_m: f64,
    /// Largest angle between the needle's tangent at the grasped point and the jaws' crossing
    /// axis, radians.
    pub needle_yaw_tolerance_rad: f64,
}

impl Default for GraspRule {
    /// 0.4 mm above the surface: the depth of the teeth of a needle driver's or grasper's jaw
    /// tips (about 0.4 mm on an 8 mm instrument), which is as high as closing jaws still bite
    /// an object's surface; 1 mm into it: the gauze pad gives that much under the jaws (the
    /// expert presses 0.8 mm). Needles up to 45 deg oblique: surgeons load a needle square to
    /// the jaws or at an angle for backhand and angled bites; along the wire it slips.
    fn default() -> Self {
        GraspRule {
            max_gap_above_m: 0.0004,
            max_depth_m: 0.001,
            needle_yaw_tolerance_rad: 45f64.to_radians(),
        }
    }
}

/// Angle between two undirected horizontal lines given by their angles, in [0, pi/2].
pub fn line_angle_difference(a_rad: f64, b_rad: f64) -> f64 {
    let d = (a_rad - b_rad).rem_euclid(PI);
    d.min(PI - d)
}

/// The point of the needle's wire centre line nearest to `point` (both in the grasp frame:
/// the arc's centre at (0, -R, 0), the half circle on the side y >= -R) and the wire's unit
/// tangent there.
pub fn nearest_wire_point(point: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let r = NEEDLE_ARC_RADIUS_M;
    let theta = wire_angle(point).clamp(0.0, PI);
    let (sin, cos) = theta.sin_cos();
    (
        Vector3::new(r * cos, r * sin - r, 0.0),
        Vector3::new(-sin, cos, 0.0),
    )
}

/// How far beside the needle's wire, horizontally, closing jaws still sweep it in, metres.
const NEEDLE_REACH_M: f64 = 0.0015;

/// The angle of `point` (grasp frame) about the needle arc's centre: within [0, pi] beside the
/// wire, outside it past either end.
fn wire_angle(point: &Vector3<f64>) -> f64 {
    let angle = (point.y + NEEDLE_ARC_RADIUS_M).atan2(point.x);
    // The ends are at 0 and pi; below the centre, atan2's (-pi, 0) is past one end or the other.
    if angle < -FRAC_PI_2 {
        angle + 2.0 * PI
    } else {
        angle
    }
}

impl GraspRule {
    /// How far the tip at `tip_position_m` is from the surface of an object of `kind` whose
    /// grasp frame is `world_from_grasp`, where the jaws would close on it (metres, negative
    /// inside), and, for the needle, the wire's tangent there (world). None when the tip is not
    /// over a gauze's or block's footprint.
    fn surface_gap(
        &self,
        tip_position_m: &Vector3<f64>,
        kind: ObjectKind,
        world_from_grasp: &Isometry3<f64>,
    ) -> Option<(f64, Option<Vector3<f64>>)> {
        let local = world_from_grasp
            .inverse_transform_point(&Point3::from(*tip_position_m))
            .coords;
        let half = match kind {
            ObjectKind::Needle => {
                if !(0.0..=PI).contains(&wire_angle(&local)) {
                    // Past an end: the jaws would close on air beyond the wire's tip.
                    return None;
                }
                let (wire, tangent) = nearest_wire_point(&local);
                let offset = local - wire;
                // Above the wire's top the jaw tips close over it; beside it, within reach,
                // the closing jaws sweep it in.
                let beside = offset.xy().norm();
                if beside > NEEDLE_REACH_M || offset.z < -NEEDLE_WIRE_RADIUS_M - self.max_depth_m {
                    return None;
                }
                let gap = offset.z - NEEDLE_WIRE_RADIUS_M;
                return Some((gap, Some(world_from_grasp.rotation * tangent)));
            }
            ObjectKind::Gauze => GAUZE_HALF_EXTENTS_M,
            ObjectKind::Block => BLOCK_HALF_EXTENTS_M,
        };
        (local.x.abs() <= half[0] && local.y.abs() <= half[1]).then_some((local.z - half[2], None))
    }

    /// The tip's distance from the object's surface if the jaws closing now at
    /// `tip_position_m` with yaw `tip_yaw_rad` (third Euler xyz angle of the reported tip frame)
    /// would bind the object, else None.
    pub fn binding_gap(
        &self,
        tip_position_m: &Vector3<f64>,
        tip_yaw_rad: f64,
        kind: ObjectKind,
        world_from_grasp: &Isometry3<f64>,
    ) -> Option<f64> {
        let (gap, tangent) = self.surface_gap(tip_position_m, kind, world_from_grasp)?;
        if gap > self.max_gap_above_m || gap < -self.max_depth_m {
            return None;
        }
        if let Some(tangent) = tangent {
            if tangent.z.abs() > 0.9 {
                return None;
            }
            let across = line_angle_difference(tangent.y.atan2(tangent.x), tip_yaw_rad + FRAC_PI_2);
            if across > self.needle_yaw_tolerance_rad {
                return None;
            }
        }
        Some(gap.abs())
    }

    /// Whether the jaws closing now would bind the object (see [`GraspRule::binding_gap`]).
    pub fn binds(
        &self,
        tip_position_m: &Vector3<f64>,
        tip_yaw_rad: f64,
        kind: ObjectKind,
        world_from_grasp: &Isometry3<f64>,
    ) -> bool {
        self.binding_gap(tip_position_m, tip_yaw_rad, kind, world_from_grasp)
            .is_some()
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

    /// A tip at the gauze's top face over its footprint binds it, pressed into the pad or
    /// just above it; closing in the air above it, beside it, or at its bottom does not.
    #[test]
    fn gauze_binds_only_where_the_jaws_close_on_its_top_face() {
        let rule = GraspRule::default();
        let object = at(0.55, 0.0, 0.68, 0.3);
        let top = GAUZE_HALF_EXTENTS_M[2];
        let binds = |x: f64, y: f64, z: f64| {
            let tip = object * Point3::new(x, y, z);
            rule.binds(&tip.coords, 0.0, ObjectKind::Gauze, &object)
        };
        // Honest: on the face (the expert closes 0.8 mm into it), at a corner of the footprint
        // with the jaw tips' teeth on the cloth.
        assert!(binds(0.0, 0.0, top));
        assert!(binds(0.0, 0.0, 0.0005));
        assert!(binds(0.007, -0.012, top + 0.0003));
        // Dishonest: 0.9, 1.5 and 3 mm above the face, 1 mm beyond its edge, through the pad.
        assert!(!binds(0.0, 0.0, top + 0.0009));
        assert!(!binds(0.0, 0.0, top + 0.0015));
        assert!(!binds(0.0, 0.0, top + 0.003));
        assert!(!binds(0.0085, 0.0, top));
        assert!(!binds(0.0, 0.0, -top));
    }

    /// The needle binds where the tip closes on its wire, anywhere along the arc, with the jaws
    /// across the tangent there; not above the wire, not inside the arc where no wire is, not
    /// with the jaws along the wire.
    #[test]
    fn needle_binds_on_its_wire_anywhere_along_the_arc_with_the_jaws_across_it() {
        let rule = GraspRule::default();
        let needle = at(0.55, 0.0, 0.68, 0.4);
        let r = NEEDLE_ARC_RADIUS_M;
        // A point theta along the arc (pi/2: the midpoint), lifted by `dz`, and the tip yaw
        // whose jaws cross the tangent there (the tangent along the tip's local z).
        let grasp = |theta: f64, inward_m: f64, dz: f64, yaw_off: f64| {
            let radial = r - inward_m;
            let local = Vector3::new(radial * theta.cos(), radial * theta.sin() - r, dz);
            let tangent = needle.rotation * Vector3::new(-theta.sin(), theta.cos(), 0.0);
            let yaw = tangent.y.atan2(tangent.x) - FRAC_PI_2 + yaw_off;
            rule.binds(
                &(needle * Point3::from(local)).coords,
                yaw,
                ObjectKind::Needle,
                &needle,
            )
        };
        let midpoint = FRAC_PI_2;
        // 10 mm along the arc from the midpoint (a third along a 63 mm needle): 0.5 rad.
        let third = FRAC_PI_2 - 0.010 / r;
        assert!(grasp(midpoint, 0.0, 0.0, 0.0));
        assert!(grasp(midpoint, 0.0, 0.0008, 0.3));
        assert!(grasp(third, 0.0, 0.0005, 0.0));
        assert!(grasp(third, 0.0, 0.0, -0.3));
        // Oblique grasps a surgeon uses: at the third with the jaws set for the midpoint's
        // tangent (29 deg off), and 40 deg off.
        assert!(grasp(third, 0.0, 0.0, midpoint - third));
        assert!(grasp(midpoint, 0.0, 0.0, 40f64.to_radians()));
        // 0.9, 2 and 3 mm above the wire's top; 8 mm inside the arc; jaws along the wire, or
        // 60 deg off across it.
        assert!(!grasp(midpoint, 0.0, 0.0014, 0.0));
        assert!(!grasp(midpoint, 0.0, 0.0025, 0.0));
        assert!(!grasp(midpoint, 0.0, 0.0035, 0.0));
        assert!(!grasp(midpoint, 0.008, 0.0, 0.0));
        assert!(!grasp(third, 0.0, 0.0, FRAC_PI_2));
        assert!(!grasp(midpoint, 0.0, 0.0, 60f64.to_radians()));
    }

    /// Near a needle's end the jaws bind on the wire; 0.1 to 0.9 mm past the end, in the air,
    /// they do not, though the end is within reach.
    #[test]
    fn a_needle_does_not_bind_past_its_end() {
        let rule = GraspRule::default();
        let needle = at(0.55, 0.0, 0.68, 0.0);
        // The end at theta = 0: (R, -R, 0) in the grasp frame, its tangent along y; the jaws
        // across it close along y (tip yaw 0).
        let r = NEEDLE_ARC_RADIUS_M;
        let binds = |local: Vector3<f64>| {
            rule.binds(
                &(needle * Point3::from(local)).coords,
                0.0,
                ObjectKind::Needle,
                &needle,
            )
        };
        assert!(binds(Vector3::new(r, -r + 0.0005, 0.0)));
        assert!(binds(Vector3::new(r, -r, 0.0)));
        for past in [0.0001, 0.0005, 0.0009] {
            assert!(!binds(Vector3::new(r, -r - past, 0.0)), "{past}");
        }
    }

    #[test]
    fn line_angle_difference_is_undirected() {
        assert!(line_angle_difference(0.1, 0.1 + PI).abs() < 1e-12);
        assert!((line_angle_difference(0.0, FRAC_PI_2) - FRAC_PI_2).abs() < 1e-12);
    }
}

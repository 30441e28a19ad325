//! What a scene holds, as plain data: movable objects (gauze, needle, block) with real sizes and
//! masses, static bodies (tray, organs, vessel), target marks, and the instrument's pose. Tasks
//! build a [`SceneSpec`]; the physics, the assets and the renderer consume it. Nothing here
//! depends on the simulator or the renderer.
//!
//! Every movable object's frame is its *grasp frame*: the origin is the grasp point (the gauze
//! and block centre, the needle's arc midpoint) and, for the needle, the local x axis is the
//! wire's tangent there. Sizes are metres, masses kilograms.

pub mod organ;

use nalgebra::{Isometry3, Vector3};

/// Table top height, metres.
pub const TABLE_TOP_Z_M: f64 = 0.675;
/// Tray pad top height, metres.
pub const TRAY_TOP_Z_M: f64 = 0.678;
/// Radius of T2-3's vessel, which lies on the tray pad: centre line 2.5 mm above the pad, clip
/// sites marked on its top.
pub const VESSEL_RADIUS_M: f64 = 0.0025;
/// Tray pad centre (x, y) and half extents (x, y), metres: the pad fills most of the
/// endoscope's view as in the reference frame.
pub const TRAY_CENTER_XY_M: [f64; 2] = [0.5225, 0.0];
pub const TRAY_HALF_EXTENTS_XY_M: [f64; 2] = [0.0775, 0.085];
/// The tray's rim around the pad: width and height above the pad top, metres.
pub const TRAY_RIM_WIDTH_M: f64 = 0.006;
pub const TRAY_RIM_HEIGHT_M: f64 = 0.008;

/// The tray's static boxes (pad, then four rim walls) as (centre, half extents), metres: one
/// description for what is drawn and what collides.
pub fn tray_boxes() -> Vec<([f64; 3], [f64; 3])> {
    let [cx, cy] = TRAY_CENTER_XY_M;
    let [hx, hy] = TRAY_HALF_EXTENTS_XY_M;
    let pad_half_z = (TRAY_TOP_Z_M - TABLE_TOP_Z_M) / 2.0;
    let rim_top = TRAY_TOP_Z_M + TRAY_RIM_HEIGHT_M;
    let rim_half_z = (rim_top - TABLE_TOP_Z_M) / 2.0;
    let rim_z = TABLE_TOP_Z_M + rim_half_z;
    let w = TRAY_RIM_WIDTH_M / 2.0;
    vec![
        ([cx, cy, TABLE_TOP_Z_M + pad_half_z], [hx, hy, pad_half_z]),
        ([cx - hx - w, cy, rim_z], [w, hy + 2.0 * w, rim_half_z]),
        ([cx + hx + w, cy, rim_z], [w, hy + 2.0 * w, rim_half_z]),
        ([cx, cy - hy - w, rim_z], [hx, w, rim_half_z]),
        ([cx, cy + hy + w, rim_z], [hx, w, rim_half_z]),
    ]
}

/// Gauze pad half extents (15 x 25 x 2.6 mm), metres.
pub const GAUZE_HALF_EXTENTS_M: [f64; 3] = [0.0075, 0.0125, 0.0013];
pub const GAUZE_MASS_KG: f64 = 0.05;
/// Needle arc radius and wire radius, metres.
pub const NEEDLE_ARC_RADIUS_M: f64 = 0.02;
pub const NEEDLE_WIRE_RADIUS_M: f64 = 0.0005;
pub const NEEDLE_MASS_KG: f64 = 0.01;
/// Number of straight capsule segments approximating the needle's half circle.
pub const NEEDLE_SEGMENTS: usize = 8;
/// Block half extents (22 x 25 x 3.25 mm), metres.
pub const BLOCK_HALF_EXTENTS_M: [f64; 3] = [0.011, 0.0125, 0.001625];
pub const BLOCK_MASS_KG: f64 = 0.01;

/// A movable object's kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ObjectKind {
    Gauze,
    Needle,
    Block,
}

impl ObjectKind {
    /// How far apart held jaws stay on this object, metres: the gauze's and the block's
    /// thickness, the needle's wire diameter.
    pub fn grip_thickness_m(self) -> f64 {
        match self {
            ObjectKind::Gauze => 2.0 * GAUZE_HALF_EXTENTS_M[2],
            ObjectKind::Needle => 2.0 * NEEDLE_WIRE_RADIUS_M,
            ObjectKind::Block => 2.0 * BLOCK_HALF_EXTENTS_M[2],
        }
    }

    /// Lower-case name used in output.
    pub fn name(self) -> &'static str {
        match self {
            ObjectKind::Gauze => "gauze",
            ObjectKind::Needle => "needle",
            ObjectKind::Block => "block",
        }
    }

    /// Mass, kilograms.
    pub fn mass_kg(self) -> f64 {
        match self {
            ObjectKind::Gauze => GAUZE_MASS_KG,
            ObjectKind::Needle => NEEDLE_MASS_KG,
            ObjectKind::Block => BLOCK_MASS_KG,
        }
    }

    /// Height of the grasp point above the surface the object rests on, metres.
    pub fn rest_height_m(self) -> f64 {
        match self {
            ObjectKind::Gauze => GAUZE_HALF_EXTENTS_M[2],
            ObjectKind::Needle => NEEDLE_WIRE_RADIUS_M,
            ObjectKind::Block => BLOCK_HALF_EXTENTS_M[2],
        }
    }

    /// Friction coefficient (gauze is high-friction cloth).
    pub fn friction(self) -> f64 {
        match self {
            ObjectKind::Gauze => 1.2,
            ObjectKind::Needle => 0.6,
            ObjectKind::Block => 0.8,
        }
    }
}

/// Needle wire centre line in the grasp frame: points on the half circle, from one end to the
/// other. The arc's centre is at (0, -R, 0) so the midpoint is the origin with tangent along x.
pub fn needle_arc_points(segments: usize) -> Vec<Vector3<f64>> {
    let n = segments.max(2);
    (0..=n)
        .map(|i| {
            let theta = std::f64::consts::PI * i as f64 / n as f64;
            Vector3::new(
                NEEDLE_ARC_RADIUS_M * theta.cos(),
                NEEDLE_ARC_RADIUS_M * theta.sin() - NEEDLE_ARC_RADIUS_M,
                0.0,
            )
        })
        .collect()
}

/// A movable object in a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct ObjectSpec {
    /// Unique name within the scene (e.g. "gauze", "needle_distractor_1").
    pub name: String,
    pub kind: ObjectKind,
    /// Initial pose of the grasp frame.
    pub world_from_object: Isometry3<f64>,
    /// A distractor: present to be ignored (drawn with its own mask ids).
    pub distractor: bool,
}

/// A static body's kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum OrganKind {
    Kidney,
    Spleen,
    Vessel,
}

impl OrganKind {
    pub fn name(self) -> &'static str {
        match self {
            OrganKind::Kidney => "kidney",
            OrganKind::Spleen => "spleen",
            OrganKind::Vessel => "vessel",
        }
    }
}

/// A static organ body; its procedural shape (see `assets::organ`) follows from the kind, the
/// semi-axes and the shape seed, for drawing and for collision alike.
#[derive(Clone, Debug, PartialEq)]
pub struct OrganSpec {
    pub kind: OrganKind,
    /// Organ frame: origin at the centre, z up. The vessel runs along its local y axis.
    pub world_from_organ: Isometry3<f64>,
    /// Semi-axes of the base shape (the vessel: x = wiggle amplitude, y = half length,
    /// z = tube radius), metres.
    pub semi_axes_m: [f64; 3],
    pub shape_seed: u64,
}

/// Colour of a mark on tissue.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MarkColour {
    Red,
    Yellow,
    Green,
    Blue,
}

impl MarkColour {
    pub fn name(self) -> &'static str {
        match self {
            MarkColour::Red => "red",
            MarkColour::Yellow => "yellow",
            MarkColour::Green => "green",
            MarkColour::Blue => "blue",
        }
    }
}

/// A mark on an organ: a bleeding spot or a clip site, drawn as a small sphere on the surface.
#[derive(Clone, Debug, PartialEq)]
pub struct MarkSpec {
    pub name: String,
    pub position_m: Vector3<f64>,
    pub radius_m: f64,
    pub colour: MarkColour,
    /// The mark the instruction refers to.
    pub target: bool,
    /// Direction of the tissue line the mark sits on (the vessel's axis at a clip site), unit,
    /// world frame; `None` on solid organs.
    pub line_direction: Option<Vector3<f64>>,
}

/// T2-3's clip band around a clip site: the tip at most this far from the vessel's axis across
/// it, metres (inside the 2.5 mm radius: the jaws close around the vessel, not beside it) ...
pub const CLIP_BAND_ACROSS_M: f64 = 0.0015;
/// ... and at most this far from the site along it, metres.
pub const CLIP_BAND_ALONG_M: f64 = 0.004;

/// Where a tip is relative to a clip site on a vessel, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClipOffset {
    /// Horizontal distance from the site along the vessel's axis.
    pub along_m: f64,
    /// Horizontal distance from the vessel's axis across it.
    pub across_m: f64,
    /// Height above the tissue the vessel lies on (the tray pad's top).
    pub above_tissue_m: f64,
    /// Height above the vessel's centre line.
    pub above_centre_line_m: f64,
}

impl ClipOffset {
    /// Whether the tip is in the clip band: between the tissue and the vessel's centre line
    /// (open jaws there straddle the vessel), within [`CLIP_BAND_ACROSS_M`] of its axis and
    /// [`CLIP_BAND_ALONG_M`] of the site.
    pub fn in_band(&self) -> bool {
        self.across_m <= CLIP_BAND_ACROSS_M
            && self.along_m <= CLIP_BAND_ALONG_M
            && self.above_tissue_m >= 0.0
            && self.above_centre_line_m <= 0.0
    }
}

impl MarkSpec {
    /// Where `tip_m` is relative to this mark, if it is a clip site on a vessel (it has a
    /// line direction; the site is on the vessel's top).
    pub fn clip_offset(&self, tip_m: &Vector3<f64>) -> Option<ClipOffset> {
        let line = self.line_direction?;
        let axis = Vector3::new(line.x, line.y, 0.0).try_normalize(1e-9)?;
        let offset = tip_m - self.position_m;
        let along = offset.x * axis.x + offset.y * axis.y;
        let across = (offset.x * axis.y - offset.y * axis.x).abs();
        Some(ClipOffset {
            along_m: along.abs(),
            across_m: across,
            above_tissue_m: tip_m.z - TRAY_TOP_Z_M,
            above_centre_line_m: offset.z + VESSEL_RADIUS_M,
        })
    }
}

/// Pose of the instrument's visible parts, from the robot's kinematics.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InstrumentPose {
    /// Origin at the wrist-pitch joint, z along the shaft away from the RCM.
    pub world_from_shaft: Isometry3<f64>,
    /// The wrist-yaw (jaw pivot) frame: the jaws turn about its z axis, close along its x axis
    /// and point along its y axis.
    pub world_from_jaw_pivot: Isometry3<f64>,
    pub jaw_angle_rad: f64,
}

/// Everything a scene holds besides the instrument, and where the instrument's tip starts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneSpec {
    pub objects: Vec<ObjectSpec>,
    pub organs: Vec<OrganSpec>,
    pub marks: Vec<MarkSpec>,
    /// Where the tip starts (pointing down, jaws open), world, metres; `None`: the
    /// simulator's configured start pose.
    pub tip_start_m: Option<Vector3<f64>>,
}

impl SceneSpec {
    /// One object of each kind on the tray (gauze at the centre, needle and block beside it),
    /// each `drop_m` above its resting height: the fixture of tests and benches.
    pub fn one_of_each(drop_m: f64) -> Self {
        let place = |name: &str, kind: ObjectKind, x: f64, y: f64| ObjectSpec {
            name: name.to_string(),
            kind,
            world_from_object: Isometry3::translation(
                x,
                y,
                TRAY_TOP_Z_M + kind.rest_height_m() + drop_m,
            ),
            distractor: false,
        };
        SceneSpec {
            objects: vec![
                place("gauze", ObjectKind::Gauze, 0.55, 0.0),
                place("needle", ObjectKind::Needle, 0.52, -0.03),
                place("block", ObjectKind::Block, 0.58, 0.03),
            ],
            ..SceneSpec::default()
        }
    }

    /// Index of the object with this name.
    pub fn object_index(&self, name: &str) -> Option<usize> {
        self.objects.iter().position(|o| o.name == name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn needle_arc_midpoint_is_origin_with_x_tangent() {
        let points = needle_arc_points(8);
        let mid = points[4];
        assert!(mid.norm() < 1e-12);
        let tangent = (points[3] - points[5]).normalize();
        assert!((tangent.x.abs() - 1.0).abs() < 1e-9);
        assert!(points.iter().all(|p| {
            ((p + Vector3::new(0.0, NEEDLE_ARC_RADIUS_M, 0.0)).norm() - NEEDLE_ARC_RADIUS_M).abs()
                < 1e-12
        }));
    }
}

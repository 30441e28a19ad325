//! Placing things in a scene: rejection sampling of object spawns against footprints, the
//! organ, mark and object builders, and the reach check of a task's target.
//!
//! A footprint is a set of points covering an object's outline seen from above; two objects
//! are clear when every pair of their points is at least [`CLEARANCE_M`] apart (plus the
//! sampling spacing as slack), and an object is on the pad when all its points are at least
//! 3 mm inside the rim.

use crate::rng::SplitMix64;
use crate::scene::organ;
use crate::scene::{
    BLOCK_HALF_EXTENTS_M, GAUZE_HALF_EXTENTS_M, MarkColour, MarkSpec, ObjectKind, ObjectSpec,
    OrganKind, OrganSpec, TRAY_CENTER_XY_M, TRAY_HALF_EXTENTS_XY_M, TRAY_TOP_Z_M,
    needle_arc_points,
};
use crate::sim::control::Workspace;
use crate::task::instance::{Range, SpawnRanges, TaskInstance};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector2, Vector3};

/// Smallest gap between two objects' footprints at spawn, metres.
pub const CLEARANCE_M: f64 = 0.004;
/// Smallest gap between a footprint and the tray's rim, metres.
const RIM_MARGIN_M: f64 = 0.003;
/// Most rejection-sampling draws per object before the spawn is declared impossible.
const MAX_DRAWS: usize = 200;

/// Why the instance's target is out of the instrument's reach, if it is: the named object's
/// grasp point and the target mark must lie within the reference workspace's x-y box.
pub(super) fn unreachable_target(instance: &TaskInstance) -> Option<String> {
    let workspace = Workspace::reference();
    let inside = |p: &Vector3<f64>| {
        (0..2).all(|axis| {
            p[axis] >= workspace.min_m[axis] + REACH_MARGIN_M
                && p[axis] <= workspace.max_m[axis] - REACH_MARGIN_M
        })
    };
    let object = instance
        .target_object
        .and_then(|i| instance.scene.objects.get(i))
        .filter(|o| !inside(&o.world_from_object.translation.vector))
        .map(|o| format!("'{}' out of reach", o.name));
    let mark = instance
        .target_mark
        .and_then(|i| instance.scene.marks.get(i))
        .filter(|m| !inside(&m.position_m))
        .map(|m| format!("'{}' out of reach", m.name));
    object.or(mark)
}

/// How far inside the workspace's x-y box a target must be, metres.
const REACH_MARGIN_M: f64 = 0.002;

/// Places objects by rejection sampling against the ones already placed.
pub(super) struct Placer<'a> {
    pub rng: &'a mut SplitMix64,
    pub placed: Vec<Vec<Vector2<f64>>>,
}

impl Placer<'_> {
    pub(super) fn xy(&mut self, x: Range, y: Range) -> [f64; 2] {
        [self.rng.uniform(x.0, x.1), self.rng.uniform(y.0, y.1)]
    }

    /// A kidney or spleen in the primary range with a red target mark on its surface in the
    /// organ-frame direction `mark.0`.
    pub(super) fn organ_with_mark(
        &mut self,
        kind: OrganKind,
        semi_axes_m: [f64; 3],
        spawn: &SpawnRanges,
        yaw_rad: f64,
        mark: (Vector3<f64>, &str),
    ) -> (OrganSpec, MarkSpec) {
        let xy = self.xy(spawn.primary_x_m, spawn.primary_y_m);
        let shape = self.rng.next_f64();
        let organ = solid_organ(kind, semi_axes_m, xy, yaw_rad, shape);
        let mark = mark_on(&organ, mark.0, mark.1, MarkColour::Red, 0.0024);
        (organ, mark)
    }

    /// An object in `range` with `yaw` (or a drawn yaw in +-90 deg when `None`).
    pub(super) fn place(
        &mut self,
        name: &str,
        kind: ObjectKind,
        range: (Range, Range),
        yaw: Option<f64>,
    ) -> Result<ObjectSpec, String> {
        for _ in 0..MAX_DRAWS {
            let [x, y] = self.xy(range.0, range.1);
            let drawn_yaw = self.rng.uniform(-90.0, 90.0).to_radians();
            let object = object(name, kind, x, y, yaw.unwrap_or(drawn_yaw));
            let points = footprint(&object);
            let clear = self.placed.iter().all(|other| {
                points.iter().all(|p| {
                    other
                        .iter()
                        .all(|q| (p - q).norm() >= CLEARANCE_M + FOOTPRINT_SPACING_M)
                })
            });
            if clear && points.iter().all(on_pad) {
                self.placed.push(points);
                return Ok(object);
            }
        }
        Err(format!(
            "no room for '{name}' clear of the others within {MAX_DRAWS} draws"
        ))
    }
}

/// Spacing of footprint sample points, metres (the clearance test adds it as slack).
const FOOTPRINT_SPACING_M: f64 = 0.0025;

/// Points covering an object's outline seen from above, world xy.
pub(super) fn footprint(object: &ObjectSpec) -> Vec<Vector2<f64>> {
    let local: Vec<Vector3<f64>> = match object.kind {
        ObjectKind::Needle => needle_arc_points(16),
        ObjectKind::Gauze | ObjectKind::Block => {
            let half = if object.kind == ObjectKind::Gauze {
                GAUZE_HALF_EXTENTS_M
            } else {
                BLOCK_HALF_EXTENTS_M
            };
            let steps = |h: f64| (2.0 * h / FOOTPRINT_SPACING_M).ceil() as usize;
            let (nx, ny) = (steps(half[0]), steps(half[1]));
            (0..=nx)
                .flat_map(|i| {
                    (0..=ny).map(move |j| {
                        Vector3::new(
                            -half[0] + 2.0 * half[0] * i as f64 / nx as f64,
                            -half[1] + 2.0 * half[1] * j as f64 / ny as f64,
                            0.0,
                        )
                    })
                })
                .collect()
        }
    };
    local
        .iter()
        .map(|p| {
            let w = object.world_from_object * Point3::from(*p);
            Vector2::new(w.x, w.y)
        })
        .collect()
}

fn on_pad(p: &Vector2<f64>) -> bool {
    let [cx, cy] = TRAY_CENTER_XY_M;
    let [hx, hy] = TRAY_HALF_EXTENTS_XY_M;
    (p.x - cx).abs() <= hx - RIM_MARGIN_M && (p.y - cy).abs() <= hy - RIM_MARGIN_M
}

/// The vessel and its three candidate clip sites (colours in a seeded order).
pub(super) fn vessel_with_sites(
    x: f64,
    y: f64,
    shape: f64,
    order: f64,
) -> (OrganSpec, Vec<MarkSpec>) {
    let radius = crate::scene::VESSEL_RADIUS_M;
    // The vessel runs towards the endoscope (along world x; its local y), so jaws closing
    // across it open left and right in the picture, where a clip across it can be seen.
    let vessel = OrganSpec {
        kind: OrganKind::Vessel,
        world_from_organ: Isometry3::from_parts(
            Translation3::new(x, y, TRAY_TOP_Z_M + radius),
            UnitQuaternion::from_euler_angles(0.0, 0.0, -std::f64::consts::FRAC_PI_2),
        ),
        semi_axes_m: [0.005, VESSEL_HALF_LENGTH_M, radius],
        shape_seed: (shape * u64::MAX as f64) as u64,
    };
    const ORDERS: [[MarkColour; 3]; 6] = [
        [MarkColour::Red, MarkColour::Yellow, MarkColour::Green],
        [MarkColour::Yellow, MarkColour::Red, MarkColour::Green],
        [MarkColour::Yellow, MarkColour::Green, MarkColour::Red],
        [MarkColour::Red, MarkColour::Blue, MarkColour::Yellow],
        [MarkColour::Blue, MarkColour::Red, MarkColour::Yellow],
        [MarkColour::Green, MarkColour::Blue, MarkColour::Red],
    ];
    let colours = ORDERS[((order * 6.0) as usize).min(5)];
    let (path, _) = organ::vessel_path(&vessel, 11);
    let marks = [3usize, 5, 7]
        .into_iter()
        .zip(colours)
        .map(|(site, colour)| {
            let local = path[site] + Vector3::new(0.0, 0.0, radius);
            let tangent = (path[site + 1] - path[site - 1]).normalize();
            MarkSpec {
                name: format!("{}_clip_site", colour.name()),
                position_m: (vessel.world_from_organ * Point3::from(local)).coords,
                // 2 mm (the reference's 1.2 mm spheres are 2-3 px dots at 224 px): a colour
                // the instruction names must be visible.
                radius_m: CLIP_SITE_RADIUS_M,
                colour,
                target: false,
                line_direction: Some(vessel.world_from_organ.rotation * tangent),
            }
        })
        .collect();
    (vessel, marks)
}

/// Half the length of T2-3's vessel segment, metres: it lies along x on the pad (the pad's far
/// rim at x 0.60), its sites 18 mm apart.
pub(super) const VESSEL_HALF_LENGTH_M: f64 = 0.045;

/// Radius of T2-3's clip-site marks, metres.
pub(super) const CLIP_SITE_RADIUS_M: f64 = 0.002;

/// Points every ~2.5 mm along an organ's base outline, world xy (for clearance tests).
pub(super) fn organ_outline(organ: &OrganSpec) -> Vec<Vector2<f64>> {
    let [a, b, _] = organ.semi_axes_m;
    let n = 160;
    (0..n)
        .map(|i| {
            let t = std::f64::consts::TAU * f64::from(i) / f64::from(n);
            let p = organ.world_from_organ * Point3::new(a * t.cos(), b * t.sin(), 0.0);
            Vector2::new(p.x, p.y)
        })
        .collect()
}

/// A kidney or spleen resting on the tray (its flattened base on the pad) at `xy`.
fn solid_organ(
    kind: OrganKind,
    semi_axes_m: [f64; 3],
    xy: [f64; 2],
    yaw_rad: f64,
    shape: f64,
) -> OrganSpec {
    let z = TRAY_TOP_Z_M + organ::BASE_FRACTION * semi_axes_m[2];
    OrganSpec {
        kind,
        world_from_organ: Isometry3::from_parts(
            Translation3::new(xy[0], xy[1], z),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        ),
        semi_axes_m,
        shape_seed: (shape * u64::MAX as f64) as u64,
    }
}

/// A target mark on an organ's surface in the organ-frame direction `direction`.
fn mark_on(
    organ_spec: &OrganSpec,
    direction: Vector3<f64>,
    name: &str,
    colour: MarkColour,
    radius_m: f64,
) -> MarkSpec {
    let local = organ::surface_point(organ_spec, direction);
    MarkSpec {
        name: name.to_string(),
        position_m: (organ_spec.world_from_organ * Point3::from(local)).coords,
        radius_m,
        colour,
        target: true,
        line_direction: None,
    }
}

fn object(name: &str, kind: ObjectKind, x: f64, y: f64, yaw_rad: f64) -> ObjectSpec {
    ObjectSpec {
        name: name.to_string(),
        kind,
        distractor: false,
        world_from_object: Isometry3::from_parts(
            Translation3::new(x, y, TRAY_TOP_Z_M + kind.rest_height_m()),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
        ),
    }
}

//! The rapier3d world: the only module that sees rapier's (glam, f32) types. Everything else
//! speaks nalgebra f64 poses; conversion happens here, in one place.
//!
//! Tuning for millimetre-sized light objects (gauze 2.6 mm thick, needle wire 0.5 mm):
//! - `length_unit = 0.01`: rapier's tolerances scale with it, so the allowed penetration is
//!   0.05 mm and the contact prediction distance 0.2 mm instead of 5 mm and 20 mm.
//! - 8 solver iterations, contacts stiffened to 240 Hz (480 Hz against static bodies), CCD on
//!   every movable object, 240 Hz steps.
//! - Resting bodies fall asleep, so a settled object stays exactly still.
//!
//! The instrument is one kinematic body (shaft and wrist as a capsule that ends at the wrist);
//! the jaws carry no collider: grasping is the binding rule, and a jaw collider pressing a 2.6 mm
//! gauze into the tray would only inject energy.

use crate::scene::organ;
use crate::scene::{
    NEEDLE_SEGMENTS, NEEDLE_WIRE_RADIUS_M, ObjectKind, OrganKind, OrganSpec, SceneSpec,
    TABLE_TOP_Z_M, needle_arc_points, tray_boxes,
};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rapier3d::prelude::{
    ColliderBuilder, ColliderHandle, PhysicsWorld, Pose, RigidBodyBuilder, RigidBodyHandle,
    RigidBodyType, Rotation, SharedShape, Vector,
};

/// Shaft radius of an 8 mm instrument, metres.
pub const SHAFT_RADIUS_M: f64 = 0.004;
/// Length of shaft modelled above the wrist, metres.
pub const SHAFT_LENGTH_M: f64 = 0.12;

/// Distance within which a held object counts as touching the tray, metres.
const TOUCH_M: f64 = 0.0002;

/// Parameters of the physics world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhysicsParams {
    pub dt_secs: f64,
    pub gravity_m_per_s2: f64,
    pub length_unit_m: f64,
    pub solver_iterations: usize,
    /// Natural frequency of contacts between movable bodies, Hz (twice that against static
    /// bodies). Penetration under load scales as g / (2 pi f)^2: rapier's 30 Hz default sinks a
    /// 50 g gauze 0.3 mm into a 10 g block, and through it; 240 Hz keeps it to micrometres.
    pub contact_frequency_hz: f64,
}

impl Default for PhysicsParams {
    fn default() -> Self {
        PhysicsParams {
            dt_secs: 1.0 / 240.0,
            gravity_m_per_s2: 9.81,
            length_unit_m: 0.01,
            solver_iterations: 8,
            contact_frequency_hz: 240.0,
        }
    }
}

fn to_pose(pose: &Isometry3<f64>) -> Pose {
    let t = pose.translation.vector;
    let q = pose.rotation.quaternion();
    Pose::from_parts(
        Vector::new(t.x as f32, t.y as f32, t.z as f32),
        Rotation::from_xyzw(q.i as f32, q.j as f32, q.k as f32, q.w as f32).normalize(),
    )
}

fn from_pose(pose: &Pose) -> Isometry3<f64> {
    let t = pose.translation;
    let q = pose.rotation;
    Isometry3::from_parts(
        Translation3::new(f64::from(t.x), f64::from(t.y), f64::from(t.z)),
        UnitQuaternion::from_quaternion(Quaternion::new(
            f64::from(q.w),
            f64::from(q.x),
            f64::from(q.y),
            f64::from(q.z),
        )),
    )
}

fn vec32(v: Vector3<f64>) -> Vector {
    Vector::new(v.x as f32, v.y as f32, v.z as f32)
}

struct ObjectBody {
    body: RigidBodyHandle,
    collider: ColliderHandle,
}

/// The physics world of one scene.
pub struct PhysicsScene {
    world: PhysicsWorld,
    tray: ColliderHandle,
    /// Every fixed collider (table, tray pad and rim, organs): what a held object must not enter.
    statics: Vec<ColliderHandle>,
    objects: Vec<ObjectBody>,
    instrument: RigidBodyHandle,
}

/// The organ's collision shape from the same geometry that is drawn: the convex hull of a solid
/// organ's surface, a chain of capsules along the vessel.
fn organ_collider(organ: &OrganSpec) -> ColliderBuilder {
    if organ.kind == OrganKind::Vessel {
        let (path, radius) = organ::vessel_path(organ, 16);
        let shapes = path
            .windows(2)
            .map(|pair| {
                (
                    Pose::IDENTITY,
                    SharedShape::capsule(vec32(pair[0]), vec32(pair[1]), radius as f32),
                )
            })
            .collect();
        return ColliderBuilder::compound(shapes);
    }
    let points: Vec<Vector> = organ::surface_samples(organ)
        .iter()
        .map(|p| Vector::new(p.x, p.y, p.z))
        .collect();
    ColliderBuilder::convex_hull(&points).unwrap_or_else(|| {
        let [a, b, c] = organ.semi_axes_m.map(|v| v as f32);
        ColliderBuilder::cuboid(a, b, c)
    })
}

fn object_collider(kind: ObjectKind) -> ColliderBuilder {
    let builder = match kind {
        ObjectKind::Gauze => {
            let h = crate::scene::GAUZE_HALF_EXTENTS_M;
            ColliderBuilder::cuboid(h[0] as f32, h[1] as f32, h[2] as f32)
        }
        ObjectKind::Block => {
            let h = crate::scene::BLOCK_HALF_EXTENTS_M;
            ColliderBuilder::cuboid(h[0] as f32, h[1] as f32, h[2] as f32)
        }
        ObjectKind::Needle => {
            let points = needle_arc_points(NEEDLE_SEGMENTS);
            let shapes = points
                .windows(2)
                .map(|pair| {
                    let shape = SharedShape::capsule(
                        vec32(pair[0]),
                        vec32(pair[1]),
                        NEEDLE_WIRE_RADIUS_M as f32,
                    );
                    (Pose::IDENTITY, shape)
                })
                .collect();
            ColliderBuilder::compound(shapes)
        }
    };
    builder
        .mass(kind.mass_kg() as f32)
        .friction(kind.friction() as f32)
        .restitution(0.0)
}

impl PhysicsScene {
    /// Builds the world: table, tray pad, organs (static), objects (dynamic), instrument
    /// (kinematic, placed at `world_from_shaft`).
    pub fn build(
        spec: &SceneSpec,
        params: &PhysicsParams,
        world_from_shaft: &Isometry3<f64>,
    ) -> Self {
        let mut world = PhysicsWorld::new();
        world.gravity = Vector::new(0.0, 0.0, -(params.gravity_m_per_s2 as f32));
        world.integration_parameters.dt = params.dt_secs as f32;
        world.integration_parameters.length_unit = params.length_unit_m as f32;
        world.integration_parameters.num_solver_iterations = params.solver_iterations.max(1);
        let frequency = params.contact_frequency_hz as f32;
        world
            .integration_parameters
            .contact_softness
            .natural_frequency = frequency;
        world
            .integration_parameters
            .static_contact_softness
            .natural_frequency = 2.0 * frequency;

        let table_half_z = 0.01f32;
        let mut statics = Vec::new();
        let (_, table) = world.insert(
            RigidBodyBuilder::fixed().translation(Vector::new(
                0.55,
                0.0,
                TABLE_TOP_Z_M as f32 - table_half_z,
            )),
            ColliderBuilder::cuboid(0.4, 0.4, table_half_z).friction(0.8),
        );
        statics.push(table);
        // The tray: pad first (its handle answers "on the tray"), then the rim walls.
        let mut tray = None;
        for (centre, half) in tray_boxes() {
            let (_, collider) = world.insert(
                RigidBodyBuilder::fixed().translation(vec32(Vector3::from(centre))),
                ColliderBuilder::cuboid(half[0] as f32, half[1] as f32, half[2] as f32)
                    .friction(1.0),
            );
            statics.push(collider);
            tray.get_or_insert(collider);
        }
        let tray = tray.unwrap_or(ColliderHandle::invalid());
        for organ in &spec.organs {
            let (_, collider) = world.insert(
                RigidBodyBuilder::fixed().pose(to_pose(&organ.world_from_organ)),
                organ_collider(organ).friction(1.0),
            );
            statics.push(collider);
        }
        let objects = spec
            .objects
            .iter()
            .map(|object| {
                let (body, collider) = world.insert(
                    RigidBodyBuilder::dynamic()
                        .pose(to_pose(&object.world_from_object))
                        .ccd_enabled(true)
                        .angular_damping(0.5),
                    object_collider(object.kind),
                );
                ObjectBody { body, collider }
            })
            .collect();
        let (instrument, _) = world.insert(
            RigidBodyBuilder::kinematic_position_based().pose(to_pose(world_from_shaft)),
            ColliderBuilder::capsule_from_endpoints(
                Vector::ZERO,
                Vector::new(0.0, 0.0, -(SHAFT_LENGTH_M as f32)),
                SHAFT_RADIUS_M as f32,
            )
            .friction(0.5),
        );
        PhysicsScene {
            world,
            tray,
            statics,
            objects,
            instrument,
        }
    }

    /// Number of movable objects.
    pub fn object_count(&self) -> usize {
        self.objects.len()
    }

    /// Current pose of object `index`'s grasp frame.
    pub fn object_pose(&self, index: usize) -> Option<Isometry3<f64>> {
        let object = self.objects.get(index)?;
        self.world
            .bodies
            .get(object.body)
            .map(|body| from_pose(body.position()))
    }

    /// Makes object `index` kinematic (bound to the jaws) or dynamic again (released, at rest).
    pub fn set_object_bound(&mut self, index: usize, bound: bool) {
        let Some(object) = self.objects.get(index) else {
            return;
        };
        let Some(body) = self.world.bodies.get_mut(object.body) else {
            return;
        };
        if bound {
            body.set_body_type(RigidBodyType::KinematicPositionBased, true);
        } else {
            body.set_body_type(RigidBodyType::Dynamic, true);
            body.set_linvel(Vector::ZERO, true);
            body.set_angvel(Vector::ZERO, true);
        }
    }

    /// Sets where a bound object must be at the end of the next substep.
    pub fn move_bound_object(&mut self, index: usize, world_from_object: &Isometry3<f64>) {
        let Some(object) = self.objects.get(index) else {
            return;
        };
        if let Some(body) = self.world.bodies.get_mut(object.body) {
            body.set_next_kinematic_position(to_pose(world_from_object));
        }
    }

    /// Sets where the instrument's shaft frame must be at the end of the next substep (origin at
    /// the wrist, z axis pointing from the RCM toward the wrist).
    pub fn move_instrument(&mut self, world_from_shaft: &Isometry3<f64>) {
        if let Some(body) = self.world.bodies.get_mut(self.instrument) {
            body.set_next_kinematic_position(to_pose(world_from_shaft));
        }
    }

    /// Advances the world by one substep.
    pub fn step(&mut self) {
        self.world.step();
    }

    fn touching(&self, a: ColliderHandle, b: ColliderHandle) -> bool {
        self.world
            .narrow_phase
            .contact_pair(a, b)
            .is_some_and(|pair| pair.has_any_active_contact())
    }

    /// Signed distance between object `index`, were it at `world_from_object`, and the static
    /// collider `handle`, metres (negative: penetration; `None`: farther than `within_m`).
    fn static_distance(
        &self,
        index: usize,
        world_from_object: &Isometry3<f64>,
        handle: ColliderHandle,
        within_m: f64,
    ) -> Option<f64> {
        let object = self
            .world
            .colliders
            .get(self.objects.get(index)?.collider)?;
        let fixed = self.world.colliders.get(handle)?;
        let contact = rapier3d::parry::query::contact(
            &to_pose(world_from_object),
            object.shape(),
            fixed.position(),
            fixed.shape(),
            within_m as f32,
        )
        .ok()??;
        Some(f64::from(contact.dist))
    }

    /// How deep object `index`, were it at `world_from_object`, would reach into static
    /// geometry (tray, organs, table), metres; 0 when clear.
    pub fn static_penetration(&self, index: usize, world_from_object: &Isometry3<f64>) -> f64 {
        self.statics
            .iter()
            .filter_map(|&h| self.static_distance(index, world_from_object, h, 0.0))
            .fold(0.0, |deepest, d| deepest.max(-d))
    }

    /// Whether object `index` is in contact with the tray pad. A held (kinematic) object has no
    /// contacts with fixed bodies in the engine, so it is tested geometrically (within 0.2 mm).
    pub fn object_on_tray(&self, index: usize) -> bool {
        let Some(object) = self.objects.get(index) else {
            return false;
        };
        let kinematic = self
            .world
            .bodies
            .get(object.body)
            .is_some_and(|b| b.is_kinematic());
        if kinematic {
            let Some(pose) = self.object_pose(index) else {
                return false;
            };
            return self
                .static_distance(index, &pose, self.tray, TOUCH_M)
                .is_some_and(|d| d <= TOUCH_M);
        }
        self.touching(object.collider, self.tray)
    }

    /// Whether objects `a` and `b` are in contact.
    pub fn objects_touching(&self, a: usize, b: usize) -> bool {
        match (self.objects.get(a), self.objects.get(b)) {
            (Some(a), Some(b)) => self.touching(a.collider, b.collider),
            _ => false,
        }
    }

    /// Whether object `index` is asleep (at rest).
    pub fn object_sleeping(&self, index: usize) -> bool {
        self.objects
            .get(index)
            .and_then(|o| self.world.bodies.get(o.body))
            .is_some_and(|body| body.is_sleeping())
    }

    /// How fast object `index` moves, metres per second (0 asleep or unknown).
    pub fn object_speed_m_per_s(&self, index: usize) -> f64 {
        self.objects
            .get(index)
            .and_then(|o| self.world.bodies.get(o.body))
            .map_or(0.0, |body| f64::from(body.linvel().length()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_conversion_round_trips_to_f32_precision() {
        let pose = Isometry3::from_parts(
            Translation3::new(0.55, -0.01, 0.68),
            UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let back = from_pose(&to_pose(&pose));
        assert!((back.translation.vector - pose.translation.vector).norm() < 1e-6);
        assert!(back.rotation.angle_to(&pose.rotation) < 1e-6);
    }
}

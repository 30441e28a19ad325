//! The simulator: a PSM moving kinematically through IK, a rapier scene, and the grasp binding.
//!
//! One control step (0.2 s at 5 Hz):
//! 1. the command becomes a clipped tip target, and IK gives the target joints (clamped);
//! 2. the jaw command is applied: a close command while the jaws are open binds the nearest
//!    object that satisfies the [`GraspRule`] at the current tip pose; an open command releases
//!    a bound object (it becomes dynamic again, at rest);
//! 3. over the physics substeps the joints move linearly to the target, the jaw angle moves at
//!    a rate that completes a full open/close in one control step, the instrument collider and
//!    any bound object follow the forward kinematics, and rapier steps.

use crate::scene::{InstrumentPose, ObjectKind, OrganKind, SceneSpec, organ};
use crate::sim::control::{
    JawCommand, NativeCommand, PhysicalAction, Timing, TipTarget, Workspace, native_target,
    physical_target,
};
use crate::sim::grasp::GraspRule;
use crate::sim::history::{Moment, TrialHistory};
use crate::sim::observation::{ObjectState, Observation};
use crate::sim::physics::{PhysicsParams, PhysicsScene};
use crate::sim::psm::{
    IkReport, JAW_CLOSED_RAD, JAW_OPEN_RAD, Joints, Psm, euler_xyz, jaw_angle_for_gap,
    pointing_down,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// A displacement larger than this from the spawn pose counts as "moved", metres.
pub const MOVED_THRESHOLD_M: f64 = 0.002;
/// How deep a held object may reach into static geometry, metres.
pub const HELD_PENETRATION_M: f64 = 0.0002;
/// Jaw angle at or below which the jaws count as closed, radians.
pub const JAWS_CLOSED_RAD: f64 = JAW_CLOSED_RAD + 0.02;

/// Everything that configures a simulator besides the scene.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimConfig {
    pub timing: Timing,
    pub workspace: Workspace,
    pub grasp: GraspRule,
    pub psm: Psm,
    /// Start pose of the tip (jaws open).
    pub world_from_start_tip: Isometry3<f64>,
    pub physics: PhysicsParams,
}

impl Default for SimConfig {
    fn default() -> Self {
        let timing = Timing::default();
        SimConfig {
            timing,
            workspace: Workspace::reference(),
            grasp: GraspRule::default(),
            psm: Psm::reference(),
            world_from_start_tip: Isometry3::from_parts(
                Translation3::new(0.50, 0.05, 0.7202),
                pointing_down(std::f64::consts::FRAC_PI_2),
            ),
            physics: PhysicsParams {
                dt_secs: timing.physics_dt_secs(),
                ..PhysicsParams::default()
            },
        }
    }
}

/// An object held by the jaws.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Binding {
    object: usize,
    tip_from_object: Isometry3<f64>,
}

/// What one control step did besides moving.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepReport {
    pub ik: IkReport,
    /// The workspace clipped the requested position.
    pub clipped: bool,
    /// Index of the object bound during this step.
    pub bound: Option<usize>,
    /// Index of the object released during this step.
    pub released: Option<usize>,
    /// The tip's descent was stopped because the held object met static geometry.
    pub descent_stopped: bool,
}

/// A headless, deterministic simulation of one scene.
pub struct Simulator {
    config: SimConfig,
    scene: SceneSpec,
    physics: PhysicsScene,
    joints: Joints,
    jaw_angle_rad: f64,
    jaw_command: JawCommand,
    binding: Option<Binding>,
    step_index: u64,
    last_report: StepReport,
    /// What the trial remembers (penetration, the vessel, releases).
    history: TrialHistory,
}

/// Pose of the instrument's shaft frame: origin at the wrist-pitch joint, z from the RCM outward.
fn world_from_shaft(psm: &Psm, joints: &Joints) -> Isometry3<f64> {
    let frames = psm.chain(joints);
    let wrist = frames.rcm_from_link[4].translation;
    psm.world_from_rcm * Isometry3::from_parts(wrist, frames.rcm_from_link[3].rotation)
}

impl Simulator {
    /// A simulator at the configured start pose with jaws open.
    pub fn new(config: SimConfig, scene: SceneSpec) -> Self {
        let mut world_from_start_tip = config.world_from_start_tip;
        if let Some(start) = scene.tip_start_m {
            world_from_start_tip.translation.vector = start;
        }
        let (joints, ik) = config.psm.inverse(&world_from_start_tip, 0.0);
        let physics = PhysicsScene::build(
            &scene,
            &config.physics,
            &world_from_shaft(&config.psm, &joints),
        );
        let objects = scene.objects.len();
        let mut sim = Simulator {
            config,
            scene,
            physics,
            joints,
            jaw_angle_rad: JAW_OPEN_RAD,
            jaw_command: JawCommand::Open,
            binding: None,
            step_index: 0,
            last_report: StepReport {
                ik,
                ..StepReport::default()
            },
            history: TrialHistory::new(objects),
        };
        sim.record_history();
        sim
    }

    /// Records the tip's penetration and its passage through the vessel in the trial's history.
    fn record_history(&mut self) {
        let tip = self.world_from_tip();
        self.history.record(&Moment {
            step_index: self.step_index,
            tip_m: tip.translation.vector,
            tip_yaw_rad: euler_xyz(&tip.rotation)[2],
            jaw_angle_rad: self.jaw_angle_rad,
            jaws_closed: self.jaw_angle_rad <= JAWS_CLOSED_RAD,
            scene: &self.scene,
        });
    }

    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    pub fn scene(&self) -> &SceneSpec {
        &self.scene
    }

    /// Current joint positions.
    pub fn joints(&self) -> Joints {
        self.joints
    }

    /// Current reported tip pose in the world.
    pub fn world_from_tip(&self) -> Isometry3<f64> {
        self.config.psm.forward(&self.joints)
    }

    /// The PSM's frames in the world: the remote centre of motion (`psm_rcm`) and each DH link
    /// frame (`psm_link_1` ..).
    pub fn link_frames(&self) -> Vec<(String, Isometry3<f64>)> {
        let psm = &self.config.psm;
        let frames = psm.chain(&self.joints);
        let mut out = vec![("psm_rcm".to_string(), psm.world_from_rcm)];
        out.extend(
            frames
                .rcm_from_link
                .iter()
                .enumerate()
                .map(|(i, link)| (format!("psm_link_{}", i + 1), psm.world_from_rcm * link)),
        );
        out
    }

    /// Pose of the instrument's visible parts (for drawing).
    pub fn instrument_pose(&self) -> InstrumentPose {
        let psm = &self.config.psm;
        let frames = psm.chain(&self.joints);
        InstrumentPose {
            world_from_shaft: world_from_shaft(psm, &self.joints),
            world_from_jaw_pivot: psm.world_from_rcm * frames.rcm_from_link[5],
            jaw_angle_rad: self.jaw_angle_rad,
        }
    }

    /// Current poses of the movable objects' grasp frames, in scene order.
    pub fn object_poses(&self) -> Vec<Isometry3<f64>> {
        (0..self.scene.objects.len())
            .map(|i| {
                self.physics
                    .object_pose(i)
                    .unwrap_or(self.scene.objects[i].world_from_object)
            })
            .collect()
    }

    /// Where a ligation clip sits for every closing of the jaws on the vessel (a clip applier
    /// leaves one each time it closes): on the vessel's axis under the tip, its x axis the
    /// direction the jaws closed along (the tip's yaw then), z up.
    pub fn world_from_clips(&self) -> Vec<Isometry3<f64>> {
        let Some(vessel) = (self.scene.organs.iter()).find(|o| o.kind == OrganKind::Vessel) else {
            return Vec::new();
        };
        (self.history.vessel_closures.iter())
            .map(|closure| {
                let tip = Vector3::from(closure.tip_m);
                let section = organ::vessel_section(vessel, &tip);
                Isometry3::from_parts(
                    Translation3::from(tip - Vector3::z() * section.above_axis_m),
                    UnitQuaternion::from_euler_angles(
                        0.0,
                        0.0,
                        closure.jaw_line_rad - std::f64::consts::FRAC_PI_2,
                    ),
                )
            })
            .collect()
    }

    /// Index of the bound object, if any.
    pub fn bound_object(&self) -> Option<usize> {
        self.binding.map(|b| b.object)
    }

    /// Applies one native command `[dx, dy, dz, dyaw, jaw]`.
    pub fn step_native(&mut self, command: &NativeCommand) -> StepReport {
        let tip = self.world_from_tip();
        let yaw = euler_xyz(&tip.rotation)[2];
        let target = native_target(&self.config.workspace, tip.translation.vector, yaw, command);
        self.step_to(target)
    }

    /// Applies one physical 7-D action (as recorded in a dataset).
    pub fn step_physical(&mut self, action: &PhysicalAction) -> StepReport {
        let tip = self.world_from_tip();
        let target = physical_target(
            &self.config.workspace,
            tip.translation.vector,
            euler_xyz(&tip.rotation),
            action,
        );
        self.step_to(target)
    }

    fn step_to(&mut self, mut target: TipTarget) -> StepReport {
        let mut report = StepReport {
            clipped: target.clipped,
            ..StepReport::default()
        };
        self.apply_jaw_command(target.jaw, &mut report);
        report.descent_stopped = self.stop_held_object_at_static_geometry(&mut target);
        let (target_joints, ik) = self
            .config
            .psm
            .inverse(&target.world_from_tip, self.joints[3]);
        report.ik = ik;

        let substeps = self.config.timing.substeps.max(1);
        // Closing jaws stop on a held object, so the jaw angle says what they hold.
        let jaw_goal = match (self.jaw_command, self.binding) {
            (JawCommand::Open, _) => JAW_OPEN_RAD,
            (JawCommand::Close, Some(binding)) => {
                let kind = self.scene.objects[binding.object].kind;
                jaw_angle_for_gap(kind.grip_thickness_m())
                    .min(self.jaw_angle_rad.max(JAW_CLOSED_RAD))
            }
            (JawCommand::Close, None) => JAW_CLOSED_RAD,
        };
        let jaw_rate = (JAW_OPEN_RAD - JAW_CLOSED_RAD) / f64::from(substeps);
        let start = self.joints;
        for substep in 1..=substeps {
            let t = f64::from(substep) / f64::from(substeps);
            let mut joints = start;
            for (q, (a, b)) in joints
                .iter_mut()
                .zip(start.iter().zip(target_joints.iter()))
            {
                *q = a + (b - a) * t;
            }
            if substep == substeps {
                joints = target_joints;
            }
            self.joints = joints;
            let delta = (jaw_goal - self.jaw_angle_rad).clamp(-jaw_rate, jaw_rate);
            self.jaw_angle_rad += delta;
            self.physics
                .move_instrument(&world_from_shaft(&self.config.psm, &self.joints));
            if let Some(binding) = self.binding {
                let pose = self.world_from_tip() * binding.tip_from_object;
                self.physics.move_bound_object(binding.object, &pose);
            }
            self.physics.step();
        }
        self.step_index += 1;
        self.last_report = report;
        self.record_history();
        report
    }

    /// A held object must not be pushed into static geometry (the tray, organs): raises the
    /// tip's target until the object, carried rigidly, reaches no deeper than
    /// [`HELD_PENETRATION_M`] (the jaws' descent stops where the object meets the surface).
    /// Returns whether it did.
    fn stop_held_object_at_static_geometry(&self, target: &mut TipTarget) -> bool {
        let Some(binding) = self.binding else {
            return false;
        };
        let mut stopped = false;
        for _ in 0..4 {
            let pose = target.world_from_tip * binding.tip_from_object;
            let depth = self.physics.static_penetration(binding.object, &pose);
            if depth <= HELD_PENETRATION_M {
                break;
            }
            target.world_from_tip.translation.vector.z += depth - 0.5 * HELD_PENETRATION_M;
            stopped = true;
        }
        stopped
    }

    fn apply_jaw_command(&mut self, command: JawCommand, report: &mut StepReport) {
        let jaws_were_open = self.jaw_angle_rad > JAW_CLOSED_RAD + 1e-9;
        match command {
            JawCommand::Close if self.binding.is_none() && jaws_were_open => {
                if let Some(object) = self.grasp_candidate() {
                    let world_from_object = self.physics.object_pose(object).unwrap_or_default();
                    let tip_from_object = self.world_from_tip().inverse() * world_from_object;
                    self.physics.set_object_bound(object, true);
                    self.history.bound(object, self.step_index);
                    self.binding = Some(Binding {
                        object,
                        tip_from_object,
                    });
                    report.bound = Some(object);
                }
            }
            JawCommand::Open => {
                if let Some(binding) = self.binding.take() {
                    let poses = self.object_poses();
                    self.history
                        .released(binding.object, self.step_index, poses);
                    self.physics.set_object_bound(binding.object, false);
                    report.released = Some(binding.object);
                }
            }
            JawCommand::Close => {}
        }
        self.jaw_command = command;
    }

    /// The object the jaws would bind now: of those satisfying the rule, the one whose surface
    /// is nearest the tip.
    pub fn grasp_candidate(&self) -> Option<usize> {
        let tip = self.world_from_tip();
        let tip_position = tip.translation.vector;
        let yaw = euler_xyz(&tip.rotation)[2];
        (0..self.physics.object_count())
            .filter_map(|i| {
                let pose = self.physics.object_pose(i)?;
                let kind = self.scene.objects.get(i)?.kind;
                self.config
                    .grasp
                    .binding_gap(&tip_position, yaw, kind, &pose)
                    .map(|gap| (gap, i))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, i)| i)
    }

    /// The current observation.
    pub fn observation(&self) -> Observation {
        let tip = self.world_from_tip();
        let block = self
            .scene
            .objects
            .iter()
            .position(|o| o.kind == ObjectKind::Block);
        let objects = self
            .scene
            .objects
            .iter()
            .enumerate()
            .map(|(i, spec)| {
                let pose = self
                    .physics
                    .object_pose(i)
                    .unwrap_or(spec.world_from_object);
                let displacement_m =
                    (pose.translation.vector - spec.world_from_object.translation.vector).norm();
                ObjectState {
                    name: spec.name.clone(),
                    kind: spec.kind,
                    world_from_object: pose,
                    bound: self.bound_object() == Some(i),
                    ever_bound: self.history.ever_bound(i),
                    // The last release, unless held again since.
                    released_at: (self.bound_object() != Some(i))
                        .then(|| self.history.releases.get(i)?.last())
                        .flatten()
                        .map(|r| r.world_from_object),
                    on_tray: self.physics.object_on_tray(i),
                    on_block: block.is_some_and(|b| b != i && self.physics.objects_touching(i, b)),
                    displacement_m,
                    moved: displacement_m > MOVED_THRESHOLD_M,
                    at_rest: self.physics.object_sleeping(i),
                    speed_m_per_s: self.physics.object_speed_m_per_s(i),
                }
            })
            .collect();
        Observation {
            step_index: self.step_index,
            time_secs: self.step_index as f64 * self.config.timing.control_dt_secs(),
            tip_position_m: tip.translation.vector.into(),
            tip_euler_xyz_rad: euler_xyz(&tip.rotation),
            jaw_angle_rad: self.jaw_angle_rad,
            jaw_command: self.jaw_command,
            joint_positions: self.joints,
            objects,
            bound_object: self.bound_object(),
            ik: self.last_report.ik,
            history: self.history.clone(),
            descent_stopped: self.last_report.descent_stopped,
        }
    }

    /// Moves the tip directly (test and setup helper): IK to `world_from_tip` with physics
    /// stepping as in a control step, jaws unchanged.
    pub fn teleport_tip(&mut self, world_from_tip: &Isometry3<f64>) -> IkReport {
        let (joints, ik) = self.config.psm.inverse(world_from_tip, self.joints[3]);
        self.joints = joints;
        self.physics
            .move_instrument(&world_from_shaft(&self.config.psm, &self.joints));
        self.record_history();
        ik
    }

    /// A pose `height_m` above object `index`'s grasp point, pointing down with `yaw_rad`.
    pub fn above_object(
        &self,
        index: usize,
        height_m: f64,
        yaw_rad: f64,
    ) -> Option<Isometry3<f64>> {
        let pose = self.physics.object_pose(index)?;
        Some(Isometry3::from_parts(
            Translation3::from(pose.translation.vector + Vector3::new(0.0, 0.0, height_m)),
            UnitQuaternion::from(pointing_down(yaw_rad)),
        ))
    }
}

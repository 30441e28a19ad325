//! Seeing the simulation: renders a [`Simulator`]'s current state through the procedural assets
//! and the CPU renderer, and lays out contact sheets. This bridge knows the simulator's public
//! state (object poses, instrument pose), never rapier; the renderer below it knows neither.

use crate::assets::{Appearance, SceneAssets};
use crate::episode::CameraInfo;
use crate::render::image::{depth_visualisation, mask_visualisation};
use crate::render::{Camera, Frame, RenderOptions, Renderer};
use crate::scene::InstrumentPose;
use crate::sim::{SimConfig, Simulator};
use crate::task::TaskId;

/// Renders the current state of `sim` as seen by `camera`.
pub fn render_simulator(
    assets: &SceneAssets,
    renderer: &mut Renderer,
    camera: &Camera,
    sim: &Simulator,
) -> Frame {
    let instances = assets.instances(
        &sim.object_poses(),
        &sim.instrument_pose(),
        &sim.world_from_clips(),
    );
    renderer.render(camera, &instances)
}

/// [`render_simulator`] with a renderer that keeps the scene's static layer from frame to
/// frame (the same pixels, drawn faster): for a renderer serving one scene, e.g. an episode's.
pub fn render_simulator_over_static(
    assets: &SceneAssets,
    renderer: &mut Renderer,
    camera: &Camera,
    sim: &Simulator,
) -> Frame {
    let instances = assets.instances(
        &sim.object_poses(),
        &sim.instrument_pose(),
        &sim.world_from_clips(),
    );
    renderer.render_over_static(camera, &instances, assets.static_count())
}

/// An RGB image assembled from tiles.
#[derive(Clone, Debug, PartialEq)]
pub struct Sheet {
    pub width_px: u32,
    pub height_px: u32,
    pub rgb: Vec<u8>,
}

impl Sheet {
    fn new(width_px: u32, height_px: u32) -> Self {
        Sheet {
            width_px,
            height_px,
            rgb: vec![255; (width_px * height_px * 3) as usize],
        }
    }

    fn paste(&mut self, x0: u32, y0: u32, width: u32, rgb: &[u8]) {
        let height = rgb.len() as u32 / 3 / width.max(1);
        for y in 0..height.min(self.height_px.saturating_sub(y0)) {
            let row = &rgb[(y * width * 3) as usize..((y + 1) * width * 3) as usize];
            let start = (((y0 + y) * self.width_px + x0) * 3) as usize;
            let end = (start + row.len()).min(self.rgb.len());
            self.rgb[start..end].copy_from_slice(&row[..end - start]);
        }
    }
}

/// The start frame of every task in `tasks` (one column each): RGB, depth and mask rows.
pub fn contact_sheet(
    tasks: &[TaskId],
    seed: u64,
    options: RenderOptions,
    appearance: Appearance,
) -> Result<Sheet, crate::task::SpawnError> {
    let camera = Camera::endoscope();
    let (w, h) = (camera.width_px, camera.height_px);
    let gap = 4;
    let columns = tasks.len() as u32;
    let mut sheet = Sheet::new(columns * (w + gap) - gap, 3 * (h + gap) - gap);
    let mut renderer = Renderer::new(RenderOptions {
        lighting: appearance.lighting(options.lighting),
        ..options
    });
    for (column, task) in tasks.iter().enumerate() {
        let scene = task.scene(seed)?;
        let sim = Simulator::new(SimConfig::default(), scene.clone());
        let assets = SceneAssets::new(&scene, seed, appearance);
        let frame = render_simulator(&assets, &mut renderer, &camera, &sim);
        let x = column as u32 * (w + gap);
        sheet.paste(x, 0, w, &frame.rgb);
        sheet.paste(x, h + gap, w, &depth_visualisation(&frame));
        sheet.paste(x, 2 * (h + gap), w, &mask_visualisation(&frame));
    }
    Ok(sheet)
}

/// The camera as datasets record it (row-major 4 x 4 `world_from_camera`).
pub fn camera_info(camera: &Camera) -> CameraInfo {
    let m = camera.world_from_camera.to_homogeneous();
    let mut world_from_camera = [[0.0; 4]; 4];
    for (r, row) in world_from_camera.iter_mut().enumerate() {
        for (c, v) in row.iter_mut().enumerate() {
            *v = m[(r, c)];
        }
    }
    CameraInfo {
        width_px: camera.width_px,
        height_px: camera.height_px,
        fx_px: camera.fx_px,
        fy_px: camera.fy_px,
        cx_px: camera.cx_px,
        cy_px: camera.cy_px,
        near_m: camera.near_m,
        far_m: camera.far_m,
        world_from_camera,
    }
}

/// The mask id table of rendered masks: (id, class name) in id order.
pub fn mask_ids() -> Vec<(u8, String)> {
    crate::assets::MaskClass::ALL
        .iter()
        .map(|(class, name)| (class.id(), name.to_string()))
        .collect()
}

fn named_pose(name: &str, pose: &nalgebra::Isometry3<f64>) -> crate::episode::NamedPose {
    let q = pose.rotation.coords;
    crate::episode::NamedPose {
        name: name.into(),
        position_m: pose.translation.vector.into(),
        rotation_xyzw: [q[0], q[1], q[2], q[3]],
    }
}

/// The robot's frames for viewers: the PSM's remote centre of motion and link frames, the
/// instrument's shaft and its jaw pivot.
pub fn robot_frames(sim: &Simulator) -> Vec<crate::episode::NamedPose> {
    let mut frames: Vec<crate::episode::NamedPose> = sim
        .link_frames()
        .iter()
        .map(|(name, pose)| named_pose(name, pose))
        .collect();
    let instrument: InstrumentPose = sim.instrument_pose();
    frames.push(named_pose("psm_shaft", &instrument.world_from_shaft));
    frames.push(named_pose(
        "psm_jaw_pivot",
        &instrument.world_from_jaw_pivot,
    ));
    frames
}

/// [`scene_meshes`] of `scene` before its first step, drawn as `collect` draws episode `seed`.
pub fn scene_meshes_at_start(
    scene: &crate::scene::SceneSpec,
    seed: u64,
    randomize_appearance: bool,
) -> Vec<crate::episode::SceneMesh> {
    let appearance = if randomize_appearance {
        Appearance::randomized(seed)
    } else {
        Appearance::default()
    };
    let assets = SceneAssets::new(scene, seed, appearance);
    scene_meshes(
        &assets,
        &Simulator::new(SimConfig::default(), scene.clone()),
    )
}

/// The scene's meshes as data for viewers (the MCAP recorder's SceneUpdate), as they stand in
/// `sim` now: static parts in the world frame, movable objects in their `object_<i>` frames, the
/// instrument's shaft in `psm_shaft` and its wrist and jaws in `psm_jaw_pivot`.
pub fn scene_meshes(assets: &SceneAssets, sim: &Simulator) -> Vec<crate::episode::SceneMesh> {
    let object_poses = sim.object_poses();
    let instrument = sim.instrument_pose();
    // Without the clips, which come last: the parts a viewer places by frame.
    let instances = assets.instances(&object_poses, &instrument, &[]);
    let statics = instances.len() - object_poses.len() - 4;
    instances
        .iter()
        .enumerate()
        .map(|(i, instance)| {
            let (name, frame, frame_pose) = if i < statics {
                (
                    format!("static_{i}"),
                    "world".to_string(),
                    nalgebra::Isometry3::identity(),
                )
            } else if i < statics + object_poses.len() {
                let k = i - statics;
                let name = sim
                    .scene()
                    .objects
                    .get(k)
                    .map_or(format!("object_{k}"), |o| o.name.clone());
                (name, format!("object_{k}"), object_poses[k])
            } else if i == statics + object_poses.len() {
                (
                    "instrument_shaft".into(),
                    "psm_shaft".into(),
                    instrument.world_from_shaft,
                )
            } else {
                (
                    format!("instrument_{}", i - statics - object_poses.len()),
                    "psm_jaw_pivot".into(),
                    instrument.world_from_jaw_pivot,
                )
            };
            let frame_from_mesh = frame_pose.inverse() * instance.world_from_mesh;
            crate::episode::SceneMesh {
                name,
                frame,
                rgb: instance.material.albedo,
                positions_m: instance
                    .mesh
                    .positions
                    .iter()
                    .map(|p| {
                        let q = frame_from_mesh
                            * nalgebra::Point3::new(
                                f64::from(p[0]),
                                f64::from(p[1]),
                                f64::from(p[2]),
                            );
                        [q.x as f32, q.y as f32, q.z as f32]
                    })
                    .collect(),
                triangles: instance.mesh.triangles.clone(),
            }
        })
        .collect()
}

/// What a dataset (or an evaluation's recording) of this simulator states once: the camera,
/// the features (`features` picks depth, mask and object poses), the control rate, the robot,
/// the mask ids and the tool tip's workspace; `collection` says how the episodes were made.
pub fn dataset_info(
    camera: &Camera,
    features: crate::episode::FeatureSet,
    collection: crate::export::collection::Collection,
) -> crate::export::DatasetInfo {
    let camera = camera_info(camera);
    let workspace = crate::sim::control::Workspace::reference();
    crate::export::DatasetInfo {
        fps: crate::sim::Timing::default().control_hz,
        robot_type: "dvrk_psm".into(),
        features: crate::episode::standard_features(
            camera.height_px as usize,
            camera.width_px as usize,
            features,
        ),
        camera,
        mask_ids: mask_ids(),
        collection: Some(collection),
        generator: format!("surgvla {}", env!("CARGO_PKG_VERSION")),
        tip_workspace: Some(crate::episode::Aabb {
            min_m: workspace.min_m,
            max_m: workspace.max_m,
        }),
        input: None,
        provenance: Vec::new(),
        splits: Vec::new(),
        notes: Vec::new(),
        omitted: Vec::new(),
        episode_fields: Vec::new(),
        carried_keys: Default::default(),
        history: Vec::new(),
    }
}
